"""A live robot node, shaped as a ROS 2 node's depth callback but needing no
ROS: frames arrive at the recorded rate from a "camera" thread; the callback
hands each to the selector (or a board) and skips it while that is busy, as a
node must not queue frames behind a slow consumer.

    python live_node.py [SEQUENCE] [PORT] [SPEEDUP]

PORT: "local:ram512k" (the device core in this process, the default), a
board ("/dev/ttyACM0") or an emulator ("tcp:127.0.0.1:PORT" from `placedb
device`). SPEEDUP replays faster than recorded (default 10).
"""

import sys
import threading
import time
from pathlib import Path

import placedb

here = Path(__file__).resolve().parent
seq_path = Path(sys.argv[1]) if len(sys.argv) > 1 else here.parents[1] / "shared" / "data" / "7scenes-1000"
port = sys.argv[2] if len(sys.argv) > 2 else "local:ram512k"
speedup = float(sys.argv[3]) if len(sys.argv) > 3 else 10.0

seq = placedb.read_sequence(seq_path, max_frames=200)
device = placedb.Device(port, new_scan=True)
device.configure(seq.intrinsics, seq.width, seq.height, stride=4)
lock = threading.Lock()
pushed, skipped, decided = [], [], []


def on_depth(depth, pose, stamp, index):
    """The depth callback: never blocks the camera behind the selector."""
    if not lock.acquire(blocking=False):
        skipped.append(index)  # the previous frame is still being pushed
        return
    try:
        if device.busy():
            skipped.append(index)
            return
        decided.extend(device.push(depth, pose, stamp))
        pushed.append(index)
    finally:
        lock.release()


def camera():
    """Frames at the recorded rate (times SPEEDUP), each on its own thread
    as a ROS executor with a callback group would run them."""
    t0, s0 = time.monotonic(), seq.timestamps[0]
    workers = []
    for i in range(len(seq)):
        due = t0 + (seq.timestamps[i] - s0) / speedup
        time.sleep(max(0.0, due - time.monotonic()))
        w = threading.Thread(target=on_depth, args=(seq.depth(i), seq.poses[i], seq.timestamps[i], i))
        w.start()
        workers.append(w)
    for w in workers:
        w.join()


camera()
with lock:
    device.finish()
    decided.extend(device.decisions())
    db = device.export()
print(f"{len(pushed)} frames pushed, {len(skipped)} skipped while busy, "
      f"{len(db)} database frames, {sum(d.kind == 'taken' for d in decided)} taken decisions")
assert len(pushed) + len(skipped) == len(seq) and len(pushed) > 0
assert sorted(d.frame for d in decided) == list(range(len(pushed)))
