"""select and Database: the command's results and files, byte for byte."""

import json

import numpy as np
import pytest

import placedb
from conftest import placedb as run_placedb

FRAMES = 120


@pytest.mark.parametrize("solver", placedb.SOLVERS)
def test_every_solver_writes_what_the_command_writes(seven_scenes, tmp_path, solver):
    cli = tmp_path / "cli"
    run_placedb("select", seven_scenes, "--max-frames", FRAMES, "--solver", solver, "-q", "-o", cli)
    db = placedb.select(seven_scenes, max_frames=FRAMES, solver=solver)
    py = tmp_path / "py"
    db.write(py)
    for name in ("database.csv", "labels.csv", "extension.bin", "topview.png"):
        assert (py / name).read_bytes() == (cli / name).read_bytes(), name
    frames = [int(line.split(",")[0]) for line in (cli / "database.csv").read_text().splitlines()[1:]]
    np.testing.assert_array_equal(db.frames, frames)
    assert db.labels.shape == (FRAMES,)
    assert set(db.labels) == set(db.frames)
    # The metrics are metrics.json's, but for the times of the run.
    on_disk = json.loads((cli / "metrics.json").read_text())
    timed = {"total_s", "peak_rss_mb", "voxelize_s", "graph_s", "solve_s", "read_s", "core_s"}
    assert set(db.metrics) == set(on_disk)
    for key, value in on_disk.items():
        if key not in timed and not key.endswith("_s"):
            assert db.metrics[key] == value, key


def test_a_sequence_read_once_selects_as_its_path_does(seven_scenes):
    seq = placedb.read_sequence(seven_scenes, max_frames=FRAMES, stride=2)
    by_seq = placedb.select(seq, mu=0.5, solver="greedy")
    by_path = placedb.select(seven_scenes, max_frames=FRAMES, stride=2, mu=0.5, solver="greedy")
    np.testing.assert_array_equal(by_seq.frames, by_path.frames)
    np.testing.assert_array_equal(by_seq.labels, by_path.labels)
    # Reading options belong to read_sequence once the sequence is read.
    with pytest.raises(ValueError, match="the sequence is read already"):
        placedb.select(seq, max_frames=10)


def test_frames_from_memory_select_as_the_sequence_does(seven_scenes):
    seq = placedb.read_sequence(seven_scenes, max_frames=60)
    depth = np.stack([seq.depth(i) for i in range(len(seq))])
    stacked = placedb.select(depth, poses=seq.poses, intrinsics=seq.intrinsics, timestamps=seq.timestamps)
    tuples = placedb.select(
        ((depth[i], seq.poses[i], seq.timestamps[i]) for i in range(len(seq))),
        intrinsics=seq.intrinsics,
    )
    read = placedb.select(seq)
    np.testing.assert_array_equal(stacked.frames, read.frames)
    np.testing.assert_array_equal(tuples.labels, read.labels)


def test_the_demo_scan(tmp_path):
    db = placedb.select(demo=True, demo_frames=100, mu=0.5)
    assert 0 < len(db) < 100
    assert db.metrics["frames"] == 100


def test_parameters_are_refused_in_the_command_lines_words(seven_scenes, tmp_path):
    with pytest.raises(ValueError, match="mu must be from 0 to below 1"):
        placedb.select(seven_scenes, mu=1.5)
    with pytest.raises(ValueError, match="mu must be from 0 to below 1"):
        placedb.select(seven_scenes, mu=-0.1)
    with pytest.raises(ValueError, match="invalid value 'fastest' for '--solver"):
        placedb.select(seven_scenes, solver="fastest")
    with pytest.raises(ValueError, match="--window 40: the ram256k profile holds from 1 to 32 frames"):
        placedb.select(seven_scenes, profile="ram256k", window=40)
    with pytest.raises(ValueError, match="demo=True or a sequence|a sequence .* or demo=True"):
        placedb.select()
    with pytest.raises(TypeError, match="source must be a sequence's path.*got int"):
        placedb.select(123)
    with pytest.raises(FileNotFoundError, match="missing-scan"):
        placedb.select(tmp_path / "missing-scan")


def test_a_refused_output_changes_nothing(seven_scenes, tmp_path):
    db = placedb.select(seven_scenes, max_frames=30)
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    with pytest.raises(ValueError, match="mine"):
        db.write(mine)
    assert (mine / "notes.txt").read_text() == "keep me"
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]


def test_exports_are_the_commands(seven_scenes, tmp_path):
    cli = tmp_path / "cli"
    run_placedb(
        "select", seven_scenes, "--max-frames", 40, "-q", "-o", cli / "db",
        "--pairs", cli / "pairs.txt", "--colmap", cli / "colmap",
    )
    db = placedb.select(seven_scenes, max_frames=40)
    lines = db.write(tmp_path / "py" / "db", pairs=tmp_path / "py" / "pairs.txt", colmap=tmp_path / "py" / "colmap")
    assert len(lines) == 2
    assert (tmp_path / "py" / "pairs.txt").read_bytes() == (cli / "pairs.txt").read_bytes()
    for name in ("cameras.txt", "images.txt", "points3D.txt"):
        a = (tmp_path / "py" / "colmap" / "sparse" / "0" / name).read_bytes()
        assert a == (cli / "colmap" / "sparse" / "0" / name).read_bytes(), name


def test_a_later_session_extends_as_the_command_does(seven_scenes, tmp_path):
    cli_a, cli_ab = tmp_path / "cli-a", tmp_path / "cli-ab"
    run_placedb("select", seven_scenes, "--max-frames", 50, "--mu", 0.9, "-q", "-o", cli_a)
    run_placedb("select", seven_scenes, "--max-frames", 80, "--mu", 0.9, "--extend", cli_a, "-q", "-o", cli_ab)
    py_a, py_ab = tmp_path / "py-a", tmp_path / "py-ab"
    placedb.select(seven_scenes, max_frames=50, mu=0.9).write(py_a)
    db = placedb.select(seven_scenes, max_frames=80, mu=0.9, extend=py_a)
    assert db.labels.shape == (130,)
    db.write(py_ab)
    for name in ("database.csv", "labels.csv", "extension.bin"):
        assert (py_ab / name).read_bytes() == (cli_ab / name).read_bytes(), name
    with pytest.raises(ValueError, match="is the directory being extended"):
        db.write(py_a)
    with pytest.raises(ValueError, match="without dataset, colmap"):
        db.write(tmp_path / "x", pairs=tmp_path / "pairs.txt")
    with pytest.raises(ValueError, match="no extension.bin here"):
        placedb.select(seven_scenes, max_frames=10, extend=tmp_path)
