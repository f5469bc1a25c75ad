"""Trajectories of rigid movers: the pose, velocity and yaw rate of a body as functions of time.

Every mover stays upright on a horizontal surface, so its motion is planar: a footprint-centre
position, a heading (yaw about +z) and their derivatives. A rigid body's surface point ``p`` moves
with ``velocity(t) + omega(t) x (p - position(t))``, ``omega = (0, 0, yaw_rate(t))``.
All quantities are in the road frame (x along the main road, y left, z up).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from radar4dgs.datasets.synth.raycast import rigid, rot_z


class Trajectory(Protocol):
    """A rigid body's motion; ``constant`` is True when velocity and heading never change."""

    constant: bool

    def pose(self, t: float) -> np.ndarray:
        """(4, 4) body-to-road at time ``t`` (s)."""
        ...

    def velocity(self, t: float) -> np.ndarray:
        """(3,) road-frame velocity of the body origin (m/s)."""
        ...

    def yaw_rate(self, t: float) -> float:
        """d(yaw)/dt (rad/s)."""
        ...


@dataclass(frozen=True)
class ConstantVelocity:
    """Straight line at constant speed and fixed heading (speed 0: a parked car).

    ``pose`` is computed exactly as the calm generator always did, so calm scenes stay bit-identical.
    """

    position0: np.ndarray  # (3,) footprint centre at t = 0
    yaw: float  # heading (rad)
    velocity0: np.ndarray  # (3,) velocity (m/s)
    constant: bool = True

    def pose(self, t: float) -> np.ndarray:
        return rigid(rot_z(self.yaw), self.position0 + self.velocity0 * t)

    def velocity(self, t: float) -> np.ndarray:
        return self.velocity0

    def yaw_rate(self, t: float) -> float:
        return 0.0


def quintic_step(u: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smooth 0 -> 1 step ``s(u) = 10u^3 - 15u^4 + 6u^5`` on u in [0, 1] (constant outside) and its
    first two derivatives; zero velocity and acceleration at both ends, as a lane change has."""
    u = np.clip(np.asarray(u, float), 0.0, 1.0)
    s = u ** 3 * (10 - 15 * u + 6 * u * u)
    ds = 30 * u * u * (1 - u) ** 2
    dds = 60 * u * (1 - u) * (1 - 2 * u)
    return s, ds, dds


@dataclass(frozen=True)
class LaneChange:
    """Constant speed ``speed`` along the lane heading ``yaw0`` and a smooth lateral shift.

    Position: ``p0 + h speed t + n offset(t)`` with ``h`` the lane direction, ``n`` its left
    normal and ``offset(t) = shift * quintic_step((t - t_start) / duration)``. The body heads
    along its velocity, so the yaw turns towards the new lane and back: not constant velocity.
    """

    position0: np.ndarray  # (3,) footprint centre at t = 0 (before the shift, if t_start > 0)
    yaw0: float  # lane heading (rad)
    speed: float  # speed along the lane (m/s), > 0
    shift: float  # lateral displacement to the left of the heading (m); negative = to the right
    t_start: float  # the lane change begins (s)
    duration: float  # and lasts this long (s), > 0
    constant: bool = False

    def _lateral(self, t: float) -> tuple[float, float, float]:
        """offset (m), its rate (m/s) and its acceleration (m/s^2) at time ``t``."""
        s, ds, dds = quintic_step((t - self.t_start) / self.duration)
        return (float(self.shift * s), float(self.shift * ds / self.duration),
                float(self.shift * dds / self.duration ** 2))

    def _axes(self) -> tuple[np.ndarray, np.ndarray]:
        c, s = np.cos(self.yaw0), np.sin(self.yaw0)
        return np.array([c, s, 0.0]), np.array([-s, c, 0.0])

    def pose(self, t: float) -> np.ndarray:
        along, left = self._axes()
        offset, rate, _ = self._lateral(t)
        yaw = self.yaw0 + np.arctan2(rate, self.speed)
        return rigid(rot_z(float(yaw)), self.position0 + along * self.speed * t + left * offset)

    def velocity(self, t: float) -> np.ndarray:
        along, left = self._axes()
        return along * self.speed + left * self._lateral(t)[1]

    def yaw_rate(self, t: float) -> float:
        """Analytic d/dt atan(rate / speed)."""
        _, rate, accel = self._lateral(t)
        return float(self.speed * accel / (self.speed ** 2 + rate ** 2))


def footprint_track(trajectory: Trajectory, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T, 2) footprint centres and (T,) headings (rad) at ``times`` (T,), sampled from ``pose``."""
    poses = np.stack([trajectory.pose(float(t)) for t in times])
    return poses[:, :2, 3], np.arctan2(poses[:, 1, 0], poses[:, 0, 0])


def rigid_point_velocity(trajectory: Trajectory, t: float, points: np.ndarray) -> np.ndarray:
    """(N, 3) road-frame velocity of body points ``points`` (N, 3, road frame) at time ``t``:
    ``v(t) + omega(t) x (p - origin(t))``."""
    origin = trajectory.pose(t)[:3, 3]
    omega = np.array([0.0, 0.0, trajectory.yaw_rate(t)])
    return trajectory.velocity(t)[None, :] + np.cross(omega[None, :], points - origin[None, :])
