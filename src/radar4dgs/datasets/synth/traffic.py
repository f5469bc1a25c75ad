"""Realistic traffic (``TrafficConfig`` profiles): movers that pass close and fast, as at 10 Hz in
real streets they move tens to hundreds of pixels per frame.

Each mover is drawn by a sampler in road-frame seconds and metres (so any fps gives the same
motion), then kept only if it stays clear of the ego, of the movers placed before it and of the
street furniture over the whole sequence (``clearance``); otherwise it is drawn again, up to
``TrafficConfig.attempts`` times, and left out if it never fits. All draws come from the traffic
stream, so the calm generator's draws are untouched.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from radar4dgs.datasets.synth import figures as F
from radar4dgs.datasets.synth.clearance import Track, clear_of_static, gap_ahead, track, tracks_overlap
from radar4dgs.datasets.synth.config import SynthConfig, TrafficConfig
from radar4dgs.datasets.synth.motion import ConstantVelocity, LaneChange
from radar4dgs.datasets.synth.raycast import Primitives, rigid
from radar4dgs.datasets.synth.world import (
    CROSS_HALF,
    EGO_LANE_Y,
    LANE,
    SIDEWALK_HEIGHT,
    EgoTrack,
    Mover,
    car_body,
    car_mover,
    constant_car,
    ranged,
)

EGO_REAR, EGO_FRONT, EGO_WIDTH = -1.0, 3.7, 1.9  # ego footprint in its own frame (m); radar at the front
MAX_SPEED = 25.0  # no mover is faster (m/s)
SAMPLE_DT = 0.02  # clearance is checked at this time step (s), from one frame before the first to one after the last
CAR_MARGIN, FIGURE_MARGIN = 0.6, 0.3  # minimum clearance between two cars / when a figure is involved (m)
PARKED_Y = 8.25  # centre line of the parking strips (|y|)
CYCLE_Y = 6.2  # cyclists ride at the right edge of the outer lanes (|y|)
WALK_Y = (10.4, 10.8)  # pedestrians on the sidewalk walk between the lamp posts and the trees (|y|)
ROAD_WALK = 9.2  # pedestrians crossing the road stay within |y| <= this (the kerb is at 9.5)


@dataclass(frozen=True)
class EgoBody:
    """The ego's footprint centre as a trajectory (for clearance checks only)."""

    ego: EgoTrack
    constant: bool = False

    def pose(self, t: float) -> np.ndarray:
        return self.ego.pose(t) @ rigid(np.eye(3), ((EGO_FRONT + EGO_REAR) / 2, 0.0, 0.0))

    def velocity(self, t: float) -> np.ndarray:
        return self.ego.velocity(t)

    def yaw_rate(self, t: float) -> float:
        return self.ego.yaw_rate(t)


def near_intersection_x(rng: np.random.Generator, traffic: TrafficConfig, ego: EgoTrack, duration: float) -> float:
    """Road-frame x of the crossing road's centre, ``intersection_gap`` beyond the ego's front
    bumper at the last frame: the ego reaches or nearly reaches it, so crossing cars look big."""
    return float(ego.position(duration)[0] + EGO_FRONT + ranged(rng, traffic.intersection_gap) + CROSS_HALF)


