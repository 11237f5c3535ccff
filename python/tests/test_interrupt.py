"""Long calls release the GIL and stop at Ctrl-C."""

import os
import signal
import subprocess
import sys
import textwrap
import time


def test_ctrl_c_interrupts_a_long_select():
    script = textwrap.dedent(
        """
        import sys, placedb
        print("started", flush=True)
        try:
            placedb.select(demo=True, demo_frames=20000, solver="greedy")
        except KeyboardInterrupt:
            print("interrupted", flush=True)
            sys.exit(3)
        print("finished", flush=True)
        """
    )
    child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert child.stdout.readline().strip() == "started"
    time.sleep(1.5)
    child.send_signal(signal.SIGINT)
    began = time.monotonic()
    out, _ = child.communicate(timeout=60)
    assert child.returncode == 3, out
    assert "interrupted" in out
    # Not a wall-clock assertion on speed: the 20,000-frame scan takes
    # minutes; an interrupt that waited for it would be far past this.
    assert time.monotonic() - began < 30


def test_other_threads_run_while_placedb_works():
    import threading

    import placedb

    ticks = []
    stop = threading.Event()

    def tick():
        while not stop.is_set():
            ticks.append(1)
            time.sleep(0.01)

    t = threading.Thread(target=tick)
    t.start()
    try:
        placedb.select(demo=True, demo_frames=400)
    finally:
        stop.set()
        t.join()
    assert len(ticks) > 5


def test_ctrl_c_after_a_write_raises_keyboard_interrupt(tmp_path):
    # Writing outputs must not take Python's Ctrl-C over: the command's
    # remove-the-partials-and-exit handler is the command's alone.
    script = textwrap.dedent(
        f"""
        import os, signal, sys, time, placedb
        placedb.select(demo=True, demo_frames=60).write({str(tmp_path / "out")!r})
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5)
        except KeyboardInterrupt:
            print("interrupted", flush=True)
            sys.exit(3)
        print("not interrupted", flush=True)
        """
    )
    child = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert child.returncode == 3, (child.returncode, child.stdout, child.stderr)
    assert (tmp_path / "out" / "database.csv").is_file()
