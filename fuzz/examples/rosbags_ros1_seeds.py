#!/usr/bin/env python3
"""Writes fuzz/corpus/ros1/seed-rosbags-{none,lz4,bz2}: tiny ROS 1 bags (2x2 16UC1 depth,
CameraInfo, PoseStamped; 2 frames) by the rosbags library's own ROS 1 writer, so the
corpus holds what a real writer lays out (bag header padding, index records, full
connection headers). Needs pip install -r host/tests/recordings/requirements.txt.

    python3 fuzz/examples/rosbags_ros1_seeds.py DIR    # then rename rosbags-X.bag to seed-rosbags-X
"""
import sys
import numpy as np
from pathlib import Path
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_typestore

ts = get_typestore(Stores.ROS1_NOETIC)
T = ts.types
def hdr(t, f):
    return T['std_msgs/msg/Header'](seq=t, stamp=T['builtin_interfaces/msg/Time'](sec=t, nanosec=0), frame_id=f)
out = Path(sys.argv[1])
for comp in (None, 'LZ4', 'BZ2'):
    p = out / f'rosbags-{(comp or "none").lower()}.bag'
    w = Writer(p)
    if comp:
        w.set_compression(getattr(Writer.CompressionFormat, comp))
    w.open()
    ci = w.add_connection('/camera/depth/camera_info', 'sensor_msgs/msg/CameraInfo', typestore=ts)
    di = w.add_connection('/camera/depth/image_rect_raw', 'sensor_msgs/msg/Image', typestore=ts)
    po = w.add_connection('/camera/pose', 'geometry_msgs/msg/PoseStamped', typestore=ts)
    for t in (1, 2):
        k = np.array([2.0, 0, 1, 0, 2.0, 1, 0, 0, 1])
        roi = T['sensor_msgs/msg/RegionOfInterest'](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        info = T['sensor_msgs/msg/CameraInfo'](header=hdr(t, 'cam'), height=2, width=2, distortion_model='plumb_bob',
            D=np.zeros(5), K=k, R=np.eye(3).reshape(-1), P=np.zeros(12), binning_x=0, binning_y=0, roi=roi)
        w.write(ci, t * 10**9, ts.serialize_ros1(info, 'sensor_msgs/msg/CameraInfo'))
        img = T['sensor_msgs/msg/Image'](header=hdr(t, 'cam'), height=2, width=2, encoding='16UC1', is_bigendian=0, step=4,
            data=np.array([232, 3, 0, 4, 1, 2, 3, 4], dtype=np.uint8))
        w.write(di, t * 10**9, ts.serialize_ros1(img, 'sensor_msgs/msg/Image'))
        pose = T['geometry_msgs/msg/Pose'](position=T['geometry_msgs/msg/Point'](x=t * 0.1, y=0, z=1),
            orientation=T['geometry_msgs/msg/Quaternion'](x=0, y=0, z=0, w=1))
        ps = T['geometry_msgs/msg/PoseStamped'](header=hdr(t, 'map'), pose=pose)
        w.write(po, t * 10**9, ts.serialize_ros1(ps, 'geometry_msgs/msg/PoseStamped'))
    w.close()
