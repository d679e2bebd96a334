"""Transient-local topics as rmw_zenoh makes them, in Python with no ROS installed: zenoh-ext's advanced
publisher and subscriber (the code rmw_zenoh's own transient-local publishers and subscriptions use, in
`eclipse-zenoh`), `rosbags` for CDR and type hashes. It listens on a Zenoh endpoint that Kairos connects
to, and:

- before Kairos runs, publishes std_msgs/Float64 values 0.5, 1.0, ... 4.0 (numbered 1..8) on /map from a
  publisher that keeps its last 10 messages, as a transient-local ROS 2 publisher does; once Kairos'
  subscription to /map is listed, 4.5 ... 6.0 (9..12) live;
- then, as a publisher that kept 49.5 ... 51.0 while Kairos could not reach it would appear (its
  liveliness token and the queryable it answers for them on, zenoh-ext's layout), offers those four from
  another GID, numbered 1..4, never live;
- once Kairos' publisher of /kairos/count is listed and has published for a while, subscribes to it as
  a transient-local subscription of depth 5 does, and records what it receives: the last messages
  Kairos kept, then the live ones;
- prints what it saw as JSON.

Usage: python3 transient_peer.py ENDPOINT SECONDS
"""

import json
import struct
import sys
import threading
import time

import zenoh.ext
from node import STORE, listening_session, topic_key
FLOAT64 = "std_msgs/msg/Float64"
INT64 = "std_msgs/msg/Int64"


def attachment(number):
    return struct.pack("<qqB", number, time.time_ns(), 16) + bytes(range(16))


def main(endpoint, seconds):
    session = listening_session(endpoint)
    seen = {"count": [], "problems": []}
    lock = threading.Lock()

    publisher = zenoh.ext.declare_advanced_publisher(
        session,
        topic_key("/map", FLOAT64),
        cache=zenoh.ext.CacheConfig(max_samples=10),
        sample_miss_detection=zenoh.ext.MissDetectionConfig(),
        publisher_detection=True,
    )

    def put(number):
        message = STORE.types[FLOAT64](data=number * 0.5)
        publisher.put(bytes(STORE.serialize_cdr(message, FLOAT64)), attachment=attachment(number))

    for number in range(1, 9):
        put(number)
    print("ready", flush=True)

    deadline = time.monotonic() + seconds

    def listed(kind, topic):
        tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/0/**") if r.ok]
        return any(f"/{kind}/" in token and f"/{topic}/" in token for token in tokens)

    while time.monotonic() < deadline and not listed("MS", "%map"):
        time.sleep(0.05)
    for number in range(9, 13):
        put(number)
        time.sleep(0.05)
    time.sleep(0.3)

    # A publisher that appears late, with messages kept from before: reached only by asking it.
    late_gid = bytes(range(16, 32))
    late_key = f"{topic_key('/map', FLOAT64)}/@adv/pub/{session.zid()}/uhlc/_"
    kept = []
    for number, value in enumerate([49.5, 50.0, 50.5, 51.0], start=1):
        message = STORE.types[FLOAT64](data=value)
        kept.append((bytes(STORE.serialize_cdr(message, FLOAT64)),
                     struct.pack("<qqB", number, time.time_ns(), 16) + late_gid))

    def on_query(query):
        asked = dict(p.split("=", 1) for p in str(query.parameters).split(";") if "=" in p)
        seen["late_query"] = str(query.selector)
        for payload, extra in kept[-int(asked.get("_max", len(kept))):]:
            query.reply(topic_key("/map", FLOAT64), payload, attachment=extra)

    late_queryable = session.declare_queryable(late_key, on_query)
    late_token = session.liveliness().declare_token(late_key)

    while time.monotonic() < deadline and not listed("MP", "%kairos%count"):
        time.sleep(0.05)
    # Kairos publishes ten a second: let it publish more than the subscription's depth.
    time.sleep(1.5)

    def on_count(sample):
        with lock:
            raw = sample.attachment.to_bytes() if sample.attachment is not None else b""
            if len(raw) != 33:
                seen["problems"].append(f"attachment of {len(raw)} bytes")
                return
            sequence = struct.unpack("<q", raw[:8])[0]
            message = STORE.deserialize_cdr(sample.payload.to_bytes(), INT64)
            seen["count"].append({
                "sequence": sequence,
                "data": message.data,
                "at": time.monotonic() - declared_at,
            })

    declared_at = time.monotonic()
    subscriber = zenoh.ext.declare_advanced_subscriber(
        session,
        topic_key("/kairos/count", INT64),
        on_count,
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=5),
    )
    while time.monotonic() < deadline:
        time.sleep(0.1)
    subscriber.undeclare()
    late_token.undeclare()
    late_queryable.undeclare()
    publisher.undeclare()
    session.close()
    with lock:
        print(json.dumps(seen), flush=True)


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]))
