"""The procedural street: static layout (sidewalks, buildings, lamp posts, trees), the calm
traffic, and ``build_world``, which draws a whole :class:`~radar4dgs.datasets.synth.world.World`.

Geometry and constants are described in ``world``; realistic traffic lives in ``traffic``.
"""

from __future__ import annotations

import numpy as np

from radar4dgs.datasets.synth import traffic as T
from radar4dgs.datasets.synth.config import SynthConfig
from radar4dgs.datasets.synth.motion import ConstantVelocity, footprint_track
from radar4dgs.datasets.synth.raycast import Primitives, rot_z
from radar4dgs.datasets.synth.texture import make_noise
from radar4dgs.datasets.synth.world import (
    BUILDING,
    CROSS_HALF,
    CURB_Y,
    EGO_LANE_Y,
    FACADE_COLORS,
    FOLIAGE,
    GROUND,
    LANE,
    POLE,
    SIDEWALK,
    SIDEWALK_HEIGHT,
    SIDEWALK_OUTER,
    TRUNK,
    EgoTrack,
    Mover,
    World,
    constant_car,
    ranged,
)

# Random stream of the traffic profiles: np.random.default_rng([seed, TRAFFIC_STREAM]); the calm
# layout uses stream 0 and generate.py's sensors 1..6.
TRAFFIC_STREAM = 21


class _BoxList:
    """Accumulates static boxes and spheres (road frame) before they become a Primitives."""

    def __init__(self) -> None:
        self.boxes: list[tuple[np.ndarray, np.ndarray, np.ndarray, int, np.ndarray]] = []
        self.spheres: list[tuple[np.ndarray, float, int, np.ndarray]] = []

    def box(self, lo, hi, material: int, color, yaw: float = 0.0) -> None:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        self.boxes.append(((lo + hi) / 2, rot_z(yaw), (hi - lo) / 2, material, np.asarray(color, float)))

    def sphere(self, center, radius: float, material: int, color) -> None:
        self.spheres.append((np.asarray(center, float), float(radius), material, np.asarray(color, float)))

    def build(self) -> Primitives:
        ground_color = np.array([[0.3, 0.3, 0.3]])
        return Primitives(
            box_center=np.reshape([b[0] for b in self.boxes], (-1, 3)),
            box_rot=np.reshape([b[1] for b in self.boxes], (-1, 3, 3)),
            box_half=np.reshape([b[2] for b in self.boxes], (-1, 3)),
            sphere_center=np.reshape([s[0] for s in self.spheres], (-1, 3)),
            sphere_radius=np.asarray([s[1] for s in self.spheres], float),
            material=np.asarray([GROUND] + [b[3] for b in self.boxes] + [s[2] for s in self.spheres], int),
            obj=np.full(1 + len(self.boxes) + len(self.spheres), -1, int),
            color=np.concatenate([ground_color, np.reshape([b[4] for b in self.boxes], (-1, 3)),
                                  np.reshape([s[3] for s in self.spheres], (-1, 3))]))


