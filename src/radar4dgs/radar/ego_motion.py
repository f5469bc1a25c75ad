"""Radar ego-motion from one scan's Doppler velocities (3-point RANSAC + least squares).

A static point seen along the unit direction ``d`` from a radar moving with velocity ``v_s``
(radar frame) has the raw Doppler ``v_r = -d . v_s`` (positive = receding). Stacking the static
points gives the linear system ``-D v_s = v_r``; moving points and clutter are outliers.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from radar4dgs.radar.config import RadarConfig


@dataclass(frozen=True)
class EgoMotion:
    """The radar's own velocity estimated from one scan.

    Attributes:
        velocity: (3,) float64 radar velocity in the radar frame (m/s); NaN when no estimate exists.
        inliers: (N,) bool, the points explained as static (False for invalid rows).
        covariance: (3, 3) float64 covariance of ``velocity`` (NaN when no estimate exists).
        ok: whether the estimate is trustworthy.
        reason: why not (or "standstill" / "" when ok).
        residual_std: std (m/s) of the inlier residuals ``v_r + d . v_s``.
        iterations: RANSAC hypotheses evaluated.
        dof: 3 (vx, vy, vz estimated) or 2 (planar model: vz = 0 in radar axes, or no motion along
            ``vertical_axis`` when one is given; see ``RadarConfig.model`` and :func:`planar_basis`).
        noise_std, azimuth_std, elevation_std: the noise model used (``classify_dynamic`` reuses it).
    """

    velocity: np.ndarray
    inliers: np.ndarray
    covariance: np.ndarray
    ok: bool
    reason: str = ""
    residual_std: float = float("nan")
    iterations: int = 0
    dof: int = 3
    standstill: bool = False
    noise_std: float = 0.1
    azimuth_std: float = 0.005
    elevation_std: float = 0.017

    @property
    def speed(self) -> float:
        return float(np.linalg.norm(self.velocity))


def _resolve_config(config: RadarConfig | None, options: dict[str, Any]) -> RadarConfig:
    config = config or RadarConfig()
    if options:
        names = {f.name for f in dataclasses.fields(RadarConfig)}
        unknown = set(options) - names
        if unknown:
            raise TypeError(f"unknown radar option(s) {sorted(unknown)}; options are {sorted(names)}")
        config = dataclasses.replace(config, **options)
    return config


def _as_points(xyz: Any, v_r: Any) -> tuple[np.ndarray, np.ndarray]:
    """Validate shapes early (clear errors instead of numpy broadcasting failures deep inside)."""
    xyz = np.asarray(xyz, dtype=np.float64)
    v_r = np.asarray(v_r, dtype=np.float64)
    if xyz.size == 0 and v_r.size == 0:
        return np.zeros((0, 3)), np.zeros(0)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"xyz must have shape (N, 3), got {xyz.shape}")
    if v_r.shape != (xyz.shape[0],):
        raise ValueError(f"v_r must have shape ({xyz.shape[0]},) to match xyz, got {v_r.shape}")
    return xyz, v_r


def unit_directions(xyz: np.ndarray, min_range: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) unit line-of-sight directions and (N,) bool validity (finite, range > min_range)."""
    rng = np.linalg.norm(xyz, axis=1)
    valid = np.isfinite(rng) & (rng > max(min_range, 1e-12))
    d = np.zeros_like(xyz)
    d[valid] = xyz[valid] / rng[valid, None]
    return d, valid


def angle_jacobians(d: np.ndarray, azimuth_std: float, elevation_std: float) -> np.ndarray:
    """(2, N, 3): ``sigma_az * dd/daz`` and ``sigma_el * dd/del`` for (N, 3) unit directions.

    With ``d = (cos e cos a, cos e sin a, sin e)``: ``dd/da = cos e (-sin a, cos a, 0)`` and
    ``dd/de = (-sin e cos a, -sin e sin a, cos e)``. The Doppler error of a static point due to
    direction noise is ``(J . v_s)``, row by row.
    """
    horizontal = np.hypot(d[:, 0], d[:, 1])                # cos e
    safe = np.where(horizontal > 1e-12, horizontal, 1.0)
    cos_a, sin_a = d[:, 0] / safe, d[:, 1] / safe
    d_az = np.stack([-d[:, 1], d[:, 0], np.zeros(len(d))], axis=1)
    d_el = np.stack([-d[:, 2] * cos_a, -d[:, 2] * sin_a, horizontal], axis=1)
    return np.stack([azimuth_std * d_az, elevation_std * d_el])


