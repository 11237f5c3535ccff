"""placedb: select a compact visual-place-recognition database from an RGB-D scan.

Each depth frame is back-projected with its pose and voxelized (0.3 m voxels);
two frames overlap when the IoU of their voxel sets is above ``mu``; the
database is a dominating set of that overlap graph: every frame is in it or
overlaps a frame in it. This package is the ``placedb`` command line's own
code, called in-process: the same readers, solvers, device core and writers,
so ``select(...).write(out)`` writes the files ``placedb select -o out`` does.

- :func:`read_sequence` opens a recorded sequence (TUM RGB-D, 7-Scenes,
  ScanNet, the reference layout, ROS 2 and ROS 1 bags);
  :meth:`Sequence.from_arrays` takes frames from numpy arrays.
- :func:`select` runs a solver and returns a :class:`Database`.
- :class:`Selector` is the device core frame by frame, in this process;
  :class:`Device` the client of a board or emulator.

Bad parameters raise ``ValueError`` in the command line's words, files
``OSError`` (``FileNotFoundError``, ...) naming the path.
"""

from __future__ import annotations

import json
import os
from typing import TYPE_CHECKING, Any, Iterable, NamedTuple, Optional, Sequence as Seq, Tuple, Union

from . import _native

if TYPE_CHECKING:
    import numpy as np
# numpy is imported where arrays are made (the functions below, and the
# native module on its first array): a script that only selects and writes
# starts without its 0.1 s import.

__all__ = [
    "Database",
    "Decision",
    "Device",
    "Selector",
    "Sequence",
    "read_sequence",
    "select",
]

PathLike = Union[str, "os.PathLike[str]"]
Intrinsics = Tuple[float, float, float, float]

#: The solvers and baselines of ``select`` (``placedb select --solver``).
SOLVERS = ("online", "in-order", "greedy", "exact", "every-nth", "distance", "cube")


def _flags(**options: Any) -> list:
    """Keyword arguments as ``placedb select`` flags (``None`` and ``False``
    left out), given as ``--flag=value`` so a negative number reaches the
    command's own range check."""
    argv = []
    for name, value in options.items():
        if value is None or value is False:
            continue
        flag = "--" + name.replace("_", "-")
        if value is True:
            argv.append(flag)
        elif isinstance(value, (tuple, list)):
            argv.append(flag + "=" + ",".join(str(v) for v in value))
        elif isinstance(value, os.PathLike):
            argv.append(flag + "=" + os.fspath(value))
        else:
            argv.append(f"{flag}={value}")
    return argv


class Sequence:
    """Depth frames with their camera-to-world poses.

    Poses, times and the camera are read at once; depth images are decoded
    on demand by :meth:`depth`. Made by :func:`read_sequence` or
    :meth:`from_arrays`.
    """

    def __init__(self, native: Any) -> None:
        self._native = native

    @classmethod
    def from_arrays(
        cls,
        depth: Union[np.ndarray, Iterable[np.ndarray]],
        poses: Union[np.ndarray, Iterable[np.ndarray]],
        intrinsics: Intrinsics,
        *,
        depth_scale: float = 1000.0,
        timestamps: Optional[Union[np.ndarray, Seq[float]]] = None,
        name: str = "arrays",
    ) -> "Sequence":
        """Frames from memory.

        ``depth``: N x H x W, uint16 in ``depth_scale`` units a metre (1000:
        millimetres; 0 = no measurement), or float metres (converted to
        uint16 at ``depth_scale``; NaN = no measurement). ``poses``: N x 4 x 4
        camera-to-world matrices (the camera looks along +z, x right, y
        down). ``intrinsics``: (fx, fy, cx, cy) in pixels. ``timestamps``: N
        seconds (default: 30 frames a second). A uint16 C-ordered stack is
        copied once.
        """
        import numpy as np

        depth = _depth_stack(depth, depth_scale)
        poses = np.asarray(poses, dtype=np.float64)
        if poses.ndim != 3:
            raise ValueError(f"poses must be N x 4 x 4 (camera to world), got shape {poses.shape}")
        times = None if timestamps is None else np.asarray(timestamps, dtype=np.float64)
        if times is not None and times.ndim != 1:
            raise ValueError(f"timestamps must be one number a frame, got shape {times.shape}")
        k = _intrinsics(intrinsics)
        return cls(_native.sequence_from_arrays(depth, poses, k, float(depth_scale), times, name))

    def __len__(self) -> int:
        return len(self._native)

    def __repr__(self) -> str:
        return repr(self._native)

    @property
    def name(self) -> str:
        """The sequence's name (its directory's or bag's)."""
        return self._native.name

    @property
    def format(self) -> str:
        """The layout read: "tum", "7scenes", "vprdb", "scannet", "ros2", "ros1", "synthetic" or "arrays"."""
        return self._native.format

    @property
    def intrinsics(self) -> Intrinsics:
        """Pinhole intrinsics (fx, fy, cx, cy), pixels."""
        return self._native.intrinsics

    @property
    def width(self) -> int:
        """Width of the depth images, pixels."""
        return self._native.width

    @property
    def height(self) -> int:
        """Height of the depth images, pixels."""
        return self._native.height

    @property
    def depth_scale(self) -> float:
        """Depth units a metre (TUM 5000, 7-Scenes 1000)."""
        return self._native.depth_scale

    @property
    def frames_skipped(self) -> int:
        """Frames of the source the reader skipped (a depth image without a pose)."""
        return self._native.frames_skipped

    @property
    def poses(self) -> np.ndarray:
        """Camera-to-world poses, N x 4 x 4 float64."""
        return self._native.poses

    @property
    def timestamps(self) -> np.ndarray:
        """Each frame's time, N float64: seconds, or the frame's number where
        the layout numbers its frames instead (7-Scenes), as labels.csv has it."""
        return self._native.timestamps

    def _argv(self) -> list:
        """The command-line arguments it was read with: select goes on from them."""
        return list(self._native.argv)

    def depth(self, i: int, *, metres: bool = False) -> np.ndarray:
        """Frame ``i``'s depth image, H x W: uint16 as recorded, or with
        ``metres=True`` float32 metres (0 where there is no measurement)."""
        return self._native.depth(int(i), metres)


