"""Metric scale recovery of a relative depth map from static radar points.

Every prior is handled as a relative inverse depth ``x`` (H, W): larger = closer, ``x <= 0`` or
non-finite = far / no depth. Both methods produce the same per-frame model

    1 / z = a * x + b            (z: metric z-depth along the optical axis)

* ``paper`` (4DRadar-GS): the unscaled depth is ``d = 1 / x`` (for a prior that *is* depth up to
  scale, ``x = 1 / depth``, so ``d`` is that depth). Visual points ``p = d * ray`` and radar points
  are put on the unit sphere; a ``cKDTree`` on the visual directions gives the 3 nearest visual
  points ``pa, pb, pc`` of each radar point ``p_i``; the plane through them has normal
  ``n = (pa - pb) x (pb - pc)``; scaling the visual points by ``s`` moves the plane to
  ``n . p = s n . pa``, so the scale that puts the plane through the radar point is
  ``s_i = n . p_i / n . pa``. Valid votes are histogrammed in log scale; the frame's scale is the
  median of the votes in the winning bin (and its neighbours). Then ``a = 1 / s``, ``b = 0``.
  A single scale is the right model for a depth-up-to-scale prior only; on a relative inverse
  depth with an unknown shift (Depth-Anything-V2) it cannot be right everywhere.
* ``affine``: robust fit of ``a`` and ``b`` on the validated radar-pixel pairs, minimising the
  relative depth residual ``r_i = z_i (a x_i + b) - 1`` (linear in ``a, b``; |r| is the relative
  error of the fitted depth ``1 / (a x_i + b)`` w.r.t. the radar's ``z_i`` to first order):
  2-point RANSAC, then IRLS with a Huber loss on the RANSAC inliers. Radar ghosts below the road
  and clutter have large residuals and are rejected.
"""

from __future__ import annotations

import math
import warnings
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
        return {REASONS[k]: int(n) for k, n in zip(*np.unique(self.reason, return_counts=True))}


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


# --------------------------------------------------------------------------------------------
# Pairs


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


# --------------------------------------------------------------------------------------------
# Paper: plane votes and histogram voting


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
    return _finish(FrameFit("paper", 1.0 / scale, 0.0, True, "ok", pairs, inliers, votes))


# --------------------------------------------------------------------------------------------
# Affine fit in inverse depth


