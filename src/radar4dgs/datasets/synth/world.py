"""The procedural street's data model: constants, the ego trajectory, movers and the World.

Geometry lives in a *road frame*: x along the main road, y to its left, z up, the road surface at
z = 0. The ego starts at x = 0 in the lane y = -1.75 and drives towards +x with a gentle lateral
S-curve. The exported world frame is the ego frame of the first frame (``road_to_world``).

Cross-section of the main road (y): two lanes each way (3.5 m), parking strips (2.5 m),
sidewalks (15 cm high) from |y| = 9.5 m, building fronts from |y| >= 13 m. A crossing road
(14 m wide) meets it at ``x_int``, beyond the ego's last position (just ahead of it in the
realistic traffic profile). ``street.build_world`` draws a layout; ``traffic`` the realistic movers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radar4dgs.datasets.synth.motion import ConstantVelocity, Trajectory, rigid_point_velocity
from radar4dgs.datasets.synth.raycast import Primitives, rigid, rot_z
from radar4dgs.datasets.synth.texture import ValueNoise

# Material ids (Primitives.material); new ones go at the end so that calm scenes keep their ids.
GROUND, SIDEWALK, BUILDING, POLE, TRUNK, FOLIAGE, CAR_BODY, CAR_CABIN, WHEEL, PERSON, BICYCLE = range(11)
MATERIAL_NAMES = ("ground", "sidewalk", "building", "pole", "trunk", "foliage", "car_body", "car_cabin", "wheel",
                  "person", "bicycle")
VEHICLE_MATERIALS = (CAR_BODY, CAR_CABIN, WHEEL)
FIGURE_MATERIALS = (PERSON, BICYCLE)  # pedestrians and cyclists

LANE = 3.5  # lane width (m)
EGO_LANE_Y = -1.75
ROAD_HALF = 7.0  # outer edge of the driving lanes
CURB_Y = 9.5  # road edge (parking strips end here)
SIDEWALK_HEIGHT = 0.15
SIDEWALK_OUTER = 40.0
CROSS_HALF = 7.0  # half width of the crossing road
DYNAMIC_SPEED = 0.5  # objects faster than this (m/s) are "moving" (SCENE_FORMAT gt/dynamic_mask)

CAR_COLORS = np.array([
    [0.92, 0.92, 0.90], [0.75, 0.76, 0.78], [0.12, 0.12, 0.13], [0.65, 0.08, 0.07], [0.10, 0.22, 0.55],
    [0.35, 0.36, 0.38], [0.55, 0.57, 0.60], [0.85, 0.65, 0.10], [0.10, 0.40, 0.25], [0.40, 0.10, 0.25]])
FACADE_COLORS = np.array([
    [0.78, 0.70, 0.58], [0.62, 0.36, 0.28], [0.70, 0.70, 0.68], [0.85, 0.82, 0.74], [0.55, 0.52, 0.48],
    [0.72, 0.60, 0.45], [0.50, 0.45, 0.42], [0.80, 0.76, 0.66]])


@dataclass(frozen=True)
class EgoTrack:
    """Ego motion: x = speed * t (plus an optional speed swing), y = lane + amplitude * sin(k x +
    phase), heading along the path."""

    speed: float  # forward speed along x (m/s)
    lane_y: float
    amplitude: float
    wavenumber: float
    phase: float
    # Optional speed change: dx/dt = speed + swing * sin(2 pi t / swing_period) (SynthConfig.ego_speed_swing);
    # 0 keeps the constant speed (and every calm scene's exact numbers).
    swing: float = 0.0
    swing_period: float = 4.0

    def along(self, t: float) -> tuple[float, float]:
        """Road x (m) and dx/dt (m/s) at time ``t``."""
        if not self.swing:
            return self.speed * t, self.speed
        w = 2 * np.pi / self.swing_period
        return (self.speed * t + self.swing / w * (1 - np.cos(w * t)),
                self.speed + self.swing * np.sin(w * t))

    def position(self, t: float) -> np.ndarray:
        x = self.along(t)[0]
        return np.array([x, self.lane_y + self.amplitude * np.sin(self.wavenumber * x + self.phase), 0.0])

    def velocity(self, t: float) -> np.ndarray:
        """(3,) road-frame velocity (m/s)."""
        x, speed = self.along(t)
        return np.array([speed, self.amplitude * self.wavenumber * speed *
                         np.cos(self.wavenumber * x + self.phase), 0.0])

    def yaw(self, t: float) -> float:
        velocity = self.velocity(t)
        return float(np.arctan2(velocity[1], velocity[0]))

    def yaw_rate(self, t: float) -> float:
        """d(yaw)/dt (rad/s), analytic."""
        if self.swing:
            x, speed = self.along(t)
            arg = self.wavenumber * x + self.phase
        else:  # the constant-speed expression, kept so calm scenes stay bit-identical
            arg, speed = self.wavenumber * self.speed * t + self.phase, self.speed
        slope = self.amplitude * self.wavenumber * np.cos(arg)
        dslope = -self.amplitude * self.wavenumber ** 2 * speed * np.sin(arg)
        return float(dslope / (1 + slope * slope))

    def pose(self, t: float) -> np.ndarray:
        """(4, 4) ego-to-road."""
        return rigid(rot_z(self.yaw(t)), self.position(t))


@dataclass(frozen=True)
class Mover:
    """A rigid object that may move: a car (parked or driving), a pedestrian or a cyclist.

    ``local_*``: (K, 3) box centres and half extents in the body frame (x forward, y left, z up,
    origin on the ground at the footprint centre), ``local_material`` (K,), ``local_color`` (K, 3).
    """

    index: int
    role: str  # calm: parked | faster | slower | oncoming | crossing; also lead | cut_in | pedestrian | cyclist
    category: str  # car | pedestrian | cyclist (scene.json "class")
    length: float  # footprint along the body x axis (m)
    width: float  # footprint along the body y axis (m)
    height: float  # (m)
    color: np.ndarray  # (3,) main colour: car paint, clothing
    trajectory: Trajectory  # pose(t), velocity(t), yaw_rate(t) in the road frame
    local_center: np.ndarray
    local_half: np.ndarray
    local_material: np.ndarray
    local_color: np.ndarray

    def pose(self, t: float) -> np.ndarray:
        """(4, 4) body-to-road at time ``t``."""
        return self.trajectory.pose(t)

    def velocity(self, t: float) -> np.ndarray:
        """(3,) road-frame velocity of the footprint centre at time ``t`` (m/s)."""
        return self.trajectory.velocity(t)

    def speed(self, t: float) -> float:
        return float(np.linalg.norm(self.trajectory.velocity(t)))

    def moving_at(self, t: float) -> bool:
        """Faster than DYNAMIC_SPEED at time ``t`` (the gt/dynamic_mask and radar-label rule)."""
        return self.speed(t) > DYNAMIC_SPEED


@dataclass(frozen=True)
class World:
    """Everything that does not change with the frame: static primitives, movers, ego, textures."""

    static: Primitives
    movers: tuple[Mover, ...]  # mover k owns primitives with obj == k (index == position)
    ego: EgoTrack
    x_int: float
    sun: np.ndarray  # (3,) unit direction towards the sun (road frame)
    noise: ValueNoise
    road_to_world: np.ndarray  # (4, 4): the world frame is the ego frame at t = 0

    def primitives_at(self, t: float) -> Primitives:
        """Static primitives plus every mover's boxes posed at time ``t``."""
        centers, rots, halves, materials, objs, colors = [], [], [], [], [], []
        for mover in self.movers:
            pose = mover.pose(t)
            for c, h, m, k in zip(mover.local_center, mover.local_half, mover.local_material, mover.local_color,
                                  strict=True):
                centers.append(pose[:3, :3] @ c + pose[:3, 3])
                rots.append(pose[:3, :3])
                halves.append(h)
                materials.append(m)
                objs.append(mover.index)
                colors.append(k)
        s = self.static
        m = s.num_boxes
        return Primitives(
            box_center=np.concatenate([s.box_center, np.reshape(centers, (-1, 3))]),
            box_rot=np.concatenate([s.box_rot, np.reshape(rots, (-1, 3, 3))]),
            box_half=np.concatenate([s.box_half, np.reshape(halves, (-1, 3))]),
            sphere_center=s.sphere_center, sphere_radius=s.sphere_radius,
            material=np.concatenate([s.material[:1 + m], np.asarray(materials, int), s.material[1 + m:]]),
            obj=np.concatenate([s.obj[:1 + m], np.asarray(objs, int), s.obj[1 + m:]]),
            color=np.concatenate([s.color[:1 + m], np.reshape(colors, (-1, 3)), s.color[1 + m:]]))

    def point_velocity(self, obj: np.ndarray, points: np.ndarray, t: float) -> np.ndarray:
        """(N, 3) road-frame velocity at time ``t`` of surface points ``points`` (N, 3, road frame)
        owned by objects ``obj`` (N,) (-1 = static): ``v + omega x r`` of the owning rigid body."""
        obj = np.asarray(obj)
        table = np.zeros((len(self.movers) + 1, 3))
        for mover in self.movers:
            table[mover.index + 1] = mover.velocity(t)
        velocity = table[obj + 1]
        for mover in self.movers:  # turning bodies only: constant ones keep the exact table value
            sel = obj == mover.index
            if not mover.trajectory.constant and sel.any():
                velocity[sel] = rigid_point_velocity(mover.trajectory, t, points[sel])
        return velocity

    def moving(self, obj: np.ndarray, t: float) -> np.ndarray:
        """(N,) bool: the owning object moves faster than DYNAMIC_SPEED at time ``t``."""
        table = np.zeros(len(self.movers) + 1, bool)
        for mover in self.movers:
            table[mover.index + 1] = mover.moving_at(t)
        return table[np.asarray(obj) + 1]


