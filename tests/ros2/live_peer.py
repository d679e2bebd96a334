"""A ROS 2 node as rmw_zenoh makes one, in Python, with no ROS installed: `eclipse-zenoh` for the wire and
`rosbags` for CDR and type hashes. It listens on a Zenoh endpoint that Kairos connects to, then:

- receives Kairos' /kairos/imu topic, checking its key expression, type hash and attachment (33 bytes, the
  sequence counting from 1) and decoding each message with rosbags;
- waits until Kairos' subscription to /speed is listed among the liveliness tokens, then publishes
  std_msgs/Float64 values 0.5, 1.0, ... on it, numbered 1..20 but for 11, which it skips (one lost);
- prints what it saw as JSON, with the liveliness tokens listed while Kairos ran.

Usage: python3 live_peer.py ENDPOINT SECONDS
"""

import json
import struct
import sys
import threading
import time

from node import STORE, listening_session, topic_key
IMU = "sensor_msgs/msg/Imu"
FLOAT64 = "std_msgs/msg/Float64"


def main(endpoint, seconds):
    session = listening_session(endpoint)
    seen = {"imu": [], "problems": [], "tokens": [], "published": 0}
    lock = threading.Lock()
    expected_key = topic_key("/kairos/imu", IMU)

    def on_imu(sample):
        with lock:
            key = str(sample.key_expr)
            if key != expected_key:
                seen["problems"].append(f"key {key}, not {expected_key}")
            attachment = sample.attachment.to_bytes() if sample.attachment is not None else b""
            if len(attachment) != 33 or attachment[16] != 16:
                seen["problems"].append(f"attachment of {len(attachment)} bytes")
                return
            sequence, source_time = struct.unpack("<qq", attachment[:16])
            message = STORE.deserialize_cdr(sample.payload.to_bytes(), IMU)
            seen["imu"].append({
                "sequence": sequence,
                "source_time": source_time,
                "stamp": message.header.stamp.sec * 10**9 + message.header.stamp.nanosec,
                "frame_id": message.header.frame_id,
                "acceleration_z": message.linear_acceleration.z,
            })

    subscriber = session.declare_subscriber("0/kairos/imu/**", on_imu)
    print("ready", flush=True)

    # Kairos' subscription listed: then publish.
    speed_key = topic_key("/speed", FLOAT64)
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        tokens = [str(reply.ok.key_expr) for reply in session.liveliness().get("@ros2_lv/0/**") if reply.ok]
        if any("/MS/" in token and "%speed" in token for token in tokens):
            seen["tokens"] = sorted(set(tokens))
            break
        time.sleep(0.1)
    publisher = session.declare_publisher(speed_key)
    gid = bytes(range(16))
    for number in range(1, 21):
        if number == 11:
            continue
        message = STORE.types[FLOAT64](data=number * 0.5)
        attachment = struct.pack("<qqB", number, time.time_ns(), 16) + gid
        publisher.put(bytes(STORE.serialize_cdr(message, FLOAT64)), attachment=attachment)
        seen["published"] += 1
        time.sleep(0.05)

    while time.monotonic() < deadline:
        time.sleep(0.1)
    seen["expected_key"] = expected_key
    subscriber.undeclare()
    session.close()
    with lock:
        print(json.dumps(seen), flush=True)


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]))
