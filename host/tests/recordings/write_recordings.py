#!/usr/bin/env python3
"""Write robot-style recordings of 7-Scenes frames, for placedb's reader tests.

The Rust tests call this script to get recordings laid out the way robots record
them -- ROS 2 bags (sqlite3, split sqlite3, mcap), ROS 1 bags (plain, bz2, lz4 as the
rosbags library and as rosbag frame it),
compressed depth in the formats image_transport's plugins write, TF trees, a
ScanNet SensReader export -- and a few broken recordings that readers must refuse.
The files are written by the ecosystem's own writers (the `rosbags` library for
bags, OpenCV for PNGs), not by placedb, so a reader that agrees with them agrees
with the outside world rather than with itself.

Every pose comes verbatim from POSES.txt (written by the Rust test from its own
reading of the 7-Scenes poses), so a reader is compared against the numbers the
test already holds; depth comes from frame-NNNNNN.depth.png.

    python3 host/tests/recordings/write_recordings.py --sevenscenes DIR \\
        --poses POSES.txt --frames N --out OUT [--only NAME ...] [--check]

OUT/manifest.json lists what was written (see VARIANTS below for the names).
--check reads every recording back with rosbags' AnyReader, deserializes every
message and decodes the compressed depth with a decoder written from
image_transport_plugins' codec.cpp / rvl_codec.cpp, comparing with the source PNGs.

Source references (github.com/ros-perception/image_transport_plugins):
  humble  = branch humble  @ ef9442d8 (2.5.0)
  rolling = branch rolling @ 7404d772 (3.2.0; first with RVL)
"""

import argparse
import json
import os
import shutil
import sqlite3
import struct
import sys
import tempfile
from pathlib import Path

try:
    import cv2
    import numpy as np
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                    QosReliability, QosTime)
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer as Writer2
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
except ImportError as err:  # say what to do rather than print a traceback
    sys.exit(f'write_recordings.py: missing dependency ({err}); '
             'pip install -r host/tests/recordings/requirements.txt')

DEPTH = '/camera/depth/image_rect_raw'
INFO = '/camera/depth/camera_info'
POSE = '/camera/pose'
COLOR = '/camera/color/image_raw'
CDEPTH = DEPTH + '/compressedDepth'   # compressed_depth_image_transport's topic suffix
CPNG = DEPTH + '/compressed'          # compressed_image_transport's topic suffix
OPTICAL = 'camera_depth_optical_frame'

# rosbags writes rosbag2 metadata version 8 or 9 only (Humble's ros2 bag writes 5,
# Jazzy 8); 8 is the oldest it can write, so the closest to what robots have.
ROS2_VERSION = 8

# --- compressed_depth_image_transport constants -----------------------------
# ConfigHeader (compression_common.h): { enum compressionFormat format; float depthParam[2]; }
# = int32 + 2 x float32, native (little-endian) byte order, 12 bytes, no padding.
CONFIG_HEADER = struct.Struct('<iff')
INV_DEPTH = 0          # enum compressionFormat { UNDEFINED = -1, INV_DEPTH }
DEPTH_MAX = 10.0       # publisher default depth_max (rolling compressed_depth_publisher.cpp)
DEPTH_QUANT = 100.0    # publisher default depth_quantization (same file)

VARIANTS = [
    'ros2-sqlite3', 'ros2-sqlite3-split', 'ros2-mcap',
    'ros2-sqlite3-zstd-file', 'ros2-sqlite3-zstd-message', 'ros2-mcap-zstd-file',
    'ros2-mcap-zstd-message',
    'ros2-compressed-png', 'ros2-compressed-png-rolling', 'ros2-compressed-rvl',
    'ros2-compressed-32f', 'ros2-png', 'ros2-tf', 'ros2-tf-half-rate',
    'ros2-pose-half-rate', 'ros1', 'ros1-bz2', 'ros1-lz4', 'ros1-roslz4', 'ros1-tf', 'ros1-tf1',
    'scannet',
    'bad-truncated-db3', 'bad-truncated-bag', 'bad-short-compressed',
    'bad-8bit-png', 'bad-tf-cycle', 'bad-tf-two-parents',
]
BAD_FRAMES = 6  # the broken recordings stay small

TS2 = get_typestore(Stores.ROS2_HUMBLE)
TS1 = get_typestore(Stores.ROS1_NOETIC)
# rosbags' Noetic store has no tf2_msgs; register it from the tf2_msgs/TFMessage.msg text
# (the md5sum rosbags derives from it is the Noetic one, 94810edda583a504dfda3829e70d7eec).
TS1.register(get_types_from_msg('geometry_msgs/TransformStamped[] transforms',
                                'tf2_msgs/msg/TFMessage'))
# Nor tf/tfMessage, what /tf carried before tf2 (TUM RGB-D's bags): the same fields.
TS1.register(get_types_from_msg('geometry_msgs/TransformStamped[] transforms',
                                'tf/msg/tfMessage'))


# --- inputs ------------------------------------------------------------------
def read_poses(path, n):
    """POSES.txt lines `t tx ty tz qx qy qz qw`, used verbatim (float() only)."""
    rows = []
    for line in Path(path).read_text().splitlines():
        if line.strip() and not line.lstrip().startswith('#'):
            vals = [float(x) for x in line.split()]
            if len(vals) != 8:
                sys.exit(f'{path}: expected 8 numbers per line, got {line!r}')
            rows.append(vals)
    if len(rows) < n:
        sys.exit(f'{path}: {len(rows)} poses, --frames asks for {n}')
    return rows[:n]


def read_intrinsics(root):
    p = root / 'camera-intrinsics.txt'
    # The 7-Scenes README: default to fx=fy=585, cx=320, cy=240 when absent.
    return np.loadtxt(p) if p.exists() else np.array([[585., 0, 320], [0, 585., 240], [0, 0, 1]])


class Frames:
    """Lazy access to the sample's files, so variants read only what they use."""

    def __init__(self, root, n):
        self.root, self.n = Path(root), n
        self._depth = {}
        self.K = read_intrinsics(self.root)

    def path(self, i, kind):
        return self.root / f'frame-{i:06d}.{kind}'

    def depth(self, i):
        if i not in self._depth:
            d = cv2.imread(str(self.path(i, 'depth.png')), cv2.IMREAD_UNCHANGED)
            if d is None or d.dtype != np.uint16 or d.ndim != 2:
                sys.exit(f'{self.path(i, "depth.png")}: not a 16-bit single-channel PNG')
            self._depth[i] = d
        return self._depth[i]

    def color_rgb(self, i):
        bgr = cv2.imread(str(self.path(i, 'color.jpg')), cv2.IMREAD_COLOR)
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


# --- message builders (one code path for ROS 1 and ROS 2 typestores) ---------
def T(ts, name):
    return ts.types[name]


def is_ros1(ts):
    return ts is TS1


def header(ts, t, frame_id):
    stamp = T(ts, 'builtin_interfaces/msg/Time')(sec=int(t), nanosec=0)
    if is_ros1(ts):  # ROS 1 headers carry seq; use the frame number as a recorder would count
        return T(ts, 'std_msgs/msg/Header')(seq=int(t), stamp=stamp, frame_id=frame_id)
    return T(ts, 'std_msgs/msg/Header')(stamp=stamp, frame_id=frame_id)


