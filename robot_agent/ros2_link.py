"""One robot's ROS 2 link for its agent: a ROS 2 node (``swarm_agent`` in the robot's namespace)
with the frame source and the command sink, on the agent's own Zenoh session or on a client-mode
session to the robot's ``rmw_zenohd`` router (``ros2.connect``).
"""

from __future__ import annotations

from dataclasses import dataclass

import zenoh

from robot_agent.ros2_commands import Ros2CommandSink
from robot_agent.ros2_frames import Ros2FrameSource
from swarm.config import Mission
from swarm.config.ros2 import Ros2Config
from swarm.protocol import bus
from swarm.ros2.node import Ros2Context, Ros2Node

NODE_NAME = "swarm_agent"


@dataclass
class Ros2Link:
    """The node, its frames and commands, and the session opened for it (None: the agent's)."""

    node: Ros2Node
    frames: Ros2FrameSource
    commands: Ros2CommandSink
    session: zenoh.Session | None = None

    @classmethod
    def open(
        cls, mission: Mission, robot_id: str, session: zenoh.Session, config: Ros2Config | None = None
    ) -> Ros2Link:
        """The link of ``robot_id`` per ``config`` (default: the mission's ``ros2`` settings for it).
        With ``connect`` endpoints a client session of its own to the robot's router carries the
        ROS 2 topics; else ``session``. Raises ConfigError, ValueError or ConnectionError."""
        config = config or mission.ros2_for(robot_id)
        own = None
        if config.connect:
            own = bus.open_session(connect=config.connect, timestamping=True)
        try:
            context = Ros2Context(own or session, config.domain_id, config.distro)
            node = context.node(NODE_NAME, config.namespace)
            frames = Ros2FrameSource(node, config, robot_id)
            tilt_head = mission.rig_for(robot_id).tilt_range_deg > 0
            commands = Ros2CommandSink(node, config, frames.stamp_of, tilt_head)
        except BaseException:
            if own is not None:
                own.close()
            raise
        return cls(node, frames, commands, own)

    def describe(self) -> str:
        return f"{self.frames.describe()}; commands: {self.commands.describe()}"

    def close(self) -> None:
        self.commands.close()
        self.frames.close()
        self.node.close()
        if self.session is not None:
            self.session.close()
