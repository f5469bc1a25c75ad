"""Constant-velocity tracking of radar objects in the world's ground plane.

State ``x = (p_x, p_y, v_x, v_y)`` (world, m and m/s), one Kalman filter per track. Each frame's
detections measure the whole state: the centroid of the object's returns (std ``centroid_std``) and
the object's velocity from its Doppler with that fit's own 2x2 covariance (a radial-only fit has a
large variance across the line of sight, which the centroid motion then fills in over frames).
Detections are assigned to the predicted tracks by the Hungarian method on the squared Mahalanobis
distance, gated at ``gate_chi2``; unassigned detections start tracks; a track not updated for more
than ``max_missed`` frames ends (a missed frame is a prediction only).

Hand-written in numpy rather than filterpy: a 4-state linear filter is ~30 lines, and filterpy is
unmaintained (no release since 2018).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radar4dgs.radar.config import RadarObjectConfig

# Cost of an assignment outside the gate: large but finite, so linear_sum_assignment stays feasible.
_FORBIDDEN = 1e12


def cv_transition(dt: float, accel_std: float) -> tuple[np.ndarray, np.ndarray]:
    """(4, 4) transition ``F`` and process noise ``Q`` of the constant-velocity model over ``dt``
    seconds, with white acceleration of std ``accel_std`` (discrete white-noise-acceleration model)."""
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    q = accel_std ** 2
    block = q * np.array([[dt ** 4 / 4, dt ** 3 / 2], [dt ** 3 / 2, dt ** 2]])
    Q = np.zeros((4, 4))
    Q[np.ix_([0, 2], [0, 2])] = block
    Q[np.ix_([1, 3], [1, 3])] = block
    return F, Q


def predict(x: np.ndarray, P: np.ndarray, dt: float, accel_std: float) -> tuple[np.ndarray, np.ndarray]:
    """State (4,) and covariance (4, 4) moved ``dt`` seconds ahead."""
    F, Q = cv_transition(dt, accel_std)
    return F @ x, F @ P @ F.T + Q


def update(x: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update with a full-state measurement ``z`` (4,) of covariance ``R`` (4, 4) (H = I).

    Joseph form, so that P stays symmetric positive definite when R holds a 100 m^2/s^2 variance
    next to a 0.01 one (radial-only fits).
    """
    S = P + R
    K = np.linalg.solve(S.T, P.T).T                 # P S^-1 (S symmetric)
    I_K = np.eye(4) - K
    P_new = I_K @ P @ I_K.T + K @ R @ K.T
    return x + K @ (z - x), 0.5 * (P_new + P_new.T)


def mahalanobis_sq(x: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray) -> float:
    """Squared Mahalanobis distance of measurement ``z`` (4,) from the predicted state (H = I)."""
    y = z - x
    return float(y @ np.linalg.solve(P + R, y))


@dataclass
class _Track:
    id: int
    x: np.ndarray
    P: np.ndarray
    missed: int = 0


@dataclass(frozen=True)
class TrackedFrame:
    """The tracker's output for one frame's M detections.

    Attributes:
        ids: (M,) int64 track id of each detection.
        states: (M, 4) filtered (p_x, p_y, v_x, v_y) after this frame's update.
        covariances: (M, 4, 4) their covariances.
    """

    ids: np.ndarray
    states: np.ndarray
    covariances: np.ndarray


def _assign(tracks: list[_Track], z: np.ndarray, R: np.ndarray, gate: float) -> list[tuple[int, int]]:
    """(track position, detection) pairs inside the gate, minimising the summed squared distance."""
    from scipy.optimize import linear_sum_assignment

    if not tracks or len(z) == 0:
        return []
    cost = np.array([[mahalanobis_sq(t.x, t.P, z[j], R[j]) for j in range(len(z))] for t in tracks])
    cost = np.where(cost <= gate, cost, _FORBIDDEN)
    rows, cols = linear_sum_assignment(cost)
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if cost[r, c] < _FORBIDDEN]


def track_detections(timestamps: np.ndarray, measurements: list[np.ndarray], covariances: list[np.ndarray],
                     config: RadarObjectConfig | None = None) -> list[TrackedFrame]:
    """Track per-frame detections with one constant-velocity Kalman filter per object (module doc).

    Args:
        timestamps: (T,) seconds, increasing.
        measurements: T arrays (M_t, 4) of (centroid x, y, velocity x, y) in the world.
        covariances: T arrays (M_t, 4, 4) of their covariances.
    Returns:
        One :class:`TrackedFrame` per frame, rows aligned with that frame's detections.
    """
    config = config or RadarObjectConfig()
    tracks: list[_Track] = []
    next_id = 0
    out = []
    for t, (z, R) in enumerate(zip(measurements, covariances, strict=True)):
        z = np.asarray(z, dtype=np.float64).reshape(-1, 4)
        R = np.asarray(R, dtype=np.float64).reshape(-1, 4, 4)
        dt = float(timestamps[t] - timestamps[t - 1]) if t > 0 else 0.0
        for track in tracks:
            track.x, track.P = predict(track.x, track.P, dt, config.accel_std)
        pairs = _assign(tracks, z, R, config.gate_chi2)
        owner = {j: tracks[i] for i, j in pairs}
        for track in tracks:
            track.missed += 1
        for j in range(len(z)):
            track = owner.get(j)
            if track is None:
                track = _Track(next_id, z[j].copy(), R[j].copy())
                next_id += 1
                tracks.append(track)
            else:
                track.x, track.P = update(track.x, track.P, z[j], R[j])
            track.missed = 0
            owner[j] = track
        tracks = [tr for tr in tracks if tr.missed <= config.max_missed]
        rows = [owner[j] for j in range(len(z))]
        out.append(TrackedFrame(np.array([tr.id for tr in rows], dtype=np.int64),
                                np.array([tr.x for tr in rows]).reshape(-1, 4),
                                np.array([tr.P for tr in rows]).reshape(-1, 4, 4)))
    return out
