"""Radar objects: one frame's dynamic points grouped into objects, each object's full planar
velocity from its returns' compensated Doppler, and tracks across frames (``tracking.py``).

Velocity model. A rigid object translating with world velocity ``v`` gives each of its returns the
compensated radial velocity ``v_r_comp_i = d_i . v`` (``d_i`` the unit direction radar -> return,
world axes). We ASSUME ``v_z = 0`` (road traffic moves in the world's ground plane; a 5 % slope at
20 m/s would add ``d_z * 1 m/s``, a few cm/s at the radar's small elevations), leaving two unknowns:
``A v = b`` with ``A`` the (N, 2) planar parts of the ``d_i``. Returns at different azimuths make
``A`` full rank, so one scan gives the tangential velocity that a single Doppler cannot see. The fit
is robust: MSAC over pairs of returns (each pair solves the 2x2 system exactly) plus one radial
hypothesis per return, then least squares on the inliers, repeated until the inlier set is stable.
Its covariance is ``s^2 (A^T A)^-1`` over the inliers, ``s^2`` the residual variance pooled with a
prior (``residual_prior_std``, ``residual_prior_dof``). When the inliers are fewer than
``min_full_fit_returns`` (two solve exactly, with nothing left to check them), their azimuths spread too little
(``min_azimuth_spread_deg``) or the tangential std that spread predicts is too large
(``max_tangential_std``), the object is flagged unobservable and its velocity is the radial-only
estimate ``s u`` (``u`` the mean planar line of sight) with variance ``unobserved_std^2`` across ``u``.
A turning object (yaw rate ``omega``) fits no worse: every return then reads the body's velocity
field at the radar, ``v + omega J (r - p)`` (``tracking.py``), so one scan's fit is that, not the
object's own velocity; the tracker separates the two over scans.

Output ``<prepared>/radar/objects.json`` (written by ``prepare_radar``; world frame of scene.json)::

    {"format": "radar4dgs-radar-objects", "version": 1,
     "frames": [{"name": "000000", "timestamp": 0.0, "objects": [{
        "track": 0,                         # track id, stable across frames
        "centroid": [x, y, z],              # mean of the object's inlier returns (world, m)
        "velocity": [vx, vy, 0.0],          # tracked velocity (IMM, at the centroid; smoothed over the whole
                                            # track unless RadarObjectConfig.smooth is off) (world, m/s)
        "velocity_covariance": [[..], [..]],        # its 2x2 covariance (m^2/s^2)
        "yaw_rate": 0.0, "yaw_rate_std": 0.3,       # tracked yaw rate (rad/s, counter-clockwise) and its std
        "turning": 0.1,                     # probability of the tracker's turning model
        "frame_velocity": [vx, vy, 0.0],    # this scan's own fit: the velocity field at the radar
        "frame_velocity_covariance": [[..], [..]],
        "radial_velocity": [vx, vy, 0.0],   # radial-only estimate along the mean line of sight
        "observable": true,                 # false: frame_velocity IS radial_velocity (narrow spread)
        "azimuth_spread_deg": 3.2,          # std of the inliers' azimuths
        "residual_std": 0.09,               # pooled residual std of the fit (m/s)
        "num_returns": 12,                  # inlier returns
        "points": [..],                     # their row indices into scene.load_radar(frame)
        "outliers": [..]}]}]}               # rows of the same cluster rejected by the fit
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radar4dgs.radar.anchor import anchored_position, track_lengths
from radar4dgs.radar.config import RadarObjectConfig
from radar4dgs.radar.doppler import angle_jacobians
from radar4dgs.radar.least_squares import direction_noise_gram
from radar4dgs.radar.tracking import TrackedFrame, smooth_tracks, track_detections

OBJECTS_FILE = "objects.json"
# The objects with every cluster's outliers fitted again (RadarObjectConfig.split_outliers), beside objects.json.
SPLIT_OBJECTS_FILE = "objects_split.json"
FORMAT = "radar4dgs-radar-objects"


def cluster_points(points: np.ndarray, radius: float, z_scale: float) -> np.ndarray:
    """(N,) int64 cluster label of each of (N, 3) points: connected components of the graph that
    links points closer than ``radius`` after heights are scaled by ``z_scale``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(points)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    scaled = np.asarray(points, dtype=np.float64) * np.array([1.0, 1.0, z_scale])
    pairs = cKDTree(scaled).query_pairs(radius, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def pair_hypotheses(A: np.ndarray, b: np.ndarray, max_pairs: int, min_sin: float,
                    rng: np.random.Generator) -> np.ndarray:
    """(M, 2) velocities solving ``A[i] v = b[i], A[j] v = b[j]`` exactly for pairs i < j of the (N, 2)
    planar directions ``A`` and (N,) radial velocities ``b``: all pairs up to ``max_pairs``, else a random
    ``max_pairs``; pairs with ``|sin(angle between)| < min_sin`` are skipped (they amplify noise)."""
    i, j = np.triu_indices(len(A), k=1)
    if len(i) > max_pairs:
        pick = rng.choice(len(i), max_pairs, replace=False)
        i, j = i[pick], j[pick]
    det = A[i, 0] * A[j, 1] - A[i, 1] * A[j, 0]
    norms = np.linalg.norm(A[i], axis=1) * np.linalg.norm(A[j], axis=1)
    good = np.abs(det) >= min_sin * norms
    i, j, det = i[good], j[good], det[good]
    # Cramer's rule on [[a_i0, a_i1], [a_j0, a_j1]] v = (b_i, b_j).
    vx = (b[i] * A[j, 1] - b[j] * A[i, 1]) / det
    vy = (A[i, 0] * b[j] - A[j, 0] * b[i]) / det
    return np.stack([vx, vy], axis=1)


def radial_hypotheses(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, 2): for each return, the velocity along its own line of sight that explains its Doppler."""
    return A * (b / np.maximum(np.einsum("ij,ij->i", A, A), 1e-12))[:, None]


def msac_inliers(A: np.ndarray, b: np.ndarray, hypotheses: np.ndarray, threshold: float) -> np.ndarray:
    """(N,) bool inliers of the (M, 2) hypothesis with the least truncated squared residual (MSAC)."""
    residual = b[:, None] - A @ hypotheses.T                      # (N, M)
    cost = np.minimum(residual * residual, threshold * threshold).sum(axis=0)
    return np.abs(residual[:, int(np.argmin(cost))]) <= threshold


def least_squares_inliers(A: np.ndarray, b: np.ndarray, inliers: np.ndarray, threshold: float,
                          rounds: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Least squares on ``inliers`` (N,) bool, re-selecting them from its residuals until stable.

    Returns (2,) velocity and (N,) bool inliers; keeps the previous set when a round would leave
    fewer than two inliers.
    """
    v = np.linalg.lstsq(A[inliers], b[inliers], rcond=None)[0]
    for _ in range(rounds):
        again = np.abs(b - A @ v) <= threshold
        if again.sum() < 2 or np.array_equal(again, inliers):
            break
        inliers = again
        v = np.linalg.lstsq(A[inliers], b[inliers], rcond=None)[0]
    return v, inliers


def pooled_std(residual: np.ndarray, dof: int, config: RadarObjectConfig) -> float:
    """Residual std (m/s) of a fit with ``dof`` degrees of freedom, pooled with the configured prior."""
    prior_dof = max(config.residual_prior_dof, 0.0)
    weight = max(dof, 0) + prior_dof
    if weight <= 0:
        return config.residual_prior_std
    total = float(residual @ residual) if dof > 0 else 0.0
    return math.sqrt((total + prior_dof * config.residual_prior_std ** 2) / weight)


def corrected_least_squares(A: np.ndarray, b: np.ndarray, noise: np.ndarray, radar_velocity: np.ndarray
                            ) -> np.ndarray | None:
    """(2,) velocity from (N, 2) noisy planar directions ``A`` and (N,) ``b``, corrected for the errors in
    ``A`` (corrected least squares, Fuller 1987, "Measurement Error Models", 2.2), or None when the
    corrected normal matrix is not positive definite (the spread is no larger than the noise).

    ``b_i = v_r_i + d~_i . v_s`` is compensated with the noisy direction ``d~_i = d_i + delta_i``, so
    ``b_i = d~_i . v - delta_i . (v - v_s)``: the regressor's noise enters both sides.
    ``E[A^T A] = A0^T A0 + noise`` and ``E[A^T b] = A0^T A0 v + noise v_s``, hence
    ``v = (A^T A - noise)^-1 (A^T b - noise v_s)``. Plain least squares instead blends ``v`` with the
    radar's velocity ``v_s`` across the line of sight, by ``noise / (A^T A)``: 3 % for a car whose
    returns spread 1.7 deg in azimuth with 0.3 deg of noise, 0.4 m/s when it crosses at 10 m/s while
    the ego drives 15 m/s.

    Args:
        noise: (2, 2) :func:`.least_squares.direction_noise_gram` of these returns. radar_velocity: (2,) planar world
        velocity of the radar ``v_s``.
    """
    normal = A.T @ A - noise
    if float(np.linalg.eigvalsh(normal)[0]) <= 0.0:
        return None
    return np.linalg.solve(normal, A.T @ b - noise @ radar_velocity)


@dataclass(frozen=True)
class VelocityFit:
    """One object's planar velocity from its returns (module doc).

    Attributes:
        velocity: (2,) world x, y (m/s): the full fit, or ``radial_velocity`` when not ``observable``.
        covariance: (2, 2).
        radial_velocity: (2,) the radial-only estimate ``s u`` along the mean line of sight ``u``.
        direction: (2,) ``u``, unit.
        inliers: (N,) bool.
        observable: the tangential part is determined by the returns' azimuth spread.
        azimuth_spread: rad, std of the inliers' azimuths about ``u``.
        residual_std: m/s, pooled.
    """

    velocity: np.ndarray
    covariance: np.ndarray
    radial_velocity: np.ndarray
    direction: np.ndarray
    inliers: np.ndarray
    observable: bool
    azimuth_spread: float
    residual_std: float


def radial_fit(A: np.ndarray, b: np.ndarray, config: RadarObjectConfig
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Radial-only fit ``v = s u`` of (N, 2) directions ``A`` and (N,) ``b``, with ``u`` their mean
    direction: (2,) velocity, (2, 2) covariance (``unobserved_std`` across ``u``), (2,) ``u``, residual std."""
    unit = A / np.maximum(np.linalg.norm(A, axis=1, keepdims=True), 1e-12)
    u = unit.mean(axis=0)
    u = u / max(float(np.linalg.norm(u)), 1e-12)
    a = A @ u
    s = float(a @ b / max(float(a @ a), 1e-12))
    sigma = pooled_std(b - a * s, len(b) - 1, config)
    across = np.array([-u[1], u[0]])
    covariance = (sigma ** 2 / max(float(a @ a), 1e-12)) * np.outer(u, u) \
        + config.unobserved_std ** 2 * np.outer(across, across)
    return s * u, covariance, u, sigma


def fit_planar_velocity(A: np.ndarray, b: np.ndarray, config: RadarObjectConfig | None = None,
                        rng: np.random.Generator | None = None, jacobians: np.ndarray | None = None,
                        radar_velocity: np.ndarray | None = None) -> VelocityFit:
    """Robust planar velocity of one rigid object (module doc).

    Args:
        A: (N, 2) planar (world x, y) parts of the unit directions radar -> return, N >= 1.
        b: (N,) compensated radial velocities (m/s, positive = receding).
        jacobians: (2, N, 2) planar parts of the returns' angle-noise Jacobians and radar_velocity: (2,)
            the radar's planar world velocity; with both (and ``correct_direction_noise``) the final least
            squares is corrected for the directions' noise (:func:`corrected_least_squares`).
    """
    config = config or RadarObjectConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    A, b = np.asarray(A, dtype=np.float64).reshape(-1, 2), np.asarray(b, dtype=np.float64).reshape(-1)
    hypotheses = np.concatenate([
        pair_hypotheses(A, b, config.max_hypotheses, math.sin(math.radians(config.min_pair_angle_deg)), rng),
        radial_hypotheses(A, b)])
    inliers = msac_inliers(A, b, hypotheses, config.inlier_threshold)
    v = np.zeros(2)
    if inliers.sum() >= 2:
        v, inliers = least_squares_inliers(A, b, inliers, config.inlier_threshold)
    Ai, bi = A[inliers], b[inliers]
    radial, radial_cov, u, radial_sigma = radial_fit(Ai, bi, config)
    unit = Ai / np.maximum(np.linalg.norm(Ai, axis=1, keepdims=True), 1e-12)
    angles = np.arctan2(unit @ np.array([-u[1], u[0]]), unit @ u)
    spread = float(np.sqrt(np.mean(angles ** 2)))
    normal = Ai.T @ Ai
    smallest = float(np.linalg.eigvalsh(normal)[0]) if len(Ai) >= 2 else 0.0
    observable = (len(Ai) >= max(config.min_full_fit_returns, 2)
                  and spread >= math.radians(config.min_azimuth_spread_deg) and smallest > 1e-12)
    if observable:
        sigma = pooled_std(bi - Ai @ v, len(bi) - 2, config)
        observable = sigma / math.sqrt(smallest) <= config.max_tangential_std
    if not observable:
        return VelocityFit(radial, radial_cov, radial, u, inliers, False, spread, radial_sigma)
    if config.correct_direction_noise and jacobians is not None and radar_velocity is not None:
        noise = direction_noise_gram(jacobians[:, inliers])
        corrected = corrected_least_squares(Ai, bi, noise, np.asarray(radar_velocity, dtype=np.float64))
        if corrected is not None:
            v, normal = corrected, normal - noise
            sigma = pooled_std(bi - Ai @ v, len(bi) - 2, config)
    covariance = sigma ** 2 * np.linalg.inv(normal)
    return VelocityFit(v, 0.5 * (covariance + covariance.T), radial, u, inliers, True, spread, sigma)


@dataclass(frozen=True)
class Detection:
    """One object in one frame, before tracking.

    Attributes:
        centroid: (3,) world mean of the inlier returns.
        fit: its :class:`VelocityFit` (world x, y): the object's velocity field at the radar.
        points: (K,) int64 scan rows of the inlier returns; outliers: (L,) the cluster's other rows.
        radar: (3,) world position of the radar at the scan (the point where ``fit`` holds).
        planar: (K, 2) world x, y of the inlier returns (``RadarObjectConfig.anchor_visible_end``); None: unknown.
    """

    centroid: np.ndarray
    fit: VelocityFit
    points: np.ndarray
    outliers: np.ndarray
    radar: np.ndarray
    planar: np.ndarray | None = None


def detect_objects(xyz: np.ndarray, v_r_comp: np.ndarray, dynamic: np.ndarray, radar_to_world: np.ndarray,
                   config: RadarObjectConfig | None = None, seed: int = 0, radar_velocity: np.ndarray | None = None,
                   angle_std: tuple[float, float] | None = None) -> list[Detection]:
    """The objects of one scan: dynamic points clustered in the world and fitted (module doc).

    Args:
        xyz: (N, 3) radar-frame positions; v_r_comp: (N,) compensated radial velocity (m/s);
        dynamic: (N,) bool; radar_to_world: (4, 4) at the scan's time.
        radar_velocity: (3,) the radar's velocity in its own frame (the ego-motion fit's ``v_s``) and
            angle_std: its (azimuth, elevation) noise std (rad); with both, each fit is corrected for the
            directions' noise (:func:`corrected_least_squares`).
    Returns:
        Detections with at least ``min_returns`` inlier returns, in order of their cluster's first row (with
        ``split_outliers``, the further objects of a cluster after its first).
    """
    config = config or RadarObjectConfig()
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    v_r_comp = np.asarray(v_r_comp, dtype=np.float64)
    rng = np.random.default_rng(seed)
    distance = np.linalg.norm(xyz, axis=1)
    rows = np.flatnonzero(np.asarray(dynamic, dtype=bool) & np.isfinite(v_r_comp) & np.isfinite(distance)
                          & (distance > 1e-6))
    rotation, translation = radar_to_world[:3, :3], radar_to_world[:3, 3]
    d_world = (xyz[rows] / distance[rows, None]) @ rotation.T
    p_world = xyz[rows] @ rotation.T + translation
    labels = cluster_points(p_world, config.radius, config.z_scale)
    jacobians = velocity = None
    if radar_velocity is not None and angle_std is not None and np.all(np.isfinite(radar_velocity)):
        jacobians = (angle_jacobians(xyz[rows] / distance[rows, None], *angle_std) @ rotation.T)[..., :2]
        velocity = (rotation @ np.asarray(radar_velocity, dtype=np.float64))[:2]
    detections = []
    for label in np.unique(labels):
        members = np.flatnonzero(labels == label)
        needed = max(config.min_returns, 1)
        while len(members) >= needed:
            fit = fit_planar_velocity(d_world[members, :2], v_r_comp[rows[members]], config, rng,
                                      None if jacobians is None else jacobians[:, members], velocity)
            if fit.inliers.sum() < needed:
                break
            detections.append(Detection(p_world[members[fit.inliers]].mean(axis=0), fit,
                                        rows[members[fit.inliers]], rows[members[~fit.inliers]], translation.copy(),
                                        p_world[members[fit.inliers], :2]))
            if not config.split_outliers or fit.inliers.all():
                break
            # Two returns fit some planar velocity exactly, so a further object never needs fewer than three.
            members, needed = members[~fit.inliers], max(config.min_returns, config.split_min_returns, 3)
    return detections


def measurement(detection: Detection, config: RadarObjectConfig) -> tuple[np.ndarray, np.ndarray]:
    """(4,) ``(centroid x, y, velocity x, y)`` and its (4, 4) covariance, the tracker's input."""
    R = np.zeros((4, 4))
    R[:2, :2] = np.eye(2) * config.centroid_std ** 2
    R[2:, 2:] = detection.fit.covariance
    return np.concatenate([detection.centroid[:2], detection.fit.velocity]), R


