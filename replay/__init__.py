"""The replay role: recorded stereo (ASL/EuRoC folders, ROS 1/2 bags) published as robot frames."""