def _intrinsics(k: Any) -> Intrinsics:
    try:
        fx, fy, cx, cy = (float(v) for v in k)
    except (TypeError, ValueError):
        raise ValueError(f"intrinsics must be four numbers (fx, fy, cx, cy) in pixels, got {k!r}") from None
    return (fx, fy, cx, cy)


def _depth_stack(depth: Any, depth_scale: float) -> np.ndarray:
    """A C-ordered N x H x W uint16 stack of ``depth`` (an array or an
    iterable of H x W images)."""
    import numpy as np

    if not isinstance(depth, np.ndarray):
        depth = np.stack([np.asarray(d) for d in depth])
    if depth.ndim != 3:
        raise ValueError(f"depth must be N x H x W (a stack of depth images), got shape {depth.shape}")
    if depth.dtype == np.uint16:
        return depth
    if np.issubdtype(depth.dtype, np.floating):
        scaled = np.nan_to_num(depth * float(depth_scale), nan=0.0, posinf=0.0, neginf=0.0)
        return np.clip(np.rint(scaled), 0, 65535).astype(np.uint16)
    raise ValueError(
        f"depth must be uint16 (in depth_scale units a metre) or float metres, got dtype {depth.dtype}"
    )


def read_sequence(
    path: PathLike,
    *,
    format: Optional[str] = None,
    depth_scale: Optional[float] = None,
    intrinsics: Optional[Intrinsics] = None,
    depth_range: Optional[Tuple[float, float]] = None,
    stride: Optional[int] = None,
    voxel: Optional[float] = None,
    grid_origin: Optional[str] = None,
    max_frames: Optional[int] = None,
    depth_topic: Optional[str] = None,
    pose_topic: Optional[str] = None,
    camera_info_topic: Optional[str] = None,
    color_topic: Optional[str] = None,
    pose_frame: Optional[str] = None,
    camera_frame: Optional[str] = None,
    pose_tolerance: Optional[float] = None,
    pose_interpolation: Optional[str] = None,
) -> Sequence:
    """Opens a recorded sequence, as ``placedb select SEQ`` reads it.

    ``path``: a sequence directory (TUM RGB-D, 7-Scenes, ScanNet's export, the
    reference code's layout), a ROS 2 bag (folder, .mcap or .db3) or a ROS 1
    bag (.bag). The options are ``placedb select``'s, with the same ranges:
    ``format`` (detected when omitted), ``depth_scale`` (units a metre),
    ``intrinsics`` (fx, fy, cx, cy replacing the sequence's), ``max_frames``,
    and for bags the topics, ``pose_frame``/``camera_frame`` (TF),
    ``pose_tolerance`` (seconds) and ``pose_interpolation`` ("linear",
    "nearest"). ``depth_range`` (min, max metres), ``stride``, ``voxel``
    and ``grid_origin`` are kept for :func:`select` on this sequence.
    """
    argv = [os.fspath(path)] + _flags(
        format=format,
        depth_scale=depth_scale,
        intrinsics=intrinsics,
        depth_range=depth_range,
        stride=stride,
        voxel=voxel,
        grid_origin=grid_origin,
        max_frames=max_frames,
        depth_topic=depth_topic,
        pose_topic=pose_topic,
        camera_info_topic=camera_info_topic,
        color_topic=color_topic,
        pose_frame=pose_frame,
        camera_frame=camera_frame,
        pose_tolerance=pose_tolerance,
        pose_interpolation=pose_interpolation,
    )
    return Sequence(_native.read_sequence(argv))