def _planar3(v: np.ndarray) -> list[float]:
    return [float(v[0]), float(v[1]), 0.0]


def _matrix(m: np.ndarray) -> list[list[float]]:
    return [[float(x) for x in row] for row in m]


def object_record(detection: Detection, track: int, state: np.ndarray, covariance: np.ndarray,
                  turning: float = 0.0) -> dict:
    """One object's JSON record (module doc) from its detection and its track's (5,) state
    (p_x, p_y, v_x, v_y, omega), (5, 5) covariance and turning-model probability after this frame."""
    fit = detection.fit
    return {"track": int(track), "centroid": [float(x) for x in detection.centroid],
            "velocity": _planar3(state[2:4]), "velocity_covariance": _matrix(covariance[2:4, 2:4]),
            "yaw_rate": float(state[4]), "yaw_rate_std": math.sqrt(max(float(covariance[4, 4]), 0.0)),
            "turning": float(turning),
            "frame_velocity": _planar3(fit.velocity), "frame_velocity_covariance": _matrix(fit.covariance),
            "radial_velocity": _planar3(fit.radial_velocity), "observable": bool(fit.observable),
            "azimuth_spread_deg": math.degrees(fit.azimuth_spread), "residual_std": float(fit.residual_std),
            "num_returns": int(len(detection.points)), "points": [int(i) for i in detection.points],
            "outliers": [int(i) for i in detection.outliers]}