def image_msg(ts, t, img, encoding, frame_id):
    h, w = img.shape[:2]
    # '<' so the bytes are little-endian whatever the host; is_bigendian = 0 says so.
    data = np.ascontiguousarray(img.astype(img.dtype.newbyteorder('<'))).view(np.uint8).reshape(-1)
    step = data.size // h
    return T(ts, 'sensor_msgs/msg/Image')(header=header(ts, t, frame_id), height=h, width=w,
                                          encoding=encoding, is_bigendian=0, step=step, data=data)


def camera_info_msg(ts, t, K, w, h):
    k = [float(x) for x in K.reshape(-1)]
    p = [k[0], k[1], k[2], 0.0, k[3], k[4], k[5], 0.0, k[6], k[7], k[8], 0.0]
    r = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]
    roi = T(ts, 'sensor_msgs/msg/RegionOfInterest')(x_offset=0, y_offset=0, height=0, width=0,
                                                    do_rectify=False)
    arr = lambda v: np.array(v, dtype=np.float64)  # noqa: E731
    fields = dict(header=header(ts, t, OPTICAL), height=h, width=w, distortion_model='plumb_bob',
                  binning_x=0, binning_y=0, roi=roi)
    names = ('D', 'K', 'R', 'P') if is_ros1(ts) else ('d', 'k', 'r', 'p')  # ROS 1 upper-case
    for name, v in zip(names, ([0.0] * 5, k, r, p)):
        fields[name] = arr(v)
    return T(ts, 'sensor_msgs/msg/CameraInfo')(**fields)


def compressed_msg(ts, t, fmt, payload, frame_id=OPTICAL):
    return T(ts, 'sensor_msgs/msg/CompressedImage')(
        header=header(ts, t, frame_id), format=fmt, data=np.frombuffer(payload, np.uint8).copy())


def pose_msg(ts, t, row, frame_id='map'):
    _, tx, ty, tz, qx, qy, qz, qw = row
    pose = T(ts, 'geometry_msgs/msg/Pose')(
        position=T(ts, 'geometry_msgs/msg/Point')(x=tx, y=ty, z=tz),
        orientation=T(ts, 'geometry_msgs/msg/Quaternion')(x=qx, y=qy, z=qz, w=qw))
    return T(ts, 'geometry_msgs/msg/PoseStamped')(header=header(ts, t, frame_id), pose=pose)


def transform_stamped(ts, t, parent, child, trans, quat):
    tr = T(ts, 'geometry_msgs/msg/Transform')(
        translation=T(ts, 'geometry_msgs/msg/Vector3')(x=float(trans[0]), y=float(trans[1]),
                                                       z=float(trans[2])),
        rotation=T(ts, 'geometry_msgs/msg/Quaternion')(x=float(quat[0]), y=float(quat[1]),
                                                       z=float(quat[2]), w=float(quat[3])))
    return T(ts, 'geometry_msgs/msg/TransformStamped')(header=header(ts, t, parent),
                                                       child_frame_id=child, transform=tr)


def tf_msg(ts, transforms, msgtype='tf2_msgs/msg/TFMessage'):
    return T(ts, msgtype)(transforms=transforms)


# --- rigid transforms (float64) --------------------------------------------
def quat_to_mat(q):
    x, y, z, w = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def mat_to_quat(R):
    # Shepperd's method: pick the largest diagonal term so the square root is well conditioned.
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[3] >= 0 else -q  # one of the two signs, consistently


def make_T(trans, quat):
    M = np.eye(4)
    M[:3, :3] = quat_to_mat(quat)
    M[:3, 3] = trans
    return M


def yaw_quat(yaw):
    return np.array([0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)])


# The TF tree used by the tf variants (documented in the manifest notes).
BASE_T_CAM = make_T([0.1, 0.02, 0.3], yaw_quat(0.05))            # base_link -> camera_link
CAM_T_OPT_Q = np.array([-0.5, 0.5, -0.5, 0.5])                   # camera_link -> optical (xyzw)
CAM_T_OPT = make_T([0.0, 0.0, 0.0], CAM_T_OPT_Q)
MAP_T_ODOM = make_T([1.0, 2.0, 0.0], yaw_quat(0.3))             # map -> odom
BASE_T_OPT = BASE_T_CAM @ CAM_T_OPT


def odom_T_base(row):
    """odom->base_link such that map->odom->base_link->camera_link->optical == the pose."""
    map_T_opt = make_T(row[1:4], row[4:8])
    M = np.linalg.inv(MAP_T_ODOM) @ map_T_opt @ np.linalg.inv(BASE_T_OPT)
    return M[:3, 3], mat_to_quat(M[:3, :3])


def static_links(ts, t=0, slash=''):
    q_bc = mat_to_quat(BASE_T_CAM[:3, :3])
    return [
        transform_stamped(ts, t, slash + 'base_link', slash + 'camera_link', BASE_T_CAM[:3, 3],
                          q_bc),
        transform_stamped(ts, t, slash + 'camera_link', slash + OPTICAL, [0, 0, 0], CAM_T_OPT_Q)]


def static_tf(ts):
    return tf_msg(ts, static_links(ts))


def map_odom_tf(ts, t, slash=''):
    return transform_stamped(ts, t, slash + 'map', slash + 'odom', MAP_T_ODOM[:3, 3],
                             mat_to_quat(MAP_T_ODOM[:3, :3]))


# --- compressed depth encoders, following image_transport_plugins -------------
def max_depth_filter_16u(depth):
    """codec.cpp 16UC1 path: pixels > ushort(depth_max*1000) are set to 0 before encoding.

    rolling codec.cpp:376-387, humble codec.cpp:295-306.  With the default 10 m this
    zeroes 65535 ("no measurement" in 7-Scenes); valid 7-Scenes depths are < 10 m.
    """
    out = depth.copy()
    out[out > np.uint16(int(np.float32(DEPTH_MAX) * np.float32(1000.0)))] = 0
    return out


def compressed_depth_png_16u(depth, png_level):
    # 16UC1: depthParam is never assigned in the source (uninitialised stack memory);
    # we write 0.0, 0.0 -- readers must ignore depthParam for 16UC1.
    ok, png = cv2.imencode('.png', max_depth_filter_16u(depth),
                           [cv2.IMWRITE_PNG_COMPRESSION, png_level])
    assert ok
    return CONFIG_HEADER.pack(INV_DEPTH, 0.0, 0.0) + png.tobytes()