def band_sq(J: np.ndarray, v: np.ndarray, noise_std: float, sigma: float) -> np.ndarray:
    """Squared noise band ``sigma^2 (s_vr^2 + (s_az dd/daz . v)^2 + (s_el dd/del . v)^2)``.

    ``J`` (2, N, k) from :func:`angle_jacobians` (first k columns); ``v`` (k,) or (k, S) hypotheses;
    returns (N,) or (N, S).
    """
    ja, je = J[0] @ v, J[1] @ v
    return sigma * sigma * (noise_std * noise_std + ja * ja + je * je)


def angular_weights(d: np.ndarray, bin_deg: float) -> np.ndarray:
    """(N,) weight 1 / (points sharing the point's azimuth-elevation bin); ones when bin_deg <= 0."""
    if bin_deg <= 0 or len(d) == 0:
        return np.ones(len(d))
    az = np.arctan2(d[:, 1], d[:, 0])
    el = np.arcsin(np.clip(d[:, 2], -1.0, 1.0))
    step = math.radians(bin_deg)
    keys = np.floor(az / step).astype(np.int64) * 100003 + np.floor(el / step).astype(np.int64)
    _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    return 1.0 / counts[inverse]


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


def _inliers_of(D: np.ndarray, J: np.ndarray, v_r: np.ndarray, v: np.ndarray, config: RadarConfig) -> np.ndarray:
    resid = v_r + D @ v
    return resid * resid <= band_sq(J, v, config.noise_std, config.inlier_sigma)