def _track(stamps: np.ndarray, z: list[np.ndarray], R: list[np.ndarray], config: RadarObjectConfig,
           radars: np.ndarray) -> list[TrackedFrame]:
    tracked = track_detections(stamps, z, R, config, radars)
    return smooth_tracks(stamps, z, R, tracked, config, radars) if config.smooth else tracked


def anchored_measurements(detections: list[list[Detection]], tracked: list[TrackedFrame], z: list[np.ndarray],
                          R: list[np.ndarray], config: RadarObjectConfig) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The tracker's T measurement arrays ``z`` (M_t, 4) and covariances ``R`` (M_t, 4, 4) for a second pass on
    the headings of ``tracked`` (the first): each detection of a moving track that has a length is measured at its
    end facing the radar (:mod:`.anchor`) when it has ``anchor_min_returns`` and that end faces the radar by
    ``anchor_min_aspect``, else at its centroid with an along-heading std of half the length; the other rows
    as given."""
    planar = [[d.planar if d.planar is not None else d.centroid[None, :2] for d in frame] for frame in detections]
    velocities = [frame.states[:, 2:4] for frame in tracked]
    lengths = track_lengths([frame.ids for frame in tracked], velocities, planar, config.anchor_min_speed,
                            config.anchor_min_scans, config.anchor_length_quantile)
    z_out = [np.array(frame, dtype=np.float64, copy=True) for frame in z]
    R_out = [np.array(frame, dtype=np.float64, copy=True) for frame in R]
    for t, frame in enumerate(detections):
        for j, detection in enumerate(frame):
            length = lengths.get(int(tracked[t].ids[j]))
            speed = float(np.linalg.norm(velocities[t][j]))
            if length is None or speed < config.anchor_min_speed or detection.planar is None:
                continue
            heading = velocities[t][j] / speed
            sight = detection.centroid[:2] - detection.radar[:2]
            aspect = abs(float(heading @ sight)) / max(float(np.linalg.norm(sight)), 1e-9)
            if len(detection.planar) >= config.anchor_min_returns and aspect >= config.anchor_min_aspect:
                z_out[t][j, :2] = anchored_position(detection.planar, detection.centroid[:2], heading,
                                                    detection.radar[:2], length)
            else:
                along_var = max(config.centroid_std, length / 2) ** 2 - config.centroid_std ** 2
                R_out[t][j, :2, :2] += along_var * np.outer(heading, heading)
    return z_out, R_out


def track_objects(names: list[str], timestamps: np.ndarray, detections: list[list[Detection]],
                  config: RadarObjectConfig | None = None) -> dict:
    """The ``objects.json`` document (module doc) of T frames' detections, tracked in the world."""
    config = config or RadarObjectConfig()
    pairs = [[measurement(d, config) for d in frame] for frame in detections]
    z = [np.array([p[0] for p in frame]).reshape(-1, 4) for frame in pairs]
    R = [np.array([p[1] for p in frame]).reshape(-1, 4, 4) for frame in pairs]
    # The radar's planar position at each scan (the point where every fit of that scan holds).
    radars = np.array([frame[0].radar[:2] if frame else np.zeros(2) for frame in detections]).reshape(-1, 2)
    stamps = np.asarray(timestamps, dtype=np.float64)
    tracked = _track(stamps, z, R, config, radars)
    if config.anchor_visible_end:
        z, R = anchored_measurements(detections, tracked, z, R, config)
        tracked = _track(stamps, z, R, config, radars)
    frames = []
    for name, stamp, found, out in zip(names, timestamps, detections, tracked, strict=True):
        objects = [object_record(d, out.ids[k], out.states[k], out.covariances[k], out.turning[k])
                   for k, d in enumerate(found)]
        frames.append({"name": name, "timestamp": float(stamp), "objects": objects})
    return {"format": FORMAT, "version": 1, "frames": frames}