class Database:
    """A selected database: its frames, every frame's class, the metrics."""

    def __init__(self, native: Any) -> None:
        self._native = native

    @property
    def frames(self) -> np.ndarray:
        """Indices of the database frames, ascending (int64)."""
        return self._native.frames

    @property
    def labels(self) -> np.ndarray:
        """Every frame's class: the database frame it is labelled with (int64)."""
        return self._native.labels

    @property
    def metrics(self) -> dict:
        """The keys of ``metrics.json`` (docs/FORMATS.md)."""
        return json.loads(self._native.metrics_json)

    def __len__(self) -> int:
        return len(self.frames)

    def __repr__(self) -> str:
        return f"<placedb.Database: {len(self.frames)} of {len(self.labels)} frames>"

    def write(
        self,
        out: PathLike,
        *,
        dataset: Optional[PathLike] = None,
        colmap: Optional[PathLike] = None,
        vpr_eval: Optional[PathLike] = None,
        pairs: Optional[PathLike] = None,
    ) -> list:
        """Writes what ``placedb select -o OUT`` writes: ``out``/database.csv,
        labels.csv, metrics.json, topview.png, extension.bin, and the
        ``dataset``, COLMAP model (``colmap``), VPR-methods-evaluation layout
        (``vpr_eval``) and hloc ``pairs`` file asked for, all together or none
        (an existing ``out`` is replaced only when it is a database
        directory). Returns one line per export written."""
        p = lambda x: None if x is None else os.fspath(x)
        return self._native.write(os.fspath(out), p(dataset), p(colmap), p(vpr_eval), p(pairs))


def select(
    source: Union[PathLike, Sequence, np.ndarray, Iterable[Tuple[np.ndarray, np.ndarray, float]], None] = None,
    *,
    mu: float = 0.3,
    solver: str = "online",
    demo: bool = False,
    demo_frames: Optional[int] = None,
    poses: Optional[np.ndarray] = None,
    intrinsics: Optional[Intrinsics] = None,
    timestamps: Optional[np.ndarray] = None,
    format: Optional[str] = None,
    depth_scale: Optional[float] = None,
    voxel: Optional[float] = None,
    stride: Optional[int] = None,
    depth_range: Optional[Tuple[float, float]] = None,
    grid_origin: Optional[str] = None,
    max_frames: Optional[int] = None,
    every_nth: Optional[int] = None,
    distance: Optional[float] = None,
    cube: Optional[float] = None,
    time_limit: Optional[float] = None,
    profile: Optional[str] = None,
    window: Optional[int] = None,
    test: Optional[PathLike] = None,
    extend: Optional[PathLike] = None,
    progress: bool = False,
    **bag_options: Any,
) -> Database:
    """Selects a database, as ``placedb select`` does (without writing it:
    :meth:`Database.write` does).

    ``source``: a sequence path, a :class:`Sequence`, a depth stack (N x H x
    W, with ``poses`` N x 4 x 4 and ``intrinsics``), or an iterable of
    ``(depth, pose, timestamp)``; or ``demo=True`` for the built-in synthetic
    office scan (``demo_frames`` frames, 600 by default).

    ``mu``: IoU threshold, from 0 to below 1: frames overlap when IoU > mu.
    ``solver``: "online" (the device core, replayed; the default),
    "in-order", "greedy", "exact" (integer program, ``time_limit`` seconds),
    or the baselines "every-nth" (``every_nth``), "distance" (``distance``
    metres of path), "cube" (``cube`` metre cubes).
    ``profile``: the online device's capacity ("ram256k", "ram512k",
    "ram1m"); ``window``: frames held undecided (1 to the profile's).
    ``voxel`` (metres, 0.3), ``stride`` (every s-th pixel, 1),
    ``depth_range`` (min, max metres, (0.1, 10)), ``grid_origin`` ("world",
    "scene-min"); ``test``: a test sequence of the same place
    (adds oracle_recall@0.3); ``extend``: an earlier database directory
    (written by ``Database.write`` or ``placedb select``/``export``) this
    sequence is added to as a new session (docs/SESSIONS.md). Reading options and bag topics
    (``depth_topic=...``) are :func:`read_sequence`'s. ``progress``: show
    progress bars on stderr.
    """
    options = dict(
        mu=mu,
        solver=solver,
        voxel=voxel,
        stride=stride,
        depth_range=depth_range,
        grid_origin=grid_origin,
        every_nth=every_nth,
        distance=distance,
        cube=cube,
        time_limit=time_limit,
        profile=profile,
        window=window,
        test=test,
        extend=extend,
        quiet=not progress,
    )
    reading = dict(format=format, depth_scale=depth_scale, max_frames=max_frames, **bag_options)
    if demo:
        if source is not None:
            raise ValueError("demo=True selects from the built-in scan: give no source with it")
        argv = ["--demo"] + _flags(demo_frames=demo_frames, **reading, **options)
        return Database(_native.select(argv, None))
    if source is None:
        raise ValueError("a sequence (a path, a Sequence or arrays) or demo=True is required")
    if isinstance(source, (str, os.PathLike)):
        argv = [os.fspath(source)] + _flags(intrinsics=intrinsics, **reading, **options)
        return Database(_native.select(argv, None))
    if not isinstance(source, Sequence) and not hasattr(source, "__array__") and not hasattr(source, "__iter__"):
        raise TypeError(
            "source must be a sequence's path, a Sequence, a depth stack or an iterable of "
            f"(depth, pose, timestamp), got {type(source).__name__}"
        )
    if not isinstance(source, Sequence):
        source = _from_memory(source, poses, intrinsics, timestamps, depth_scale)
        reading = {}
    elif any(v is not None for v in reading.values()) or intrinsics is not None:
        raise ValueError(
            "the sequence is read already: give reading options (format, depth_scale, "
            "intrinsics, max_frames, topics) to read_sequence"
        )
    argv = source._argv() + _flags(**options)
    return Database(_native.select(argv, source._native))


