"""Writes a rosbag2 recording (MCAP storage, CDR messages) with the `rosbags` package, independent of
Kairos, and the values it wrote as JSON, for the tests to replay the bag and compare.

Each topic has its own message type: the common ones Kairos maps to its types, and one it does not
(sensor_msgs/Temperature), which replays as a structured value. Header stamps and log times differ (the
log time is 5 ms after the stamp), so the test can tell which time went where.

Usage: python3 write_rosbag2.py DIR [STORAGE]   (writes DIR/drive/ and DIR/expected.json)

STORAGE is `mcap` (the default), `sqlite3` (a .db3 bag with its message definitions, as ROS 2 Iron and
later write it) or `sqlite3-old` (the same without them, as bags recorded before Iron are).
"""

import json
import math
import sqlite3
import sys
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

STORE = get_typestore(Stores.ROS2_HUMBLE)
T = STORE.types

START_NS = 1_700_000_000 * 10**9
LOG_DELAY_NS = 5_000_000


def header(stamp_ns, frame):
    return T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
        frame_id=frame,
    )


def vector(x, y, z):
    return T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)


def quaternion(x, y, z, w):
    return T["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)


def imu(i, stamp):
    angular = [0.1 * i, -0.2 * i, 0.3]
    linear = [9.81, 0.01 * i, -1.5]
    # Odd messages say they have no orientation (covariance[0] = -1).
    has_orientation = i % 2 == 0
    half = 0.05 * i
    q = [0.0, 0.0, math.sin(half), math.cos(half)]
    covariance = np.zeros(9)
    if not has_orientation:
        covariance[0] = -1.0
    message = T["sensor_msgs/msg/Imu"](
        header=header(stamp, "imu"),
        orientation=quaternion(*q),
        orientation_covariance=covariance,
        angular_velocity=vector(*angular),
        angular_velocity_covariance=np.zeros(9),
        linear_acceleration=vector(*linear),
        linear_acceleration_covariance=np.zeros(9),
    )
    return message, {"angular_velocity": angular, "linear_acceleration": linear,
                     "orientation": q if has_orientation else None}


def fix(i, stamp):
    latitude, longitude, altitude = 48.8566 + 1e-5 * i, 2.3522 - 2e-5 * i, 35.0 + i
    covariance = np.zeros(9)
    covariance[0], covariance[4], covariance[8] = 4.0, 9.0, 16.0
    status = [-1, 0, 2][i % 3]
    message = T["sensor_msgs/msg/NavSatFix"](
        header=header(stamp, "gnss"),
        status=T["sensor_msgs/msg/NavSatStatus"](status=status, service=1),
        latitude=latitude,
        longitude=longitude,
        altitude=altitude,
        position_covariance=covariance,
        position_covariance_type=2,
    )
    return message, {"latitude": latitude, "longitude": longitude, "altitude": altitude,
                     "horizontal_accuracy": 3.0, "vertical_accuracy": 4.0,
                     "status": ["no_fix", "fix", "rtk_fixed"][i % 3]}


def image(i, stamp):
    width, height = 5, 3
    step = width * 3 + 1  # a padded row: the stride is kept
    data = np.array([(i * 31 + k * 7) % 256 for k in range(step * height)], dtype=np.uint8)
    message = T["sensor_msgs/msg/Image"](
        header=header(stamp, "camera"), height=height, width=width, encoding="rgb8",
        is_bigendian=0, step=step, data=data,
    )
    return message, {"width": width, "height": height, "step": step, "data": data.tolist()}


def points(i, stamp):
    Field = T["sensor_msgs/msg/PointField"]
    fields = [Field(name=n, offset=4 * k, datatype=7, count=1) for k, n in enumerate(["x", "y", "z", "intensity"])]
    xyz = [[float(p), float(-p) * 0.5, 0.25 * i] for p in range(6)]
    intensity = [float(10 * p + i) for p in range(6)]
    flat = np.array([v for p, w in zip(xyz, intensity) for v in (*p, w)], dtype="<f4")
    message = T["sensor_msgs/msg/PointCloud2"](
        header=header(stamp, "lidar"), height=1, width=6, fields=fields, is_bigendian=False,
        point_step=16, row_step=96, data=flat.view(np.uint8), is_dense=True,
    )
    return message, {"xyz": xyz, "intensity": intensity}


def speed(i, stamp):
    value = 13.5 + 0.125 * i
    return T["std_msgs/msg/Float64"](data=value), {"data": value}


def pose(i, stamp):
    position = [1.0 + i, 2.0, -0.5 * i]
    q = [0.0, math.sin(0.1 * i), 0.0, math.cos(0.1 * i)]
    message = T["geometry_msgs/msg/PoseStamped"](
        header=header(stamp, "map"),
        pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=position[0], y=position[1], z=position[2]),
                                          orientation=quaternion(*q)),
    )
    return message, {"position": position, "orientation": q}


