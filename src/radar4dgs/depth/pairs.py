"""Radar-pixel pairs of one frame and the per-frame fit record shared by both scale methods.

:func:`match_radar` pairs the radar points of a frame with the relative inverse depth ``x`` (H, W)
under them and runs the checks both methods share, recording per point why it gave no pair
(``REASONS``); :class:`FrameFit` is the result of a frame's scale recovery, ``1 / z = a * x + b``,
and :func:`finish_fit` fills its inlier statistics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from radar4dgs.depth.config import DepthConfig
from radar4dgs.depth.geometry import DirectionIndex, bilinear, project, unit


class DepthWarning(UserWarning):
    """A frame of the depth front end was repaired (fallback to neighbours, no static mask, ...)."""


# Why a radar point gave no pair (codes stored per point, for the summary and the figures).
REASONS = ("valid", "dynamic", "depth range", "off image", "no visual depth", "depth edge", "sky",
           "degenerate normal", "grazing ray", "bad vote")
VALID, DYNAMIC, DEPTH_RANGE, OFF_IMAGE, NO_DEPTH, DEPTH_EDGE, SKY, DEGENERATE, GRAZING, BAD_VOTE = range(10)


@dataclass
class RadarPairs:
    """Radar points of one frame matched to the visual points.

    Attributes (N radar points):
        points: (N, 3) radar points in the camera frame (m).
        uv: (N, 2) their pixel coordinates.
        z: (N,) their camera z-depth (m).
        x: (N,) relative inverse depth of the image at ``uv`` (bilinear; NaN where none).
        neighbours: (N, 3) indices into the direction index of the 3 nearest visual directions,
            nearest first.
        reason: (N,) int8, ``VALID`` for validated pairs, else why not (``REASONS``).
    """

    points: np.ndarray
    uv: np.ndarray
    z: np.ndarray
    x: np.ndarray
    neighbours: np.ndarray
    reason: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """(N,) bool: pairs that passed the shared checks (and, in paper mode, the plane checks)."""
        return self.reason == VALID

    def reason_counts(self) -> dict[str, int]:
        return {REASONS[k]: int(n) for k, n in zip(*np.unique(self.reason, return_counts=True), strict=True)}


@dataclass
class FrameFit:
    """Scale recovery result of one frame: ``1 / z = a * x + b``.

    ``ok`` is False when the frame had too few validated pairs or the fit failed; ``a``/``b`` are
    NaN then, and the scene-level fallback fills them from the neighbours.
    """

    method: str
    a: float
    b: float
    ok: bool
    reason: str
    pairs: RadarPairs
    inliers: np.ndarray  # (N,) bool
    votes: np.ndarray | None = None  # (N,) paper-mode per-point scales s_i (NaN where invalid)
    scale_only: bool = False  # affine fit fell back to b = 0 (prior values not spread enough)
    x_range: tuple[float, float] = (math.nan, math.nan)  # inliers' x span (confidence)
    residual_median: float = math.nan  # median |relative residual| of the inliers
    extra: dict = field(default_factory=dict)

    @property
    def num_valid(self) -> int:
        return int(self.pairs.valid.sum())

    @property
    def num_inliers(self) -> int:
        return int(self.inliers.sum())

    @property
    def depth_scale(self) -> float:
        """The depth multiplier ``s`` of a pure-scale model (``z = s / x``), ``1 / a``."""
        return 1.0 / self.a if self.a and math.isfinite(self.a) else math.nan


def match_radar(x: np.ndarray, points_cam: np.ndarray, K: np.ndarray, index: DirectionIndex,
                config: DepthConfig, static: np.ndarray | None = None,
                sky: np.ndarray | None = None) -> RadarPairs:
    """Match radar points to the visual points of relative inverse depth ``x`` and run the
    checks shared by both methods.

    Args:
        x: (H, W) relative inverse depth (larger = closer; <= 0 or non-finite = no depth).
        points_cam: (N, 3) radar points in the camera frame.
        K: (3, 3) intrinsics.
        index: unit-sphere index of the pixel grid (``DirectionIndex(K, W, H, stride)``).
        config: thresholds (``min_depth``, ``max_depth``, ``max_sphere_angle_deg``,
            ``max_neighbour_depth_ratio``).
        static: (N,) bool, True for static points (None: all static).
        sky: (H, W) bool sky mask; pairs landing on sky are rejected (None: no mask).
    """
    points_cam = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    n = len(points_cam)
    uv, z = project(K, points_cam)
    reason = np.full(n, VALID, dtype=np.int8)
    if static is not None:
        reason[~np.asarray(static, dtype=bool)] = DYNAMIC
    in_range = np.isfinite(z) & (z >= config.min_depth) & (z <= config.max_depth)
    reason[(reason == VALID) & ~in_range] = DEPTH_RANGE

    neighbours = np.zeros((n, 3), dtype=np.int64)
    if n == 0:
        return RadarPairs(points_cam, uv.reshape(0, 2), z, np.zeros(0), neighbours, reason)
    # Neighbours on the unit sphere: chord length 2 sin(theta / 2) for angle theta.
    chord, neighbours = index.tree.query(unit(points_cam), k=3)
    max_chord = 2.0 * math.sin(math.radians(config.max_sphere_angle_deg) / 2.0)
    reason[(reason == VALID) & ~(chord <= max_chord).all(axis=1)] = OFF_IMAGE

    # The neighbours' unscaled depths d = 1 / x must exist and agree (no depth edge).
    x_flat = x.reshape(-1)
    x_nb = x_flat[index.flat_index[neighbours]]
    has_depth = (np.isfinite(x_nb) & (x_nb > 0)).all(axis=1)
    reason[(reason == VALID) & ~has_depth] = NO_DEPTH
    with np.errstate(divide="ignore", invalid="ignore"):
        spread = x_nb.max(axis=1) / x_nb.min(axis=1) - 1.0  # = d_max / d_min - 1
    reason[(reason == VALID) & ~(spread <= config.max_neighbour_depth_ratio)] = DEPTH_EDGE
    if sky is not None:
        on_sky = sky.reshape(-1)[index.flat_index[neighbours]].any(axis=1)
        reason[(reason == VALID) & on_sky] = SKY

    x_at = bilinear(x, uv)
    reason[(reason == VALID) & ~(np.isfinite(x_at) & (x_at > 0))] = NO_DEPTH
    return RadarPairs(points_cam, uv, z, x_at, neighbours, reason)


def relative_residuals(a: float, b: float, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """r = z (a x + b) - 1: relative error of the fitted depth 1 / (a x + b) to first order."""
    return z * (a * x + b) - 1.0


def finish_fit(fit: FrameFit) -> FrameFit:
    """Fill the inlier statistics used by the confidence map and the summary."""
    if fit.inliers.any():
        xi = fit.pairs.x[fit.inliers]
        fit.x_range = (float(xi.min()), float(xi.max()))
        r = relative_residuals(fit.a, fit.b, xi, fit.pairs.z[fit.inliers])
        fit.residual_median = float(np.median(np.abs(r)))
    return fit
