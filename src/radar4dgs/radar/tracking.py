"""Tracking of radar objects in the world's ground plane: three motion models per track, going
straight, turning gently and turning, mixed by an interacting multiple model (IMM) filter.

State ``x = (p_x, p_y, v_x, v_y, omega)`` (world, m, m/s, rad/s). The turning model is the
coordinated turn (``v`` rotates at the yaw rate ``omega``, an extended Kalman filter); the straight
model holds ``omega = 0`` and lets a track faster than 1 m/s accelerate only ``lateral_accel_std``
across its velocity (a road vehicle brakes along its heading; sideways it turns). The gently turning
model is the coordinated turn with the straight model's acceleration and a small yaw-rate noise
(``gentle_turn_yaw_accel_std``): a bend or a slow lane change at 0.05-0.1 rad/s is too slow for the
turning model, whose yaw-rate noise is sized for lane changes at 0.45 rad/s, to win scan by scan, and
the straight model then reads the Doppler's ``omega J (r - p)`` (0.1 rad/s x 20 m = 2 m/s, below) as
velocity.

Why the yaw rate. The Doppler of a rigid object that turns does not measure its velocity: a body
point ``x`` moves at ``v + omega J (x - p)`` (``J`` the 90 deg rotation, ``p`` the reference point),
and every return's radial velocity ``d . (v + omega J (x - p))`` with ``d`` along ``x - r`` (``r``
the radar) equals ``d . (v + omega J (r - p))``: one scan's fit (``objects.py``) measures the body's
velocity field AT THE RADAR, ``w = v + omega J (r - p)``, exactly, for any spread of returns. A car
changing lanes 15 m ahead at 0.45 rad/s thus reads 6.8 m/s off across the line of sight. Both models
measure ``z = (centroid, w)`` with ``h(x) = (p, v + omega J (r - p))``; a jump of ``w`` across the
line of sight that the straight model cannot follow makes the turning model the likelier one.
Why not the turning model alone: it also explains a new track's unknown tangential velocity
(a radial-only first fit) by a yaw rate, and then needs many scans to undo it.

Each frame's detections are assigned to the tracks' combined predictions by the Hungarian method on
the squared Mahalanobis distance of the innovation, gated at ``gate_chi2``; unassigned detections
start tracks (``omega = 0``, std ``yaw_rate_std`` in the turning model); a track not updated for more
than ``max_missed`` frames ends (a missed frame is a prediction only). A tentative track (fewer than
``tentative_hits`` updates) that has missed a frame is gated at ``tentative_gate_chi2`` instead: it often
knows only its radial velocity, and its full gate would reach tens of metres across the line of sight.
The reported velocity is the models' combination: the velocity of the body point at the returns'
centroid (not the box centre: 0.45 rad/s x 2 m = 0.9 m/s apart on a turning car seen from behind).

Hand-written in numpy rather than filterpy: a 5-state filter and its IMM are ~100 lines, and filterpy is
unmaintained (no release since 2018).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radar4dgs.radar.config import RadarObjectConfig

# 90 degree rotation in the plane: J (x, y) = (-y, x); d R(theta) / d theta = J R(theta).
_J = np.array([[0.0, -1.0], [1.0, 0.0]])


def _rotation(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def cv_transition(dt: float, accel: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(4, 4) transition ``F`` and process noise ``Q`` of the constant-velocity model over ``dt``
    seconds, with white acceleration of std ``accel`` (m/s^2) or of (2, 2) covariance ``accel``
    (discrete white-noise-acceleration model)."""
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    cov = np.eye(2) * accel ** 2 if np.ndim(accel) == 0 else np.asarray(accel, dtype=np.float64)
    Q = np.kron(np.array([[dt ** 4 / 4, dt ** 3 / 2], [dt ** 3 / 2, dt ** 2]]), cov)
    return F, Q


def acceleration_covariance(v: np.ndarray, config: RadarObjectConfig, straight: bool) -> np.ndarray:
    """(2, 2) covariance of the white acceleration: ``accel_std`` in every direction, except for the
    straight model of a track moving faster than 1 m/s, which only gets ``lateral_accel_std`` across
    its velocity (a road vehicle cannot slide sideways; it turns, which is the other model)."""
    speed = float(np.linalg.norm(v))
    if not straight or speed < 1.0:
        return np.eye(2) * config.accel_std ** 2
    u = v / speed
    return config.accel_std ** 2 * np.outer(u, u) + config.lateral_accel_std ** 2 * np.outer(_J @ u, _J @ u)


