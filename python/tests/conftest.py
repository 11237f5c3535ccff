"""What the tests share: the `placedb` binary to compare with, the sample
data of ../shared/data, and running the command."""

import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(os.environ.get("PLACEDB_DATA", ROOT.parent / "shared" / "data"))
SEVEN_SCENES = DATA / "7scenes-1000"
BIN = os.environ.get("PLACEDB_BIN", str(ROOT / "target" / "checked" / "placedb"))


def placedb(*args: str) -> subprocess.CompletedProcess:
    """Runs the `placedb` command; fails the test when it fails."""
    out = subprocess.run([BIN, *map(str, args)], capture_output=True, text=True)
    assert out.returncode == 0, f"placedb {' '.join(map(str, args))}: {out.stderr}"
    return out


@pytest.fixture
def seven_scenes() -> Path:
    return SEVEN_SCENES
