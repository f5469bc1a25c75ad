"""Which velocity model a scan supports: the 2-D model's plane (:func:`planar_basis`), whether the
directions determine vz (:func:`vz_observable`), and the resulting dof (:func:`choose_dof`).
"""

from __future__ import annotations

import math

import numpy as np

from radar4dgs.radar.config import RadarConfig


def vz_observable(d: np.ndarray, config: RadarConfig) -> bool:
    """Whether (N, 3) unit directions spread enough in elevation to determine vz: the smallest
    singular value of ``d / sqrt(N)`` is at least 3 * ``min_conditioning``."""
    if len(d) < 3:
        return False
    return bool(np.linalg.svd(d / math.sqrt(len(d)), compute_uv=False)[-1] >= 3 * config.min_conditioning)


def choose_dof(d: np.ndarray, config: RadarConfig) -> int:
    """The largest model the directions allow: 3 when ``model="3d"`` or (``"auto"``) when the
    directions make vz observable (:func:`vz_observable`), else 2. In ``"auto"`` mode
    :func:`~radar4dgs.radar.ego_motion.estimate_ego_motion` applies this to the scan first and
    then again to the static inliers of a 2-D fit, which decides."""
    if config.model != "auto":
        return 3 if config.model == "3d" else 2
    if len(d) < 3:
        return 3
    return 3 if vz_observable(d, config) else 2


def planar_basis(vertical_axis: np.ndarray | None) -> np.ndarray:
    """(3, 2) orthonormal basis of the 2-D model's velocity plane: the radar's own x-y plane, or,
    with a ``vertical_axis`` (the ego's z axis in radar axes), the plane orthogonal to it (a ground
    vehicle moves in its own x-y plane; a pitched radar then sees a vz of its own)."""
    if vertical_axis is None:
        return np.eye(3)[:, :2]
    a = np.asarray(vertical_axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    ex = np.array([1.0, 0.0, 0.0]) - a[0] * a
    ex /= np.linalg.norm(ex)
    return np.stack([ex, np.cross(a, ex)], axis=1)
