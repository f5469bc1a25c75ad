"""Radar ego-motion from one scan's Doppler velocities (3-point RANSAC + least squares).

A static point seen along the unit direction ``d`` from a radar moving with velocity ``v_s``
(radar frame) has the raw Doppler ``v_r = -d . v_s`` (positive = receding). Stacking the static
points gives the linear system ``-D v_s = v_r``; moving points and clutter are outliers.

This module is the public entry point (:func:`estimate_ego_motion`, :class:`EgoMotion`) and runs
the steps: set up the scan's designs, search (standstill check, RANSAC in :mod:`.ransac`), refine
(:mod:`.least_squares`, model choice in :mod:`.velocity_model`), then the checks that decide
whether the result is trusted. The measurement model is in :mod:`.doppler`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from radar4dgs.radar.config import RadarConfig
from radar4dgs.radar.doppler import angle_jacobians, angular_weights, inliers_of, unit_directions
from radar4dgs.radar.least_squares import covariance as inlier_covariance
from radar4dgs.radar.least_squares import least_squares, min_inlier_singular
from radar4dgs.radar.ransac import ransac
from radar4dgs.radar.velocity_model import choose_dof, planar_basis, vz_observable


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


def _fail(n: int, reason: str, config: RadarConfig, valid: np.ndarray | None = None,
          velocity: np.ndarray | None = None, inliers: np.ndarray | None = None, iterations: int = 0,
          dof: int = 3) -> EgoMotion:
    return EgoMotion(
        velocity=np.full(3, np.nan) if velocity is None else velocity,
        inliers=np.zeros(n, dtype=bool) if inliers is None else inliers,
        covariance=np.full((3, 3), np.nan), ok=False, reason=reason, iterations=iterations, dof=dof,
        noise_std=config.noise_std, azimuth_std=config.azimuth_std, elevation_std=config.elevation_std)


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
    errors-in-variables correction for the noisy directions
    (:func:`.least_squares.direction_noise_gram`); the final design matrix is checked for
    conditioning and the covariance is ``s^2 H^-1`` with ``s^2`` the reduced chi-square of the
    inliers (at least 1).

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


@dataclass(frozen=True, eq=False)
class _Scan:
    """The valid points of one scan and everything the search and refinement reuse.

    Attributes:
        D3: (n, 3) unit directions; vr: (n,) raw Doppler.
        J3: (2, n, 3) angle Jacobians (:func:`angle_jacobians`); weights: (n,) angular weights.
        bases: ``{k: (3, k)}`` velocity parametrisations ``v = B u`` (2: :func:`planar_basis`).
        designs: ``{k: (D, J, M)}``: directions (n, k), Jacobians (2, n, k) and their (3n, k)
            stack in the parameters of ``bases[k]`` (k = 2 only when the 2-D model can be used).
        vertical: (3,) unit ego z axis in radar axes, or None; prior_v: (3,) prior velocity or None.
        k_max: :func:`choose_dof` of the scan; auto: ``model == "auto"``.
    """

    D3: np.ndarray
    vr: np.ndarray
    J3: np.ndarray
    weights: np.ndarray
    bases: dict[int, np.ndarray]
    designs: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]
    vertical: np.ndarray | None
    prior_v: np.ndarray | None
    k_max: int
    auto: bool

    def fixed_hypotheses(self, k: int, extra: np.ndarray | None = None) -> np.ndarray:
        """(F, k): zero, the prior and ``extra`` (3,) in the parameters of ``bases[k]``: always scored."""
        fixed = [np.zeros(k)]
        if self.prior_v is not None:
            fixed.append(self.bases[k].T @ self.prior_v)
        if extra is not None:
            fixed.append(self.bases[k].T @ extra)
        return np.stack(fixed)


@dataclass(frozen=True, eq=False)
class _Search:
    """Outcome of the search: the model (k) and (3,) velocity to refine, and how it was found.

    ``seed_v`` is the 2-D (or standstill) winner a failed 3-D refinement falls back to;
    ``inliers_2d`` (n,) the inliers of that 2-D winner (None at a standstill).
    """

    k: int
    best_v: np.ndarray
    seed_v: np.ndarray
    inliers_2d: np.ndarray | None
    iterations: int
    conditioned: int
    standstill: bool


def _prepare(D3: np.ndarray, vr: np.ndarray, config: RadarConfig, prior: np.ndarray | None,
             vertical_axis: np.ndarray | None) -> _Scan:
    """The designs of the (n, 3) valid directions ``D3`` and the cleaned prior and vertical axis."""
    k_max = choose_dof(D3, config)
    auto = config.model == "auto"
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
    return _Scan(D3, vr, J3, weights, bases, designs, vertical, prior_v, k_max, auto)


def _search(scan: _Scan, config: RadarConfig, rng: np.random.Generator) -> _Search:
    """Standstill check, else RANSAC (:func:`_ransac_search`)."""
    standstill_inl = inliers_of(scan.D3, scan.J3, scan.vr, np.zeros(3), config)
    if float(standstill_inl.mean()) >= config.standstill_fraction:
        # At a standstill the zero hypothesis seeds the refinement (a slow crawl is still recovered).
        k = 3 if (scan.k_max == 3 and (not scan.auto or vz_observable(scan.D3[standstill_inl], config))) else 2
        best_v = seed_v = np.zeros(3)
        return _Search(k, best_v, seed_v, None, 0, 0, True)
    return _ransac_search(scan, config, rng)


def _ransac_search(scan: _Scan, config: RadarConfig, rng: np.random.Generator) -> _Search:
    """RANSAC of the largest model allowed (the 2-D one first in ``"auto"`` mode, extended to 3-D
    when its static inliers determine vz)."""
    n, vr = len(scan.vr), scan.vr
    k = 2 if scan.auto else scan.k_max
    D, J, M = scan.designs[k]
    u, iterations, conditioned = ransac(D, M, vr, scan.weights, scan.fixed_hypotheses(k), rng, config)
    best_v = seed_v = scan.bases[k] @ u
    inl2 = inliers_of(D, J, vr, u, config)
    if (scan.auto and scan.k_max == 3 and conditioned > 0 and inl2.sum() >= config.min_inlier_fraction * n
            and vz_observable(scan.D3[inl2], config)):
        # The 2-D fit found a static world (enough inliers) that determines vz: fit the full
        # model. (A 2-D fit explaining too few points is reported as such, not rescued by the
        # extra freedom of vz: a wild vz widens the speed-dependent band until noise fits.)
        M3 = scan.designs[3][2]
        v3, it3, c3 = ransac(scan.D3, M3, vr, scan.weights, scan.fixed_hypotheses(3, best_v), rng, config)
        k, best_v, iterations, conditioned = 3, v3, iterations + it3, conditioned + c3
    return _Search(k, best_v, seed_v, inl2, iterations, conditioned, False)


def _refine(scan: _Scan, config: RadarConfig, k: int, v0: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, float] | None]:
    """Least squares of the k-dof model from the (3,) velocity ``v0``: (k,) parameters, (n,)
    inliers and the vertical prior used (3-D model with a vertical axis only)."""
    vprior = None
    if scan.vertical is not None and config.vertical_prior_std > 0 and k == 3:
        vprior = (scan.vertical, config.vertical_prior_std)
    D, J, _ = scan.designs[k]
    u, inl = least_squares(D, J, scan.vr, scan.bases[k].T @ v0, config, vprior)
    return u, inl, vprior


def _refine_search(scan: _Scan, search: _Search, config: RadarConfig
                   ) -> tuple[int, np.ndarray, np.ndarray, tuple[np.ndarray, float] | None]:
    """The search's winner refined: (k, (k,) parameters, (n,) inliers, vertical prior)."""
    k = search.k
    u, inl, vprior = _refine(scan, config, k, search.best_v)
    if scan.auto and k == 3 and (not vz_observable(scan.D3[inl], config)
                                 or (not search.standstill and inl.sum() < 0.8 * search.inliers_2d.sum())):
        # The 3-D fit settled on inliers that do not determine vz, or explains clearly fewer points
        # (< 80 %) than the 2-D fit it extends (it went astray): use the 2-D model.
        k = 2
        u, inl, vprior = _refine(scan, config, 2, search.seed_v)
    return k, u, inl, vprior


