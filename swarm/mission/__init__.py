"""Mission tooling: launch a simulated mission, watch it, evaluate it, report it, run studies.

This is the top of the house: it starts the roles as processes and may import them.
"""