def _from_memory(source: Any, poses: Any, intrinsics: Any, timestamps: Any, depth_scale: Any) -> Sequence:
    """A :class:`Sequence` of a depth stack or of ``(depth, pose, timestamp)`` tuples."""
    import numpy as np

    if intrinsics is None:
        raise ValueError("frames from memory need intrinsics=(fx, fy, cx, cy)")
    scale = 1000.0 if depth_scale is None else depth_scale
    if isinstance(source, np.ndarray):
        if poses is None:
            raise ValueError("a depth stack needs poses= (N x 4 x 4, camera to world)")
        return Sequence.from_arrays(source, poses, intrinsics, depth_scale=scale, timestamps=timestamps)
    if poses is not None or timestamps is not None:
        raise ValueError("(depth, pose, timestamp) tuples carry their poses and times: give no poses= or timestamps=")
    depths, pose_list, times = [], [], []
    for item in source:
        try:
            d, p, t = item
        except (TypeError, ValueError):
            raise ValueError("each frame must be a (depth, pose, timestamp) tuple") from None
        depths.append(np.asarray(d))
        pose_list.append(np.asarray(p, dtype=np.float64))
        times.append(float(t))
    if not depths:
        raise ValueError("no frames were given")
    return Sequence.from_arrays(depths, np.stack(pose_list), intrinsics, depth_scale=scale, timestamps=times)


class Decision(NamedTuple):
    """One frame's final decision."""

    #: The frame's index.
    frame: int
    #: "taken" (a database frame), "dominated" (overlaps database frame
    #: ``label``) or "uncovered" (the database is full; ``label`` is the
    #: nearest database frame, if any).
    kind: str
    #: The frame's class: the database frame it is labelled with.
    label: Optional[int]


