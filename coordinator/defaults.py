"""Defaults that the coordinator's role and its command line share (the command line reads them
without importing the role, so that ``swarm coordinator --help`` stays fast)."""

#: Seconds to wait for a map server's snapshot at start.
SNAPSHOT_TIMEOUT_S = 3.0