def temperature(i, stamp):
    value = 21.5 + i
    message = T["sensor_msgs/msg/Temperature"](header=header(stamp, "room"), temperature=value, variance=0.25)
    return message, {"temperature": value, "variance": 0.25, "frame_id": "room"}


def compressed(i, stamp):
    """A PNG in colour, a PNG in grey, then a JPEG, as cv_bridge compresses (OpenCV, from BGR)."""
    import cv2
    width, height = 6, 4
    bgr = np.array([[[(x * 40 + i) % 256, (y * 60) % 256, (x * y * 9) % 256] for x in range(width)]
                    for y in range(height)], dtype=np.uint8)
    if i % 3 == 0:
        encoded, kind = cv2.imencode(".png", bgr)[1], "bgr8; png compressed bgr8"
        values = {"format": "Rgb8", "step": width * 3, "data": bgr[..., ::-1].reshape(-1).tolist()}
    elif i % 3 == 1:
        grey = bgr[..., 1].copy()
        encoded, kind = cv2.imencode(".png", grey)[1], "mono8; png compressed mono8"
        values = {"format": "Gray8", "step": width, "data": grey.reshape(-1).tolist()}
    else:
        encoded, kind = cv2.imencode(".jpg", bgr)[1], "jpeg"
        values = {"format": "Rgb8", "step": width * 3}
    message = T["sensor_msgs/msg/CompressedImage"](header=header(stamp, "camera"), format=kind,
                                                   data=np.frombuffer(encoded.tobytes(), dtype=np.uint8))
    values.update({"width": width, "height": height})
    return message, values


TOPICS = {
    "/imu": ("sensor_msgs/msg/Imu", imu, 20),
    "/fix": ("sensor_msgs/msg/NavSatFix", fix, 6),
    "/camera/image_raw": ("sensor_msgs/msg/Image", image, 3),
    "/points": ("sensor_msgs/msg/PointCloud2", points, 2),
    "/speed": ("std_msgs/msg/Float64", speed, 10),
    "/pose": ("geometry_msgs/msg/PoseStamped", pose, 3),
    "/temperature": ("sensor_msgs/msg/Temperature", temperature, 4),
    "/camera/compressed": ("sensor_msgs/msg/CompressedImage", compressed, 3),
}


def main(out, storage="mcap"):
    out = Path(out)
    expected = {}
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(out / "drive", version=9, storage_plugin=plugin) as writer:
        connections = {topic: writer.add_connection(topic, kind, typestore=STORE) for topic, (kind, _, _) in TOPICS.items()}
        # Interleaved in log-time order, 10 ms apart, as a recorder would receive them.
        messages = []
        for topic, (kind, make, count) in TOPICS.items():
            for i in range(count):
                stamp = START_NS + i * 10_000_000 + len(messages) * 1_000
                message, values = make(i, stamp)
                values.update({"stamp_ns": stamp, "log_ns": stamp + LOG_DELAY_NS})
                messages.append((stamp + LOG_DELAY_NS, topic, kind, message))
                expected.setdefault(topic, []).append(values)
        for log_ns, topic, kind, message in sorted(messages, key=lambda m: m[0]):
            writer.write(connections[topic], log_ns, STORE.serialize_cdr(message, kind))
    if storage == "sqlite3-old":
        database = sqlite3.connect(out / "drive" / "drive.db3")
        database.execute("DROP TABLE message_definitions")
        database.commit()
        database.close()
    (out / "expected.json").write_text(json.dumps(expected))


if __name__ == "__main__":
    main(*sys.argv[1:])