@dataclass(frozen=True)
class RadarObject:
    """One object of one frame as loaded from ``objects.json`` (fields as in the module doc;
    vectors (3,) world with v_z = 0, covariances (2, 2), ``points`` / ``outliers`` (K,) int64)."""

    track: int
    centroid: np.ndarray
    velocity: np.ndarray
    velocity_covariance: np.ndarray
    frame_velocity: np.ndarray
    frame_velocity_covariance: np.ndarray
    radial_velocity: np.ndarray
    observable: bool
    num_returns: int
    points: np.ndarray
    outliers: np.ndarray


def _radar_object(record: dict) -> RadarObject:
    arrays = {k: np.asarray(record[k], dtype=np.float64) for k in (
        "centroid", "velocity", "velocity_covariance", "frame_velocity", "frame_velocity_covariance",
        "radial_velocity")}
    return RadarObject(track=int(record["track"]), observable=bool(record["observable"]),
                       num_returns=int(record["num_returns"]),
                       points=np.asarray(record["points"], dtype=np.int64),
                       outliers=np.asarray(record["outliers"], dtype=np.int64), **arrays)


def load_radar_objects(prepared_dir: str | Path, name: str = OBJECTS_FILE) -> list[list[RadarObject]]:
    """The objects of every frame, in frame order, from ``<prepared_dir>/radar/<name>`` (``objects.json``,
    or :data:`SPLIT_OBJECTS_FILE`)."""
    path = Path(prepared_dir) / "radar" / name
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing file (run `radar4dgs prepare --only radar`; "
                                f"older prepared folders lack it: add --force)")
    document = json.loads(path.read_text(encoding="utf-8"))
    if document.get("format") != FORMAT:
        raise ValueError(f"{path}: not a {FORMAT} file (format {document.get('format')!r})")
    try:
        return [[_radar_object(o) for o in frame["objects"]] for frame in document["frames"]]
    except (KeyError, TypeError) as exc:
        raise ValueError(f"{path}: malformed object record ({exc!r})") from exc


def optional_radar_objects(prepared_dir: str | Path | None, n_frames: int, name: str = OBJECTS_FILE
                           ) -> tuple[list[list[RadarObject]] | None, str | None]:
    """The objects of every frame (:func:`load_radar_objects`) for the stages that work without
    them, or None and why not: no prepared folder, a missing or malformed ``objects.json``, or one
    made for another number of frames than the scene's ``n_frames`` (stale)."""
    if prepared_dir is None:
        return None, "no prepared folder"
    try:
        objects = load_radar_objects(prepared_dir, name)
    except (FileNotFoundError, ValueError) as exc:
        return None, str(exc)
    if len(objects) != n_frames:
        return None, (f"{Path(prepared_dir) / 'radar' / name}: has {len(objects)} frames, the scene "
                      f"{n_frames} (stale: rerun `radar4dgs prepare --only radar --force`)")
    return objects, None