def _direction_noise_gram(J: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(k, k) ``sum_i w_i Sigma_d,i``: the weighted covariance of the measured directions.

    The directions are measured with angle noise, so the design matrix is noisy and correlated with
    the Doppler error ``(J delta) . v`` that this noise causes (errors in variables): plain least
    squares is biased by ``-(A^T W A)^-1 (sum_i w_i Sigma_d,i) v``. Subtracting this term from the
    information matrix (corrected least squares) removes the bias to first order. It matters for
    the worst-determined component: vz of an imaging radar with a narrow elevation field and ~1 deg
    elevation noise (a 0.02-0.03 m/s bias on the synthetic scenes, their dominant error).
    """
    return np.einsum("n,sni,snj->ij", w, J, J)


def _normal_equations(A: np.ndarray, b: np.ndarray, w: np.ndarray,
                      prior: tuple[np.ndarray, float] | None,
                      J: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(k, k) information matrix and (k,) right-hand side of weighted LS, plus an optional
    zero-velocity prior ``axis . v = 0 +- std``.

    With ``J`` (the rows' angle Jacobians) the errors-in-variables correction
    :func:`_direction_noise_gram` is subtracted, scaled by the variance factor
    ``s^2 = min(1, reduced chi-square)`` of the plain weighted LS fit: the configured angle noise is
    an upper bound, data cleaner than the noise model get a proportionally smaller correction and
    noise-free data none (the plain solution is then exact). The correction is dropped when it
    would remove more than half of the information in some direction.
    """
    AtW = A.T * w
    H, g = AtW @ A, AtW @ b
    Hp = H
    if prior is not None:
        axis, std = prior
        Hp = H + np.outer(axis, axis) / std ** 2
    if J is None or len(b) <= A.shape[1]:
        return Hp, g
    v = np.linalg.solve(Hp, g)
    r = b - A @ v
    s2 = min(1.0, float(np.sum(w * r * r)) / (len(b) - A.shape[1]))
    Hc = H - s2 * _direction_noise_gram(J, w)
    if np.linalg.eigvalsh(Hc)[0] <= 0.5 * np.linalg.eigvalsh(H)[0]:
        return Hp, g
    return (Hc if prior is None else Hc + (Hp - H)), g


def _least_squares(D: np.ndarray, J: np.ndarray, v_r: np.ndarray, v_guess: np.ndarray,
                   config: RadarConfig, prior: tuple[np.ndarray, float] | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Weighted, errors-in-variables corrected LS on the inlier set, iterated: returns (k,)
    velocity and (n,) inlier mask."""
    v = v_guess
    inl = _inliers_of(D, J, v_r, v, config)
    for _ in range(max(1, config.refine_iterations)):
        if inl.sum() < D.shape[1]:
            break
        A = -D[inl]
        Ji = J[:, inl]
        # Weights 1/sigma_i^2 of each point's noise (the direction term grows with speed).
        w = 1.0 / band_sq(Ji, v, config.noise_std, 1.0)
        try:
            v_new = np.linalg.solve(*_normal_equations(A, v_r[inl], w, prior, Ji))
        except np.linalg.LinAlgError:
            break
        inl_new = _inliers_of(D, J, v_r, v_new, config)
        v = v_new
        if np.array_equal(inl_new, inl):
            break
        inl = inl_new
    return v, inl


def _fail(n: int, reason: str, config: RadarConfig, valid: np.ndarray | None = None,
          velocity: np.ndarray | None = None, inliers: np.ndarray | None = None, iterations: int = 0,
          dof: int = 3) -> EgoMotion:
    return EgoMotion(
        velocity=np.full(3, np.nan) if velocity is None else velocity,
        inliers=np.zeros(n, dtype=bool) if inliers is None else inliers,
        covariance=np.full((3, 3), np.nan), ok=False, reason=reason, iterations=iterations, dof=dof,
        noise_std=config.noise_std, azimuth_std=config.azimuth_std, elevation_std=config.elevation_std)


def vz_observable(d: np.ndarray, config: RadarConfig) -> bool:
    """Whether (N, 3) unit directions spread enough in elevation to determine vz: the smallest
    singular value of ``d / sqrt(N)`` is at least 3 * ``min_conditioning``."""
    if len(d) < 3:
        return False
    return bool(np.linalg.svd(d / math.sqrt(len(d)), compute_uv=False)[-1] >= 3 * config.min_conditioning)


def choose_dof(d: np.ndarray, config: RadarConfig) -> int:
    """The largest model the directions allow: 3 when ``model="3d"`` or (``"auto"``) when the
    directions make vz observable (:func:`vz_observable`), else 2. In ``"auto"`` mode
    :func:`estimate_ego_motion` applies this to the scan first and then again to the static
    inliers of a 2-D fit, which decides."""
    if config.model != "auto":
        return 3 if config.model == "3d" else 2
    if len(d) < 3:
        return 3
    return 3 if vz_observable(d, config) else 2


def dominant_cluster_fraction(d_inliers: np.ndarray, d_all: np.ndarray, config: RadarConfig) -> tuple[float, float]:
    """(fraction, window_deg): the largest fraction of the inliers that lies inside one azimuth
    window, the window being ``cluster_window_fraction`` of the scan's azimuth extent (5-95 %
    percentiles of all valid points), at least 2 angular bins wide. The static world seen from a
    moving radar spans the field of view; a large moving object (a truck) is compact in azimuth."""
    if len(d_inliers) == 0:
        return 0.0, float("nan")
    az_all = np.degrees(np.arctan2(d_all[:, 1], d_all[:, 0]))
    lo, hi = np.percentile(az_all, [5.0, 95.0])
    window = max(config.cluster_window_fraction * (hi - lo), 2.0 * config.angular_bin_deg)
    az = np.sort(np.degrees(np.arctan2(d_inliers[:, 1], d_inliers[:, 0])))
    ends = np.searchsorted(az, az + window, side="right")
    return float(np.max(ends - np.arange(len(az))) / len(az)), float(window)


def _ransac(D: np.ndarray, M: np.ndarray, vr: np.ndarray, weights: np.ndarray, fixed_h: np.ndarray,
            rng: np.random.Generator, config: RadarConfig) -> tuple[np.ndarray, int, int]:
    """Best (k,) hypothesis of adaptive RANSAC (the always-scored ``fixed_h`` (F, k) included),
    hypotheses evaluated, well-conditioned minimal samples."""
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


def estimate_ego_motion(xyz: Any, v_r: Any, config: RadarConfig | None = None,
                        prior: np.ndarray | None = None, vertical_axis: np.ndarray | None = None,
                        **options: Any) -> EgoMotion:
    """The radar's velocity from one scan, robust to moving points and clutter.

    Args:
        xyz: (N, 3) point positions in the radar frame (m). Rows with NaN/inf or a range below
            ``min_range`` are ignored (their ``inliers`` entry is False).
        v_r: (N,) raw Doppler radial velocities (m/s), positive = receding.
        config: options (``RadarConfig``); ``options`` override single fields, e.g. ``seed=3``.
        prior: optional (3,) velocity of the previous scan: scored as an extra hypothesis, and the
            fit is not ``ok`` when it disagrees with it by more than ``prior_gate`` + 3 sigma.
        vertical_axis: optional (3,) unit vector, the ego's z axis in radar axes; with
            ``vertical_prior_std > 0`` the refinement adds ``vertical_axis . v = 0 +- std`` (a
            ground vehicle does not move along its own z axis). Needs the mounting, so the scene
            processor passes it; plain calls estimate v unconstrained.

    Returns:
        EgoMotion. ``ok`` is False, with a reason, for empty or too small scans, degenerate
        geometry, when fewer than ``min_inlier_fraction`` of the points agree on one velocity,
        when the inliers are one compact angular cluster (``max_cluster_fraction``: likely a big
        moving object, not the static world), or when the velocity contradicts ``prior``.

    Method: 3-point minimal samples (2-point in 2d mode) solved in vectorised batches, each sample
    checked for conditioning; hypotheses scored by angularly weighted inlier count with a
    noise- and speed-aware band; the iteration count adapts to the best inlier fraction so far
    (``log(1-p)/log(1-w^k)``); the zero velocity (standstill) and ``prior`` are always scored too;
    the winner is refined by weighted least squares on its inliers, iterated, with the
    errors-in-variables correction for the noisy directions (:func:`_direction_noise_gram`); the
    final design matrix is checked for conditioning and the covariance is ``s^2 H^-1`` with ``s^2``
    the reduced chi-square of the inliers (at least 1).

    Model choice (``model="auto"``): a 2-D fit runs first (:func:`planar_basis`: vz = 0 in radar
    axes, or, with ``vertical_axis``, no motion along the ego's z axis); only when its static
    inliers spread enough in elevation to determine vz (:func:`vz_observable`) is the 3-D model
    fitted (RANSAC seeded with the 2-D winner, then LS), and the 3-D result is kept only when its
    own inliers still determine vz. Deciding from the whole scan instead lets a tall moving
    object lend its elevation spread to a radar whose static world is flat, and a 3-D fit then
    follows the object.
    """
    config = _resolve_config(config, options)
    xyz, v_r = _as_points(xyz, v_r)
    return _estimate(xyz, v_r, config, prior, vertical_axis, refit=True)


def _estimate(xyz: np.ndarray, v_r: np.ndarray, config: RadarConfig, prior: np.ndarray | None,
              vertical_axis: np.ndarray | None, refit: bool) -> EgoMotion:
    n_all = len(xyz)
    if n_all == 0:
        return _fail(0, "empty scan", config)
    d_all, valid = unit_directions(xyz, config.min_range)
    valid &= np.isfinite(v_r)
    n = int(valid.sum())
    if n < max(config.min_points, 3):
        return _fail(n_all, f"too few valid points ({n} < {max(config.min_points, 3)})", config)

    D3, vr = d_all[valid], v_r[valid]
    k_max = choose_dof(D3, config)
    auto = config.model == "auto"
    rng = np.random.default_rng(config.seed)
    J3 = angle_jacobians(D3, config.azimuth_std, config.elevation_std)
    weights = angular_weights(D3, config.angular_bin_deg)
    M3 = np.ascontiguousarray(np.concatenate([D3, J3[0], J3[1]]))
    vertical = None
    if vertical_axis is not None and np.all(np.isfinite(vertical_axis)) and np.linalg.norm(vertical_axis) > 0:
        vertical = np.asarray(vertical_axis, dtype=np.float64) / np.linalg.norm(vertical_axis)
    # Velocity parametrisations: v = B u, B (3, k). 2-D: the planar model (see planar_basis).
    bases = {3: np.eye(3), 2: planar_basis(vertical)}
    designs = {3: (D3, J3, M3)}
    if k_max == 2 or auto:
        B2 = bases[2]
        designs[2] = (D3 @ B2, J3 @ B2, np.ascontiguousarray(M3 @ B2))
    prior_v = None
    if prior is not None and np.all(np.isfinite(prior)):
        prior_v = np.asarray(prior, dtype=np.float64).reshape(3)

    standstill_inl = _inliers_of(D3, J3, vr, np.zeros(3), config)
    standstill = float(standstill_inl.mean()) >= config.standstill_fraction

    def fixed_hypotheses(k: int, extra: np.ndarray | None = None) -> np.ndarray:
        fixed = [np.zeros(k)]
        if prior_v is not None:
            fixed.append(bases[k].T @ prior_v)
        if extra is not None:
            fixed.append(bases[k].T @ extra)
        return np.stack(fixed)

    iterations, conditioned = 0, 0
    if standstill:
        # At a standstill the zero hypothesis seeds the refinement (a slow crawl is still recovered).
        k = 3 if (k_max == 3 and (not auto or vz_observable(D3[standstill_inl], config))) else 2
        best_v = seed_v = np.zeros(3)
    else:
        k = 2 if auto else k_max
        D, J, M = designs[k]
        u, iterations, conditioned = _ransac(D, M, vr, weights, fixed_hypotheses(k), rng, config)
        best_v = seed_v = bases[k] @ u
        inl2 = _inliers_of(D, J, vr, u, config)
        if (auto and k_max == 3 and conditioned > 0 and inl2.sum() >= config.min_inlier_fraction * n
                and vz_observable(D3[inl2], config)):
            # The 2-D fit found a static world (enough inliers) that determines vz: fit the full
            # model. (A 2-D fit explaining too few points is reported as such, not rescued by the
            # extra freedom of vz: a wild vz widens the speed-dependent band until noise fits.)
            v3, it3, c3 = _ransac(D3, M3, vr, weights, fixed_hypotheses(3, best_v), rng, config)
            k, best_v, iterations, conditioned = 3, v3, iterations + it3, conditioned + c3
        if conditioned == 0:
            return _fail(n_all, f"degenerate geometry: none of {iterations} minimal samples is "
                                f"well-conditioned (directions span too little)", config, iterations=iterations,
                         dof=k)

    def refine(k: int, v0: np.ndarray):
        vprior = None
        if vertical is not None and config.vertical_prior_std > 0 and k == 3:
            vprior = (vertical, config.vertical_prior_std)
        D, J, _ = designs[k]
        u, inl = _least_squares(D, J, vr, bases[k].T @ v0, config, vprior)
        return u, inl, vprior

    u, inl, vprior = refine(k, best_v)
    if auto and k == 3 and (not vz_observable(D3[inl], config)
                            or (not standstill and inl.sum() < 0.8 * inl2.sum())):
        # The 3-D fit settled on inliers that do not determine vz, or explains clearly fewer points
        # (< 80 %) than the 2-D fit it extends (it went astray): use the 2-D model.
        k = 2
        u, inl, vprior = refine(2, seed_v)

    D, J, _ = designs[k]
    v = u
    inliers = np.zeros(n_all, dtype=bool)
    inliers[np.flatnonzero(valid)[inl]] = True
    n_in = int(inl.sum())
    velocity = bases[k] @ u
    fail = dict(velocity=velocity, inliers=inliers, iterations=iterations, dof=k)
    if n_in < max(config.min_points, k):
        return _fail(n_all, f"too few inliers ({n_in} of {n})", config, **fail)
    A = -D[inl]
    sing = np.linalg.svd(A / math.sqrt(n_in), compute_uv=False)
    if sing[-1] < config.min_conditioning:
        return _fail(n_all, f"degenerate geometry: inlier directions span too little "
                            f"(smallest singular value {sing[-1]:.2g} < {config.min_conditioning})",
                     config, **fail)
    Ji = J[:, inl]
    w = 1.0 / band_sq(Ji, v, config.noise_std, 1.0)
    resid = vr[inl] + D[inl] @ v
    chi2 = float(np.sum(w * resid * resid) / max(n_in - k, 1))
    # s^2 = max(1, reduced chi-square): never more confident than the noise model says.
    cov_k = np.linalg.inv(_normal_equations(A, vr[inl], w, vprior, Ji)[0]) * max(chi2, 1.0)
    covariance = bases[k] @ cov_k @ bases[k].T
    if k == 2:
        normal = np.cross(bases[2][:, 0], bases[2][:, 1])
        covariance = covariance + np.outer(normal, normal) * config.vertical_std_2d ** 2
    residual_std = float(np.std(resid)) if n_in > 1 else float("nan")

    def untrusted(reason: str, set_aside: bool = False) -> EgoMotion:
        failed = dataclasses.replace(_fail(n_all, reason, config, **fail), covariance=covariance,
                                     residual_std=residual_std)
        if not (set_aside and refit):
            return failed
        # The winner looks like one moving object (compact, or contradicting the prior): set its
        # points aside and fit the rest once (sequential RANSAC); trust that only if it passes
        # every check on its own and still explains min_inlier_fraction of the whole scan.
        rest = np.where(inliers, np.nan, v_r)
        second = _estimate(xyz, rest, config, prior, vertical_axis, refit=False)
        second = dataclasses.replace(second, iterations=iterations + second.iterations)
        if second.ok and second.inliers.sum() >= config.min_inlier_fraction * n:
            return second
        why = second.reason if not second.ok else (
            f"{second.inliers.sum()} inliers < {config.min_inlier_fraction:.0%} of {n} points")
        return dataclasses.replace(failed, reason=f"{reason}; refit without those points: {why}")

    fraction = n_in / n
    if fraction < config.min_inlier_fraction:
        return untrusted(f"too many outliers: {fraction:.0%} inliers < {config.min_inlier_fraction:.0%}")
    if not standstill and config.max_cluster_fraction < 1.0:
        share, window = dominant_cluster_fraction(D3[inl], D3, config)
        if share > config.max_cluster_fraction:
            return untrusted(f"inliers are one compact angular cluster ({share:.0%} of them within "
                             f"{window:.0f} deg of azimuth > {config.max_cluster_fraction:.0%}): likely a "
                             f"large moving object, not the static world", set_aside=True)
    if prior_v is not None and config.prior_gate > 0:
        change = float(np.linalg.norm(velocity - prior_v))
        sigma = math.sqrt(max(float(np.linalg.eigvalsh(covariance)[-1]), 0.0))
        if change > config.prior_gate + 3.0 * sigma:
            return untrusted(f"disagrees with the prior (previous scan) velocity by {change:.2f} m/s "
                             f"> prior_gate {config.prior_gate:g} + 3 sigma ({3 * sigma:.2f})", set_aside=True)
    return EgoMotion(velocity, inliers, covariance, True, "standstill" if standstill else "",
                     residual_std, iterations, k, standstill, config.noise_std, config.azimuth_std,
                     config.elevation_std)
