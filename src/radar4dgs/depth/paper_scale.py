"""The paper's (4DRadar-GS) single-scale recovery: plane votes and histogram voting.

The unscaled depth is ``d = 1 / x`` (for a prior that *is* depth up to scale, ``x = 1 / depth``,
so ``d`` is that depth). Visual points ``p = d * ray`` and radar points are put on the unit
sphere; a ``cKDTree`` on the visual directions gives the 3 nearest visual points ``pa, pb, pc`` of
each radar point ``p_i``; the plane through them has normal ``n = (pa - pb) x (pb - pc)``; scaling
the visual points by ``s`` moves the plane to ``n . p = s n . pa``, so the scale that puts the
plane through the radar point is ``s_i = n . p_i / n . pa``. Valid votes are histogrammed in log
scale; the frame's scale is the median of the votes in the winning bin (and its neighbours). Then
``a = 1 / s``, ``b = 0`` in ``1 / z = a * x + b``. A single scale is the right model for a
depth-up-to-scale prior only; on a relative inverse depth with an unknown shift
(Depth-Anything-V2) it cannot be right everywhere.
"""

from __future__ import annotations

import math

import numpy as np

from radar4dgs.depth.config import DepthConfig
from radar4dgs.depth.geometry import DirectionIndex, unit
from radar4dgs.depth.pairs import BAD_VOTE, DEGENERATE, GRAZING, VALID, FrameFit, RadarPairs, finish_fit


def plane_votes(points_cam: np.ndarray, visual: np.ndarray, min_normal_sine: float,
                min_incidence_cos: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-point scales ``s_i = n . p_i / n . pa`` of the plane through 3 visual points.

    Args:
        points_cam: (N, 3) radar points p_i (camera frame).
        visual: (N, 3, 3) the unscaled visual points pa, pb, pc of each radar point.
        min_normal_sine: degenerate-triangle threshold on |n| / (|pa - pb| |pb - pc|).
        min_incidence_cos: grazing threshold on |cos(ray, n)|.

    Returns:
        votes (N,) float64 (NaN where invalid) and reason (N,) int8 (VALID, DEGENERATE, GRAZING,
        BAD_VOTE).
    """
    pa, pb, pc = visual[:, 0], visual[:, 1], visual[:, 2]
    e1, e2 = pa - pb, pb - pc
    normal = np.cross(e1, e2)
    norm = np.linalg.norm(normal, axis=1)
    lengths = np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
    reason = np.full(len(points_cam), VALID, dtype=np.int8)
    with np.errstate(divide="ignore", invalid="ignore"):
        sine = norm / lengths
        reason[~(sine >= min_normal_sine)] = DEGENERATE
        ray = unit(points_cam)
        incidence = np.abs(np.einsum("ij,ij->i", normal, ray)) / norm
        reason[(reason == VALID) & ~(incidence >= min_incidence_cos)] = GRAZING
        votes = np.einsum("ij,ij->i", normal, points_cam) / np.einsum("ij,ij->i", normal, pa)
    bad = ~(np.isfinite(votes) & (votes > 0))
    reason[(reason == VALID) & bad] = BAD_VOTE
    votes = np.where(reason == VALID, votes, np.nan)
    return votes, reason


def histogram_vote(votes: np.ndarray, bins: int, refine_neighbours: int = 1) -> float:
    """Robust mode of positive ``votes`` (N,): the log-scale histogram's winning bin (over the
    2nd-98th percentile range) refined by the median of the votes in it and in
    ``refine_neighbours`` bins on each side. NaN for no votes."""
    votes = np.asarray(votes, dtype=np.float64)
    logs = np.log(votes[np.isfinite(votes) & (votes > 0)])
    if len(logs) == 0:
        return math.nan
    lo, hi = np.percentile(logs, [2.0, 98.0])
    if hi - lo < 1e-9:
        return float(np.exp(np.median(logs)))
    counts, edges = np.histogram(logs, bins=bins, range=(lo, hi))
    k = int(np.argmax(counts))
    width = edges[1] - edges[0]
    window = (logs >= edges[k] - refine_neighbours * width) & (logs <= edges[k + 1] + refine_neighbours * width)
    return float(np.exp(np.median(logs[window])))


def paper_fit(x: np.ndarray, pairs: RadarPairs, index: DirectionIndex, config: DepthConfig) -> FrameFit:
    """The paper's single-scale recovery on validated ``pairs`` (see the module docstring)."""
    reason = pairs.reason.copy()
    votes = np.full(len(reason), np.nan)
    valid = reason == VALID
    if valid.any():
        nb = pairs.neighbours[valid]
        d = 1.0 / x.reshape(-1)[index.flat_index[nb]]  # (n, 3) unscaled depth of the neighbours
        visual = index.rays[nb] * d[..., None]  # (n, 3, 3) visual points at the unscaled depth
        v, r = plane_votes(pairs.points[valid], visual, config.min_normal_sine, config.min_incidence_cos)
        votes[valid], reason[valid] = v, r
    pairs = RadarPairs(pairs.points, pairs.uv, pairs.z, pairs.x, pairs.neighbours, reason)
    count = int((reason == VALID).sum())
    if count < config.min_pairs:
        return FrameFit("paper", math.nan, math.nan, False, f"{count} valid votes < min_pairs {config.min_pairs}",
                        pairs, np.zeros(len(reason), bool), votes)
    scale = histogram_vote(votes, config.histogram_bins, config.histogram_refine_neighbours)
    with np.errstate(invalid="ignore"):
        inliers = np.abs(votes / scale - 1.0) < config.inlier_threshold
    return finish_fit(FrameFit("paper", 1.0 / scale, 0.0, True, "ok", pairs, inliers, votes))
