"""Pedestrians and cyclists: small rigid movers built from a few boxes (no limb motion).

Body frame as a car's: x forward, y left, z up, origin on the ground at the footprint centre.
Every builder returns (K, 3) box centres, (K, 3) half extents, (K,) materials and (K, 3) colours.
"""

from __future__ import annotations

import numpy as np

from radar4dgs.datasets.synth.motion import Trajectory
from radar4dgs.datasets.synth.world import BICYCLE, PERSON, Mover

LIFT = 0.01  # feet and tyres float 1 cm above the ground, so that the surfaces never touch
CLOTHES = np.array([[0.15, 0.17, 0.30], [0.55, 0.12, 0.10], [0.20, 0.35, 0.22], [0.85, 0.80, 0.70],
                    [0.10, 0.10, 0.10], [0.60, 0.55, 0.20], [0.35, 0.45, 0.65], [0.80, 0.40, 0.10]])
SKIN = np.array([[0.87, 0.70, 0.58], [0.65, 0.47, 0.34], [0.42, 0.29, 0.20]])


def person_boxes(height: float, shoulders: float, shirt: np.ndarray, trousers: np.ndarray, skin: np.ndarray):
    """Two legs, a torso, two arms and a head of a standing person ``height`` tall (m);
    ``shoulders`` is the torso width (m)."""
    leg, torso = 0.47 * height, 0.32 * height
    head = height - leg - torso - 0.03
    arm_y, arm_z = shoulders / 2 + 0.05, leg + 0.55 * torso
    centers = np.array([[0.0, 0.1, LIFT + leg / 2], [0.0, -0.1, LIFT + leg / 2], [0.0, 0.0, leg + torso / 2],
                        [0.0, arm_y, arm_z], [0.0, -arm_y, arm_z], [0.0, 0.0, leg + torso + 0.03 + head / 2]])
    halves = np.array([[0.09, 0.075, leg / 2 - LIFT / 2], [0.09, 0.075, leg / 2 - LIFT / 2],
                       [0.13, shoulders / 2, torso / 2], [0.05, 0.045, 0.45 * torso], [0.05, 0.045, 0.45 * torso],
                       [0.1, 0.085, head / 2]])
    colors = np.array([trousers, trousers, shirt, shirt, shirt, skin])
    return centers, halves, np.full(6, PERSON), colors


def _clothing(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Drawn shirt, trousers and skin colours, (3,) each."""
    shirt, trousers = (np.clip(CLOTHES[rng.integers(len(CLOTHES))] * rng.uniform(0.85, 1.1), 0, 1)
                       for _ in range(2))
    return shirt, trousers, SKIN[rng.integers(len(SKIN))]


def pedestrian(rng: np.random.Generator, index: int, trajectory: Trajectory) -> Mover:
    """A drawn pedestrian (1.6-1.9 m) walking along ``trajectory`` (whose z is the height of the
    surface walked on: 0 on the road, the kerb height on a sidewalk)."""
    height, shoulders = float(rng.uniform(1.6, 1.9)), float(rng.uniform(0.38, 0.48))
    shirt, trousers, skin = _clothing(rng)
    centers, halves, materials, colors = person_boxes(height, shoulders, shirt, trousers, skin)
    return Mover(index, "pedestrian", "pedestrian", 0.3, shoulders + 0.2, height, shirt, trajectory,
                 centers, halves, materials, colors)


def cyclist(rng: np.random.Generator, index: int, trajectory: Trajectory) -> Mover:
    """A drawn cyclist: a bicycle (two thin wheels, a frame, handlebars) and a rider sitting on it."""
    shirt, trousers, skin = _clothing(rng)
    frame = np.clip(CLOTHES[rng.integers(len(CLOTHES))] * 1.1, 0, 1)
    tyre = np.array([0.08, 0.08, 0.08])
    wheel_r, base = 0.34, 0.52  # wheel radius, half wheel base (m)
    centers = np.array([[base, 0.0, LIFT + wheel_r], [-base, 0.0, LIFT + wheel_r],
                        [0.0, 0.0, 0.62], [0.42, 0.0, 0.98],
                        [-0.12, 0.0, 0.75],  # rider's legs, from the seat down to the pedals
                        [-0.12, 0.0, 1.22],  # torso
                        [-0.05, 0.0, 1.58]])  # head
    halves = np.array([[wheel_r, 0.02, wheel_r], [wheel_r, 0.02, wheel_r],
                       [0.45, 0.025, 0.06], [0.03, 0.25, 0.03],
                       [0.1, 0.16, 0.28], [0.14, 0.2, 0.19], [0.1, 0.085, 0.11]])
    materials = np.array([BICYCLE, BICYCLE, BICYCLE, BICYCLE, PERSON, PERSON, PERSON])
    colors = np.array([tyre, tyre, frame, frame, trousers, shirt, skin])
    return Mover(index, "cyclist", "cyclist", 2 * (base + wheel_r), 0.6, 1.69, shirt, trajectory,
                 centers, halves, materials, colors)
