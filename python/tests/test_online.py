"""Selector (the device core in this process) and Device: frame by frame,
the decisions and files of `placedb select --solver online`."""

import os
import re
import subprocess

import numpy as np
import pytest

import placedb
from conftest import BIN
from conftest import placedb as run_placedb

FRAMES = 80


def push_all(selector, seq):
    decided = []
    for i in range(len(seq)):
        decided += selector.push(seq.depth(i), seq.poses[i], seq.timestamps[i])
    rest, db = selector.finish()
    return decided + rest, db


@pytest.mark.parametrize("profile,window", [("ram512k", 32), ("ram256k", 8)])
def test_pushing_a_sequence_decides_as_select_online(seven_scenes, tmp_path, profile, window):
    seq = placedb.read_sequence(seven_scenes, max_frames=FRAMES)
    sel = placedb.Selector(seq.intrinsics, seq.width, seq.height, mu=0.3, profile=profile, window=window)
    decided, db = push_all(sel, seq)
    # Every frame decided once, in the window's order.
    assert sorted(d.frame for d in decided) == list(range(FRAMES))
    offline = placedb.select(seq, profile=profile, window=window)
    np.testing.assert_array_equal(db.frames, offline.frames)
    np.testing.assert_array_equal(db.labels, offline.labels)
    labels = {d.frame: d.label for d in decided}
    assert [labels[i] for i in range(FRAMES)] == list(offline.labels)
    taken = sorted(d.frame for d in decided if d.kind == "taken")
    assert taken == list(offline.frames)
    # Its files are the command's: the labels byte for byte; the poses as
    # the core took them from 4 x 4 matrices instead of the reader's
    # quaternions (the same rotation to float precision).
    cli = tmp_path / "cli"
    run_placedb("select", seven_scenes, "--max-frames", FRAMES, "--profile", profile, "--window", window, "-q", "-o", cli)
    db.write(tmp_path / "py")
    assert (tmp_path / "py" / "labels.csv").read_bytes() == (cli / "labels.csv").read_bytes()
    ours = np.loadtxt(tmp_path / "py" / "database.csv", delimiter=",", skiprows=1, ndmin=2)
    theirs = np.loadtxt(cli / "database.csv", delimiter=",", skiprows=1, ndmin=2)
    np.testing.assert_array_equal(ours[:, :2], theirs[:, :2])
    np.testing.assert_allclose(ours, theirs, atol=1e-6)


def test_selector_options_are_refused_in_the_command_lines_words():
    k = (585.0, 585.0, 320.0, 240.0)
    with pytest.raises(ValueError, match="mu must be from 0 to below 1"):
        placedb.Selector(k, 640, 480, mu=1.0)
    with pytest.raises(ValueError, match="--window 40: the ram256k profile holds from 1 to 32 frames"):
        placedb.Selector(k, 640, 480, profile="ram256k", window=40)
    with pytest.raises(ValueError, match="invalid value 'ram9g'"):
        placedb.Selector(k, 640, 480, profile="ram9g")


def test_a_wrong_frame_is_refused_and_the_scan_goes_on(seven_scenes):
    seq = placedb.read_sequence(seven_scenes, max_frames=3)
    sel = placedb.Selector(seq.intrinsics, seq.width, seq.height)
    with pytest.raises(ValueError, match="depth must be 480 x 640"):
        sel.push(np.zeros((240, 320), np.uint16), seq.poses[0], 0.0)
    with pytest.raises(ValueError, match="pose must be 4 x 4"):
        sel.push(seq.depth(0), np.eye(3), 0.0)
    with pytest.raises(ValueError, match="pose"):
        sel.push(seq.depth(0), np.eye(4) * 2, 0.0)
    for i in range(3):
        sel.push(seq.depth(i), seq.poses[i], seq.timestamps[i])
    _, db = sel.finish()
    assert len(db.labels) == 3


def test_a_device_on_the_local_port_is_the_client_library(seven_scenes, tmp_path):
    seq = placedb.read_sequence(seven_scenes, max_frames=20)
    dev = placedb.Device("local:ram512k")
    before = dev.configure(seq.intrinsics, seq.width, seq.height, stride=4)
    assert before["frames_seen"] == 0
    for i in range(len(seq)):
        while dev.busy():
            pass
        dev.push(seq.depth(i), seq.poses[i], seq.timestamps[i])
    status = dev.finish()
    assert status["frames_seen"] == 20
    db = dev.export()
    offline = placedb.select(seven_scenes, max_frames=20, stride=4)
    np.testing.assert_array_equal(db.frames, offline.frames)
    db.write(tmp_path / "out")
    assert (tmp_path / "out" / "labels.csv").exists()
    with pytest.raises(ValueError, match="without the sequence's images"):
        db.write(tmp_path / "out2", colmap=tmp_path / "colmap")


def test_a_device_of_another_profile_is_refused_then_the_right_one_goes_on(seven_scenes):
    seq = placedb.read_sequence(seven_scenes, max_frames=2)
    dev = placedb.Device("local:ram256k")
    with pytest.raises(Exception, match="ram512k"):
        dev.configure(seq.intrinsics, seq.width, seq.height, profile="ram512k")
    dev.configure(seq.intrinsics, seq.width, seq.height, window=8, profile="ram256k")
    dev.push(seq.depth(0), seq.poses[0], seq.timestamps[0])
    assert dev.finish()["frames_seen"] == 1


def test_a_port_that_is_not_there_is_an_os_error():
    with pytest.raises(OSError, match="no-such-tty"):
        placedb.Device("/dev/no-such-tty")


@pytest.fixture
def qemu_board():
    """`placedb device --qemu` in the background: its port."""
    if "PLACEDB_QEMU_FIRMWARE" not in os.environ:
        pytest.skip("needs the QEMU firmware (tests/python_package.rs builds it)")
    board = subprocess.Popen([BIN, "device", "--qemu"], stdout=subprocess.PIPE, text=True)
    try:
        port = None
        for line in board.stdout:
            found = re.search(r"on port (tcp:\S+)", line)
            if found:
                port = found.group(1)
                break
        assert port, "placedb device --qemu printed no port"
        yield port
    finally:
        board.terminate()
        board.wait(timeout=30)


def test_the_client_library_on_the_emulated_board(seven_scenes, qemu_board, tmp_path):
    seq = placedb.read_sequence(seven_scenes, max_frames=12)
    dev = placedb.Device(qemu_board, reply_timeout=120)
    dev.configure(seq.intrinsics, seq.width, seq.height, stride=8, window=8)
    decided = []
    for i in range(len(seq)):
        decided += dev.push(seq.depth(i), seq.poses[i], seq.timestamps[i])
    assert dev.finish()["frames_seen"] == 12
    decided += dev.decisions()
    db = dev.export()
    # The board decides as the host's replay of its core (profile ram512k).
    offline = placedb.select(seven_scenes, max_frames=12, stride=8, window=8)
    np.testing.assert_array_equal(db.frames, offline.frames)
    np.testing.assert_array_equal(db.labels, offline.labels)
    assert sorted(d.frame for d in decided) == list(range(12))
    db.write(tmp_path / "board")
    assert (tmp_path / "board" / "labels.csv").read_text().count("\n") == 13
    # A second client while this one holds the board is refused in words.
    with pytest.raises(OSError, match="(?i)busy|another"):
        placedb.Device(qemu_board, reply_timeout=5).status()