def _distrust(scan: _Scan, inl: np.ndarray, velocity: np.ndarray, covariance: np.ndarray,
              standstill: bool, config: RadarConfig) -> tuple[str, bool] | None:
    """Why the refined (3,) velocity with (n,) inliers is not trusted, and whether its inliers
    look like one moving object (to be set aside and refitted); None when it is trusted."""
    n, n_in = len(scan.vr), int(inl.sum())
    fraction = n_in / n
    if fraction < config.min_inlier_fraction:
        return f"too many outliers: {fraction:.0%} inliers < {config.min_inlier_fraction:.0%}", False
    if not standstill and config.max_cluster_fraction < 1.0:
        share, window = dominant_cluster_fraction(scan.D3[inl], scan.D3, config)
        if share > config.max_cluster_fraction:
            return (f"inliers are one compact angular cluster ({share:.0%} of them within "
                    f"{window:.0f} deg of azimuth > {config.max_cluster_fraction:.0%}): likely a "
                    f"large moving object, not the static world"), True
    if scan.prior_v is not None and config.prior_gate > 0:
        change = float(np.linalg.norm(velocity - scan.prior_v))
        sigma = math.sqrt(max(float(np.linalg.eigvalsh(covariance)[-1]), 0.0))
        if change > config.prior_gate + 3.0 * sigma:
            return (f"disagrees with the prior (previous scan) velocity by {change:.2f} m/s "
                    f"> prior_gate {config.prior_gate:g} + 3 sigma ({3 * sigma:.2f})"), True
    return None