def _relative_residuals(a: float, b: float, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """r = z (a x + b) - 1: relative error of the fitted depth 1 / (a x + b) to first order."""
    return z * (a * x + b) - 1.0


def _weighted_ls(x: np.ndarray, z: np.ndarray, w: np.ndarray, scale_only: bool) -> tuple[float, float]:
    """Weighted least squares of z (a x + b) = 1; returns (a, b) (b = 0 when ``scale_only``)."""
    sw = np.sqrt(w)
    if scale_only:
        col = sw * z * x
        return float(col @ sw / (col @ col)), 0.0
    design = np.stack([z * x, z], axis=1) * sw[:, None]
    solution, *_ = np.linalg.lstsq(design, sw, rcond=None)
    return float(solution[0]), float(solution[1])


def fit_inverse_affine(x: np.ndarray, z: np.ndarray, threshold: float, iterations: int, huber_delta: float,
                       irls_iterations: int, min_spread: float, rng: np.random.Generator
                       ) -> tuple[float, float, np.ndarray, bool]:
    """Robust fit of ``1 / z ≈ a x + b`` with ``a > 0``.

    Args:
        x: (N,) relative inverse depth at the radar points (> 0).
        z: (N,) radar z-depth (m, > 0).
        threshold: inlier bound on the relative residual |z (a x + b) - 1|.
        iterations: RANSAC 2-point samples.
        huber_delta: Huber threshold of the IRLS refinement (relative residual).
        irls_iterations: IRLS steps.
        min_spread: below this std(1/z) / mean(1/z) of the RANSAC inliers, fit the scale only (b = 0).
        rng: random generator for the samples.

    Returns:
        a, b, inliers (N,) bool, scale_only. ``a`` is NaN when no fit with a > 0 was found.
    """
    n = len(x)
    if n < 2:
        return math.nan, math.nan, np.zeros(n, bool), False
    # Candidate models: random 2-point samples plus the 1-point scale-only models (which keep a
    # near-constant-depth frame from being left without a hypothesis).
    i = rng.integers(0, n, size=iterations)
    j = rng.integers(0, n, size=iterations)
    keep = x[i] != x[j]
    i, j = i[keep], j[keep]
    inv_i, inv_j = 1.0 / z[i], 1.0 / z[j]
    a_cand = (inv_i - inv_j) / (x[i] - x[j])
    b_cand = inv_i - a_cand * x[i]
    one = rng.integers(0, n, size=max(8, iterations // 8))
    a_cand = np.concatenate([a_cand, 1.0 / (z[one] * x[one])])
    b_cand = np.concatenate([b_cand, np.zeros(len(one))])
    ok = a_cand > 0
    a_cand, b_cand = a_cand[ok], b_cand[ok]
    if len(a_cand) == 0:
        return math.nan, math.nan, np.zeros(n, bool), False
    # MSAC score of all candidates at once: (n_cand, N) residual matrix, N is a few hundred.
    residual = np.abs(z[None, :] * (a_cand[:, None] * x[None, :] + b_cand[:, None]) - 1.0)
    score = np.minimum(residual, threshold).sum(axis=1)
    k = int(np.argmin(score))
    inliers = residual[k] < threshold
    if inliers.sum() < 2:
        return math.nan, math.nan, inliers, False
    # The shift is observable only when the radar depths spread: with every point at one depth,
    # any (a, b) through that depth fits. Then fit the scale alone (best 1-point model).
    inverse = 1.0 / z[inliers]
    scale_only = bool(np.std(inverse) < min_spread * np.mean(inverse))
    if scale_only:
        score = np.where(b_cand == 0.0, score, np.inf)
        k = int(np.argmin(score))
        if not np.isfinite(score[k]):
            return math.nan, math.nan, np.zeros(n, bool), True
    a, b = float(a_cand[k]), float(b_cand[k])
    xi = x[inliers]
    for _ in range(irls_iterations + 1):
        r = _relative_residuals(a, b, x, z)
        inliers = np.abs(r) < threshold
        if inliers.sum() < 2:
            return math.nan, math.nan, inliers, scale_only
        weights = np.minimum(1.0, huber_delta / np.maximum(np.abs(r[inliers]), 1e-12))
        a_new, b_new = _weighted_ls(x[inliers], z[inliers], weights, scale_only)
        # Converged when the fitted inverse depth moves by < 1e-9 relative at the inliers' mean x.
        step = abs(a_new - a) * np.mean(xi) + abs(b_new - b)
        a, b = a_new, b_new
        if step <= 1e-9 * abs(a * np.mean(xi) + b):
            break
    if not (math.isfinite(a) and a > 0 and math.isfinite(b)):
        return math.nan, math.nan, np.zeros(n, bool), scale_only
    inliers = np.abs(_relative_residuals(a, b, x, z)) < threshold
    return a, b, inliers, scale_only


def affine_fit(pairs: RadarPairs, config: DepthConfig, rng: np.random.Generator) -> FrameFit:
    """Robust inverse-depth affine fit on the validated ``pairs``."""
    valid = pairs.valid
    count = int(valid.sum())
    empty = np.zeros(len(valid), bool)
    if count < config.min_pairs:
        return FrameFit("affine", math.nan, math.nan, False, f"{count} valid pairs < min_pairs {config.min_pairs}",
                        pairs, empty)
    a, b, inl, scale_only = fit_inverse_affine(pairs.x[valid], pairs.z[valid], config.inlier_threshold,
                                               config.ransac_iterations, config.huber_delta,
                                               config.irls_iterations, config.min_depth_spread, rng)
    inliers = empty.copy()
    inliers[valid] = inl
    if not math.isfinite(a):
        return FrameFit("affine", math.nan, math.nan, False, "no fit with a positive scale", pairs, inliers,
                        scale_only=scale_only)
    if int(inliers.sum()) < config.min_pairs:
        return FrameFit("affine", math.nan, math.nan, False,
                        f"{int(inliers.sum())} inliers < min_pairs {config.min_pairs}", pairs, inliers,
                        scale_only=scale_only)
    return _finish(FrameFit("affine", a, b, True, "ok", pairs, inliers, scale_only=scale_only))


def _window_irls(x: np.ndarray, z: np.ndarray, d: np.ndarray, w: np.ndarray, a: float, b: float,
                 scale_only: bool, drift: bool, threshold: float, huber_delta: float, iterations: int
                 ) -> tuple[float, float]:
    """Huber IRLS of ``z ((a + alpha d) x + (b + beta d)) = 1`` on pairs with prior weights ``w``
    (frame offsets ``d``), started at ``(a, b)`` with no drift; returns the centre ``(a, b)``
    (NaN when fewer than 2 pairs stay within ``threshold``). ``scale_only``: b = beta = 0;
    ``drift`` False: alpha = beta = 0."""
    columns = [z * x] + ([] if scale_only else [z])
    if drift:
        columns += [z * x * d] + ([] if scale_only else [z * d])
    design = np.stack(columns, axis=1)
    theta = np.zeros(design.shape[1])
    theta[0] = a
    if not scale_only:
        theta[1] = b
    for _ in range(iterations + 1):
        r = design @ theta - 1.0
        keep = np.abs(r) < threshold
        if keep.sum() < design.shape[1]:
            return math.nan, math.nan
        sw = np.sqrt(w[keep] * np.minimum(1.0, huber_delta / np.maximum(np.abs(r[keep]), 1e-12)))
        new, *_ = np.linalg.lstsq(design[keep] * sw[:, None], sw, rcond=None)
        step = np.abs(new[:2] - theta[:2]).max()
        theta = new
        if step <= 1e-12 * abs(theta[0]):
            break
    return float(theta[0]), (0.0 if scale_only else float(theta[1]))


def temporal_refine(fits: list[FrameFit], config: DepthConfig) -> list[FrameFit]:
    """Temporal consistency of the ``affine`` per-frame parameters (``config.temporal_window``).

    Frame i's ``(a_i, b_i)`` is re-fitted on the robust-fit inliers of every good frame j with
    ``|j - i| <= half = temporal_window // 2`` (its own included), each pair weighted
    ``1 - |j - i| / (half + 1)``, with the model ``1/z = (a_i + alpha (j - i)) x + (b_i + beta (j - i))``:
    scale and shift drift linearly across the window (locally linear regression in time), so a
    slow drift is followed without bias and the per-frame pair noise averages out. Each pair keeps
    its own frame's prior value ``x_j``. Frames whose fit failed are not used and stay failed (the
    neighbour fallback fills them afterwards); ``paper`` fits and ``temporal_window`` 1 are returned
    unchanged. Each refined fit keeps its per-frame parameters in ``extra["frame_a"]`` /
    ``extra["frame_b"]`` and the frames used in ``extra["window_frames"]``.
    """
    half = config.temporal_window // 2
    if half == 0:
        return list(fits)
    out: list[FrameFit] = []
    for i, fit in enumerate(fits):
        if not (fit.ok and fit.method == "affine"):
            out.append(fit)
            continue
        used = [j for j in range(max(0, i - half), min(len(fits), i + half + 1))
                if fits[j].ok and fits[j].method == "affine" and fits[j].num_inliers > 0]
        xs, zs, ds, ws = [], [], [], []
        for j in used:
            inl = fits[j].inliers
            xs.append(fits[j].pairs.x[inl])
            zs.append(fits[j].pairs.z[inl])
            ds.append(np.full(int(inl.sum()), float(j - i)))
            ws.append(np.full(int(inl.sum()), 1.0 - abs(j - i) / (half + 1.0)))
        # A drift needs data at two offsets at least; otherwise this is the frame's own fit again.
        a, b = _window_irls(np.concatenate(xs), np.concatenate(zs), np.concatenate(ds), np.concatenate(ws),
                            fit.a, fit.b, fit.scale_only, len(used) >= 2, config.inlier_threshold,
                            config.huber_delta, config.irls_iterations)
        if not (math.isfinite(a) and a > 0 and math.isfinite(b)):
            out.append(fit)  # keep the frame's own fit
            continue
        extra = {**fit.extra, "frame_a": fit.a, "frame_b": fit.b, "window_frames": used}
        refined = FrameFit(fit.method, a, b, True, fit.reason, fit.pairs, fit.inliers, fit.votes,
                           fit.scale_only, extra=extra)
        out.append(_finish(refined))
    return out


def limit_metric_correction(fits: list[FrameFit], max_change: float, x_min: float) -> list[FrameFit]:
    """Reject the fits that move an already metric prior (``x = 1 / depth``) too far.

    A fit multiplies the prior's depth by ``x / (a x + b)``, monotonic in ``x``; over the prior's
    whole range ``[x_min, inf)`` (``x_min = 1 / farthest depth``) the largest change is at an end:
    ``x_min / (a x_min + b)`` or ``1 / a``. The radar inliers of a sparse radar sit in a narrow
    span (the few ground returns are near), so the fit is judged where it is extrapolated too.
    Fits whose change exceeds ``max_change`` (a fraction) come back with ``ok`` False and the
    reason (pairs and inliers kept for the summary); the others unchanged.
    """
    out = []
    for fit in fits:
        if not fit.ok:
            out.append(fit)
            continue
        far = fit.a * x_min + fit.b
        ratios = np.array([x_min / far if far > 0 else math.inf, 1.0 / fit.a])
        change = float(np.max(np.abs(ratios - 1.0)))
        if change <= max_change:
            out.append(fit)
            continue
        what = f"by {change:.0%}" if math.isfinite(change) else "to beyond infinity at its far end"
        out.append(FrameFit(fit.method, math.nan, math.nan, False,
                            f"radar fit changes the metric prior's depth {what} (> {max_change:.0%})",
                            fit.pairs, fit.inliers, fit.votes, fit.scale_only,
                            extra={**fit.extra, "rejected_a": fit.a, "rejected_b": fit.b}))
    return out


def _finish(fit: FrameFit) -> FrameFit:
    """Fill the inlier statistics used by the confidence map and the summary."""
    if fit.inliers.any():
        xi = fit.pairs.x[fit.inliers]
        fit.x_range = (float(xi.min()), float(xi.max()))
        r = _relative_residuals(fit.a, fit.b, xi, fit.pairs.z[fit.inliers])
        fit.residual_median = float(np.median(np.abs(r)))
    return fit


def recover_scale(x: np.ndarray, points_cam: np.ndarray, K: np.ndarray, config: DepthConfig, method: str,
                  static: np.ndarray | None = None, sky: np.ndarray | None = None,
                  index: DirectionIndex | None = None, rng: np.random.Generator | None = None) -> FrameFit:
    """Scale recovery of one frame.

    Args:
        x: (H, W) relative inverse depth (for a depth-up-to-scale map pass ``1 / depth``).
        points_cam: (N, 3) radar points in the camera frame.
        K: (3, 3) intrinsics.
        config: thresholds.
        method: "paper" or "affine".
        static: (N,) bool static-point mask (None: all static).
        sky: (H, W) bool sky mask (None: none).
        index: the camera's :class:`DirectionIndex` (built here when None; pass one per scene).
        rng: random generator for RANSAC (default: ``config.seed``).
    """
    height, width = x.shape
    if index is None or not index.matches(K, width, height, config.visual_stride):
        index = DirectionIndex(K, width, height, config.visual_stride)
    pairs = match_radar(x, points_cam, K, index, config, static, sky)
    if method == "paper":
        return paper_fit(x, pairs, index, config)
    if method == "affine":
        return affine_fit(pairs, config, rng if rng is not None else np.random.default_rng(config.seed))
    raise ValueError(f"unknown scale method {method!r}; choose 'paper' or 'affine'")


# --------------------------------------------------------------------------------------------
# Neighbour fallback and the metric depth


@dataclass(frozen=True)
class FrameParameters:
    """The parameters a frame's metric depth is made with, and where they come from."""

    a: float
    b: float
    source: str  # "fit", "neighbours", "metric prior"
    from_frames: tuple[int, ...] = ()


def fill_from_neighbours(fits: list[FrameFit], timestamps, names=None, metric_prior: bool = False
                         ) -> list[FrameParameters]:
    """Per-frame parameters: a frame's own fit when ``ok``, else the time-interpolation of the
    nearest good frames before and after it (the one good neighbour where only one side has one),
    with a :class:`DepthWarning`. When no frame has a fit: a ``metric_prior`` (already metric, as
    the flat-world source) is used as it is (a = 1, b = 0, source "metric prior", one warning);
    otherwise ValueError.
    """
    timestamps = np.asarray(timestamps, dtype=np.float64)
    names = list(names) if names is not None else [str(i) for i in range(len(fits))]
    good = [i for i, fit in enumerate(fits) if fit.ok]
    if not good and metric_prior and fits:
        reasons = sorted({f.reason for f in fits})
        listed = "; ".join(reasons[:3]) + ("; ..." if len(reasons) > 3 else "")
        warnings.warn(f"depth: no frame has a radar fit ({listed}); the metric prior is used unscaled "
                      "(scale 1, shift 0)", DepthWarning, stacklevel=2)
        return [FrameParameters(1.0, 0.0, "metric prior") for _ in fits]
    if not good:
        raise ValueError("no frame has enough validated radar pairs for scale recovery "
                         f"({fits[0].reason if fits else 'no frames'}); check the radar calibration, "
                         "lower min_pairs, or use another scale method")
    out: list[FrameParameters] = []
    for i, fit in enumerate(fits):
        if fit.ok:
            out.append(FrameParameters(fit.a, fit.b, "fit"))
            continue
        before = [g for g in good if g < i]
        after = [g for g in good if g > i]
        p, q = (before[-1] if before else None), (after[0] if after else None)
        if p is not None and q is not None:
            t = (timestamps[i] - timestamps[p]) / (timestamps[q] - timestamps[p])
            a = (1 - t) * fits[p].a + t * fits[q].a
            b = (1 - t) * fits[p].b + t * fits[q].b
            sources = (p, q)
        else:
            g = p if p is not None else q
            a, b, sources = fits[g].a, fits[g].b, (g,)
        warnings.warn(f"depth: frame {names[i]}: {fit.reason}; using the scale of frame(s) "
                      f"{', '.join(names[s] for s in sources)}", DepthWarning, stacklevel=2)
        out.append(FrameParameters(float(a), float(b), "neighbours", tuple(int(s) for s in sources)))
    return out


def metric_depth(x: np.ndarray, a: float, b: float, min_depth: float, max_depth: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Metric z-depth ``z = 1 / (a x + b)`` of (H, W) relative inverse depth ``x``.

    Returns:
        depth (H, W) float32 clamped to [min_depth, max_depth], and valid (H, W) bool: False where
        ``x`` is not finite or ``a x + b`` falls below ``1 / max_depth`` (beyond range or
        non-positive: the far end of the prior); such pixels get ``max_depth``.
    """
    with np.errstate(invalid="ignore", over="ignore"):
        inverse = a * x.astype(np.float64) + b
        valid = np.isfinite(inverse) & (inverse >= 1.0 / max_depth)
        depth = np.where(valid, 1.0 / np.where(valid, inverse, 1.0), max_depth)
    return np.clip(depth, min_depth, max_depth).astype(np.float32), valid


def confidence_map(depth: np.ndarray, valid: np.ndarray, x: np.ndarray, frame_confidence: float,
                   x_range: tuple[float, float], edge_scale: float) -> np.ndarray:
    """Per-pixel confidence in [0, 1] (H, W) float32.

    The product of: the frame's confidence (inlier count, fallback); an edge term
    ``exp(-g / edge_scale)`` with ``g`` the largest |log z| step to a 4-neighbour (pixels on depth
    discontinuities mix two surfaces); a range term ``exp(-|log(x / clip(x, x_lo, x_hi))|)`` that
    decays outside the inverse-depth span the radar inliers covered (extrapolation). Zero where
    ``valid`` is False.
    """
    log_z = np.log(np.maximum(depth.astype(np.float64), 1e-6))
    step = np.zeros_like(log_z)
    dv = np.abs(np.diff(log_z, axis=0))
    du = np.abs(np.diff(log_z, axis=1))
    step[1:] = np.maximum(step[1:], dv)
    step[:-1] = np.maximum(step[:-1], dv)
    step[:, 1:] = np.maximum(step[:, 1:], du)
    step[:, :-1] = np.maximum(step[:, :-1], du)
    conf = frame_confidence * np.exp(-step / edge_scale)
    lo, hi = x_range
    if math.isfinite(lo) and math.isfinite(hi) and lo > 0:
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.abs(np.log(x / np.clip(x, lo, hi)))
        conf = conf * np.exp(-np.nan_to_num(ratio, nan=np.inf))
    conf = np.where(valid, conf, 0.0)
    return np.clip(conf, 0.0, 1.0).astype(np.float32)


def frame_confidences(fits: list[FrameFit], parameters: list[FrameParameters], config: DepthConfig
                      ) -> list[tuple[float, tuple[float, float]]]:
    """Per frame: (confidence, inverse-depth span) for :func:`confidence_map`.

    An own fit with n inliers has confidence n / (n + min_pairs) and its inliers' x span; a frame
    filled from neighbours gets ``config.fallback_confidence`` times the mean of its sources'
    confidences and the union of their spans; an unscaled metric prior gets
    ``config.fallback_confidence`` and no span.
    """
    own = [(f.num_inliers / (f.num_inliers + config.min_pairs), f.x_range) if f.ok else (0.0, (math.nan, math.nan))
           for f in fits]
    out = []
    for i, p in enumerate(parameters):
        if p.source == "fit":
            out.append(own[i])
            continue
        if p.source == "metric prior":
            out.append((config.fallback_confidence, (math.nan, math.nan)))
            continue
        sources = [own[s] for s in p.from_frames] or [(0.0, (math.nan, math.nan))]
        conf = config.fallback_confidence * float(np.mean([c for c, _ in sources]))
        lo = min((r[0] for _, r in sources if math.isfinite(r[0])), default=math.nan)
        hi = max((r[1] for _, r in sources if math.isfinite(r[1])), default=math.nan)
        out.append((conf, (lo, hi)))
    return out
