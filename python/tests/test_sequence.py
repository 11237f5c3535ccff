"""read_sequence and Sequence.from_arrays: what the command line reads, as arrays."""

import numpy as np
import pytest

import placedb


def test_reads_the_sample_as_the_command_does(seven_scenes):
    seq = placedb.read_sequence(seven_scenes, max_frames=20)
    assert len(seq) == 20
    assert seq.format == "7scenes"
    assert seq.intrinsics == (585.0, 585.0, 320.0, 240.0)
    assert (seq.width, seq.height) == (640, 480)
    assert seq.poses.shape == (20, 4, 4) and seq.poses.dtype == np.float64
    np.testing.assert_allclose(seq.poses[:, 3], np.tile([0, 0, 0, 1.0], (20, 1)))
    # Each frame's pose file, as 7-Scenes writes it (camera to world); the
    # reader keeps its rotation as a unit quaternion, so the matrix comes
    # back orthonormal (the file's is within 1e-4 of one).
    first = np.loadtxt(seven_scenes / "frame-000000.pose.txt")
    np.testing.assert_allclose(seq.poses[0], first, atol=1e-4)
    r = seq.poses[0, :3, :3]
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    # 7-Scenes numbers its frames instead of stamping them: the numbers
    # are the times, as labels.csv writes them.
    np.testing.assert_array_equal(seq.timestamps[:3], [0.0, 1.0, 2.0])


def test_depth_is_read_lazily_as_recorded_or_in_metres(seven_scenes):
    seq = placedb.read_sequence(seven_scenes, max_frames=3)
    raw = seq.depth(2)
    assert raw.shape == (480, 640) and raw.dtype == np.uint16
    metres = seq.depth(-1, metres=True)
    assert metres.dtype == np.float32
    np.testing.assert_allclose(metres, raw / 1000.0, rtol=1e-6)
    with pytest.raises(IndexError, match="frame 3 is not in the sequence's 3 frames"):
        seq.depth(3)


def test_options_are_refused_in_the_command_lines_words(seven_scenes):
    with pytest.raises(ValueError, match="depth scale must be from"):
        placedb.read_sequence(seven_scenes, depth_scale=0)
    with pytest.raises(ValueError, match="expected four numbers fx,fy,cx,cy"):
        placedb.read_sequence(seven_scenes, intrinsics=(1, 2, 3))
    with pytest.raises(ValueError, match="invalid value 'fancy' for '--format"):
        placedb.read_sequence(seven_scenes, format="fancy")


def test_a_missing_sequence_is_a_file_not_found_naming_it(tmp_path):
    missing = tmp_path / "no-such-scan"
    with pytest.raises(FileNotFoundError, match="no-such-scan"):
        placedb.read_sequence(missing)


def test_frames_from_arrays_are_checked_and_kept(seven_scenes):
    seq = placedb.read_sequence(seven_scenes, max_frames=4)
    depth = np.stack([seq.depth(i) for i in range(4)])
    mem = placedb.Sequence.from_arrays(depth, seq.poses, seq.intrinsics, timestamps=seq.timestamps)
    assert len(mem) == 4 and mem.format == "arrays"
    np.testing.assert_array_equal(mem.depth(3), depth[3])
    np.testing.assert_allclose(mem.poses, seq.poses, atol=1e-6)
    # Float metres are taken at the depth scale.
    mm = placedb.Sequence.from_arrays(depth / 1000.0, seq.poses, seq.intrinsics)
    np.testing.assert_array_equal(mm.depth(1), depth[1])
    bad = seq.poses.copy()
    bad[2, :3, :3] *= 2.0
    with pytest.raises(ValueError, match="frame 2: bad pose"):
        placedb.Sequence.from_arrays(depth, bad, seq.intrinsics)
    with pytest.raises(ValueError, match="poses must be 4 x 4"):
        placedb.Sequence.from_arrays(depth, seq.poses[:3], seq.intrinsics)
    with pytest.raises(ValueError, match="depth must be uint16"):
        placedb.Sequence.from_arrays(depth.astype(np.int32), seq.poses, seq.intrinsics)
    with pytest.raises(ValueError, match="focal lengths must be > 0"):
        placedb.Sequence.from_arrays(depth, seq.poses, (0, 585, 320, 240))
