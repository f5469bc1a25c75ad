import numpy as np
import pytest
from _radar_helpers import directions, mixed_scan, static_scan
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.radar import RadarConfig, classify_dynamic, dynamic_threshold, estimate_ego_motion

V_S = np.array([12.0, -0.4, 0.2])


def test_recovers_velocity_with_covariance():
    rng = np.random.default_rng(1)
    xyz, v_r = static_scan(rng, 500, V_S, noise=0.05)
    ego = estimate_ego_motion(xyz, v_r, seed=0)
    assert ego.ok and ego.reason == "" and ego.dof == 3
    assert np.linalg.norm(ego.velocity - V_S) < 0.05
    # The error is consistent with the reported covariance (Mahalanobis, 3 dof, generous bound).
    err = ego.velocity - V_S
    assert err @ np.linalg.solve(ego.covariance, err) < 20
    assert ego.inliers.mean() > 0.95


def test_outliers_rejected_and_classified():
    rng = np.random.default_rng(2)
    xyz, v_r, moving = mixed_scan(rng, 1000, V_S, dynamic_fraction=0.4)
    ego = estimate_ego_motion(xyz, v_r, seed=0)
    assert ego.ok
    assert np.linalg.norm(ego.velocity - V_S) < 0.05
    dynamic, comp = classify_dynamic(xyz, v_r, ego)
    assert (dynamic & moving).sum() / dynamic.sum() > 0.98
    assert (dynamic & moving).sum() / moving.sum() > 0.95
    d = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    np.testing.assert_allclose(comp, v_r + d @ ego.velocity)
    assert not (ego.inliers & dynamic).any()


def test_deterministic_given_seed():
    rng = np.random.default_rng(3)
    xyz, v_r, _ = mixed_scan(rng, 300, V_S, dynamic_fraction=0.5)
    a = estimate_ego_motion(xyz, v_r, seed=7)
    b = estimate_ego_motion(xyz, v_r, seed=7)
    np.testing.assert_array_equal(a.velocity, b.velocity)
    np.testing.assert_array_equal(a.inliers, b.inliers)
    assert a.iterations == b.iterations


def test_config_and_options():
    rng = np.random.default_rng(4)
    xyz, v_r = static_scan(rng, 100, V_S)
    ego = estimate_ego_motion(xyz, v_r, RadarConfig(noise_std=0.2), seed=1)
    assert ego.noise_std == 0.2 and ego.ok
    with pytest.raises(TypeError, match="unknown radar option"):
        estimate_ego_motion(xyz, v_r, nosie_std=0.1)


def test_flat_scan_uses_2d_model():
    rng = np.random.default_rng(5)
    xyz, v_r = static_scan(rng, 60, [30.0, 0.1, 0.0], el=0.01)
    ego = estimate_ego_motion(xyz, v_r, seed=0)
    assert ego.ok and ego.dof == 2
    assert ego.velocity[2] == 0.0
    assert abs(ego.velocity[0] - 30.0) < 0.05
    forced = estimate_ego_motion(xyz, v_r, model="3d")
    assert not forced.ok and "degenerate" in forced.reason


def test_standstill():
    rng = np.random.default_rng(6)
    xyz, v_r, moving = mixed_scan(rng, 300, [0.0, 0.0, 0.0], dynamic_fraction=0.3)
    ego = estimate_ego_motion(xyz, v_r)
    assert ego.ok and ego.standstill and ego.reason == "standstill"
    assert np.linalg.norm(ego.velocity) < 0.05
    assert ego.iterations == 0
    dynamic, _ = classify_dynamic(xyz, v_r, ego)
    assert (dynamic == moving).mean() > 0.98


def test_big_compact_truck_does_not_win():
    rng = np.random.default_rng(7)
    xyz, v_r = static_scan(rng, 300, V_S)
    # 300 more points on one truck 20 m ahead-left, moving at 8 m/s forward: a perfectly consistent
    # second "world" with as many points, but packed in a few degrees.
    truck = np.array([20.0, 4.0, 0.5]) + rng.uniform([-1, -1.2, -1], [1, 1.2, 1], (300, 3))
    d = truck / np.linalg.norm(truck, axis=1, keepdims=True)
    v_truck = np.array([8.0, 0.0, 0.0])
    vr_truck = d @ (v_truck - V_S) + rng.normal(0, 0.05, 300)
    ego = estimate_ego_motion(np.vstack([xyz, truck]), np.concatenate([v_r, vr_truck]), seed=0)
    assert ego.ok
    assert np.linalg.norm(ego.velocity - V_S) < 0.1
    assert not ego.inliers[300:].any()


