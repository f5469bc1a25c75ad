"""Turning objects: the Doppler fit reads the velocity field at the radar, and the straight/turning
IMM tracker separates the object's velocity from its yaw rate (radar/tracking.py)."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from radar4dgs.radar.config import RadarObjectConfig
from radar4dgs.radar.objects import detect_objects, track_objects
from radar4dgs.radar.tracking import _birth, _models, gated_assignment, smooth_tracks, track_detections

J = np.array([[0.0, -1.0], [1.0, 0.0]])


def test_a_turning_objects_doppler_fit_is_its_velocity_field_at_the_radar():
    rng = np.random.default_rng(0)
    radar = np.array([2.0, -1.0, 0.5])
    radar_to_world = np.eye(4)
    radar_to_world[:3, 3] = radar
    centre, v, omega = np.array([17.0, 3.0]), np.array([8.0, 1.0]), 0.4
    world = np.column_stack([centre + rng.uniform(-1.0, 1.0, (30, 2)) * [2.2, 0.9], rng.uniform(0.3, 1.4, 30)])
    velocity = v + omega * (world[:, :2] - centre) @ J.T                 # v + omega J (x - c), per return
    d = (world - radar) / np.linalg.norm(world - radar, axis=1, keepdims=True)
    doppler = np.einsum("ij,ij->i", d[:, :2], velocity)
    found = detect_objects(world - radar, doppler, np.ones(30, bool), radar_to_world)
    assert len(found) == 1 and found[0].fit.observable
    # Closed form: every return reads v + omega J (r - c), the rigid motion's velocity at the radar.
    np.testing.assert_allclose(found[0].fit.velocity, v + omega * J @ (radar[:2] - centre), atol=1e-7)
    np.testing.assert_allclose(found[0].radar, radar)
    record = track_objects(["000000"], np.zeros(1), [found])["frames"][0]["objects"][0]
    assert record["yaw_rate"] == 0.0 and record["yaw_rate_std"] > 0 and 0.0 < record["turning"] < 1.0


def lane_change(fps=5.0, seconds=5.0, speed=8.0, omega=0.4, seed=1):
    """A car 15-25 m ahead of a radar driving at 6 m/s along x: straight for 1 s, then a lane change
    whose yaw rate rises to ``omega`` and back within 1.5 s, then straight again. Returns timestamps
    (T,), measurements [(1, 4)], covariances [(1, 4, 4)], radar positions (T, 2), true velocities
    (T, 2) and yaw rates (T,)."""
    rng = np.random.default_rng(seed)
    times = np.arange(int(seconds * fps)) / fps
    rates = np.where((times >= 1.0) & (times < 2.5), omega * np.sin(np.pi * (times - 1.0) / 1.5) ** 2, 0.0)
    heading = np.concatenate([[0.0], np.cumsum(rates[:-1]) / fps])
    velocity = speed * np.stack([np.cos(heading), np.sin(heading)], axis=1)
    position = np.array([15.0, 0.0]) + np.concatenate([[[0.0, 0.0]], np.cumsum(velocity[:-1], axis=0) / fps])
    radars = np.stack([6.0 * times, np.zeros_like(times)], axis=1)
    noise = np.array([0.5, 0.5, 0.05, 0.05])
    z, R = [], []
    for k in range(len(times)):
        w = velocity[k] + rates[k] * J @ (radars[k] - position[k])
        z.append((np.concatenate([position[k], w]) + rng.normal(0.0, noise)).reshape(1, 4))
        R.append(np.diag(noise ** 2).reshape(1, 4, 4))
    return times, z, R, radars, velocity, rates


def test_the_tracker_separates_a_lane_changes_yaw_rate_from_its_velocity():
    times, z, R, radars, velocity, rates = lane_change()
    turning = np.flatnonzero(rates > 0.3)
    out = track_detections(times, z, R, RadarObjectConfig(), radars)
    assert {int(f.ids[0]) for f in out} == {0}
    states = np.array([f.states[0] for f in out])
    errors = np.linalg.norm(states[:, 2:4] - velocity, axis=1)
    # The scan's own fit is off by omega * range (0.4 rad/s x ~17 m = 6.8 m/s) while turning.
    assert np.linalg.norm(np.array([zz[0, 2:] for zz in z])[turning] - velocity[turning], axis=1).min() > 5.0
    assert errors[turning].max() < 1.0 and np.median(errors) < 0.3
    np.testing.assert_allclose(states[turning, 4], rates[turning], atol=0.05)
    assert min(f.turning[0] for f in np.array(out)[turning]) > 0.5
    # Straight only (no turning model ever starts): the tracked velocity follows the biased fits.
    straight_only = RadarObjectConfig(turn_start_probability=0.0, gentle_turn_yaw_accel_std=0.0)
    straight = track_detections(times, z, R, straight_only, radars)
    straight_errors = np.linalg.norm(np.array([f.states[0, 2:4] for f in straight]) - velocity, axis=1)
    assert straight_errors[turning].min() > 3.0


def test_a_straight_track_stays_straight():
    times, z, R, radars, velocity, _ = lane_change(omega=0.0, seed=2)
    out = track_detections(times, z, R, RadarObjectConfig(), radars)
    states = np.array([f.states[0] for f in out])
    assert np.abs(states[:, 4]).max() < 0.05 and max(f.turning[0] for f in out) < 0.5
    assert np.linalg.norm(states[:, 2:4] - velocity, axis=1).max() < 0.3


def velocity_errors(frames, velocity):
    return np.linalg.norm(np.array([f.states[0, 2:4] for f in frames]) - velocity, axis=1)


def test_smoothing_gives_a_new_tracks_radial_only_scans_the_velocity_the_later_scans_measured():
    times, z, R, radars, velocity, _ = lane_change(omega=0.0, fps=10.0, seed=4)
    # The first three scans see the car at a narrow azimuth spread: their fit is the radial part only
    # (along x here), with the traffic-scale std across the line of sight (objects.py).
    for k in range(3):
        z[k] = z[k].copy()
        z[k][0, 3] = 0.0
        R[k] = np.diag([0.25, 0.25, 0.05 ** 2, 10.0 ** 2]).reshape(1, 4, 4)
    velocity = velocity + np.array([0.0, 3.0])     # the car also drifts sideways at 3 m/s
    position = np.array([15.0, 0.0]) + np.outer(times, velocity[0])
    for k in range(len(times)):
        z[k] = z[k].copy()
        z[k][0, :2] = position[k]
        if k >= 3:
            z[k][0, 3] = velocity[k, 1]
    forward = track_detections(times, z, R, RadarObjectConfig(), radars)
    smoothed = smooth_tracks(times, z, R, forward, RadarObjectConfig(), radars)
    before, after = velocity_errors(forward, velocity), velocity_errors(smoothed, velocity)
    # The forward filter knows only the radial part, then what the centroid's motion tells it.
    assert before[0] > 2.5 and before[:2].min() > 1.0
    assert after[:3].max() < 0.3 and after.max() < 0.3
    assert [int(f.ids[0]) for f in smoothed] == [int(f.ids[0]) for f in forward]
    # The fused covariance is no wider than the forward one, and at the start much narrower.
    assert smoothed[0].covariances[0, 3, 3] < 0.01 * forward[0].covariances[0, 3, 3]
    assert all(np.trace(s.covariances[0]) <= np.trace(f.covariances[0]) + 1e-9
               for s, f in zip(smoothed, forward, strict=True))


def test_smoothing_follows_a_gentle_lane_change_that_the_forward_filter_drifts_on():
    times, z, R, radars, velocity, rates = lane_change(omega=0.1, fps=10.0, seed=3)
    two_models = RadarObjectConfig(gentle_turn_yaw_accel_std=0.0)
    forward = track_detections(times, z, R, two_models, radars)
    smoothed = smooth_tracks(times, z, R, forward, two_models, radars)
    before, after = velocity_errors(forward, velocity), velocity_errors(smoothed, velocity)
    # 0.1 rad/s x ~17 m = 1.7 m/s of bias, too slow for the turning model to take over going forward.
    assert np.percentile(before, 90) > 1.5
    assert np.percentile(after, 90) < 0.7 and np.median(after) <= np.median(before)


def test_the_gently_turning_model_follows_a_gentle_lane_change_going_forward():
    times, z, R, radars, velocity, rates = lane_change(omega=0.1, fps=10.0, seed=3)
    out = track_detections(times, z, R, RadarObjectConfig(), radars)
    errors = velocity_errors(out, velocity)
    # Two models only, the same track drifts by more than 1.5 m/s (the test above).
    assert np.percentile(errors, 90) < 0.6 and errors.max() < 1.0
    assert max(f.turning[0] for f in out) < 0.5          # the (sharp) turning model stays out of it


def test_smoothing_keeps_a_straight_track_and_its_last_frame():
    times, z, R, radars, velocity, _ = lane_change(omega=0.0, seed=2)
    forward = track_detections(times, z, R, RadarObjectConfig(), radars)
    smoothed = smooth_tracks(times, z, R, forward, RadarObjectConfig(), radars)
    assert velocity_errors(smoothed, velocity).max() < 0.2
    # The last detection has no later data: its estimate is the forward one.
    np.testing.assert_array_equal(smoothed[-1].states, forward[-1].states)


@given(start=st.floats(0.0, 0.5), end=st.floats(0.0, 1.0), gentle=st.floats(0.0, 0.5), with_gentle=st.booleans())
def test_a_new_tracks_model_probabilities_are_the_switching_chains_stationary_ones(start, end, gentle, with_gentle):
    config = RadarObjectConfig(turn_start_probability=start, turn_end_probability=end,
                               gentle_turn_switch_probability=gentle,
                               gentle_turn_yaw_accel_std=0.2 if with_gentle else 0.0)
    models, switch = _models(config)
    mu = _birth(0, np.zeros(4), np.eye(4), config).mu
    assert len(mu) == len(models) == (3 if with_gentle else 2)
    assert mu.sum() == pytest.approx(1.0) and (mu >= 0).all()
    np.testing.assert_allclose(mu @ switch, mu, atol=1e-9)


def test_switch_probabilities_that_do_not_sum_to_one_are_refused():
    with pytest.raises(ValueError, match="turn_start_probability"):
        _models(RadarObjectConfig(turn_start_probability=0.6, gentle_turn_switch_probability=0.5))


def _best_gated_pairs(cost: np.ndarray, gate: float) -> tuple[int, float]:
    """(number of pairs, summed cost) of the best gated assignment, by enumerating every one."""
    import itertools

    # Enumerate the side with fewer entries against ordered choices of the other (transpose if needed).
    tall = cost.shape[0] > cost.shape[1]
    small = cost.T if tall else cost
    best = (0, 0.0)
    for chosen in itertools.permutations(range(small.shape[1]), small.shape[0]):
        kept = [small[r, c] for r, c in enumerate(chosen) if small[r, c] <= gate]
        candidate = (len(kept), float(sum(kept)))
        if candidate[0] > best[0] or (candidate[0] == best[0] and candidate[1] < best[1]):
            best = candidate
    return best


@given(st.integers(1, 4), st.integers(1, 4), st.integers(0, 10_000), st.sampled_from([0.5, 4.0, 18.47]))
def test_gated_assignment_finds_the_most_gated_pairs_at_the_least_cost(rows, cols, seed, gate):
    rng = np.random.default_rng(seed)
    cost = rng.uniform(0.0, 2.5 * gate, size=(rows, cols))
    cost[rng.random((rows, cols)) < 0.2] = np.inf
    pairs = gated_assignment(cost, gate)
    assert len({r for r, _ in pairs}) == len({c for _, c in pairs}) == len(pairs)
    assert all(cost[r, c] <= gate for r, c in pairs)
    count, total = _best_gated_pairs(cost, gate)
    assert len(pairs) == count
    assert sum(cost[r, c] for r, c in pairs) == pytest.approx(total, abs=1e-9)


def test_gated_assignment_does_not_trade_a_good_pair_for_one_beyond_the_gate():
    # Ungated, the cheapest full assignment is (0, 1) + (1, 0) = 41 (the other one costs inf); dropping the
    # pair beyond the gate afterwards would leave (1, 0) at 1.0 instead of the better (0, 0) at 0.5.
    cost = np.array([[0.5, 40.0], [1.0, np.inf]])
    assert gated_assignment(cost, 4.0) == [(0, 0)]
    assert gated_assignment(np.zeros((0, 3)), 4.0) == []


def radial_only_detection(position, radial_speed, tangential_std=10.0):
    """(4,) measurement and (4, 4) covariance of a scan whose returns spread too little in azimuth: the
    velocity along the line of sight from a radar at the origin is known, the one across it is not."""
    u = np.asarray(position, float) / np.linalg.norm(position)
    t = J @ u
    R = np.zeros((4, 4))
    R[:2, :2] = np.eye(2)
    R[2:, 2:] = 0.15 ** 2 * np.outer(u, u) + tangential_std ** 2 * np.outer(t, t)
    return np.concatenate([position, radial_speed * u]), R


def tentative_scenario(across: float, along: float):
    """A far object seen once with a radial velocity only, two empty scans, then a detection ``across`` m
    across and ``along`` m along the line of sight from where the first object's radial motion puts it."""
    times = np.arange(4) * 0.2
    first = np.array([90.0, 15.0])
    u = first / np.linalg.norm(first)
    z0, R0 = radial_only_detection(first, 2.0)
    z3, R3 = radial_only_detection(first + (0.6 * 2.0 + along) * u + across * (J @ u), 2.0)
    empty = (np.zeros((0, 4)), np.zeros((0, 4, 4)))
    return times, [z0[None], empty[0], empty[0], z3[None]], [R0[None], empty[1], empty[1], R3[None]]


