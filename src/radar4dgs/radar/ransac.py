"""Adaptive RANSAC for the Doppler velocity: minimal samples solved in vectorised batches,
checked for conditioning, scored by angularly weighted inlier count within the noise band, with
the iteration count adapted to the best inlier fraction so far.
"""

from __future__ import annotations

import math

import numpy as np

from radar4dgs.radar.config import RadarConfig


def _min_singular(a: np.ndarray) -> np.ndarray:
    """Smallest singular value of each (..., k, k) matrix."""
    return np.linalg.svd(a, compute_uv=False)[..., -1]


def _solve_minimal(D: np.ndarray, v_r: np.ndarray, idx: np.ndarray, min_singular: float) -> np.ndarray:
    """(S, k) hypotheses from (S, k) sample indices; rows of ill-conditioned samples are dropped.

    Solves ``-D[idx] v = v_r[idx]``; samples with repeated indices are singular and dropped too.
    """
    A = -D[idx]                                    # (S, k, k)
    b = v_r[idx]                                   # (S, k)
    good = _min_singular(A) >= min_singular
    if not good.any():
        return np.zeros((0, D.shape[1]))
    return np.linalg.solve(A[good], b[good][..., None])[..., 0]


def _score(M: np.ndarray, v_r: np.ndarray, weights: np.ndarray, hyps: np.ndarray,
           config: RadarConfig) -> np.ndarray:
    """(S,) angularly weighted inlier score of (S, k) hypotheses on all points.

    ``M`` (3N, k) stacks the directions and the two angle Jacobians (one matmul for all three);
    the arithmetic is in place because this is the hot loop (N x S elements per batch).
    """
    n = len(v_r)
    P = M @ hyps.T                                 # (3N, S)
    resid = P[:n]
    resid += v_r[:, None]
    resid *= resid
    band = P[n:2 * n]
    band *= band
    je = P[2 * n:]
    je *= je
    band += je
    band += config.noise_std ** 2
    band *= config.inlier_sigma ** 2
    return weights @ (resid <= band)


def _needed_iterations(inlier_fraction: float, k: int, confidence: float, cap: int) -> int:
    """Standard RANSAC count log(1 - p) / log(1 - w^k), capped."""
    good = inlier_fraction ** k
    if good <= 0:
        return cap
    if good >= 1:
        return 1
    return int(min(cap, math.ceil(math.log(1 - confidence) / math.log(1 - good))))


def ransac(D: np.ndarray, M: np.ndarray, vr: np.ndarray, weights: np.ndarray, fixed_h: np.ndarray,
           rng: np.random.Generator, config: RadarConfig) -> tuple[np.ndarray, int, int]:
    """Best (k,) hypothesis of adaptive RANSAC (the always-scored ``fixed_h`` (F, k) included),
    hypotheses evaluated, well-conditioned minimal samples.

    ``D`` (N, k) directions, ``M`` (3N, k) directions and angle Jacobians stacked (see
    :func:`_score`), ``vr`` (N,) Doppler, ``weights`` (N,) angular weights. Draws ``(batch, k)``
    sample indices from ``rng`` batch by batch until the adaptive count is reached.
    """
    n, k = D.shape
    total_weight = weights.sum()
    scores = _score(M, vr, weights, fixed_h, config)
    best_i = int(np.argmax(scores))
    best_v, best_score = fixed_h[best_i], float(scores[best_i])
    iterations, conditioned = 0, 0
    needed = _needed_iterations(best_score / total_weight, k, config.confidence, config.max_iterations)
    while iterations < min(needed, config.max_iterations):
        size = int(min(config.batch_size, config.max_iterations - iterations))
        idx = rng.integers(0, n, size=(size, k))
        iterations += size
        hyps = _solve_minimal(D, vr, idx, config.sample_min_singular)
        conditioned += len(hyps)
        if len(hyps) == 0:
            continue
        scores = _score(M, vr, weights, hyps, config)
        i = int(np.argmax(scores))
        if scores[i] > best_score:
            best_score, best_v = float(scores[i]), hyps[i]
            needed = _needed_iterations(best_score / total_weight, k, config.confidence,
                                        config.max_iterations)
    return best_v, iterations, conditioned
