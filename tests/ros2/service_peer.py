"""ROS 2 services as rmw_zenoh carries them, in Python with no ROS installed: `eclipse-zenoh` for the wire,
`rosbags` for CDR (the service messages registered from their definitions). It listens on a Zenoh endpoint
that Kairos connects to, and:

- serves /reset (std_srvs/srv/Trigger) as an rmw_zenoh service server does: a complete queryable on the
  service's key expression with the type hash ROS 2 gives Trigger; each request is checked (the 33-byte
  attachment, numbered from 1; the request's CDR) and answered "reset N", the attachment echoed;
- once Kairos' server of /kairos/mark is listed (its liveliness token, kind SS), calls it as an rmw_zenoh
  client does, on the key its token names: SetBool true, then false, each reply's attachment and CDR checked;
- prints what it saw as JSON.

Usage: python3 service_peer.py ENDPOINT SECONDS
"""

import json
import struct
import sys
import threading
import time

import zenoh
from node import STORE, TRIGGER_HASH, listening_session
from rosbags.typesys import get_types_from_msg

# Registered under message names (rosbags reads no .srv): the CDR is the same.
for name, definition in [
    ("std_srvs/msg/Trigger_Request", "uint8 structure_needs_at_least_one_member"),
    ("std_srvs/msg/Trigger_Response", "bool success\nstring message"),
    ("std_srvs/msg/SetBool_Request", "bool data"),
    ("std_srvs/msg/SetBool_Response", "bool success\nstring message"),
]:
    STORE.register(get_types_from_msg(definition, name))


def attachment(sequence, gid):
    return struct.pack("<qqB", sequence, time.time_ns(), 16) + gid


def main(endpoint, seconds):
    session = listening_session(endpoint)
    seen = {"requests": [], "marks": [], "problems": []}
    lock = threading.Lock()

    def on_reset(query):
        with lock:
            raw = query.attachment.to_bytes() if query.attachment is not None else b""
            if len(raw) != 33 or raw[16] != 16:
                seen["problems"].append(f"a request's attachment of {len(raw)} bytes")
                query.reply_err("no attachment")
                return
            sequence = struct.unpack("<q", raw[:8])[0]
            payload = query.payload.to_bytes() if query.payload is not None else b""
            STORE.deserialize_cdr(payload, "std_srvs/msg/Trigger_Request")
            seen["requests"].append({"sequence": sequence, "payload": payload.hex(), "key": str(query.key_expr)})
            response = STORE.types["std_srvs/msg/Trigger_Response"](success=True, message=f"reset {sequence}")
            query.reply(f"0/reset/std_srvs::srv::dds_::Trigger_/{TRIGGER_HASH}",
                        bytes(STORE.serialize_cdr(response, "std_srvs/msg/Trigger_Response")),
                        attachment=raw[:8] + struct.pack("<q", time.time_ns()) + raw[16:])

    server = session.declare_queryable(f"0/reset/std_srvs::srv::dds_::Trigger_/{TRIGGER_HASH}", on_reset,
                                       complete=True)
    print("ready", flush=True)

    deadline = time.monotonic() + seconds
    mark = None
    while time.monotonic() < deadline and mark is None:
        for reply in session.liveliness().get("@ros2_lv/0/**"):
            token = str(reply.ok.key_expr) if reply.ok else ""
            if "/SS/" in token and "/%kairos%mark/" in token:
                mark = token
        time.sleep(0.05)
    if mark is None:
        seen["problems"].append("Kairos' server of /kairos/mark never listed")
    else:
        seen["mark_token"] = mark
        dds_type, type_hash = mark.split("/")[-3:-1]
        key = f"0/kairos/mark/{dds_type}/{type_hash}"
        gid = bytes(range(32, 48))
        for sequence, data in [(1, True), (2, False)]:
            request = STORE.types["std_srvs/msg/SetBool_Request"](data=data)
            replies = session.get(key, payload=bytes(STORE.serialize_cdr(request, "std_srvs/msg/SetBool_Request")),
                                  attachment=attachment(sequence, gid),
                                  target=zenoh.QueryTarget.ALL_COMPLETE,
                                  consolidation=zenoh.ConsolidationMode.NONE, timeout=5.0)
            for reply in replies:
                if not reply.ok:
                    seen["problems"].append(f"call {sequence}: {reply.err.payload.to_string()}")
                    continue
                raw = reply.ok.attachment.to_bytes() if reply.ok.attachment is not None else b""
                echoed = struct.unpack("<q", raw[:8])[0] if len(raw) == 33 else None
                response = STORE.deserialize_cdr(reply.ok.payload.to_bytes(), "std_srvs/msg/SetBool_Response")
                seen["marks"].append({
                    "sequence": echoed,
                    "gid_echoed": raw[17:] == gid,
                    "success": response.success,
                    "message": response.message,
                })

    while time.monotonic() < deadline:
        time.sleep(0.1)
    server.undeclare()
    session.close()
    with lock:
        print(json.dumps(seen), flush=True)


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]))
