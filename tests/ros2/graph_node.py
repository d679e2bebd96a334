"""A ROS 2 graph as rmw_zenoh advertises it, in Python with no ROS installed: one node with a publisher of
/lidar/points (sensor_msgs/msg/PointCloud2), a subscription to /robot1/cmd_vel (geometry_msgs/msg/Twist), a
server of /scanner/reset (std_srvs/srv/Trigger) and a client of /robot1/plan (nav_msgs/srv/GetPlan), each
declared as the liveliness token rmw_zenoh's design document gives
(`@ros2_lv/<domain>/<session>/<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node>/<topic>/<type>/
<type hash>/<qos>`, names with `/` as `%`), type hashes from rosbags (Trigger's as ROS 2 gives it). Listens on ENDPOINT; says "ready" once
the tokens are declared, then holds them for SECONDS.

Usage: python3 graph_node.py ENDPOINT SECONDS
"""

import sys
import time

from node import STORE, TRIGGER_HASH, dds, listening_session


def main(endpoint, seconds):
    session = listening_session(endpoint)
    zid = str(session.info.zid())
    node = f"@ros2_lv/0/{zid}/0/0/NN/%/%/scanner"
    entities = [
        (1, "MP", "%lidar%points", "sensor_msgs/msg/PointCloud2", STORE.hash_rihs01("sensor_msgs/msg/PointCloud2"),
         "::,5:,:,:,,"),
        (2, "MS", "%robot1%cmd_vel", "geometry_msgs/msg/Twist", STORE.hash_rihs01("geometry_msgs/msg/Twist"),
         "::,10:,:,:,,"),
        (3, "SS", "%scanner%reset", "std_srvs/srv/Trigger", TRIGGER_HASH, "::,10:,:,:,,"),
        (4, "SC", "%robot1%plan", "nav_msgs/srv/GetPlan", "TypeHashNotSupported", "::,10:,:,:,,"),
    ]
    tokens = [session.liveliness().declare_token(node)]
    for entity, kind, name, ros_type, type_hash, qos in entities:
        key = f"@ros2_lv/0/{zid}/0/{entity}/{kind}/%/%/scanner/{name}/{dds(ros_type)}/{type_hash}/{qos}"
        tokens.append(session.liveliness().declare_token(key))
    print("ready", flush=True)
    time.sleep(seconds)
    for token in tokens:
        token.undeclare()
    session.close()


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]))