def _street_furniture(rng: np.random.Generator, boxes: _BoxList, x_start: float, x_end: float,
                      x_int: float) -> None:
    """Sidewalks, buildings, lamp posts and trees along both sides of the main road."""
    gap = (x_int - CROSS_HALF, x_int + CROSS_HALF)
    for side in (-1.0, 1.0):
        for x0, x1 in ((x_start, gap[0]), (gap[1], x_end)):
            y_in, y_out = sorted((side * CURB_Y, side * SIDEWALK_OUTER))
            boxes.box((x0, y_in, 0.0), (x1, y_out, SIDEWALK_HEIGHT), SIDEWALK, (0.62, 0.61, 0.58))
        x = x_start
        while x < x_end:
            length = rng.uniform(8.0, 26.0)
            if x < gap[1] + 1.5 and x + length > gap[0] - 1.5:  # keep the intersection open
                x = gap[1] + 1.5
                continue
            front = rng.uniform(13.0, 16.0)
            depth = rng.uniform(8.0, 14.0)
            height = rng.uniform(6.0, 24.0)
            y_in, y_out = sorted((side * front, side * (front + depth)))
            color = np.clip(FACADE_COLORS[rng.integers(len(FACADE_COLORS))] * rng.uniform(0.9, 1.1), 0, 1)
            boxes.box((x, y_in, 0.0), (x + length, y_out, height), BUILDING, color)
            x += length + (rng.uniform(0.0, 1.5) if rng.random() < 0.7 else rng.uniform(4.0, 9.0))
        x = x_start + rng.uniform(0.0, 20.0)
        while x < x_end:
            if not (gap[0] - 2.0 < x < gap[1] + 2.0):
                y = side * 10.0
                boxes.box((x - 0.08, y - 0.08, 0.0), (x + 0.08, y + 0.08, rng.uniform(5.5, 7.5)), POLE,
                          (0.45, 0.46, 0.48))
            x += rng.uniform(22.0, 34.0)
        x = x_start + rng.uniform(5.0, 15.0)
        while x < x_end:
            if not (gap[0] - 3.0 < x < gap[1] + 3.0) and rng.random() < 0.75:
                y = side * rng.uniform(11.2, 12.2)
                trunk = rng.uniform(2.2, 3.4)
                radius = rng.uniform(1.3, 2.2)
                boxes.box((x - 0.15, y - 0.15, 0.0), (x + 0.15, y + 0.15, trunk + 0.5 * radius), TRUNK,
                          (0.33, 0.24, 0.16))
                green = np.array([0.20, 0.42, 0.14]) * rng.uniform(0.75, 1.15)
                boxes.sphere((x, y, trunk + 0.8 * radius), radius, FOLIAGE, green)
            x += rng.uniform(11.0, 19.0)


def _cars(rng: np.random.Generator, config: SynthConfig, ego: EgoTrack, duration: float,
          x_int: float) -> list[Mover]:
    """Parked cars in the parking strips and moving cars in their lanes, never overlapping."""
    travel = ego.speed * duration
    cars: list[Mover] = []
    n_parked = int(rng.integers(config.parked_cars[0], config.parked_cars[1] + 1))
    slots: list[float] = []
    for _ in range(50 * max(n_parked, 1)):
        if len(slots) == n_parked:
            break
        x = rng.uniform(0.4 * travel + 12.0, min(travel + 55.0, x_int - CROSS_HALF - 4.0))
        if all(abs(x - s) > 6.5 for s in slots):
            slots.append(x)
    for x in slots:
        side = -1.0 if rng.random() < 0.6 else 1.0
        yaw = (0.0 if side < 0 else np.pi) + rng.normal(0.0, 0.03)
        cars.append(constant_car(rng, len(cars), "parked", (x, side * 8.25, 0.0), yaw, 0.0))

    n_moving = int(rng.integers(config.moving_cars[0], config.moving_cars[1] + 1))
    crossing = rng.random() < config.crossing_probability
    extras = ["slower", "oncoming"]
    rng.shuffle(extras)
    crossing = crossing and n_moving >= 1
    # A crossing car counts as one of the moving cars (it is placed last, clear of the others).
    roles = (["faster", "oncoming"] + extras)[:max(0, n_moving - int(crossing))]
    used_oncoming_lanes = 0
    for role in roles:
        if role == "faster":
            speed = ego.speed + rng.uniform(2.0, 6.0)
            cars.append(constant_car(rng, len(cars), role, (rng.uniform(14.0, 28.0), EGO_LANE_Y, 0.0), 0.0, speed))
        elif role == "slower":
            speed = max(2.0, ego.speed - rng.uniform(2.0, 5.0))
            cars.append(constant_car(rng, len(cars), role, (rng.uniform(18.0, 40.0), -LANE * 1.5, 0.0), 0.0, speed))
        elif role == "oncoming":
            speed = rng.uniform(8.0, 15.0)
            lane_y = LANE * (0.5 if used_oncoming_lanes == 0 else 1.5)
            used_oncoming_lanes += 1
            x0 = travel + speed * duration + rng.uniform(12.0, 50.0)
            cars.append(constant_car(rng, len(cars), role, (x0, lane_y, 0.0), np.pi, speed))
    if crossing:  # passes y = 0 at the intersection during the sequence, clear of other traffic
        for _ in range(30):
            speed = rng.uniform(6.0, 12.0)
            direction = 1.0 if rng.random() < 0.5 else -1.0
            t_cross = rng.uniform(0.35, 0.75) * duration
            x = x_int + (-1.75 if direction > 0 else 1.75)
            candidate = constant_car(rng, len(cars), "crossing", (x, -direction * speed * t_cross, 0.0),
                                  direction * np.pi / 2, speed)
            if not any(_collide(candidate, other, duration) for other in cars):
                cars.append(candidate)
                break
    return cars


