"""Benchmark 26's peer: writes a rosbag2 bag of 1080p camera images and lidar point clouds with the
`rosbags` package, and reads one back as fast as `rosbags` can, as a ROS user's script would.

Usage:
  python3 bag.py write DIR MEGABYTES   writes DIR/drive/ (MCAP storage, CDR messages, no compression)
  python3 bag.py read DIR              reads and deserialises every message; prints JSON
                                       {"seconds", "messages", "bytes"}

The images are photographs' worth of content (smooth gradients with noise), the clouds 100 000 points of
x, y, z and intensity as a 32-beam lidar lays them out; content does not change what either reader costs
(neither decompresses), only the sizes do.
"""

import json
import sys
import time
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

STORE = get_typestore(Stores.ROS2_HUMBLE)
T = STORE.types
START_NS = 1_700_000_000 * 10**9
WIDTH, HEIGHT = 1920, 1080
POINTS = 100_000


def header(stamp_ns, frame):
    return T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
        frame_id=frame,
    )


def image(i, stamp, rng):
    x = np.linspace(0, 255, WIDTH, dtype=np.float32)
    y = np.linspace(0, 255, HEIGHT, dtype=np.float32)[:, None]
    base = (x + y + 8 * i) % 256
    noise = rng.integers(0, 16, size=(HEIGHT, WIDTH), dtype=np.uint8)
    pixels = np.stack([base, 255 - base, base / 2], axis=-1).astype(np.uint8) + noise[..., None]
    return T["sensor_msgs/msg/Image"](
        header=header(stamp, "camera"), height=HEIGHT, width=WIDTH, encoding="rgb8",
        is_bigendian=0, step=WIDTH * 3, data=pixels.reshape(-1),
    )


def cloud(i, stamp, rng):
    Field = T["sensor_msgs/msg/PointField"]
    fields = [Field(name=n, offset=4 * k, datatype=7, count=1) for k, n in enumerate(["x", "y", "z", "intensity"])]
    azimuth = np.linspace(0, 2 * np.pi, POINTS // 32, dtype=np.float32).repeat(32)
    elevation = np.tile(np.linspace(-0.3, 0.2, 32, dtype=np.float32), POINTS // 32)
    reach = 5 + 40 * rng.random(POINTS, dtype=np.float32)
    points = np.stack([
        reach * np.cos(elevation) * np.cos(azimuth),
        reach * np.cos(elevation) * np.sin(azimuth),
        reach * np.sin(elevation),
        rng.random(POINTS, dtype=np.float32) * 255,
    ], axis=-1).astype("<f4")
    return T["sensor_msgs/msg/PointCloud2"](
        header=header(stamp, "lidar"), height=1, width=POINTS, fields=fields, is_bigendian=False,
        point_step=16, row_step=16 * POINTS, data=points.reshape(-1).view(np.uint8), is_dense=True,
    )


def write(out, megabytes):
    rng = np.random.default_rng(7)
    pair_bytes = WIDTH * HEIGHT * 3 + POINTS * 16
    pairs = max(1, int(megabytes * 1e6 / pair_bytes))
    with Writer(Path(out) / "drive", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        camera = writer.add_connection("/camera/image_raw", "sensor_msgs/msg/Image", typestore=STORE)
        lidar = writer.add_connection("/lidar/points", "sensor_msgs/msg/PointCloud2", typestore=STORE)
        for i in range(pairs):
            stamp = START_NS + i * 100_000_000
            writer.write(camera, stamp, STORE.serialize_cdr(image(i, stamp, rng), "sensor_msgs/msg/Image"))
            writer.write(lidar, stamp + 50_000_000,
                         STORE.serialize_cdr(cloud(i, stamp, rng), "sensor_msgs/msg/PointCloud2"))


def read(folder):
    messages = 0
    size = 0
    started = time.perf_counter()
    with AnyReader([Path(folder) / "drive"], default_typestore=STORE) as reader:
        for connection, _, raw in reader.messages():
            message = reader.deserialize(raw, connection.msgtype)
            size += len(raw)
            messages += 1
            # What a consumer would touch first: the header and the array's length.
            _ = (message.header.stamp.sec, len(message.data))
    seconds = time.perf_counter() - started
    print(json.dumps({"seconds": seconds, "messages": messages, "bytes": size}))


if __name__ == "__main__":
    if sys.argv[1] == "write":
        write(sys.argv[2], float(sys.argv[3]))
    else:
        read(sys.argv[2])
