"""The team map as ROS 2 topics over rmw_zenoh (``swarm map ros2``; docs/ros2.md "Team map"): a
client of the mission's bus that follows the merged deltas (``replica``), decides what to send
when (``outputs``) and publishes it as a ROS 2 node (``role``), with its options (``options``).
"""