def _refit_without(failed: EgoMotion, reason: str, xyz: np.ndarray, v_r: np.ndarray, n: int,
                   config: RadarConfig, prior: np.ndarray | None,
                   vertical_axis: np.ndarray | None) -> EgoMotion:
    """The ``failed`` winner's inliers set aside, the rest of the (N, 3) scan fitted once more."""
    # The winner looks like one moving object (compact, or contradicting the prior): set its
    # points aside and fit the rest once (sequential RANSAC); trust that only if it passes
    # every check on its own and still explains min_inlier_fraction of the whole scan.
    rest = np.where(failed.inliers, np.nan, v_r)
    second = _estimate(xyz, rest, config, prior, vertical_axis, refit=False)
    second = dataclasses.replace(second, iterations=failed.iterations + second.iterations)
    if second.ok and second.inliers.sum() >= config.min_inlier_fraction * n:
        return second
    why = second.reason if not second.ok else (
        f"{second.inliers.sum()} inliers < {config.min_inlier_fraction:.0%} of {n} points")
    return dataclasses.replace(failed, reason=f"{reason}; refit without those points: {why}")


def _estimate(xyz: np.ndarray, v_r: np.ndarray, config: RadarConfig, prior: np.ndarray | None,
              vertical_axis: np.ndarray | None, refit: bool) -> EgoMotion:
    """:func:`estimate_ego_motion` on validated (N, 3) ``xyz`` and (N,) ``v_r``; ``refit``: whether
    an untrusted winner that looks like one moving object may be set aside and the rest refitted."""
    n_all = len(xyz)
    if n_all == 0:
        return _fail(0, "empty scan", config)
    d_all, valid = unit_directions(xyz, config.min_range)
    valid &= np.isfinite(v_r)
    n = int(valid.sum())
    if n < max(config.min_points, 3):
        return _fail(n_all, f"too few valid points ({n} < {max(config.min_points, 3)})", config)

    rng = np.random.default_rng(config.seed)
    scan = _prepare(d_all[valid], v_r[valid], config, prior, vertical_axis)
    search = _search(scan, config, rng)
    iterations = search.iterations
    if not search.standstill and search.conditioned == 0:
        return _fail(n_all, f"degenerate geometry: none of {iterations} minimal samples is "
                            f"well-conditioned (directions span too little)", config, iterations=iterations,
                     dof=search.k)

    k, u, inl, vprior = _refine_search(scan, search, config)
    D, J, _ = scan.designs[k]
    inliers = np.zeros(n_all, dtype=bool)
    inliers[np.flatnonzero(valid)[inl]] = True
    n_in = int(inl.sum())
    velocity = scan.bases[k] @ u
    fail = dict(velocity=velocity, inliers=inliers, iterations=iterations, dof=k)
    if n_in < max(config.min_points, k):
        return _fail(n_all, f"too few inliers ({n_in} of {n})", config, **fail)
    smallest = min_inlier_singular(D, inl)
    if smallest < config.min_conditioning:
        return _fail(n_all, f"degenerate geometry: inlier directions span too little "
                            f"(smallest singular value {smallest:.2g} < {config.min_conditioning})",
                     config, **fail)
    covariance, residual_std = inlier_covariance(D, J, scan.vr, inl, u, scan.bases[k], config, vprior)

    distrust = _distrust(scan, inl, velocity, covariance, search.standstill, config)
    if distrust is None:
        return EgoMotion(velocity, inliers, covariance, True, "standstill" if search.standstill else "",
                         residual_std, iterations, k, search.standstill, config.noise_std, config.azimuth_std,
                         config.elevation_std)
    reason, set_aside = distrust
    failed = dataclasses.replace(_fail(n_all, reason, config, **fail), covariance=covariance,
                                 residual_std=residual_std)
    if not (set_aside and refit):
        return failed
    return _refit_without(failed, reason, xyz, v_r, n, config, prior, vertical_axis)
