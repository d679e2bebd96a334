"""Cross-checks a Kairos recording with the independent Python `mcap` reader.

Reads every message with CRC validation, decodes Foxglove protobuf channels with their schemas and JSON
channels with `json`, checks that each message keeps both times (publish time = timestamp <= log time =
time of issue) and prints per-topic counts and a few decoded values as JSON.

Usage: python3 check_mcap.py FILE
"""

import json
import sys

from mcap.decoder import DecoderFactory as BaseDecoderFactory
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory


class JsonDecoderFactory(BaseDecoderFactory):
    """Decodes channels whose message encoding is JSON."""

    def decoder_for(self, message_encoding, schema):
        if message_encoding != "json":
            return None
        return lambda data: json.loads(data)


def main(path):
    topics = {}
    with open(path, "rb") as stream:
        reader = make_reader(
            stream,
            validate_crcs=True,
            decoder_factories=[ProtobufDecoderFactory(), JsonDecoderFactory()],
        )
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            if message.publish_time > message.log_time:
                raise SystemExit(f"{channel.topic}: publish time after log time at sequence {message.sequence}")
            entry = topics.setdefault(channel.topic, {"schema": schema.name, "count": 0, "first": None})
            entry["count"] += 1
            if entry["first"] is None:
                if schema.name == "foxglove.RawImage":
                    entry["first"] = {"width": decoded.width, "height": decoded.height, "encoding": decoded.encoding,
                                      "bytes": len(decoded.data)}
                elif schema.name == "foxglove.LocationFix":
                    entry["first"] = {"latitude": decoded.latitude, "longitude": decoded.longitude}
                elif schema.name == "foxglove.PoseInFrame":
                    entry["first"] = {"x": decoded.pose.position.x, "w": decoded.pose.orientation.w}
                else:
                    entry["first"] = decoded
    print(json.dumps(topics))


if __name__ == "__main__":
    main(sys.argv[1])