def car_boxes(length: float, width: float, height: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body, cabin and two wheel boxes of a car: (4, 3) centres, (4, 3) half extents, (4,) materials."""
    body_lo, body_hi = 0.3, 0.95
    cabin_len = 0.55 * length
    wheel_r = 0.33
    lift = 0.02  # tyres float 2 cm above the road, so that road and tyre surfaces never touch
    centers = np.array([[0.0, 0.0, (body_lo + body_hi) / 2],
                        [-0.08 * length, 0.0, (body_hi + height) / 2],
                        [0.32 * length, 0.0, wheel_r + lift],
                        [-0.32 * length, 0.0, wheel_r + lift]])
    halves = np.array([[length / 2, width / 2, (body_hi - body_lo) / 2],
                       [cabin_len / 2, width / 2 - 0.08, (height - body_hi) / 2],
                       [wheel_r, width / 2 + 0.01, wheel_r],
                       [wheel_r, width / 2 + 0.01, wheel_r]])
    return centers, halves, np.array([CAR_BODY, CAR_CABIN, WHEEL, WHEEL])


def ranged(rng: np.random.Generator, bounds) -> float:
    """A uniform draw in ``bounds`` (low, high); ``low`` without drawing when high <= low."""
    lo, hi = float(bounds[0]), float(bounds[1])
    return lo if hi <= lo else float(rng.uniform(lo, hi))


def car_body(rng: np.random.Generator) -> tuple[float, float, float, np.ndarray]:
    """A drawn car's length, width, height (m) and (3,) paint colour."""
    length, width = rng.uniform(4.0, 4.9), rng.uniform(1.72, 1.92)
    height = rng.uniform(1.40, 1.65)
    color = np.clip(CAR_COLORS[rng.integers(len(CAR_COLORS))] * rng.uniform(0.9, 1.08), 0, 1)
    return float(length), float(width), float(height), color


def car_mover(index: int, role: str, body: tuple[float, float, float, np.ndarray],
              trajectory: Trajectory) -> Mover:
    """A car of ``body`` (from :func:`car_body`) moving along ``trajectory``."""
    length, width, height, color = body
    centers, halves, materials = car_boxes(length, width, height)
    return Mover(index, role, "car", length, width, height, color, trajectory, centers, halves, materials,
                 np.tile(color, (len(materials), 1)))


def constant_car(rng: np.random.Generator, index: int, role: str, position0, yaw: float, speed: float) -> Mover:
    """A drawn car at ``position0`` (3,) heading ``yaw`` at constant ``speed`` (0 = parked)."""
    body = car_body(rng)
    heading = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    return car_mover(index, role, body, ConstantVelocity(np.asarray(position0, float), float(yaw),
                                                         heading * float(speed)))
