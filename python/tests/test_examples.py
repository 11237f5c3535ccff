"""The examples run as a user runs them."""

import subprocess
import sys
from pathlib import Path

from conftest import SEVEN_SCENES

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def run(script, *args, cwd):
    out = subprocess.run([sys.executable, str(EXAMPLES / script), *map(str, args)], capture_output=True, text=True, cwd=cwd)
    assert out.returncode == 0, out.stdout + out.stderr
    return out.stdout


def test_select_and_export(tmp_path):
    said = run("select_and_export.py", SEVEN_SCENES, tmp_path / "out", cwd=tmp_path)
    assert "database frames" in said
    for f in ("database/database.csv", "pairs.txt", "colmap/sparse/0/images.txt", "topview-matplotlib.png"):
        assert (tmp_path / "out" / f).stat().st_size > 0, f


def test_live_node(tmp_path):
    said = run("live_node.py", SEVEN_SCENES, "local:ram512k", 20, cwd=tmp_path)
    assert "frames pushed" in said
