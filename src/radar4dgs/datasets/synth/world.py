"""The procedural street: layout, the ego trajectory and the cars, all analytic in time.

Geometry lives in a *road frame*: x along the main road, y to its left, z up, the road surface at
z = 0. The ego starts at x = 0 in the lane y = -1.75 and drives towards +x with a gentle lateral
S-curve. The exported world frame is the ego frame of the first frame (``road_to_world``).

Cross-section of the main road (y): two lanes each way (3.5 m), parking strips (2.5 m),
sidewalks (15 cm high) from |y| = 9.5 m, building fronts from |y| >= 13 m. A crossing road
(14 m wide) meets it at ``x_int``, beyond the ego's last position.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radar4dgs.datasets.synth.config import SynthConfig
from radar4dgs.datasets.synth.raycast import Primitives, rigid, rot_z
from radar4dgs.datasets.synth.texture import ValueNoise, make_noise

# Material ids (Primitives.material).
GROUND, SIDEWALK, BUILDING, POLE, TRUNK, FOLIAGE, CAR_BODY, CAR_CABIN, WHEEL = range(9)
MATERIAL_NAMES = ("ground", "sidewalk", "building", "pole", "trunk", "foliage", "car_body", "car_cabin", "wheel")
VEHICLE_MATERIALS = (CAR_BODY, CAR_CABIN, WHEEL)

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
    """Ego motion: x = speed * t, y = lane + amplitude * sin(k x + phase), heading along the path."""

    speed: float  # forward speed along x (m/s)
    lane_y: float
    amplitude: float
    wavenumber: float
    phase: float

    def position(self, t: float) -> np.ndarray:
        x = self.speed * t
        return np.array([x, self.lane_y + self.amplitude * np.sin(self.wavenumber * x + self.phase), 0.0])

    def velocity(self, t: float) -> np.ndarray:
        """(3,) road-frame velocity (m/s)."""
        x = self.speed * t
        return np.array([self.speed, self.amplitude * self.wavenumber * self.speed *
                         np.cos(self.wavenumber * x + self.phase), 0.0])

    def yaw(self, t: float) -> float:
        velocity = self.velocity(t)
        return float(np.arctan2(velocity[1], velocity[0]))

    def yaw_rate(self, t: float) -> float:
        """d(yaw)/dt (rad/s), analytic."""
        arg = self.wavenumber * self.speed * t + self.phase
        slope = self.amplitude * self.wavenumber * np.cos(arg)
        dslope = -self.amplitude * self.wavenumber ** 2 * self.speed * np.sin(arg)
        return float(dslope / (1 + slope * slope))

    def pose(self, t: float) -> np.ndarray:
        """(4, 4) ego-to-road."""
        return rigid(rot_z(self.yaw(t)), self.position(t))


@dataclass(frozen=True)
class Car:
    """A rigid car moving in a straight line at constant speed (zero for parked cars).

    ``local_*``: (K, 3) box centres and half extents in the car frame (x forward, y left, z up,
    origin on the ground at the footprint centre), ``local_material`` (K,).
    """

    index: int
    role: str  # parked | faster | slower | oncoming | crossing
    length: float
    width: float
    height: float
    color: np.ndarray
    position0: np.ndarray  # (3,) road-frame footprint centre at t = 0
    yaw: float  # heading in the road frame (rad)
    velocity: np.ndarray  # (3,) road-frame velocity (m/s)
    local_center: np.ndarray
    local_half: np.ndarray
    local_material: np.ndarray

    @property
    def speed(self) -> float:
        return float(np.linalg.norm(self.velocity))

    @property
    def moving(self) -> bool:
        return self.speed > DYNAMIC_SPEED

    def pose(self, t: float) -> np.ndarray:
        """(4, 4) car-to-road at time ``t``."""
        return rigid(rot_z(self.yaw), self.position0 + self.velocity * t)


@dataclass(frozen=True)
class World:
    """Everything that does not change with the frame: static primitives, cars, ego, textures."""

    static: Primitives
    cars: tuple[Car, ...]
    ego: EgoTrack
    x_int: float
    sun: np.ndarray  # (3,) unit direction towards the sun (road frame)
    noise: ValueNoise
    road_to_world: np.ndarray  # (4, 4): the world frame is the ego frame at t = 0

    def primitives_at(self, t: float) -> Primitives:
        """Static primitives plus every car's boxes posed at time ``t``."""
        centers, rots, halves, materials, objs, colors = [], [], [], [], [], []
        for car in self.cars:
            pose = car.pose(t)
            for c, h, m in zip(car.local_center, car.local_half, car.local_material, strict=True):
                centers.append(pose[:3, :3] @ c + pose[:3, 3])
                rots.append(pose[:3, :3])
                halves.append(h)
                materials.append(m)
                objs.append(car.index)
                colors.append(car.color)
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

    def car_velocity(self, obj: np.ndarray) -> np.ndarray:
        """(N, 3) road-frame velocity of surface points owned by objects ``obj`` (N,) (-1 = static)."""
        table = np.zeros((len(self.cars) + 1, 3))
        for car in self.cars:
            table[car.index + 1] = car.velocity
        return table[np.asarray(obj) + 1]

    def car_moving(self, obj: np.ndarray) -> np.ndarray:
        """(N,) bool: the owning object moves faster than DYNAMIC_SPEED."""
        table = np.zeros(len(self.cars) + 1, bool)
        for car in self.cars:
            table[car.index + 1] = car.moving
        return table[np.asarray(obj) + 1]


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


