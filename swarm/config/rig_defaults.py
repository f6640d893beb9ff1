"""Rig defaults that command lines show in their help, in a module that imports nothing (the
rig's model, :class:`swarm.config.models.RigConfig`, uses them)."""

#: The stereo matcher's nearest depth (m) unless a rig sets ``min_depth``: SGBM's time is
#: about proportional to the disparities searched, fx b / min_depth, and at 0.35 m a 640 x 480
#: EuRoC pair (fx b = 42.9 px m) needs 128 of them against 144 at 0.3 m (docs/stereo.md).
DEFAULT_MIN_DEPTH = 0.35

#: The names of OpenCV's SGBM variants a rig or ``swarm stereo depth --mode`` may choose
#: (``robot_agent.stereo.SGBM_MODES`` maps them to OpenCV's constants).
SGBM_MODE_NAMES = ("sgbm", "hh", "3way", "hh4")
