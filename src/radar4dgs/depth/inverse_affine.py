"""Robust scale-and-shift fit in inverse depth (the ``affine`` scale method).

Fits ``a`` and ``b`` of ``1 / z = a * x + b`` on the validated radar-pixel pairs, minimising the
relative depth residual ``r_i = z_i (a x_i + b) - 1`` (linear in ``a, b``; |r| is the relative
error of the fitted depth ``1 / (a x_i + b)`` w.r.t. the radar's ``z_i`` to first order): 2-point
RANSAC, then IRLS with a Huber loss on the RANSAC inliers. Radar ghosts below the road and clutter
have large residuals and are rejected.
"""

from __future__ import annotations

import math

import numpy as np

from radar4dgs.depth.config import DepthConfig
from radar4dgs.depth.pairs import FrameFit, RadarPairs, finish_fit, relative_residuals


def _weighted_ls(x: np.ndarray, z: np.ndarray, w: np.ndarray, scale_only: bool) -> tuple[float, float]:
    """Weighted least squares of z (a x + b) = 1; returns (a, b) (b = 0 when ``scale_only``)."""
    sw = np.sqrt(w)
    if scale_only:
        col = sw * z * x
        return float(col @ sw / (col @ col)), 0.0
    design = np.stack([z * x, z], axis=1) * sw[:, None]
    solution, *_ = np.linalg.lstsq(design, sw, rcond=None)
    return float(solution[0]), float(solution[1])


def _candidate_models(x: np.ndarray, z: np.ndarray, iterations: int, rng: np.random.Generator
                     ) -> tuple[np.ndarray, np.ndarray]:
    """RANSAC hypotheses ``(a_cand, b_cand)`` (M,) each, all with ``a > 0``, from ``x``, ``z`` (N,), N >= 2.

    Random 2-point samples plus the 1-point scale-only models (which keep a near-constant-depth
    frame from being left without a hypothesis); ``iterations`` 2-point samples are drawn.
    """
    n = len(x)
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
    return a_cand[ok], b_cand[ok]


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
    a_cand, b_cand = _candidate_models(x, z, iterations, rng)
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
        r = relative_residuals(a, b, x, z)
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
    inliers = np.abs(relative_residuals(a, b, x, z)) < threshold
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
    return finish_fit(FrameFit("affine", a, b, True, "ok", pairs, inliers, scale_only=scale_only))