def _ranged(rng: np.random.Generator, bounds) -> float:
    lo, hi = float(bounds[0]), float(bounds[1])
    return lo if hi <= lo else float(rng.uniform(lo, hi))


def _make_car(rng: np.random.Generator, index: int, role: str, position0, yaw: float, speed: float) -> Car:
    length, width = rng.uniform(4.0, 4.9), rng.uniform(1.72, 1.92)
    height = rng.uniform(1.40, 1.65)
    color = np.clip(CAR_COLORS[rng.integers(len(CAR_COLORS))] * rng.uniform(0.9, 1.08), 0, 1)
    heading = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    centers, halves, materials = car_boxes(length, width, height)
    return Car(index, role, float(length), float(width), float(height), color,
               np.asarray(position0, float), float(yaw), heading * float(speed), centers, halves, materials)


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
          x_int: float) -> list[Car]:
    """Parked cars in the parking strips and moving cars in their lanes, never overlapping."""
    travel = ego.speed * duration
    cars: list[Car] = []
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
        cars.append(_make_car(rng, len(cars), "parked", (x, side * 8.25, 0.0), yaw, 0.0))

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
            cars.append(_make_car(rng, len(cars), role, (rng.uniform(14.0, 28.0), EGO_LANE_Y, 0.0), 0.0, speed))
        elif role == "slower":
            speed = max(2.0, ego.speed - rng.uniform(2.0, 5.0))
            cars.append(_make_car(rng, len(cars), role, (rng.uniform(18.0, 40.0), -LANE * 1.5, 0.0), 0.0, speed))
        elif role == "oncoming":
            speed = rng.uniform(8.0, 15.0)
            lane_y = LANE * (0.5 if used_oncoming_lanes == 0 else 1.5)
            used_oncoming_lanes += 1
            x0 = travel + speed * duration + rng.uniform(12.0, 50.0)
            cars.append(_make_car(rng, len(cars), role, (x0, lane_y, 0.0), np.pi, speed))
    if crossing:  # passes y = 0 at the intersection during the sequence, clear of other traffic
        for _ in range(30):
            speed = rng.uniform(6.0, 12.0)
            direction = 1.0 if rng.random() < 0.5 else -1.0
            t_cross = rng.uniform(0.35, 0.75) * duration
            x = x_int + (-1.75 if direction > 0 else 1.75)
            candidate = _make_car(rng, len(cars), "crossing", (x, -direction * speed * t_cross, 0.0),
                                  direction * np.pi / 2, speed)
            if not any(_collide(candidate, other, duration) for other in cars):
                cars.append(candidate)
                break
    return cars


def _collide(a: Car, b: Car, duration: float, margin: float = 1.0) -> bool:
    """Whether two cars' bounding circles come closer than ``margin`` within the sequence (and one
    frame interval on either side), sampled every 20 ms."""
    times = np.arange(-0.5, duration + 0.5, 0.02)
    gap = (a.position0 - b.position0)[None, :2] + (a.velocity - b.velocity)[None, :2] * times[:, None]
    reach = np.hypot(a.length, a.width) / 2 + np.hypot(b.length, b.width) / 2 + margin
    return bool((np.linalg.norm(gap, axis=1) < reach).any())


def build_world(config: SynthConfig) -> World:
    """Draw a street layout, an ego trajectory and cars from ``config.seed``."""
    rng = np.random.default_rng([config.seed, 0])
    duration = (config.num_frames - 1) / config.fps
    speed = _ranged(rng, config.ego_speed)
    wavelength = _ranged(rng, config.weave_wavelength)
    ego = EgoTrack(speed=speed, lane_y=EGO_LANE_Y, amplitude=_ranged(rng, config.weave_amplitude),
                   wavenumber=2 * np.pi / wavelength, phase=float(rng.uniform(0, 2 * np.pi)))
    travel = speed * duration
    x_int = travel + rng.uniform(35.0, 70.0)
    boxes = _BoxList()
    _street_furniture(rng, boxes, x_start=-40.0, x_end=travel + 260.0, x_int=x_int)
    static = boxes.build()
    cars = _cars(rng, config, ego, duration, x_int)
    sun_az, sun_el = rng.uniform(-np.pi, np.pi), rng.uniform(np.radians(30), np.radians(60))
    sun = np.array([np.cos(sun_el) * np.cos(sun_az), np.cos(sun_el) * np.sin(sun_az), np.sin(sun_el)])
    return World(static=static, cars=tuple(cars), ego=ego, x_int=float(x_int), sun=sun,
                 noise=make_noise(rng), road_to_world=np.linalg.inv(ego.pose(0.0)))
