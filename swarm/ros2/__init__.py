"""ROS 2 over Zenoh as rmw_zenoh_cpp puts it on the wire: names and liveliness tokens
(``graph``), the sample attachment (``attachment``), message types of a distribution with CDR and
RIHS01 hashes from ``rosbags`` (``types``), and a node with publishers and subscriptions on a Zenoh
session (``node``). A robot running ROS 2 with ``RMW_IMPLEMENTATION=rmw_zenoh_cpp`` talks to these
directly; no ROS install is needed on our side (docs/ros2.md).
"""