def rvl_encode(img):
    """RVL as rvl_codec.cpp CompressRVL (rolling rvl_codec.cpp:11-24, 43-68), vectorised.

    Token stream, over pixels in row-major order: repeat { VLE(#zeros), VLE(#nonzeros),
    VLE(zigzag(delta)) for each nonzero } until the end; delta = value - previous
    nonzero value (previous starts at 0, zeros do not reset it); zigzag = (d<<1)^(d>>31).
    VLE: 3 value bits per nibble, least significant group first, bit 3 (0x8) set when
    more nibbles follow.  Nibbles fill an int32 word from its most significant nibble
    down (word <<= 4; word |= nibble); full words are stored as native (little-endian)
    int32; a last partial word is shifted left so its nibbles sit at the top.
    """
    flat = img.reshape(-1)
    nz = flat != 0
    n = flat.size
    if n == 0:
        return b''
    bounds = np.flatnonzero(nz[1:] != nz[:-1]) + 1
    starts = np.concatenate(([0], bounds))
    lengths = np.diff(np.concatenate((starts, [n])))
    kinds = nz[starts]
    zeros, nonzeros = [], []
    runs = list(zip(kinds.tolist(), lengths.tolist()))
    if runs[0][0]:                    # image starts with a nonzero: zero run of length 0 first
        runs.insert(0, (False, 0))
    if not runs[-1][0]:               # ends with zeros: the encoder still writes nonzeros=0
        runs.append((True, 0))
    for i in range(0, len(runs), 2):
        zeros.append(runs[i][1])
        nonzeros.append(runs[i + 1][1])
    zeros = np.array(zeros, dtype=np.int64)
    nonzeros = np.array(nonzeros, dtype=np.int64)
    vals = flat[nz].astype(np.int64)
    delta = vals - np.concatenate(([0], vals[:-1]))
    zz = (delta << 1) ^ (delta >> 31)
    # Interleave: pair i occupies 2 + nonzeros[i] tokens.
    per = 2 + nonzeros
    off = np.concatenate(([0], np.cumsum(per)[:-1]))
    tokens = np.empty(int(per.sum()), dtype=np.int64)
    is_head = np.zeros(tokens.size, dtype=bool)
    is_head[off] = True
    is_head[off + 1] = True
    tokens[off] = zeros
    tokens[off + 1] = nonzeros
    tokens[~is_head] = zz
    # VLE nibbles.
    k = np.ones(tokens.size, dtype=np.int64)
    for s in range(3, 33, 3):
        k += (tokens >> s) > 0
    tok_idx = np.repeat(np.arange(tokens.size), k)
    first = np.concatenate(([0], np.cumsum(k)[:-1]))
    j = np.arange(tok_idx.size) - np.repeat(first, k)
    nib = ((tokens[tok_idx] >> (3 * j)) & 7) | np.where(j < k[tok_idx] - 1, 8, 0)
    pad = (-nib.size) % 8
    nib = np.concatenate((nib, np.zeros(pad, dtype=np.int64))).reshape(-1, 8)
    words = np.zeros(nib.shape[0], dtype=np.uint64)
    for i in range(8):
        words |= nib[:, i].astype(np.uint64) << np.uint64(4 * (7 - i))
    return words.astype('<u4').tobytes()


def compressed_depth_rvl_16u(depth):
    d = max_depth_filter_16u(depth)
    h, w = d.shape
    # rolling codec.cpp:404-413: uint32 cols, uint32 rows (native order), then RVL words.
    return CONFIG_HEADER.pack(INV_DEPTH, 0.0, 0.0) + struct.pack('<II', w, h) + rvl_encode(d)


def quant_params():
    # rolling codec.cpp:266-267, 291-292 (float arithmetic)
    z0, dmax = np.float32(DEPTH_QUANT), np.float32(DEPTH_MAX)
    a = np.float32(z0 * (z0 + np.float32(1.0)))
    b = np.float32(np.float32(1.0) - a / dmax)
    return a, b


def mm_to_metres_32f(depth):
    # depth_image_proc's convert_metric: raw 0 -> NaN, else raw * 0.001 (float32).
    m = depth.astype(np.float32) * np.float32(0.001)
    m[depth == 0] = np.nan
    return m


def inv_depth_quantise(m):
    """rolling codec.cpp:300-312: inv = ushort(A / d + B) if d < depth_max else 0.

    NaN fails `d < depth_max` -> 0; d >= depth_max (65535 mm) -> 0.  The float->ushort
    conversion truncates toward zero.
    """
    a, b = quant_params()
    with np.errstate(divide='ignore', invalid='ignore'):
        q = a / m + b                               # float32 throughout, like the source
    ok = m < np.float32(DEPTH_MAX)
    out = np.zeros(m.shape, dtype=np.uint16)
    out[ok] = np.trunc(q[ok]).astype(np.uint16)
    return out


def compressed_depth_png_32f(depth):
    a, b = quant_params()
    ok, png = cv2.imencode('.png', inv_depth_quantise(mm_to_metres_32f(depth)),
                           [cv2.IMWRITE_PNG_COMPRESSION, 3])  # rolling default png_level 3
    assert ok
    return CONFIG_HEADER.pack(INV_DEPTH, float(a), float(b)) + png.tobytes()


# --- decoders used by --check (written from codec.cpp / rvl_codec.cpp) --------
def rvl_decode(buf, num_pixels):
    words = np.frombuffer(buf[:len(buf) // 4 * 4], dtype='<u4').astype(np.uint64)
    shifts = np.uint64(4) * (np.uint64(7) - np.arange(8, dtype=np.uint64))
    nib = ((words[:, None] >> shifts[None, :]) & np.uint64(0xF)).reshape(-1).astype(np.int64)
    ends = (nib & 8) == 0
    tok = np.concatenate(([0], np.cumsum(ends)[:-1]))
    starts = np.concatenate(([0], np.flatnonzero(ends)[:-1] + 1))
    j = np.arange(nib.size) - starts[tok]
    vals = np.bincount(tok, weights=((nib & 7) << (3 * j)).astype(np.float64)).astype(np.int64)
    out = np.zeros(num_pixels, dtype=np.int64)
    pos, ti = 0, 0
    deltas_at, deltas_from = [], []
    while pos < num_pixels:
        zeros, nonzeros = int(vals[ti]), int(vals[ti + 1])
        ti += 2
        pos += zeros
        deltas_at.append((pos, nonzeros, ti))
        pos += nonzeros
        ti += nonzeros
    idx = np.concatenate([np.arange(p, p + c) for p, c, _ in deltas_at if c] or [np.zeros(0, int)])
    src = np.concatenate([np.arange(t, t + c) for _, c, t in deltas_at if c] or [np.zeros(0, int)])
    pos_tok = vals[src]
    delta = (pos_tok >> 1) ^ -(pos_tok & 1)
    out[idx] = np.cumsum(delta) & 0xFFFF   # ushort arithmetic wraps
    return out.astype(np.uint16)


def decode_compressed_depth(fmt, data):
    """As rolling decodeCompressedDepthImage; returns (encoding, image)."""
    enc, _, rest = fmt.partition(';')
    codec = 'rvl' if 'compressedDepth rvl' in rest else 'png'
    if len(data) <= CONFIG_HEADER.size:
        raise ValueError('payload not longer than the 12-byte ConfigHeader')
    _, a, b = CONFIG_HEADER.unpack_from(data)
    body = bytes(data[CONFIG_HEADER.size:])
    if codec == 'png':
        img = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_UNCHANGED)
    else:
        cols, rows = struct.unpack_from('<II', body)
        img = rvl_decode(body[8:], cols * rows).reshape(rows, cols)
    if img.dtype != np.uint16:
        raise ValueError(f'inner image is {img.dtype}, not 16-bit')
    if enc == '32FC1':
        with np.errstate(divide='ignore'):
            m = np.float32(a) / (img.astype(np.float32) - np.float32(b))
        m[img == 0] = np.nan
        return enc, m
    return enc, img


# --- writers -------------------------------------------------------------------
def qos_transient_local():
    # What a /tf_static publisher offers (static_transform_broadcaster: transient local, depth 1).
    zero = QosTime(0, 0)
    return Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
               zero, zero, QosLiveliness.AUTOMATIC, zero, False)