def predict(x: np.ndarray, P: np.ndarray, dt: float, config: RadarObjectConfig, straight: bool = False,
            yaw_accel_std: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """State (5,) and covariance (5, 5) moved ``dt`` seconds ahead by the coordinated turn:
    ``v <- R(omega dt) v``, ``p <- p + dt R(omega dt / 2) v`` (midpoint rule), with the linearised
    transition for the covariance, white acceleration (:func:`acceleration_covariance`) on p, v and
    white yaw acceleration on omega (``yaw_accel_std``, by default the config's, none for a
    ``straight`` model)."""
    p, v, omega = x[:2], x[2:4], float(x[4])
    half, full = _rotation(omega * dt / 2), _rotation(omega * dt)
    F = np.eye(5)
    F[:2, 2:4] = dt * half
    F[:2, 4] = dt * dt / 2 * (_J @ half @ v)
    F[2:4, 2:4] = full
    F[2:4, 4] = dt * (_J @ full @ v)
    Q = np.zeros((5, 5))
    Q[:4, :4] = cv_transition(dt, acceleration_covariance(v, config, straight))[1]
    yaw_accel_std = (0.0 if straight else config.yaw_accel_std) if yaw_accel_std is None else yaw_accel_std
    Q[4, 4] = (yaw_accel_std * dt) ** 2
    moved = np.concatenate([p + dt * half @ v, full @ v, [omega]])
    P_new = F @ P @ F.T + Q
    return moved, 0.5 * (P_new + P_new.T)


def observe(x: np.ndarray, radar: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Predicted measurement ``h(x) = (p, v + omega J (r - p))`` (4,) for the planar radar position
    ``radar`` (2,) and its (4, 5) Jacobian."""
    p, v, omega = x[:2], x[2:4], float(x[4])
    H = np.zeros((4, 5))
    H[:2, :2] = np.eye(2)
    H[2:4, :2] = -omega * _J
    H[2:4, 2:4] = np.eye(2)
    H[2:4, 4] = _J @ (radar - p)
    return np.concatenate([p, v + omega * _J @ (radar - p)]), H


def update(x: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray, radar: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """EKF update with measurement ``z`` (4,) = (centroid, velocity field at the radar) of covariance
    ``R`` (4, 4). Joseph form, so that P stays symmetric positive definite when R holds a
    100 m^2/s^2 variance next to a 0.01 one (radial-only fits)."""
    predicted, H = observe(x, radar)
    S = H @ P @ H.T + R
    K = np.linalg.solve(S.T, (P @ H.T).T).T          # P H^T S^-1 (S symmetric)
    I_KH = np.eye(5) - K @ H
    P_new = I_KH @ P @ I_KH.T + K @ R @ K.T
    return x + K @ (z - predicted), 0.5 * (P_new + P_new.T)


def mahalanobis_sq(x: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray, radar: np.ndarray) -> float:
    """Squared Mahalanobis distance of measurement ``z`` (4,) from the predicted one."""
    predicted, H = observe(x, radar)
    y = z - predicted
    return float(y @ np.linalg.solve(H @ P @ H.T + R, y))


@dataclass
class _Track:
    """One track: the IMM's per-model states ``x`` (K, 5), covariances ``P`` (K, 5, 5) and model
    probabilities ``mu`` (K,) in the order of :func:`_models` (straight first, turning last)."""

    id: int
    x: np.ndarray
    P: np.ndarray
    mu: np.ndarray
    missed: int = 0
    hits: int = 1

    def combined(self, mu: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(5,) state and (5, 5) covariance of the mixture of the models with weights ``mu``."""
        return _mixture(self.x, self.P, self.mu if mu is None else mu)


def _mixture(x: np.ndarray, P: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Moment-matched (5,) mean and (5, 5) covariance of Gaussians (K, 5), (K, 5, 5) with weights (K,)."""
    mean = weights @ x
    spread = x - mean
    return mean, np.einsum("k,kij->ij", weights, P) + np.einsum("k,ki,kj->ij", weights, spread, spread)


@dataclass(frozen=True)
class TrackedFrame:
    """The tracker's output for one frame's M detections.

    Attributes:
        ids: (M,) int64 track id of each detection.
        states: (M, 5) filtered (p_x, p_y, v_x, v_y, omega) after this frame's update (the IMM's
            combined estimate).
        covariances: (M, 5, 5) their covariances.
        turning: (M,) probability of the (sharp) turning model.
    """

    ids: np.ndarray
    states: np.ndarray
    covariances: np.ndarray
    turning: np.ndarray


def _straight(x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The straight model's copy of a state: omega 0 and certain."""
    x, P = x.copy(), P.copy()
    x[4] = 0.0
    P[4, :] = P[:, 4] = 0.0
    return x, P


@dataclass(frozen=True)
class _Model:
    """One motion model of the IMM: ``straight`` holds omega at 0; ``road`` accelerates mostly along
    its velocity (:func:`acceleration_covariance`); ``yaw_accel_std`` is its yaw-rate noise."""

    straight: bool
    road: bool
    yaw_accel_std: float


def _models(config: RadarObjectConfig) -> tuple[list[_Model], np.ndarray]:
    """The IMM's models (straight, gently turning when ``gentle_turn_yaw_accel_std`` > 0, turning; the
    turning one last) and their (K, K) switch probabilities per scan, [from, to]."""
    start, end = config.turn_start_probability, config.turn_end_probability
    gentle = config.gentle_turn_switch_probability
    if config.gentle_turn_yaw_accel_std <= 0:
        models = [_Model(True, True, 0.0), _Model(False, False, config.yaw_accel_std)]
        switch = np.array([[1.0 - start, start], [end, 1.0 - end]])
    else:
        models = [_Model(True, True, 0.0), _Model(False, True, config.gentle_turn_yaw_accel_std),
                  _Model(False, False, config.yaw_accel_std)]
        switch = np.array([[1.0 - start - gentle, gentle, start], [gentle, 1.0 - gentle - start, start],
                           [end, 0.0, 1.0 - end]])
    if (switch < 0).any():
        raise ValueError("RadarObjectConfig: turn_start_probability + gentle_turn_switch_probability and "
                         "turn_end_probability must each be at most 1 (they are per-scan probabilities)")
    return models, switch


def _imm_predict(track: _Track, dt: float, config: RadarObjectConfig) -> np.ndarray:
    """Mix the models' states (IMM), move each ahead by ``dt`` and return the (K,) predicted model
    probabilities; the track's ``x``, ``P`` hold the predicted per-model states afterwards."""
    models, switch = _models(config)
    predicted = track.mu @ switch
    xs, Ps = [], []
    for j, model in enumerate(models):
        x, P = track.combined(switch[:, j] * track.mu / max(predicted[j], 1e-300))
        if model.straight:
            x, P = _straight(x, P)
        x, P = predict(x, P, dt, config, straight=model.road, yaw_accel_std=model.yaw_accel_std)
        xs.append(x)
        Ps.append(P)
    track.x, track.P = np.array(xs), np.array(Ps)
    return predicted


def _imm_update(track: _Track, predicted: np.ndarray, z: np.ndarray, R: np.ndarray, radar: np.ndarray) -> None:
    """Update every model with ``z`` (4,), ``R`` (4, 4) and re-weight them by their likelihoods."""
    log_like = np.zeros(len(track.x))
    for j in range(len(track.x)):
        expected, H = observe(track.x[j], radar)
        S = H @ track.P[j] @ H.T + R
        y = z - expected
        log_like[j] = -0.5 * (float(y @ np.linalg.solve(S, y)) + np.linalg.slogdet(S)[1])
        track.x[j], track.P[j] = update(track.x[j], track.P[j], z, R, radar)
    track.x[0], track.P[0] = _straight(track.x[0], track.P[0])
    weights = np.log(np.maximum(predicted, 1e-300)) + log_like
    weights = np.exp(weights - weights.max())
    track.mu = weights / weights.sum()


def gated_assignment(cost: np.ndarray, gate: float) -> list[tuple[int, int]]:
    """(row, column) pairs of the (R, C) ``cost`` matrix (non-negative; inf = no pair), each costing at
    most ``gate``: the most such pairs, and among those the smallest summed cost (Hungarian assignment).

    Pairs beyond the gate are forbidden before the assignment, not dropped after it: left in, the
    solver would trade a good pair for a costly one it then throws away."""
    from scipy.optimize import linear_sum_assignment

    if cost.size == 0:
        return []
    inside = cost <= gate
    # Finite, so the solver stays feasible; dearer than every gated pair together, so one more gated
    # pair always wins; and near the gated costs' scale, so float64 keeps their differences in the sums.
    forbidden = (min(cost.shape) + 1) * max(gate, 1.0) + 1.0
    rows, cols = linear_sum_assignment(np.where(inside, cost, forbidden))
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if inside[r, c]]


def _assign(tracks: list[_Track], z: np.ndarray, R: np.ndarray, radar: np.ndarray, config: RadarObjectConfig
            ) -> list[tuple[int, int]]:
    """(track position, detection) pairs inside the gate of the tracks' combined predictions (gating on
    the nearer model instead let the turning model's wide prediction take wrong detections), minimising
    the summed squared distance. A tentative track (fewer than ``tentative_hits`` updates) that has
    missed a scan pairs only within ``tentative_gate_chi2``."""
    if not tracks or len(z) == 0:
        return []
    states = [t.combined() for t in tracks]
    cost = np.array([[mahalanobis_sq(x, P, z[j], R[j], radar) for j in range(len(z))] for x, P in states])
    for row, track in enumerate(tracks):
        if _tentative(track, config) and track.missed > 0:
            cost[row, cost[row] > config.tentative_gate_chi2] = np.inf
    return gated_assignment(cost, config.gate_chi2)


def _tentative(track: _Track, config: RadarObjectConfig) -> bool:
    return track.hits < config.tentative_hits


def _birth(track_id: int, z: np.ndarray, R: np.ndarray, config: RadarObjectConfig) -> _Track:
    """A new track at measurement ``z`` (4,): not turning, with the configured yaw-rate std in the
    turning models, every model at its stationary probability."""
    P = np.zeros((5, 5))
    P[:4, :4] = R
    P[4, 4] = config.yaw_rate_std ** 2
    x = np.concatenate([z, [0.0]])
    models, switch = _models(config)
    values, vectors = np.linalg.eig(switch.T)
    stationary = np.abs(np.real(vectors[:, int(np.argmin(np.abs(values - 1.0)))]))
    states = [_straight(x, P) if model.straight else (x, P) for model in models]
    return _Track(track_id, np.array([s[0] for s in states]), np.array([s[1] for s in states]),
                  stationary / stationary.sum())


def track_detections(timestamps: np.ndarray, measurements: list[np.ndarray], covariances: list[np.ndarray],
                     config: RadarObjectConfig | None = None, radar_positions: np.ndarray | None = None
                     ) -> list[TrackedFrame]:
    """Track per-frame detections with one coordinated-turn Kalman filter per object (module doc).

    Args:
        timestamps: (T,) seconds, increasing.
        measurements: T arrays (M_t, 4) of (centroid x, y, object velocity field at the radar x, y)
            in the world (a scan's fit, ``objects.py``).
        covariances: T arrays (M_t, 4, 4) of their covariances.
        radar_positions: (T, 2) planar world position of the radar at each scan (None: the origin).
    Returns:
        One :class:`TrackedFrame` per frame, rows aligned with that frame's detections.
    """
    config = config or RadarObjectConfig()
    radars = np.zeros((len(timestamps), 2)) if radar_positions is None else np.asarray(radar_positions, float)
    tracks: list[_Track] = []
    next_id = 0
    out = []
    for t, (z, R) in enumerate(zip(measurements, covariances, strict=True)):
        z = np.asarray(z, dtype=np.float64).reshape(-1, 4)
        R = np.asarray(R, dtype=np.float64).reshape(-1, 4, 4)
        dt = float(timestamps[t] - timestamps[t - 1]) if t > 0 else 0.0
        predicted = {track.id: _imm_predict(track, dt, config) for track in tracks}
        for track in tracks:
            track.mu = predicted[track.id]
        owner = {j: tracks[i] for i, j in _assign(tracks, z, R, radars[t, :2], config)}
        for track in tracks:
            track.missed += 1
        for j in range(len(z)):
            track = owner.get(j)
            if track is None:
                track = _birth(next_id, z[j], R[j], config)
                next_id += 1
                tracks.append(track)
            else:
                _imm_update(track, predicted[track.id], z[j], R[j], radars[t, :2])
                track.hits += 1
            track.missed = 0
            owner[j] = track
        # A tentative track with no gate of its own to coast on ends at its first miss.
        tracks = [tr for tr in tracks if tr.missed <= (0 if _tentative(tr, config) and config.tentative_gate_chi2 <= 0
                                                       else config.max_missed)]
        rows = [owner[j] for j in range(len(z))]
        combined = [tr.combined() for tr in rows]
        out.append(TrackedFrame(np.array([tr.id for tr in rows], dtype=np.int64),
                                np.array([c[0] for c in combined]).reshape(-1, 5),
                                np.array([c[1] for c in combined]).reshape(-1, 5, 5),
                                np.array([tr.mu[-1] for tr in rows], dtype=np.float64)))
    return out


# Time reversal of a state (p, v, omega) and of a measurement (centroid, w): positions stay, velocities
# and the yaw rate change sign (v'(s) = -v(T - s) turns at -omega), and so does w = v + omega J (r - p).
_REVERSE_STATE = np.diag([1.0, 1.0, -1.0, -1.0, -1.0])
_REVERSE_MEASUREMENT = np.diag([1.0, 1.0, -1.0, -1.0])


def _backward_predictions(times: np.ndarray, z: np.ndarray, R: np.ndarray, radars: np.ndarray,
                          config: RadarObjectConfig) -> tuple[np.ndarray, np.ndarray]:
    """One track's detections filtered backward in time by the same IMM, each step's PREDICTION from
    the later detections only (so that fusing it with the forward estimate counts every measurement
    once): (K - 1, 5) states and (K - 1, 5, 5) covariances, in forward time, of detections 0 .. K - 2
    (the last has no later data).

    Args:
        times: (K,) increasing seconds; z: (K, 4); R: (K, 4, 4); radars: (K, 2).
    """
    K = len(times)
    states, covs = np.zeros((K - 1, 5)), np.zeros((K - 1, 5, 5))
    D = _REVERSE_MEASUREMENT
    track = _birth(0, D @ z[-1], D @ R[-1] @ D, config)
    for k in range(K - 2, -1, -1):
        predicted = _imm_predict(track, float(times[k + 1] - times[k]), config)
        track.mu = predicted
        x, P = track.combined()
        states[k], covs[k] = _REVERSE_STATE @ x, _REVERSE_STATE @ P @ _REVERSE_STATE
        _imm_update(track, predicted, D @ z[k], D @ R[k] @ D, radars[k])
    return states, covs


def fuse(x_forward: np.ndarray, P_forward: np.ndarray, x_backward: np.ndarray, P_backward: np.ndarray
         ) -> tuple[np.ndarray, np.ndarray]:
    """Product of the Gaussians (5,), (5, 5) of the forward filter and the backward prediction (the
    two-filter smoother), written as a Kalman update of the forward estimate by the backward one so
    that only ``P_forward + P_backward`` is inverted (either alone may be near singular: the straight
    model's yaw rate is certain)."""
    gain = np.linalg.solve((P_forward + P_backward).T, P_forward.T).T      # P_f (P_f + P_b)^-1
    P = P_forward - gain @ P_forward
    return x_forward + gain @ (x_backward - x_forward), 0.5 * (P + P.T)


def smooth_tracks(timestamps: np.ndarray, measurements: list[np.ndarray], covariances: list[np.ndarray],
                  tracked: list[TrackedFrame], config: RadarObjectConfig | None = None,
                  radar_positions: np.ndarray | None = None) -> list[TrackedFrame]:
    """Fixed-interval smoothing of :func:`track_detections`' output: every track's forward estimate
    fused with the backward filter's prediction from the track's later detections (:func:`fuse`), the
    association kept as the forward pass made it.

    Why: the scene is reconstructed offline, so a frame's estimate may use the whole drive. A new
    track's first scans know only the radial velocity when their returns span little azimuth, and
    the forward filter reports them so; the backward pass arrives with the velocity the later scans
    pinned down. Arguments as :func:`track_detections`; returns frames of the same shape with the
    smoothed ``states`` and ``covariances`` (``ids`` and ``turning`` unchanged).
    """
    config = config or RadarObjectConfig()
    radars = np.zeros((len(timestamps), 2)) if radar_positions is None else np.asarray(radar_positions, float)
    rows: dict[int, list[tuple[int, int]]] = {}
    for t, frame in enumerate(tracked):
        for j, track_id in enumerate(frame.ids):
            rows.setdefault(int(track_id), []).append((t, j))
    states = [frame.states.copy() for frame in tracked]
    covs = [frame.covariances.copy() for frame in tracked]
    for members in rows.values():
        if len(members) < 2:
            continue
        frames = np.array([t for t, _ in members])
        z = np.array([np.asarray(measurements[t], float).reshape(-1, 4)[j] for t, j in members])
        R = np.array([np.asarray(covariances[t], float).reshape(-1, 4, 4)[j] for t, j in members])
        back_x, back_P = _backward_predictions(np.asarray(timestamps, float)[frames], z, R, radars[frames, :2], config)
        for k, (t, j) in enumerate(members[:-1]):
            states[t][j], covs[t][j] = fuse(tracked[t].states[j], tracked[t].covariances[j], back_x[k], back_P[k])
    return [TrackedFrame(frame.ids, s, c, frame.turning) for frame, s, c in zip(tracked, states, covs, strict=True)]
