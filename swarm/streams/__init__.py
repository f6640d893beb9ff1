"""Camera streams to robot frames, with no I/O: ROS image and CameraInfo messages to pixels and
calibrations, the tf tree and pose interpolation at a stamp, pairing streams by stamp, camera
pose conventions, and the rectified ``robot/<id>/frame`` of a stereo pair.

Used by the recordings' replay (``replay``) and by a live ROS 2 robot's frame source
(``robot_agent``), so both give the agent the same frames.
"""