class Bag2:
    """Thin wrapper over rosbags.rosbag2.Writer: topic -> connection, write(msg, t)."""

    def __init__(self, path, storage=StoragePlugin.SQLITE3, compression=None):
        self.w = Writer2(path, version=ROS2_VERSION, storage_plugin=storage)
        if compression:
            # ros2 bag record --compression-mode file|message --compression-format zstd
            self.w.set_compression(compression, CompressionFormat.ZSTD)
        self.w.open()
        self.conns = {}

    def conn(self, topic, msgtype, latched=False):
        if topic not in self.conns:
            qos = [qos_transient_local()] if latched else []
            self.conns[topic] = self.w.add_connection(topic, msgtype, typestore=TS2,
                                                      offered_qos_profiles=qos)
        return self.conns[topic]

    def write(self, topic, msg, t, latched=False):
        c = self.conn(topic, msg.__msgtype__, latched)
        self.w.write(c, int(t) * 1_000_000_000, TS2.serialize_cdr(msg, msg.__msgtype__))

    def close(self):
        self.w.close()


def roslz4(data):
    """A chunk's lz4 frame as rosbag writes it (ros_comm roslz4/lz4s.c, block size id 6
    from rosbag_storage's LZ4Stream): independent 1 MiB blocks, a content checksum, no
    content size. The rosbags library's own lz4 chunks are linked 64 KiB blocks without
    checksums."""
    import lz4.frame
    return lz4.frame.compress(data, 0, block_size=lz4.frame.BLOCKSIZE_MAX1MB,
                              block_linked=False, content_checksum=True, store_size=False)


class Bag1:
    CALLERID = {DEPTH: '/camera/realsense2_camera', INFO: '/camera/realsense2_camera',
                COLOR: '/camera/realsense2_camera', POSE: '/localization',
                '/tf': '/robot_state_publisher', '/tf_static': '/robot_state_publisher'}

    def __init__(self, path, compression=None, chunk_threshold=None, compressor=None):
        self.w = Writer1(path)
        if compression:
            self.w.set_compression(compression)
        if compressor:
            self.w.compressor = compressor
        if chunk_threshold:
            self.w.chunk_threshold = chunk_threshold
        self.w.open()
        self.conns = {}

    def write(self, topic, msg, t, latched=False):
        if topic not in self.conns:
            # rosbag record stores callerid and latching in every connection record.
            self.conns[topic] = self.w.add_connection(
                topic, msg.__msgtype__, typestore=TS1,
                callerid=self.CALLERID.get(topic, '/recorder'), latching=1 if latched else 0)
        self.w.write(self.conns[topic], int(t) * 1_000_000_000,
                     TS1.serialize_ros1(msg, msg.__msgtype__))

    def close(self):
        self.w.close()


def write_frames(bag, ts, fr, poses, *, depth='raw', color=False, pose_every=1, tf=None,
                 tf_every=1, bad_frame=None, bad_payload=None):
    """Write frames 0..n-1 in one order per stamp: tf, pose, camera_info, depth, colour.

    depth: 'raw' | 'png16' (humble compressedDepth) | 'png16-rolling' | 'rvl' | 'png32' | 'png'.
    tf: None | 'tree' | 'cycle' | 'two-parents' | 'tf1' (the tree as tf1 recorded it: every
    link on /tf as tf/tfMessage at each stamp, the static ones too, frames named with a
    leading slash, the depth images' frame as well).
    """
    n = len(poses)
    slash = '/' if tf == 'tf1' else ''
    optical = slash + OPTICAL
    if tf and tf != 'tf1':
        # /tf_static once, as the very first message (stamp 0, log time 0), latched.
        bag.write('/tf_static', static_tf(ts), 0, latched=True)
    for i in range(n):
        row = poses[i]
        t = int(row[0])
        if tf and i % tf_every == 0:
            trans, quat = odom_T_base(row)
            tfs = [map_odom_tf(ts, t, slash),
                   transform_stamped(ts, t, slash + 'odom', slash + 'base_link', trans, quat)]
            if tf == 'tf1':
                tfs += static_links(ts, t, slash)
            elif tf == 'cycle':          # base_link -> map closes map->odom->base_link->map
                tfs.append(transform_stamped(ts, t, 'base_link', 'map', [0.5, 0, 0], [0, 0, 0, 1]))
            elif tf == 'two-parents':  # base_link gets a second parent, map
                tfs.append(transform_stamped(ts, t, 'map', 'base_link', [0.5, 0, 0], [0, 0, 0, 1]))
            tf_type = 'tf/msg/tfMessage' if tf == 'tf1' else 'tf2_msgs/msg/TFMessage'
            bag.write('/tf', tf_msg(ts, tfs, tf_type), t)
        if not tf and i % pose_every == 0:
            bag.write(POSE, pose_msg(ts, t, row), t)
        d = fr.depth(i)
        h, w = d.shape
        bag.write(INFO, camera_info_msg(ts, t, fr.K, w, h), t)
        if depth == 'raw':
            bag.write(DEPTH, image_msg(ts, t, d, '16UC1', optical), t)
        elif depth == 'png':
            ok, png = cv2.imencode('.png', d, [cv2.IMWRITE_PNG_COMPRESSION, 3])
            # humble compressed_publisher.cpp:258: "; png compressed " + "" for mono images
            bag.write(CPNG, compressed_msg(ts, t, '16UC1; png compressed ', png.tobytes()), t)
        else:
            fmt, payload = {
                # Humble's default png_level is 9 (humble compressed_depth_publisher.cpp:48),
                # but level 9 costs ~0.3 s a frame here; the level changes only zlib's effort,
                # not the decoded pixels, so 3 keeps the whole run within budget.
                'png16': lambda: ('16UC1; compressedDepth', compressed_depth_png_16u(d, 3)),
                'png16-rolling': lambda: ('16UC1; compressedDepth png',
                                          compressed_depth_png_16u(d, 3)),
                'rvl': lambda: ('16UC1; compressedDepth rvl', compressed_depth_rvl_16u(d)),
                'png32': lambda: ('32FC1; compressedDepth png', compressed_depth_png_32f(d)),
            }[depth]()
            if i == bad_frame:
                fmt, payload = bad_payload(d, fmt, payload)
            bag.write(CDEPTH, compressed_msg(ts, t, fmt, payload), t)
        if color == 'jpeg':
            # compressed_image_transport's JPEG of an rgb8 image (humble
            # compressed_publisher.cpp: "rgb8; jpeg compressed bgr8"); the
            # sample's own JPEG bytes stand for the encoder's.
            jpeg = Path(fr.path(i, 'color.jpg')).read_bytes()
            bag.write(COLOR + '/compressed',
                      compressed_msg(ts, t, 'rgb8; jpeg compressed bgr8', jpeg,
                                     'camera_color_optical_frame'), t)
        elif color:
            bag.write(COLOR, image_msg(ts, t, fr.color_rgb(i), 'rgb8', 'camera_color_optical_frame'), t)


