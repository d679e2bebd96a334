"""What the tests' ROS 2 nodes in Python share: a Zenoh session as rmw_zenoh's peers open theirs, listening
where Kairos connects, and ROS 2's names as rmw_zenoh writes them."""

import json

import zenoh
from rosbags.typesys import Stores, get_typestore

STORE = get_typestore(Stores.ROS2_JAZZY)

# The hash ROS 2 keys std_srvs/srv/Trigger by (REP 2011), as a ROS 2 Jazzy node declares it (rosbags hashes
# messages only).
TRIGGER_HASH = "RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f"


def listening_session(endpoint):
    """A peer listening on `endpoint`, no multicast scouting: Kairos connects to it as to a router."""
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("listen/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(config)


def dds(ros_type):
    """`std_msgs/msg/String` as DDS names it: `std_msgs::msg::dds_::String_`."""
    package, interface, name = ros_type.split("/")
    return f"{package}::{interface}::dds_::{name}_"


def topic_key(topic, ros_type, domain=0):
    """The key expression of a topic's messages (the topic without its outer slashes)."""
    return f"{domain}/{topic.strip('/')}/{dds(ros_type)}/{STORE.hash_rihs01(ros_type)}"
