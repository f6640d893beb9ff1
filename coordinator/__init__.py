"""The coordinator role: a replica of the team map and eq. 35 targets spread over the team."""