# ---- bad input: clear results, no exceptions


def test_empty_scan():
    ego = estimate_ego_motion(np.zeros((0, 3)), np.zeros(0))
    assert not ego.ok and ego.reason == "empty scan"
    assert ego.inliers.shape == (0,) and np.isnan(ego.velocity).all()
    dynamic, comp = classify_dynamic(np.zeros((0, 3)), np.zeros(0), ego)
    assert dynamic.shape == (0,) and comp.shape == (0,)
    # Plain empty lists work too.
    assert estimate_ego_motion([], []).reason == "empty scan"


def test_single_point():
    ego = estimate_ego_motion([[10.0, 1.0, 0.0]], [-10.0])
    assert not ego.ok and "too few valid points" in ego.reason
    dynamic, comp = classify_dynamic([[10.0, 1.0, 0.0]], [-10.0], ego)
    assert not dynamic.any() and np.isnan(comp).all()


def test_nan_rows_are_ignored():
    rng = np.random.default_rng(8)
    xyz, v_r = static_scan(rng, 100, V_S)
    xyz[3] = np.nan
    v_r[7] = np.nan
    xyz[11] = 0.0  # zero range: no direction
    ego = estimate_ego_motion(xyz, v_r)
    assert ego.ok and not ego.inliers[[3, 7, 11]].any()
    dynamic, comp = classify_dynamic(xyz, v_r, ego)
    assert np.isnan(comp[[3, 7, 11]]).all() and not dynamic[[3, 7, 11]].any()
    assert np.isfinite(np.delete(comp, [3, 7, 11])).all()


def test_all_nan():
    ego = estimate_ego_motion(np.full((5, 3), np.nan), np.full(5, np.nan))
    assert not ego.ok and "too few valid points" in ego.reason


def test_all_points_dynamic():
    rng = np.random.default_rng(9)
    xyz = directions(rng, 200) * 20
    v_r = rng.uniform(-20, 20, 200)  # no common velocity explains them
    ego = estimate_ego_motion(xyz, v_r, seed=0)
    assert not ego.ok and "too many outliers" in ego.reason


def test_degenerate_geometry():
    xyz = np.tile([[20.0, 0.0, 0.0]], (50, 1)) + np.random.default_rng(0).normal(0, 1e-4, (50, 3))
    ego = estimate_ego_motion(xyz, np.full(50, -10.0))
    assert not ego.ok


def test_shape_errors_are_clear():
    with pytest.raises(ValueError, match=r"xyz must have shape \(N, 3\)"):
        estimate_ego_motion(np.zeros((4, 2)), np.zeros(4))
    with pytest.raises(ValueError, match="v_r must have shape"):
        estimate_ego_motion(np.zeros((4, 3)), np.zeros(5))


# ---- threshold


def test_threshold_grows_with_speed_and_noise():
    rng = np.random.default_rng(10)
    xyz, v_r = static_scan(rng, 200, V_S)
    ego = estimate_ego_motion(xyz, v_r)
    d = directions(rng, 50, az=1.0)
    slow = dynamic_threshold(d, ego.__class__(**{**ego.__dict__, "velocity": V_S / 10}), 3.0)
    fast = dynamic_threshold(d, ego, 3.0)
    assert (fast >= slow).all() and (fast > slow).any()
    noisy = dynamic_threshold(d, ego.__class__(**{**ego.__dict__, "noise_std": 0.5}), 3.0)
    assert (noisy > fast).all()
    # Straight ahead the direction noise does not matter (dd/daz is orthogonal to the motion).
    ahead = dynamic_threshold(np.array([[1.0, 0, 0]]), ego.__class__(
        **{**ego.__dict__, "velocity": np.array([10.0, 0, 0]), "covariance": np.zeros((3, 3))}), 3.0)
    assert ahead[0] == pytest.approx(3 * ego.noise_std)


@settings(max_examples=30, deadline=None)
@given(vx=st.floats(-30, 30), vy=st.floats(-5, 5), vz=st.floats(-1, 1), seed=st.integers(0, 1000))
def test_noise_free_recovery(vx, vy, vz, seed):
    rng = np.random.default_rng(seed)
    v = np.array([vx, vy, vz])
    xyz, v_r = static_scan(rng, 80, v, noise=0.0)
    ego = estimate_ego_motion(xyz, v_r, seed=seed)
    assert ego.ok
    np.testing.assert_allclose(ego.velocity, v, atol=1e-6)


