"""The Doppler measurement model of a static point: line-of-sight directions, their angle-noise
Jacobians, the speed-dependent noise band and the inlier test against it.

A static point seen along the unit direction ``d`` from a radar moving with velocity ``v_s``
(radar frame) has the raw Doppler ``v_r = -d . v_s`` (positive = receding).
"""

from __future__ import annotations

import math

import numpy as np

from radar4dgs.radar.config import RadarConfig


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


def inliers_of(D: np.ndarray, J: np.ndarray, v_r: np.ndarray, v: np.ndarray, config: RadarConfig) -> np.ndarray:
    """(N,) bool: the points whose residual ``v_r + D v`` lies within the ``inlier_sigma`` noise band
    of the (k,) velocity ``v``; ``D`` (N, k) directions, ``J`` (2, N, k) their angle Jacobians."""
    resid = v_r + D @ v
    return resid * resid <= band_sq(J, v, config.noise_std, config.inlier_sigma)
