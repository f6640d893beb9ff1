"""The pymunk world: static walls and boxes, differential-drive disc robots, collisions.

Each robot is a dynamic disc whose velocity is set from its command (forward speed along
its heading, turn rate, clipped to the robot's limits) at every physics sub-step, before
pymunk's contact solver runs (a velocity_func). So the solver stops a robot at walls,
boxes and other robots (it slides along a wall it meets at an angle); rotation is not
disturbed by contacts (infinite moment, no friction).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pymunk

from swarm.formats.floor_plan import FloorPlan

#: Physics sub-step (s). Contacts are found after a sub-step's motion, so a robot can
#: overlap a wall by at most one sub-step of travel (2.5 mm at 0.5 m/s) before the solver
#: pushes it back; a new command takes effect one sub-step later.
SUBSTEP = 0.005


@dataclass
class RobotState:
    """A robot in the world: its body and shape, command and odometry."""

    robot_id: str
    body: pymunk.Body
    shape: pymunk.Circle
    v: float = 0.0
    omega: float = 0.0
    distance: float = 0.0


class World:
    """A floor plan as a pymunk space with differential-drive robots."""

    def __init__(
        self,
        plan: FloorPlan,
        radius: float = 0.18,
        max_speed: float = 0.5,
        max_turn_rate: float = 1.5,
    ):
        self.plan = plan
        self.radius = radius
        self.max_speed = max_speed
        self.max_turn_rate = max_turn_rate
        self.time = 0.0
        self.space = pymunk.Space()
        self.space.collision_slop = 0.001
        self.space.iterations = 20
        self.robots: dict[str, RobotState] = {}
        for quad in plan.quads:
            shape = pymunk.Poly(self.space.static_body, [tuple(p) for p in quad])
            shape.friction = 0.0
            self.space.add(shape)

    def add_robot(self, robot_id: str, x: float, y: float, yaw: float = 0.0) -> RobotState:
        """Place a robot; it starts still."""
        if robot_id in self.robots:
            raise ValueError(f"robot {robot_id!r} is already in the world")
        body = pymunk.Body(mass=10.0, moment=math.inf)
        body.position = (x, y)
        body.angle = yaw
        shape = pymunk.Circle(body, self.radius)
        shape.friction = 0.0
        state = RobotState(robot_id, body, shape)

        def drive(body: pymunk.Body, _gravity, _damping, _dt) -> None:
            # Runs before the contact solver, so contacts correct the commanded velocity
            # before positions are integrated with it.
            body.velocity = (state.v * math.cos(body.angle), state.v * math.sin(body.angle))
            body.angular_velocity = state.omega

        body.velocity_func = drive
        self.space.add(body, shape)
        self.robots[robot_id] = state
        return state

    def command(self, robot_id: str, v: float, omega: float) -> None:
        """Set a robot's forward speed (m/s) and turn rate (rad/s), clipped to its limits."""
        state = self.robots[robot_id]
        state.v = min(max(float(v), -self.max_speed), self.max_speed)
        state.omega = min(max(float(omega), -self.max_turn_rate), self.max_turn_rate)

    def step(self, dt: float) -> None:
        """Advance the world by ``dt`` seconds in sub-steps of at most SUBSTEP."""
        n = max(1, math.ceil(dt / SUBSTEP - 1e-9))
        h = dt / n
        for _ in range(n):
            before = {rid: s.body.position for rid, s in self.robots.items()}
            self.space.step(h)
            for rid, state in self.robots.items():
                state.distance += (state.body.position - before[rid]).length
        self.time += dt

    def pose(self, robot_id: str) -> tuple[float, float, float]:
        """(x, y, yaw) of a robot, yaw wrapped to (-pi, pi]."""
        body = self.robots[robot_id].body
        yaw = math.atan2(math.sin(body.angle), math.cos(body.angle))
        return float(body.position.x), float(body.position.y), yaw

    def poses(self) -> dict[str, tuple[float, float, float]]:
        return {rid: self.pose(rid) for rid in self.robots}