def _collide(a: Mover, b: Mover, duration: float, margin: float = 1.0) -> bool:
    """Whether two movers' bounding circles come closer than ``margin`` within the sequence (and one
    frame interval on either side), sampled every 20 ms from their poses (for two constant-velocity
    movers, from the closed form of those poses, which calm scenes have always used)."""
    times = np.arange(-0.5, duration + 0.5, 0.02)
    ta, tb = a.trajectory, b.trajectory
    if isinstance(ta, ConstantVelocity) and isinstance(tb, ConstantVelocity):
        gap = (ta.position0 - tb.position0)[None, :2] + (ta.velocity0 - tb.velocity0)[None, :2] * times[:, None]
    else:
        gap = footprint_track(ta, times)[0] - footprint_track(tb, times)[0]
    reach = np.hypot(a.length, a.width) / 2 + np.hypot(b.length, b.width) / 2 + margin
    return bool((np.linalg.norm(gap, axis=1) < reach).any())


def build_world(config: SynthConfig) -> World:
    """Draw a street layout, an ego trajectory and movers from ``config.seed``.

    The calm draws come from stream ``[seed, 0]`` in a fixed order; the traffic profile's draws
    (``config.traffic``) from stream ``[seed, TRAFFIC_STREAM]``, so calm scenes never change.
    """
    rng = np.random.default_rng([config.seed, 0])
    traffic_rng = np.random.default_rng([config.seed, TRAFFIC_STREAM])
    duration = (config.num_frames - 1) / config.fps
    speed = ranged(rng, config.ego_speed)
    wavelength = ranged(rng, config.weave_wavelength)
    ego = EgoTrack(speed=speed, lane_y=EGO_LANE_Y, amplitude=ranged(rng, config.weave_amplitude),
                   wavenumber=2 * np.pi / wavelength, phase=float(rng.uniform(0, 2 * np.pi)),
                   swing=config.ego_speed_swing, swing_period=config.ego_speed_period)
    travel = speed * duration
    x_int = travel + rng.uniform(35.0, 70.0)
    if config.traffic.near_intersection:
        x_int = T.near_intersection_x(traffic_rng, config.traffic, ego, duration)
    boxes = _BoxList()
    _street_furniture(rng, boxes, x_start=-40.0, x_end=travel + 260.0, x_int=x_int)
    static = boxes.build()
    movers = _cars(rng, config, ego, duration, x_int) if config.traffic.calm_cars else []
    movers += T.realistic_movers(traffic_rng, config, ego, duration, x_int, static, movers)
    sun_az, sun_el = rng.uniform(-np.pi, np.pi), rng.uniform(np.radians(30), np.radians(60))
    sun = np.array([np.cos(sun_el) * np.cos(sun_az), np.cos(sun_el) * np.sin(sun_az), np.sin(sun_el)])
    return World(static=static, movers=tuple(movers), ego=ego, x_int=float(x_int), sun=sun,
                 noise=make_noise(rng), road_to_world=np.linalg.inv(ego.pose(0.0)))