TF_NOTES = ('No PoseStamped. /tf_static (tf2_msgs/msg/TFMessage) is the first message, stamp 0 '
            'and log time 0, written once: base_link->camera_link (t=(0.1,0.02,0.3), yaw 0.05 rad) '
            'and camera_link->camera_depth_optical_frame (q xyzw=(-0.5,0.5,-0.5,0.5), t=0). '
            '/tf at each frame stamp: map->odom (t=(1,2,0), yaw 0.3 rad) and odom->base_link, '
            'chosen in float64 so map->odom->base_link->camera_link->camera_depth_optical_frame '
            'equals the POSES.txt pose (to float64 rounding, ~1e-15). Depth header.frame_id = '
            'camera_depth_optical_frame.')


def ros2_variant(name, out, fr, poses, storage=StoragePlugin.SQLITE3, compression=None, **kw):
    bag = Bag2(out / name, storage, compression)
    write_frames(bag, TS2, fr, poses, **kw)
    bag.close()


def write_split(name, out, fr, poses):
    """rosbags' Writer cannot split; write two bags, then lay them out as
    `ros2 bag record --max-bag-size` does: NAME/NAME_0.db3, NAME/NAME_1.db3, one metadata.yaml."""
    n = len(poses)
    half = max(1, n // 2)
    stage = Path(tempfile.mkdtemp(dir=out))
    metas = []
    for part, (lo, hi) in enumerate(((0, half), (half, n))):
        p = stage / f'{name}_{part}'   # Writer names the db3 after its folder: NAME_k.db3
        bag = Bag2(p)
        sub = Frames(fr.root, fr.n)
        sub._depth = fr._depth
        # write frames lo..hi-1 with their own stamps (all topics registered in each file,
        # as rosbag2 re-registers every topic in each split file)
        for topic, mt in ((POSE, 'geometry_msgs/msg/PoseStamped'),
                          (INFO, 'sensor_msgs/msg/CameraInfo'), (DEPTH, 'sensor_msgs/msg/Image')):
            bag.conn(topic, mt)
        for i in range(lo, hi):
            row = poses[i]
            t = int(row[0])
            d = fr.depth(i)
            bag.write(POSE, pose_msg(TS2, t, row), t)
            bag.write(INFO, camera_info_msg(TS2, t, fr.K, d.shape[1], d.shape[0]), t)
            bag.write(DEPTH, image_msg(TS2, t, d, '16UC1', OPTICAL), t)
        bag.close()
        metas.append(p / 'metadata.yaml')
    dst = out / name
    dst.mkdir()
    infos = []
    for part, m in enumerate(metas):
        shutil.move(str(m.parent / f'{name}_{part}.db3'), str(dst / f'{name}_{part}.db3'))
        infos.append(yaml_load(m))
    shutil.rmtree(stage)
    merged = infos[0]
    merged['relative_file_paths'] = [f'{name}_0.db3', f'{name}_1.db3']
    merged['files'] = [f for i in infos for f in i['files']]
    start = min(i['starting_time']['nanoseconds_since_epoch'] for i in infos)
    end = max(i['starting_time']['nanoseconds_since_epoch'] + i['duration']['nanoseconds']
              for i in infos)
    merged['starting_time'] = {'nanoseconds_since_epoch': start}
    merged['duration'] = {'nanoseconds': end - start}
    merged['message_count'] = sum(i['message_count'] for i in infos)
    counts = {}
    for i in infos:
        for tm in i['topics_with_message_count']:
            counts[tm['topic_metadata']['name']] = counts.get(tm['topic_metadata']['name'], 0) + \
                tm['message_count']
    for tm in merged['topics_with_message_count']:
        tm['message_count'] = counts[tm['topic_metadata']['name']]
    yaml_dump({'rosbag2_bagfile_information': merged}, dst / 'metadata.yaml')


def yaml_load(path):
    from ruamel.yaml import YAML   # rosbags' own YAML dependency
    return YAML(typ='safe').load(path.read_text())['rosbag2_bagfile_information']


def yaml_dump(obj, path):
    from io import StringIO
    from ruamel.yaml import YAML
    y = YAML(typ='safe')
    y.default_flow_style = False
    s = StringIO()
    y.dump(obj, s)
    path.write_text(s.getvalue())


def ros1_variant(name, out, fr, poses, compression=None, chunk_threshold=None, compressor=None,
                 **kw):
    bag = Bag1(out / f'{name}.bag', compression, chunk_threshold, compressor)
    write_frames(bag, TS1, fr, poses, **kw)
    bag.close()


def write_scannet(out, fr, poses):
    """Layout of ScanNet SensReader/python/SensorData.py export_* (files named by frame
    index without padding; matrices one row per line, space separated)."""
    root = out / 'scannet'
    for sub in ('color', 'depth', 'pose', 'intrinsic'):
        (root / sub).mkdir(parents=True, exist_ok=True)

    def save_mat(M, path, fmt):
        # SensorData.save_mat_to_file: np.savetxt(f, row[np.newaxis], fmt='%f') per row.
        with open(path, 'w') as f:
            for row in M:
                f.write(' '.join(fmt(float(v)) for v in row) + '\n')

    K4 = np.eye(4)
    K4[:3, :3] = fr.K
    pct_f = lambda v: '%f' % v   # noqa: E731  (exact for these intrinsics)
    for nm, M in (('intrinsic_color', K4), ('extrinsic_color', np.eye(4)),
                  ('intrinsic_depth', K4), ('extrinsic_depth', np.eye(4))):
        save_mat(M, root / 'intrinsic' / f'{nm}.txt', pct_f)
    for i in range(len(poses)):
        shutil.copyfile(fr.path(i, 'color.jpg'), root / 'color' / f'{i}.jpg')
        assert cv2.imwrite(str(root / 'depth' / f'{i}.png'), fr.depth(i))
        if i == 3:   # ScanNet marks a failed tracking frame by an all -inf matrix
            M = np.full((4, 4), -np.inf)
        else:
            M = np.loadtxt(fr.path(i, 'pose.txt'))
        # ScanNet's '%f' keeps 6 decimals, which would change the 7-Scenes numbers; repr()
        # (shortest round trip) keeps the layout and parses back to the identical doubles.
        save_mat(M, root / 'pose' / f'{i}.txt', lambda v: '-inf' if v == -np.inf else repr(v))


def truncate_middle_of_chunk(path):
    """Cut a ROS 1 bag in the middle of its second chunk record's data."""
    data = path.read_bytes()
    pos = len(b'#ROSBAG V2.0\n')
    chunks = []
    while pos + 4 <= len(data):
        hlen = struct.unpack_from('<I', data, pos)[0]
        hdr = data[pos + 4:pos + 4 + hlen]
        dpos = pos + 4 + hlen
        dlen = struct.unpack_from('<I', data, dpos)[0]
        fields, q = {}, 0
        while q < len(hdr):
            flen = struct.unpack_from('<I', hdr, q)[0]
            k, _, v = hdr[q + 4:q + 4 + flen].partition(b'=')
            fields[k] = v
            q += 4 + flen
        if fields.get(b'op') == b'\x05':
            chunks.append((dpos + 4, dlen))
        pos = dpos + 4 + dlen
    start, dlen = chunks[1] if len(chunks) > 1 else chunks[0]
    cut = start + dlen // 2
    path.write_bytes(data[:cut])
    return len(chunks), cut, len(data)


# --- main ----------------------------------------------------------------------
def build(name, out, fr, poses):
    """Write one variant; return its manifest entry."""
    e = {'name': name}
    small = poses[:BAD_FRAMES]
    if name == 'ros2-sqlite3':
        ros2_variant(name, out, fr, poses, color=True)
        e.update(path=name, kind='ros2', depth_topic=DEPTH,
                 notes='rosbag2 metadata version 8, one .db3; raw 16UC1 depth, camera_info, '
                       f'PoseStamped on {POSE}, rgb8 colour on {COLOR}.')
    elif name == 'ros2-sqlite3-split':
        write_split(name, out, fr, poses)
        e.update(path=name, kind='ros2', depth_topic=DEPTH,
                 notes='Two .db3 files (NAME_0.db3 frames 0..N/2-1, NAME_1.db3 the rest), each '
                       'written by rosbags Writer as its own bag and moved into one folder; '
                       'metadata.yaml merged by this script (relative_file_paths and files list '
                       'both, counts summed). Each .db3 also has its own metadata table row for '
                       'its part only. Topics are registered in both files.')
    elif name == 'ros2-mcap':
        ros2_variant(name, out, fr, poses, storage=StoragePlugin.MCAP)
        e.update(path=name, kind='ros2', depth_topic=DEPTH,
                 notes='mcap storage, same messages as ros2-sqlite3 without colour.')
    elif name.endswith(('-zstd-file', '-zstd-message')):
        storage = StoragePlugin.MCAP if name.startswith('ros2-mcap') else StoragePlugin.SQLITE3
        mode = CompressionMode.FILE if name.endswith('-file') else CompressionMode.MESSAGE
        ros2_variant(name, out, fr, poses, storage=storage, compression=mode)
        e.update(path=name, kind='ros2', depth_topic=DEPTH,
                 notes='The messages of ros2-sqlite3 / ros2-mcap (no colour), compressed by rosbag2 '
                       'as `ros2 bag record --compression-format zstd --compression-mode '
                       f'{mode.name.lower()}` does (rosbags Writer.set_compression): '
                       + ('each bag file zstd-compressed whole (NAME_0.db3.zstd / .mcap.zstd)'
                          if mode == CompressionMode.FILE
                          else 'each message\'s CDR bytes a zstd frame of their own')
                       + '; metadata.yaml says compression_mode and compression_format.')
    elif name == 'ros2-compressed-png':
        ros2_variant(name, out, fr, poses, depth='png16')
        e.update(path=name, kind='ros2', depth_topic=CDEPTH,
                 notes='Humble compressedDepth: format "16UC1; compressedDepth" (no codec suffix '
                       'in Humble), 12-byte ConfigHeader (format 0, depthParam 0,0) + 16-bit PNG '
                       '(zlib level 3; Humble default 9, only the compression effort differs). '
                       'Pixels > 10000 mm zeroed by the codec (65535 -> 0). '
                       'No raw depth topic.')
    elif name == 'ros2-compressed-png-rolling':
        ros2_variant(name, out, fr, poses, depth='png16-rolling', color='jpeg')
        e.update(path=name, kind='ros2', depth_topic=CDEPTH,
                 notes='As ros2-compressed-png but as the rolling branch (3.x, with RVL support) '
                       'writes it: format "16UC1; compressedDepth png", PNG level 3. Colour as '
                       'compressed_image_transport records it: /camera/color/image_raw/compressed, '
                       '"rgb8; jpeg compressed bgr8", the sample\'s JPEG bytes.')
    elif name == 'ros2-compressed-rvl':
        ros2_variant(name, out, fr, poses, depth='rvl')
        e.update(path=name, kind='ros2', depth_topic=CDEPTH,
                 notes='format "16UC1; compressedDepth rvl": ConfigHeader, uint32 LE cols, uint32 '
                       'LE rows, RVL words (rolling rvl_codec.cpp). Pixels > 10000 mm zeroed.')
    elif name == 'ros2-compressed-32f':
        ros2_variant(name, out, fr, poses, depth='png32')
        a, b = quant_params()
        e.update(path=name, kind='ros2', depth_topic=CDEPTH,
                 notes=f'format "32FC1; compressedDepth png": depth mm/1000 as float32 with raw 0 '
                       f'-> NaN; inv = trunc(A/d + B) (0 when d is NaN or >= 10 m) as 16-bit PNG; '
                       f'ConfigHeader depthParam = (A, B) = ({float(a)}, {float(b)}); decoded '
                       f'depth = A/(inv - B) metres, inv 0 -> NaN. 65535 mm -> NaN.')
    elif name == 'ros2-png':
        ros2_variant(name, out, fr, poses, depth='png')
        e.update(path=name, kind='ros2', depth_topic=CPNG,
                 notes='compressed_image_transport png: format "16UC1; png compressed " (trailing '
                       'space), payload a bare 16-bit PNG (no header, no depth filter).')
    elif name in ('ros2-tf', 'ros2-tf-half-rate'):
        half = name.endswith('half-rate')
        ros2_variant(name, out, fr, poses, tf='tree', tf_every=2 if half else 1)
        e.update(path=name, kind='ros2', depth_topic=DEPTH, notes=TF_NOTES + (
            ' Half rate: map->odom and odom->base_link only at even frame stamps; odd frames '
            'need interpolation (last odd frame, if N is even, is after the last /tf).'
            if half else '') + ' /tf_static offered QoS transient_local.')
    elif name == 'ros2-pose-half-rate':
        ros2_variant(name, out, fr, poses, pose_every=2)
        e.update(path=name, kind='ros2', depth_topic=DEPTH,
                 notes='PoseStamped only at even frame stamps; raw depth at every frame.')
    elif name in ('ros1', 'ros1-bz2', 'ros1-lz4'):
        comp = {'ros1': None, 'ros1-bz2': Writer1.CompressionFormat.BZ2,
                'ros1-lz4': Writer1.CompressionFormat.LZ4}[name]
        thr = 64 * 1024 if name == 'ros1-bz2' else None
        ros1_variant(name, out, fr, poses, compression=comp, chunk_threshold=thr,
                     color=(name == 'ros1'))
        e.update(path=f'{name}.bag', kind='ros1', depth_topic=DEPTH,
                 notes=f'ROS 1 bag v2.0, chunk compression {comp.name.lower() if comp else "none"}'
                       + (', chunk threshold 64 KiB (about one chunk per depth message)'
                          if thr else ', chunk threshold 1 MiB (rosbags default)')
                       + (', rgb8 colour' if name == 'ros1' else '')
                       + '. Connection records carry callerid and latching.')
    elif name == 'ros1-roslz4':
        ros1_variant(name, out, fr, poses, compression=Writer1.CompressionFormat.LZ4,
                     compressor=roslz4)
        e.update(path=f'{name}.bag', kind='ros1', depth_topic=DEPTH,
                 notes='ROS 1 bag v2.0, lz4 chunks framed as rosbag writes them (roslz4: '
                       'independent 1 MiB blocks, content checksum), chunk threshold 1 MiB.')
    elif name == 'ros1-tf':
        ros1_variant(name, out, fr, poses, tf='tree')
        e.update(path=f'{name}.bag', kind='ros1', depth_topic=DEPTH,
                 notes=TF_NOTES + ' /tf_static connection has latching=1.')
    elif name == 'ros1-tf1':
        ros1_variant(name, out, fr, poses, tf='tf1')
        e.update(path=f'{name}.bag', kind='ros1', depth_topic=DEPTH,
                 notes='The ros1-tf tree as tf1 recorded it (TUM RGB-D): no /tf_static; /tf '
                       '(tf/tfMessage) at each frame stamp holds all four links, the static two '
                       'stamped like the others; every frame named with a leading slash '
                       '(/map, /camera_depth_optical_frame), the depth header.frame_id too.')
    elif name == 'scannet':
        write_scannet(out, fr, poses)
        e.update(path='scannet', kind='scannet', depth_topic=None, invalid_pose_frames=[3],
                 notes='SensReader export layout: color/K.jpg, depth/K.png (16-bit mm), '
                       'pose/K.txt (4x4 camera-to-world, rows on lines), intrinsic/'
                       '{intrinsic,extrinsic}_{color,depth}.txt. Frame 3 pose all -inf (invalid, '
                       'as ScanNet marks lost tracking). Pose numbers written with repr() so they '
                       'parse to the same doubles as the 7-Scenes files (ScanNet itself writes %f).')
    elif name == 'bad-truncated-db3':
        ros2_variant(name, out, fr, small)
        db = out / name / f'{name}.db3'
        size = db.stat().st_size
        with open(db, 'r+b') as f:
            f.truncate(size // 2)
        e.update(path=name, kind='bad', depth_topic=DEPTH,
                 notes=f'.db3 cut from {size} to {size // 2} bytes; metadata.yaml intact.',
                 expect='refuse: sqlite file truncated/malformed (messages promised by '
                        'metadata.yaml missing) -- an error, not a shorter recording')
    elif name == 'bad-truncated-bag':
        p = out / f'{name}.bag'
        bag = Bag1(p, chunk_threshold=32 * 1024)
        write_frames(bag, TS1, fr, small)
        bag.close()
        nch, cut, size = truncate_middle_of_chunk(p)
        e.update(path=f'{name}.bag', kind='bad', depth_topic=DEPTH,
                 notes=f'uncompressed ROS 1 bag with {nch} chunks cut at byte {cut} of {size}, '
                       'in the middle of the second chunk\'s data; the bag header\'s index_pos '
                       'points past the end.',
                 expect='refuse: truncated bag (index beyond end of file / chunk shorter than '
                        'its data_len)')
    elif name == 'bad-short-compressed':
        ros2_variant(name, out, fr, small, depth='png16-rolling', bad_frame=2,
                     bad_payload=lambda d, fmt, p: (fmt, p[:7]))
        e.update(path=name, kind='bad', depth_topic=CDEPTH,
                 notes='frame 2 compressedDepth payload is 7 bytes (shorter than the 12-byte '
                       'ConfigHeader); other frames are fine.',
                 expect='refuse frame 2 (codec.cpp requires data.size() > 12)', bad_frames=[2])
    elif name == 'bad-8bit-png':
        def eight_bit(d, fmt, p):
            ok, png = cv2.imencode('.png', np.clip(d // 16, 0, 255).astype(np.uint8))
            return fmt, CONFIG_HEADER.pack(INV_DEPTH, 0.0, 0.0) + png.tobytes()
        ros2_variant(name, out, fr, small, depth='png16-rolling', bad_frame=2,
                     bad_payload=eight_bit)
        e.update(path=name, kind='bad', depth_topic=CDEPTH,
                 notes='frame 2 is "16UC1; compressedDepth png" whose PNG is 8-bit grey.',
                 expect='refuse frame 2: inner PNG is not 16-bit', bad_frames=[2])
    elif name == 'bad-tf-cycle':
        ros2_variant(name, out, fr, small, tf='cycle')
        e.update(path=name, kind='bad', depth_topic=DEPTH,
                 notes='/tf at each stamp: map->odom, odom->base_link, base_link->map (cycle '
                       'map->odom->base_link->map; every child has one parent). Static tree as '
                       'in ros2-tf.',
                 expect='refuse: TF tree has a cycle')
    elif name == 'bad-tf-two-parents':
        ros2_variant(name, out, fr, small, tf='two-parents')
        e.update(path=name, kind='bad', depth_topic=DEPTH,
                 notes='/tf at each stamp: map->odom, odom->base_link and map->base_link '
                       '(base_link has parents odom and map). Static tree as in ros2-tf.',
                 expect='refuse: frame base_link has two parents')
    else:
        raise SystemExit(f'unknown variant {name!r}; known: {", ".join(VARIANTS)}')
    return e


# --- self-check ------------------------------------------------------------------
def compose_tf(tfs_by_child, child, t):
    """map->child from the latest-at-or-before-t transforms (exact stamps here)."""
    M, seen = np.eye(4), set()
    while child != 'map':
        if child in seen:
            raise ValueError('cycle')
        seen.add(child)
        parent, trans, quat = tfs_by_child[child]
        M = make_T(trans, quat) @ M
        child = parent
    return M


def check(out, manifest, fr, poses):
    """Read each recording back with rosbags' AnyReader and compare with the sample."""
    from rosbags.highlevel import AnyReader
    failures = []

    def fail(name, msg):
        failures.append(f'{name}: {msg}')

    for e in manifest:
        name, kind = e['name'], e['kind']
        n = BAD_FRAMES if kind == 'bad' else len(poses)
        n = min(n, len(poses))
        if kind == 'scannet':
            root = out / e['path']
            for i in range(n):
                d = cv2.imread(str(root / 'depth' / f'{i}.png'), cv2.IMREAD_UNCHANGED)
                if not np.array_equal(d, fr.depth(i)):
                    fail(name, f'depth {i} differs')
                P = np.loadtxt(root / 'pose' / f'{i}.txt')
                ref = np.loadtxt(fr.path(i, 'pose.txt'))
                if i == 3:
                    if not np.all(P == -np.inf):
                        fail(name, 'frame 3 not -inf')
                elif not np.array_equal(P, ref):
                    fail(name, f'pose {i} differs')
            print(f'{"FAIL" if any(f.startswith(name + ":") for f in failures) else "ok  "} {name}')
            continue
        path = out / e['path']
        try:
            with AnyReader([path], default_typestore=TS1 if path.suffix == '.bag' else None) as r:
                if path.suffix == '.bag':
                    # AnyReader builds ROS 1 types from the bag's own message definitions.
                    pass
                depth, pose, tf, static, info, color = {}, {}, {}, None, 0, 0
                tf_all = {}
                for c, ts_ns, raw in r.messages():
                    msg = r.deserialize(raw, c.msgtype)
                    if hasattr(msg, 'header'):
                        st = msg.header.stamp
                        if st.nanosec != 0 or ts_ns != st.sec * 1_000_000_000:
                            fail(name, f'{c.topic}: log time {ts_ns} != stamp {st}')
                    if c.topic == DEPTH:
                        img = np.frombuffer(msg.data, '<u2').reshape(msg.height, msg.width)
                        depth[msg.header.stamp.sec] = (msg.encoding, img)
                    elif c.topic in (CDEPTH, CPNG):
                        t = msg.header.stamp.sec
                        try:
                            if c.topic == CPNG:
                                img = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8),
                                                   cv2.IMREAD_UNCHANGED)
                                depth[t] = (msg.format, img)
                            else:
                                depth[t] = (msg.format,) + decode_compressed_depth(
                                    msg.format, bytes(msg.data))[1:]
                        except ValueError as err:
                            depth[t] = ('error', str(err))
                    elif c.topic == POSE:
                        p, q = msg.pose.position, msg.pose.orientation
                        pose[msg.header.stamp.sec] = [p.x, p.y, p.z, q.x, q.y, q.z, q.w]
                    elif c.topic == '/tf':
                        for x in msg.transforms:
                            tr, q = x.transform.translation, x.transform.rotation
                            tf_all.setdefault(x.header.stamp.sec, []).append(
                                (x.child_frame_id, x.header.frame_id))
                            tf.setdefault(x.header.stamp.sec, {})[x.child_frame_id] = (
                                x.header.frame_id, [tr.x, tr.y, tr.z], [q.x, q.y, q.z, q.w])
                    elif c.topic == '/tf_static':
                        if static is not None or ts_ns != 0:
                            fail(name, '/tf_static not once at log time 0')
                        static = {x.child_frame_id: (x.header.frame_id,
                                                     [x.transform.translation.x,
                                                      x.transform.translation.y,
                                                      x.transform.translation.z],
                                                     [x.transform.rotation.x, x.transform.rotation.y,
                                                      x.transform.rotation.z, x.transform.rotation.w])
                                  for x in msg.transforms}
                    elif c.topic == INFO:
                        k = msg.K if hasattr(msg, 'K') else msg.k
                        if not np.array_equal(np.asarray(k).reshape(3, 3), fr.K):
                            fail(name, 'camera_info K differs')
                        info += 1
                    elif c.topic == COLOR:
                        rgb = np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.width, 3)
                        if not np.array_equal(rgb, fr.color_rgb(msg.header.stamp.sec)):
                            fail(name, 'colour differs')
                        color += 1
        except Exception as err:  # noqa: BLE001 -- bad inputs are meant to fail here
            if kind == 'bad':
                print(f'ok   {name}: refused by rosbags ({type(err).__name__}: {err})'[:200])
                continue
            fail(name, f'reading failed: {type(err).__name__}: {err}')
            continue
        # Compare frames.
        for i in range(n):
            t = int(poses[i][0])
            src = fr.depth(i)
            got = depth.get(t)
            if got is None:
                fail(name, f'no depth at t={t}')
                continue
            fmt, img = got[0], got[1]
            if kind == 'bad' and i == 2 and name in ('bad-short-compressed', 'bad-8bit-png'):
                if fmt != 'error':
                    fail(name, 'bad frame 2 decoded without error')
                continue
            if fmt == 'error':
                fail(name, f'frame {t}: {img}')
            elif fmt.startswith('32FC1'):
                ref = mm_to_metres_32f(src)
                ref[src > 10000] = np.nan
                if not np.array_equal(np.isnan(img), np.isnan(ref)):
                    fail(name, f'frame {t}: NaN pattern differs')
                ok = ~np.isnan(ref)
                err = np.abs(img[ok] - ref[ok])
                bound = ref[ok] ** 2 / float(quant_params()[0]) * 1.01 + 1e-6  # one step
                if np.any(err > bound):
                    fail(name, f'frame {t}: 32FC1 error {err.max()} beyond one step')
            elif 'compressedDepth' in fmt:
                if not np.array_equal(img, max_depth_filter_16u(src)):
                    fail(name, f'frame {t}: 16UC1 differs')
            elif not np.array_equal(img, src):
                fail(name, f'frame {t}: depth differs')
        if name == 'ros2-pose-half-rate':
            want = {int(p[0]) for k, p in enumerate(poses) if k % 2 == 0}
        elif tf or name.startswith('bad-tf'):
            want = set()
        else:
            want = {int(p[0]) for p in poses[:n]}
        if set(pose) != want:
            fail(name, f'pose stamps {sorted(pose)} != {sorted(want)}')
        for t, v in pose.items():
            if v != poses[t][1:]:
                fail(name, f'pose at {t} not verbatim')
        if tf and not name.startswith('bad-tf'):
            every = 2 if 'half-rate' in name else 1
            if sorted(tf) != [int(p[0]) for k, p in enumerate(poses) if k % every == 0]:
                fail(name, f'tf stamps {sorted(tf)}')
            for t, links in tf.items():
                M = compose_tf({**static, **links}, OPTICAL, t)
                ref = make_T(poses[t][1:4], poses[t][4:8])
                if np.abs(M - ref).max() > 1e-12:
                    fail(name, f'tf at {t} composes to a different pose')
        if name.startswith('bad-tf'):
            try:
                for t, links in tf_all.items():
                    parents = {}
                    edges = [(c, p) for c, (p, _, _) in static.items()] + links
                    for child, parent in edges:
                        parents.setdefault(child, set()).add(parent)
                    if any(len(v) > 1 for v in parents.values()):
                        raise ValueError('two parents')
                    for start in parents:          # walk up from every frame
                        seen, f = set(), start
                        while f in parents:
                            if f in seen:
                                raise ValueError('cycle')
                            seen.add(f)
                            f = next(iter(parents[f]))
                fail(name, 'tf looks valid')
            except ValueError:
                pass
        if kind != 'bad' and info != n:
            fail(name, f'{info} camera_info messages')
        print(f'{"FAIL" if any(f.startswith(name + ":") for f in failures) else "ok  "} {name}'
              f' ({len(depth)} depth, {len(pose)} pose, {len(tf)} tf stamps, {color} colour)')
    for f in failures:
        print('FAIL', f)
    return 1 if failures else 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--sevenscenes', required=True, type=Path)
    ap.add_argument('--poses', required=True, type=Path)
    ap.add_argument('--frames', required=True, type=int)
    ap.add_argument('--out', required=True, type=Path)
    ap.add_argument('--only', nargs='+', metavar='NAME', choices=VARIANTS)
    ap.add_argument('--check', action='store_true',
                    help='read everything back with rosbags and compare with the sample')
    a = ap.parse_args(argv)
    if a.frames < 1:
        sys.exit('--frames must be at least 1')
    poses = read_poses(a.poses, a.frames)
    fr = Frames(a.sevenscenes, a.frames)
    a.out.mkdir(parents=True, exist_ok=True)
    names = a.only or VARIANTS
    manifest = []
    for name in names:
        dst = a.out / name
        for p in (dst, a.out / f'{name}.bag'):   # writers refuse to overwrite; start clean
            if p.is_dir():
                shutil.rmtree(p)
            elif p.exists():
                p.unlink()
        manifest.append(build(name, a.out, fr, poses))
    (a.out / 'manifest.json').write_text(json.dumps(manifest, indent=2) + '\n')
    if a.check:
        return check(a.out, manifest, fr, poses)
    return 0


if __name__ == '__main__':
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    sys.exit(main())