@pytest.mark.parametrize("tentative_hits, tentative_gate_chi2, same_track",
                         [(1, 0.0, True), (2, 0.0, False), (2, 4.0, False)])
def test_a_one_scan_track_does_not_take_another_objects_detection_after_a_miss(tentative_hits, tentative_gate_chi2,
                                                                                same_track):
    # 8 m across and 3 m along the line of sight: inside the full gate that the unknown tangential
    # velocity opens (a coasting one-scan track takes it and reads the offset as speed), outside the
    # tentative gate, and ended with the track where there is none.
    times, z, R = tentative_scenario(8.0, 3.0)
    config = RadarObjectConfig(tentative_hits=tentative_hits, tentative_gate_chi2=tentative_gate_chi2)
    out = track_detections(times, z, R, config)
    assert (out[3].ids[0] == out[0].ids[0]) == same_track


def test_a_one_scan_track_still_finds_its_object_again_where_it_should_be():
    times, z, R = tentative_scenario(2.0, 0.0)
    out = track_detections(times, z, R, RadarObjectConfig(tentative_hits=2, tentative_gate_chi2=4.0))
    assert out[3].ids[0] == out[0].ids[0]


def test_a_confirmed_track_still_coasts_across_a_missed_scan():
    times = np.arange(5) * 0.2
    velocity = np.array([0.0, 11.0])                     # crossing, seen in full by its first two scans
    z, R = [], []
    for k in range(5):
        position = np.array([40.0, -5.0]) + velocity * times[k]
        z.append(np.concatenate([position, velocity])[None] if k not in (2, 3) else np.zeros((0, 4)))
        R.append(np.diag([1.0, 1.0, 0.04, 0.04])[None] if k not in (2, 3) else np.zeros((0, 4, 4)))
    # Two updates make it confirmed: it coasts where a tentative track would end (gate 0).
    out = track_detections(times, z, R, RadarObjectConfig(tentative_hits=2, tentative_gate_chi2=0.0))
    assert out[4].ids[0] == out[0].ids[0]
    out = track_detections(times, z, R, RadarObjectConfig(tentative_hits=3, tentative_gate_chi2=0.0))
    assert out[4].ids[0] != out[0].ids[0]