@dataclass
class Placer:
    """The scene so far: what a new mover has to stay clear of."""

    traffic: TrafficConfig
    ego: EgoTrack
    duration: float
    x_int: float
    static: Primitives
    camera_x: float  # camera position along the ego's x axis (m)
    frame_dt: float  # frame interval (s): gt/flow of the last frame reaches one interval beyond it
    times: np.ndarray = field(init=False)
    ego_track: Track = field(init=False)
    placed: list[tuple[Mover, Track]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.times = np.append(np.arange(-self.frame_dt, self.duration + self.frame_dt, SAMPLE_DT),
                               self.duration + self.frame_dt)
        self.ego_track = track(EgoBody(self.ego), EGO_FRONT - EGO_REAR, EGO_WIDTH, (0.0, 1.6), self.times)

    def ego_x(self, t: float) -> float:
        return float(self.ego.position(t)[0])

    def track_of(self, mover: Mover) -> Track:
        z0 = float(mover.pose(0.0)[2, 3])
        return track(mover.trajectory, mover.length, mover.width, (z0, z0 + mover.height), self.times)

    def fits(self, mover: Mover) -> Track | None:
        """The mover's track if it stays clear of everything placed, the ego and the street; the
        ego keeps at least ``min_gap`` to anything ahead of it in its corridor."""
        candidate = self.track_of(mover)
        if tracks_overlap(candidate, self.ego_track, CAR_MARGIN):
            return None
        if gap_ahead(self.ego_track, candidate).min() < self.traffic.min_gap:
            return None
        for other, other_track in self.placed:
            margin = CAR_MARGIN if mover.category == other.category == "car" else FIGURE_MARGIN
            if tracks_overlap(candidate, other_track, margin):
                return None
        return candidate if clear_of_static(candidate, self.static) else None

    def place(self, rng: np.random.Generator, sample: Callable[[np.random.Generator, "Placer", int], Mover | None],
              index: int) -> Mover | None:
        """Draw with ``sample`` until the mover fits (then keep it) or the attempts run out."""
        for _ in range(self.traffic.attempts):
            mover = sample(rng, self, index)
            if mover is None:
                continue
            fitted = self.fits(mover)
            if fitted is not None:
                self.placed.append((mover, fitted))
                return mover
        return None


# ---------------------------------------------------------------- samplers: (rng, placer, index) -> Mover


def parked(rng: np.random.Generator, p: Placer, index: int) -> Mover | None:
    """A parked car in a parking strip, ahead of the ego, not in the intersection."""
    x = rng.uniform(p.ego_x(0.0) + 5.0, p.ego_x(p.duration) + 80.0)
    if abs(x - p.x_int) < CROSS_HALF + 6.0:  # the crossing road and the zebra before it stay free
        return None
    side = -1.0 if rng.random() < 0.6 else 1.0
    yaw = (0.0 if side < 0 else np.pi) + rng.normal(0.0, 0.03)
    return constant_car(rng, index, "parked", (x, side * PARKED_Y, 0.0), yaw, 0.0)


def van_body(rng: np.random.Generator) -> tuple[float, float, float, np.ndarray]:
    """A drawn van: a car body, longer and taller (1.9-2.5 m), so that it stays visible over a car."""
    length, width, _, color = car_body(rng)
    return 1.2 * length, min(1.05 * width, 2.0), float(rng.uniform(1.9, 2.5)), color


def lead(rng: np.random.Generator, p: Placer, index: int) -> Mover | None:
    """A slower van in the ego lane; the ego closes in to ``lead_gap_end`` at the last frame (a
    van, so that the roof shows over a car that cuts in between)."""
    body = van_body(rng)
    speed = max(p.ego.speed - ranged(rng, p.traffic.lead_closing_speed), 0.4 * p.ego.speed)
    x_end = p.ego_x(p.duration) + EGO_FRONT + ranged(rng, p.traffic.lead_gap_end) + body[0] / 2
    start = np.array([x_end - speed * p.duration, EGO_LANE_Y, 0.0])
    return car_mover(index, "lead", body, ConstantVelocity(start, 0.0, np.array([speed, 0.0, 0.0])))


def cut_in(rng: np.random.Generator, p: Placer, index: int) -> Mover | None:
    """A car changing from the adjacent lane (right of the ego) into the ego lane ahead of it."""
    body = car_body(rng)
    speed = float(np.clip(p.ego.speed + ranged(rng, p.traffic.cut_in_relative_speed), 3.0, MAX_SPEED))
    duration = min(ranged(rng, p.traffic.cut_in_duration), 0.8 * p.duration)
    t_mid = ranged(rng, p.traffic.cut_in_time) * p.duration
    x_mid = p.ego_x(t_mid) + EGO_FRONT + ranged(rng, p.traffic.cut_in_gap) + body[0] / 2
    start = np.array([x_mid - speed * t_mid, EGO_LANE_Y - LANE, 0.0])
    trajectory = LaneChange(start, 0.0, speed, LANE, t_mid - duration / 2, max(duration, 0.5))
    return car_mover(index, "cut_in", body, trajectory)


def oncoming(rng: np.random.Generator, p: Placer, index: int) -> Mover | None:
    """A car in an oncoming lane (mostly the one next to the ego) that passes the camera within
    the sequence, leaving the image at its side."""
    body = car_body(rng)
    speed = ranged(rng, p.traffic.oncoming_speed)
    t_pass = ranged(rng, p.traffic.oncoming_pass) * p.duration
    lane_y = -EGO_LANE_Y if rng.random() < 0.75 else -EGO_LANE_Y + LANE
    x0 = p.ego_x(t_pass) + p.camera_x + speed * t_pass
    return car_mover(index, "oncoming", body, ConstantVelocity(np.array([x0, lane_y, 0.0]), float(np.pi),
                                                               np.array([-speed, 0.0, 0.0])))


def crossing(rng: np.random.Generator, p: Placer, index: int) -> Mover | None:
    """A car on the crossing road that crosses the ego lane's line late in the sequence, when the
    ego is close to the intersection (right-hand traffic)."""
    body = car_body(rng)
    speed = ranged(rng, p.traffic.crossing_speed)
    direction = 1.0 if rng.random() < 0.5 else -1.0  # +1: towards +y (from the ego's right)
    t_cross = ranged(rng, p.traffic.crossing_time) * p.duration
    x = p.x_int + direction * LANE / 2
    start = np.array([x, EGO_LANE_Y - direction * speed * t_cross, 0.0])
    return car_mover(index, "crossing", body, ConstantVelocity(start, float(direction * np.pi / 2),
                                                               np.array([0.0, direction * speed, 0.0])))


def _walker_across(rng: np.random.Generator, p: Placer, speed: float) -> ConstantVelocity | None:
    """Crossing the main road ahead of the ego, on the zebra or anywhere; None if the walk would
    leave the road during the sequence."""
    t_lane = rng.uniform(0.1, 0.9) * p.duration  # in the middle of the ego lane then
    if rng.random() < 0.4:
        x = p.x_int - CROSS_HALF - rng.uniform(1.0, 3.5)  # on the zebra
    else:
        x = p.ego_x(t_lane) + EGO_FRONT + rng.uniform(8.0, 35.0)
    direction = 1.0 if rng.random() < 0.5 else -1.0
    y_at = EGO_LANE_Y + direction * speed * (p.times[[0, -1]] - t_lane)
    if np.abs(y_at).max() > ROAD_WALK:
        return None
    return ConstantVelocity(np.array([x, EGO_LANE_Y - direction * speed * t_lane, 0.0]),
                            float(direction * np.pi / 2), np.array([0.0, direction * speed, 0.0]))


def _walker_along(rng: np.random.Generator, p: Placer, speed: float) -> ConstantVelocity | None:
    """Walking along a sidewalk (at kerb height), clear of the intersection where the sidewalk ends."""
    side = 1.0 if rng.random() < 0.5 else -1.0
    direction = 1.0 if rng.random() < 0.5 else -1.0
    x0 = p.ego_x(0.0) + rng.uniform(10.0, p.ego_x(p.duration) - p.ego_x(0.0) + 40.0)
    x_at = x0 + direction * speed * p.times[[0, -1]]
    if x_at.max() > p.x_int - CROSS_HALF - 1.0 and x_at.min() < p.x_int + CROSS_HALF + 1.0:
        return None
    return ConstantVelocity(np.array([x0, side * rng.uniform(*WALK_Y), SIDEWALK_HEIGHT]),
                            0.0 if direction > 0 else float(np.pi), np.array([direction * speed, 0.0, 0.0]))


def walker(rng: np.random.Generator, p: Placer, index: int) -> Mover | None:
    """A pedestrian crossing the road (mostly) or walking along a sidewalk."""
    speed = ranged(rng, p.traffic.pedestrian_speed)
    across = rng.random() < 0.75
    trajectory = _walker_across(rng, p, speed) if across else _walker_along(rng, p, speed)
    return None if trajectory is None else F.pedestrian(rng, index, trajectory)


def rider(rng: np.random.Generator, p: Placer, index: int) -> Mover | None:
    """A cyclist along the road's right edge (either direction) or across the intersection."""
    speed = ranged(rng, p.traffic.cyclist_speed)
    mode = rng.integers(3)
    if mode == 2:  # across, on the outer part of the crossing road
        direction = 1.0 if rng.random() < 0.5 else -1.0
        t_cross = rng.uniform(0.3, 0.95) * p.duration
        start = np.array([p.x_int + direction * (CROSS_HALF - 1.5), EGO_LANE_Y - direction * speed * t_cross, 0.0])
        trajectory = ConstantVelocity(start, float(direction * np.pi / 2), np.array([0.0, direction * speed, 0.0]))
    else:  # along the main road: with the ego (it overtakes) or towards it
        direction = 1.0 if mode == 0 else -1.0
        t_pass = rng.uniform(0.3, 1.2) * p.duration  # the camera passes it then (maybe after the end)
        x0 = p.ego_x(t_pass) + p.camera_x - direction * speed * t_pass
        start = np.array([x0, -direction * CYCLE_Y, 0.0])
        trajectory = ConstantVelocity(start, 0.0 if direction > 0 else float(np.pi),
                                      np.array([direction * speed, 0.0, 0.0]))
    return F.cyclist(rng, index, trajectory)


def _count(rng: np.random.Generator, bounds: tuple[int, int]) -> int:
    return int(rng.integers(bounds[0], bounds[1] + 1)) if bounds[1] > 0 else 0


def realistic_movers(rng: np.random.Generator, config: SynthConfig, ego: EgoTrack, duration: float, x_int: float,
                     static: Primitives, existing: list[Mover]) -> list[Mover]:
    """The movers of ``config.traffic`` (none for the calm default), clear of the ``existing``
    ones (the calm cars, if kept) and indexed after them.

    Order matters: earlier movers have the first pick of space and time. The cut-in and the
    crossing cars come first (the ego-lane gap and the late crossing are the tightest to fit); the
    lead car then finds a gap that lets them through.
    """
    traffic = config.traffic
    plan: list[Callable] = []
    if not traffic.calm_cars:
        plan += [parked] * _count(rng, config.parked_cars)
    plan += [cut_in] * int(rng.random() < traffic.cut_in_probability)
    plan += [lead] * int(rng.random() < traffic.lead_probability)
    plan += [crossing] * _count(rng, traffic.crossing_cars)
    plan += [oncoming] * _count(rng, traffic.oncoming_cars)
    plan += [rider] * _count(rng, traffic.cyclists)
    plan += [walker] * _count(rng, traffic.pedestrians)
    if not plan:
        return []
    placer = Placer(traffic, ego, duration, x_int, static, float(config.camera_xyz[0]), 1.0 / config.fps)
    placer.placed += [(mover, placer.track_of(mover)) for mover in existing]
    movers: list[Mover] = []
    for sample in plan:
        mover = placer.place(rng, sample, len(existing) + len(movers))
        if mover is not None:
            movers.append(mover)
    return movers
