"""Dynamic-point classification from ego-motion-compensated Doppler."""

from __future__ import annotations

from typing import Any

import numpy as np

from radar4dgs.radar.config import RadarConfig
from radar4dgs.radar.doppler import angle_jacobians, band_sq, unit_directions
from radar4dgs.radar.ego_motion import EgoMotion, _as_points


def dynamic_threshold(d: np.ndarray, ego: EgoMotion, sigma: float) -> np.ndarray:
    """(N,) threshold on |compensated v_r| for (N, 3) unit directions ``d``.

    ``tau = k * sqrt(s_vr^2 + (s_az dd/daz . v_s)^2 + (s_el dd/del . v_s)^2 + d^T Sigma d)``:
    the Doppler noise; the Doppler error that azimuth and elevation noise cause (it acts on the
    ego velocity's component across the line of sight, so it grows with the speed and vanishes
    straight along the direction of travel); and the ego-velocity uncertainty ``Sigma`` propagated
    along ``d``.
    """
    v = ego.velocity
    J = angle_jacobians(d, ego.azimuth_std, ego.elevation_std)
    cov = np.nan_to_num(ego.covariance, nan=0.0)
    propagated = np.maximum(np.einsum("ni,ij,nj->n", d, cov, d), 0.0)
    return np.sqrt(band_sq(J, v, ego.noise_std, sigma) + sigma * sigma * propagated)


def classify_dynamic(xyz: Any, v_r: Any, ego: EgoMotion, config: RadarConfig | None = None,
                     sigma: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mark the points that move in the world.

    Args:
        xyz: (N, 3) positions in the radar frame; v_r: (N,) raw Doppler (positive = receding).
        ego: the scan's ego-motion (its noise model ``noise_std``, ``azimuth_std``, ``elevation_std`` is reused).
        config: for ``dynamic_sigma`` (default 3); ``sigma`` overrides it.

    Returns:
        ``is_dynamic`` (N,) bool and ``compensated_v_r`` (N,) float64, where
        ``compensated_v_r = v_r + d . v_s`` is the point's own radial velocity in the world
        (0 for a static point; positive = moving away from the radar). A point is dynamic when
        ``|compensated_v_r| > k * sqrt(s_vr^2 + (s_az dd/daz . v_s)^2 + (s_el dd/del . v_s)^2
        + d^T Sigma d)``
        (see :func:`dynamic_threshold`). Rows with NaN or zero range, and every row when the
        ego velocity is unknown (NaN), get ``compensated_v_r = NaN`` and ``is_dynamic = False``.
        A fit with ``ego.ok == False`` but a finite velocity is still applied; check ``ego.ok``.
    """
    k = sigma if sigma is not None else (config or RadarConfig()).dynamic_sigma
    xyz, v_r = _as_points(xyz, v_r)
    n = len(xyz)
    comp = np.full(n, np.nan)
    dynamic = np.zeros(n, dtype=bool)
    if n == 0 or not np.all(np.isfinite(ego.velocity)):
        return dynamic, comp
    d, valid = unit_directions(xyz)
    valid &= np.isfinite(v_r)
    comp[valid] = v_r[valid] + d[valid] @ ego.velocity
    dynamic[valid] = np.abs(comp[valid]) > dynamic_threshold(d[valid], ego, k)
    return dynamic, comp


def compensated_radial_velocity(xyz: np.ndarray, v_r: np.ndarray, radar_velocity: np.ndarray) -> np.ndarray:
    """``v_r + d . v_s``: (N,) world radial velocity of (N, 3) radar-frame points with raw Doppler
    ``v_r`` (N,), for a radar moving with ``radar_velocity`` (3,) (radar axes). Points at the origin
    get NaN."""
    xyz = np.asarray(xyz, dtype=np.float64)
    norm = np.linalg.norm(xyz, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = xyz / norm[:, None]
    result = np.asarray(v_r, dtype=np.float64) + d @ np.asarray(radar_velocity, dtype=np.float64)
    return np.where(norm > 0, result, np.nan)
