"""The failure of a role process that a mission or replay started (``swarm.mission.runner``)."""


class RoleError(RuntimeError):
    """A role process failed or did not answer in time; the message says which and why (the
    command line prints it as one error line)."""