def _flat_scan_with_tall_truck(seed):
    """aiMotive-like: 40 static points, +-14 deg azimuth, +-2 deg elevation, 30 m/s; plus 40 points
    on a 3.8 m tall truck 30 m ahead (compact in azimuth, spread in elevation) at 8 m/s."""
    rng = np.random.default_rng(seed)
    v_s = np.array([30.0, 0.1, 0.0])
    xyz, v_r = static_scan(rng, 40, v_s, noise=0.05, az=0.24, el=0.035)
    truck = np.array([30.0, 3.5, 1.5]) + rng.uniform([-6, -1.3, -1.9], [6, 1.3, 1.9], (40, 3))
    d = truck / np.linalg.norm(truck, axis=1, keepdims=True)
    vr_truck = d @ (np.array([8.0, 0.0, 0.0]) - v_s) + rng.normal(0, 0.05, 40)
    return np.vstack([xyz, truck]), np.concatenate([v_r, vr_truck]), v_s


@pytest.mark.parametrize("seed", range(8))
def test_tall_truck_on_flat_radar(seed):
    # The truck's elevation spread must not turn the fit 3-D, and the fit must either find the
    # static world or say why not: never ok=True with the truck's velocity.
    xyz, v_r, v_s = _flat_scan_with_tall_truck(seed)
    ego = estimate_ego_motion(xyz, v_r, seed=seed)
    if ego.ok:
        assert ego.dof == 2
        assert np.linalg.norm(ego.velocity[:2] - v_s[:2]) < 0.2
        assert not ego.inliers[40:].any()
    else:
        assert ego.reason


def test_compact_cluster_is_not_ok():
    # Only the truck is consistent (the "static" points are random): the fit must not claim ok.
    rng = np.random.default_rng(11)
    xyz, v_r, _ = _flat_scan_with_tall_truck(0)
    v_r = v_r.copy()
    v_r[:40] = rng.uniform(-40, 0, 40)
    ego = estimate_ego_motion(xyz, v_r, seed=0)
    assert not ego.ok and "compact angular cluster" in ego.reason


def test_prior_disagreement_is_not_ok():
    rng = np.random.default_rng(12)
    xyz, v_r = static_scan(rng, 200, V_S)
    ok = estimate_ego_motion(xyz, v_r, prior=V_S + 0.5)
    assert ok.ok
    bad = estimate_ego_motion(xyz, v_r, prior=V_S + np.array([8.0, 0, 0]))
    assert not bad.ok and "prior" in bad.reason
    assert np.linalg.norm(bad.velocity - V_S) < 0.05


def test_planar_2d_model_with_vertical_axis():
    # A radar pitched by 2 deg on a car at 30 m/s: the 2-D model moves in the ego's plane.
    rng = np.random.default_rng(13)
    pitch = np.radians(2.0)
    vertical = np.array([-np.sin(pitch), 0.0, np.cos(pitch)])   # ego z in radar axes
    v_s = 30.0 * np.array([np.cos(pitch), 0.0, np.sin(pitch)])  # ego x in radar axes
    xyz, v_r = static_scan(rng, 60, v_s, el=0.01)
    ego = estimate_ego_motion(xyz, v_r, vertical_axis=vertical, seed=0)
    assert ego.ok and ego.dof == 2
    assert abs(ego.velocity @ vertical) < 1e-9
    assert np.linalg.norm(ego.velocity - v_s) < 0.05


def test_errors_in_variables_vz_bias():
    # 1 deg elevation noise, all points below the horizon, 20 m/s: plain LS biases vz; the
    # corrected LS removes most of that bias (mean over scans).
    errs, plain = [], []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        n = 600
        a, e = rng.uniform(-1.0, 1.0, n), rng.uniform(-0.17, 0.0, n)
        d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=1)
        v_s = np.array([20.0, 0.0, 0.0])
        v_r = -d @ v_s + rng.normal(0, 0.05, n)
        e_meas = e + rng.normal(0, 0.017, n)
        d_meas = np.stack([np.cos(e_meas) * np.cos(a), np.cos(e_meas) * np.sin(a), np.sin(e_meas)], axis=1)
        ego = estimate_ego_motion(d_meas * 30.0, v_r, seed=seed, model="3d", noise_std=0.05)
        assert ego.ok
        errs.append(ego.velocity[2] - v_s[2])
        plain.append(np.linalg.lstsq(-d_meas, v_r, rcond=None)[0][2] - v_s[2])
    assert abs(np.mean(errs)) < 0.5 * abs(np.mean(plain))
