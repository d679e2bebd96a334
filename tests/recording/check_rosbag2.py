"""Reads a rosbag2 recording Kairos wrote with two independent ROS 2 readers: `mcap_ros2` (the MCAP
project's decoder, driven by each channel's ros2msg schema) and `rosbags` (its own CDR deserialiser, with
types built from the same schema text). Both must agree; prints each topic's messages as plain values.

Usage: python3 check_rosbag2.py FILE
"""

import json
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.typesys import Stores, get_types_from_msg, get_typestore


def stamp(message):
    return message.header.stamp.sec * 10**9 + message.header.stamp.nanosec


def values(schema, m):
    if schema == "sensor_msgs/msg/Image":
        return {"stamp": stamp(m), "frame_id": m.header.frame_id, "width": m.width, "height": m.height,
                "encoding": m.encoding, "step": m.step, "bytes": len(m.data), "sum": sum(bytes(m.data))}
    if schema == "sensor_msgs/msg/Imu":
        return {"stamp": stamp(m), "angular_velocity": [m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z],
                "linear_acceleration": [m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z],
                "orientation": [m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w],
                "orientation_covariance0": m.orientation_covariance[0]}
    if schema == "sensor_msgs/msg/NavSatFix":
        return {"stamp": stamp(m), "latitude": m.latitude, "longitude": m.longitude, "altitude": m.altitude,
                "status": m.status.status, "covariance_type": m.position_covariance_type,
                "covariance": list(m.position_covariance)}
    if schema == "geometry_msgs/msg/PoseStamped":
        p, q = m.pose.position, m.pose.orientation
        return {"stamp": stamp(m), "position": [p.x, p.y, p.z], "orientation": [q.x, q.y, q.z, q.w]}
    if schema in ("std_msgs/msg/Float64", "std_msgs/msg/Int64", "std_msgs/msg/Bool", "std_msgs/msg/String"):
        return {"data": m.data}
    if schema == "std_msgs/msg/Float64MultiArray":
        return {"data": list(m.data), "dims": [d.size for d in m.layout.dim]}
    raise SystemExit(f"unexpected schema {schema}")


def main(path):
    store = get_typestore(Stores.EMPTY)
    registered = set()
    topics = {}
    with open(path, "rb") as stream:
        reader = make_reader(stream, validate_crcs=True, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            if schema.name not in registered:
                store.register(get_types_from_msg(schema.data.decode(), schema.name))
                registered.add(schema.name)
            again = store.deserialize_cdr(message.data, schema.name)
            ours, theirs = values(schema.name, decoded), values(schema.name, again)
            if ours != theirs:
                raise SystemExit(f"{channel.topic}: mcap_ros2 read {ours}, rosbags {theirs}")
            entry = topics.setdefault(channel.topic, {"schema": schema.name, "encoding": schema.encoding,
                                                      "message_encoding": channel.message_encoding, "messages": []})
            ours["log_time"] = message.log_time
            entry["messages"].append(ours)
    print(json.dumps({"profile": header.profile, "topics": topics}))


if __name__ == "__main__":
    main(sys.argv[1])
