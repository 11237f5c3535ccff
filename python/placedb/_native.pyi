# Types of the extension module placedb._native (python/src/); users call the
# typed API of placedb/__init__.py, which wraps it.
from typing import Any, Optional, Sequence as Seq, Tuple

import numpy as np

SKETCH_MARGIN: float

class Sequence:
    argv: list[str]
    name: str
    format: str
    intrinsics: Tuple[float, float, float, float]
    width: int
    height: int
    depth_scale: float
    frames_skipped: int
    timestamps: np.ndarray
    poses: np.ndarray
    def __len__(self) -> int: ...
    def depth(self, i: int, metres: bool = False) -> np.ndarray: ...

class Database:
    frames: np.ndarray
    labels: np.ndarray
    metrics_json: str
    def write(
        self,
        out: str,
        dataset: Optional[str] = None,
        colmap: Optional[str] = None,
        vpr_eval: Optional[str] = None,
        pairs: Optional[str] = None,
    ) -> list[str]: ...

class Device:
    def __init__(self, port: str, reply_timeout: float = 60.0, new_scan: bool = False) -> None: ...
    def configure(
        self,
        intrinsics: Tuple[float, float, float, float],
        width: int,
        height: int,
        depth_scale: float,
        depth_range: Tuple[float, float],
        stride: int,
        voxel: float,
        mu: float,
        window: int,
        sketch_margin: float,
        profile: Optional[str] = None,
    ) -> str: ...
    def push(self, depth: np.ndarray, pose: np.ndarray, timestamp: float) -> list[Tuple[int, str, Optional[int]]]: ...
    def busy(self) -> bool: ...
    def take_decisions(self) -> list[Tuple[int, str, Optional[int]]]: ...
    def status_json(self) -> str: ...
    def finish_json(self) -> str: ...
    def export(self) -> Database: ...
    def export_to(self, out: str) -> None: ...

def read_sequence(argv: Seq[str]) -> Sequence: ...
def sequence_from_arrays(
    depth: np.ndarray,
    poses: np.ndarray,
    intrinsics: Tuple[float, float, float, float],
    depth_scale: float,
    timestamps: Optional[np.ndarray] = None,
    name: str = "arrays",
) -> Sequence: ...
def select(argv: Seq[str], sequence: Optional[Sequence] = None) -> Database: ...
def check_select(argv: Seq[str]) -> None: ...