class Device:
    """The client of a placedb device: a board ("/dev/ttyACM0"), an emulator
    ("tcp:127.0.0.1:PORT", from ``placedb device``) or the core in this
    process ("local:ram512k"). One scan: :meth:`configure`, :meth:`push`
    frames, :meth:`finish`, :meth:`export`.

    A device holding a scan refuses a new one, naming what it holds, unless
    opened with ``new_scan=True``.
    """

    def __init__(self, port: str, *, reply_timeout: float = 60.0, new_scan: bool = False) -> None:
        self._native = _native.Device(str(port), float(reply_timeout), bool(new_scan))
        self._scale = 1000.0

    def __repr__(self) -> str:
        return repr(self._native)

    def configure(
        self,
        intrinsics: Intrinsics,
        width: int,
        height: int,
        *,
        mu: float = 0.3,
        window: int = 32,
        depth_scale: float = 1000.0,
        depth_range: Tuple[float, float] = (0.1, 10.0),
        stride: int = 1,
        voxel: float = 0.3,
        profile: Optional[str] = None,
    ) -> dict:
        """Starts a scan with this camera and these settings (``select``'s,
        checked with the same words); with ``profile``, the device must run
        that capacity profile (so its results are ``select(profile=...)``'s).
        Returns the device's status before it."""
        _check(mu=mu, window=window, depth_scale=depth_scale, depth_range=depth_range, stride=stride, voxel=voxel, profile=profile)
        k = _intrinsics(intrinsics)
        status = self._native.configure(
            k, int(width), int(height), float(depth_scale), tuple(float(v) for v in depth_range),
            int(stride), float(voxel), float(mu), int(window), float(_native.SKETCH_MARGIN),
            profile,
        )
        self._scale = float(depth_scale)
        return json.loads(status)

    def push(self, depth: np.ndarray, pose: np.ndarray, timestamp: float) -> list:
        """Sends one frame: ``depth`` H x W uint16 (the configured depth
        scale's units; float metres are converted), ``pose`` 4 x 4 camera to
        world, ``timestamp`` seconds. Returns the :class:`Decision` s that
        became final since the last call (a frame is decided up to
        ``window`` frames later)."""
        import numpy as np

        d = np.asarray(depth)
        if d.ndim != 2:
            raise ValueError(f"depth must be one H x W image, got shape {d.shape}")
        if d.dtype != np.uint16:
            d = _depth_stack(d[None, ...], self._scale)[0]
        p = np.asarray(pose, dtype=np.float64)
        return [Decision(*t) for t in self._native.push(d, p, float(timestamp))]

    def busy(self) -> bool:
        """Whether a push now would wait for the device: a live program skips
        the frame instead. Takes the replies that arrived; never waits."""
        return self._native.busy()

    def decisions(self) -> list:
        """The decisions that became final since the last call or push."""
        return [Decision(*t) for t in self._native.take_decisions()]

    def status(self) -> dict:
        """The device's status (frames seen, database frames, degradation counters, ...)."""
        return json.loads(self._native.status_json())

    def finish(self) -> dict:
        """Ends the scan: every pending frame is decided. Returns the final status."""
        return json.loads(self._native.finish_json())

    def export(self) -> Database:
        """Pulls the database and every label; :meth:`Database.write` writes
        database.csv, labels.csv and metrics.json as ``placedb export`` does."""
        return Database(self._native.export())


def _check(**options: Any) -> None:
    """Checks ``options`` as ``placedb select`` does (ValueError in its words)."""
    _native.check_select(["<frames>"] + _flags(**options))


class Selector:
    """The device core in this process, frame by frame: :meth:`push` each
    depth frame, :meth:`finish`, and the :class:`Database` is what a board
    would export. Pushing a sequence's frames gives the decisions of
    ``select(seq, solver="online")`` with the same settings.
    """

    def __init__(
        self,
        intrinsics: Intrinsics,
        width: int,
        height: int,
        *,
        mu: float = 0.3,
        profile: str = "ram512k",
        window: int = 32,
        depth_scale: float = 1000.0,
        depth_range: Tuple[float, float] = (0.1, 10.0),
        stride: int = 1,
        voxel: float = 0.3,
    ) -> None:
        _check(mu=mu, window=window, depth_scale=depth_scale, depth_range=depth_range, stride=stride, voxel=voxel, profile=profile)
        self._device = Device(f"local:{profile}")
        self._device.configure(
            intrinsics, width, height, mu=mu, window=window, depth_scale=depth_scale,
            depth_range=depth_range, stride=stride, voxel=voxel, profile=profile,
        )
        self._depth_scale = float(depth_scale)

    def push(self, depth: np.ndarray, pose: np.ndarray, timestamp: float) -> list:
        """Takes one frame (``depth`` H x W uint16 in ``depth_scale`` units,
        or float metres; ``pose`` 4 x 4 camera to world; ``timestamp``
        seconds) and returns the :class:`Decision` s that became final."""
        import numpy as np

        d = np.asarray(depth)
        if d.ndim == 2 and d.dtype != np.uint16:
            d = _depth_stack(d[None, ...], self._depth_scale)[0]
        return self._device.push(d, pose, timestamp)

    def busy(self) -> bool:
        """Always False in-process: a push returns when the frame is taken."""
        return self._device.busy()

    def finish(self) -> Tuple[list, Database]:
        """Decides the frames still pending; returns those decisions and the database."""
        self._device.finish()
        rest = self._device.decisions()
        return rest, self._device.export()
