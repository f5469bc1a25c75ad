import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.radar.config import RadarConfig, RadarObjectConfig
from radar4dgs.radar.least_squares import direction_noise_gram
from radar4dgs.radar.objects import (
    OBJECTS_FILE,
    SPLIT_OBJECTS_FILE,
    cluster_points,
    corrected_least_squares,
    detect_objects,
    fit_planar_velocity,
    load_radar_objects,
    optional_radar_objects,
    track_objects,
)
from radar4dgs.radar.tracking import track_detections


def car_returns(rng, centre, n, length=4.5, width=1.8):
    """(n, 3) points on the outline of a car footprint at ``centre`` (2,), heights 0.3-1.4 m."""
    side = rng.integers(0, 4, n)
    s = rng.uniform(-0.5, 0.5, n)
    local = np.where(side[:, None] < 2,
                     np.stack([s * length, np.where(side == 0, 0.5, -0.5) * width], axis=1),
                     np.stack([np.where(side == 2, 0.5, -0.5) * length, s * width], axis=1))
    return np.column_stack([local + centre, rng.uniform(0.3, 1.4, n)])


def planar_system(points, velocity, noise=0.0, rng=None):
    """(N, 2) planar parts of the unit directions origin -> points and (N,) exact (or noisy) d . v."""
    d = points / np.linalg.norm(points, axis=1, keepdims=True)
    b = d[:, :2] @ np.asarray(velocity, float)
    if noise:
        b = b + rng.normal(0.0, noise, len(b))
    return d[:, :2], b


def test_exact_doppler_recovers_the_planar_velocity():
    rng = np.random.default_rng(0)
    A, b = planar_system(car_returns(rng, np.array([15.0, 4.0]), 20), [3.0, -7.0])
    fit = fit_planar_velocity(A, b)
    assert fit.observable and fit.inliers.all()
    np.testing.assert_allclose(fit.velocity, [3.0, -7.0], atol=1e-9)
    # The radial-only baseline only sees the component along the mean line of sight.
    assert fit.radial_velocity @ np.array([-fit.direction[1], fit.direction[0]]) == pytest.approx(0.0, abs=1e-12)


@settings(max_examples=40, deadline=None)
@given(vx=st.floats(-25, 25), vy=st.floats(-25, 25), rng_m=st.floats(6.0, 30.0),
       azimuth=st.floats(-1.0, 1.0), n=st.integers(4, 40), seed=st.integers(0, 2 ** 16))
def test_exact_recovery_wherever_the_object_is(vx, vy, rng_m, azimuth, n, seed):
    rng = np.random.default_rng(seed)
    centre = rng_m * np.array([math.cos(azimuth), math.sin(azimuth)])
    A, b = planar_system(car_returns(rng, centre, n), [vx, vy])
    fit = fit_planar_velocity(A, b, rng=rng)
    assert fit.inliers.all()
    if fit.observable:
        np.testing.assert_allclose(fit.velocity, [vx, vy], atol=1e-7)
    else:
        # Only a corner seen end-on: the fallback is radial and says so in its covariance.
        assert np.linalg.eigvalsh(fit.covariance)[-1] == pytest.approx(100.0, rel=1e-6)


@pytest.mark.parametrize("min_full_fit_returns, observable", [(2, True), (3, False)])
def test_two_returns_get_the_radial_estimate_since_nothing_checks_their_exact_fit(min_full_fit_returns, observable):
    # Two returns 8 degrees apart, one from a car receding at 10 m/s along its line of sight and
    # one a clutter return reading 0: the 2x2 system solves exactly to a speed no road user has.
    A = np.array([[math.cos(a), math.sin(a)] for a in np.radians([0.0, 8.0])])
    b = np.array([10.0, 0.0])
    fit = fit_planar_velocity(A, b, RadarObjectConfig(min_full_fit_returns=min_full_fit_returns))
    assert fit.observable == observable
    speed = float(np.linalg.norm(fit.velocity))
    assert (speed > 50.0) if observable else (speed < 10.0)  # 72 m/s exact, 10 radial


def test_covariance_is_calibrated_under_noise():
    rng = np.random.default_rng(1)
    config = RadarObjectConfig()
    sigma, v = 0.1, np.array([8.0, 5.0])
    nees, errors, predicted = [], [], []
    for _ in range(400):
        A, b = planar_system(car_returns(rng, np.array([18.0, -6.0]), 15), v, sigma, rng)
        fit = fit_planar_velocity(A, b, config, rng)
        assert fit.observable
        e = fit.velocity - v
        nees.append(e @ np.linalg.solve(fit.covariance, e))
        errors.append(e)
        predicted.append(fit.covariance)
    # A calibrated 2x2 covariance gives a mean squared Mahalanobis error of 2 (chi-square, 2 dof);
    # a factor 1.5 in std either way is 2 / 2.25 .. 2 * 2.25.
    assert 2 / 1.5 ** 2 < np.mean(nees) < 2 * 1.5 ** 2
    # The error scales as predicted along the worst-determined (tangential) direction too.
    worst = np.linalg.eigh(np.mean(predicted, axis=0))[1][:, -1]
    spread = np.std(np.array(errors) @ worst)
    expected = math.sqrt(worst @ np.mean(predicted, axis=0) @ worst)
    assert expected / 1.5 < spread < expected * 1.5


def test_outliers_are_rejected():
    rng = np.random.default_rng(2)
    v = np.array([-4.0, 9.0])
    A, b = planar_system(car_returns(rng, np.array([12.0, 3.0]), 30), v, 0.05, rng)
    bad = rng.choice(30, 6, replace=False)                         # 20 %
    b[bad] += rng.choice([-1.0, 1.0], 6) * rng.uniform(2.0, 15.0, 6)
    fit = fit_planar_velocity(A, b)
    assert not fit.inliers[bad].any() and fit.inliers.sum() == 24
    assert np.linalg.norm(fit.velocity - v) < 3 * math.sqrt(np.trace(fit.covariance))


def test_narrow_azimuth_spread_falls_back_to_radial():
    rng = np.random.default_rng(3)
    azimuth = rng.uniform(0.300, 0.305, 8)                          # 0.3 deg wide at 80 m
    points = np.column_stack([80 * np.cos(azimuth), 80 * np.sin(azimuth), np.full(8, 1.0)])
    v = np.array([2.0, 6.0])
    A, b = planar_system(points, v, 0.05, rng)
    fit = fit_planar_velocity(A, b)
    assert not fit.observable and math.degrees(fit.azimuth_spread) < 0.5
    np.testing.assert_array_equal(fit.velocity, fit.radial_velocity)
    u = fit.direction
    assert fit.velocity @ u == pytest.approx(v @ u, abs=0.1)
    assert fit.velocity @ np.array([-u[1], u[0]]) == pytest.approx(0.0, abs=1e-9)
    small, large = np.linalg.eigvalsh(fit.covariance)
    assert large == pytest.approx(RadarObjectConfig().unobserved_std ** 2, rel=1e-3) and small < 0.01


def test_clusters_split_far_objects_and_keep_ghosts_below_the_road():
    rng = np.random.default_rng(4)
    a, b = car_returns(rng, np.array([15.0, 4.0]), 24), car_returns(rng, np.array([30.0, -8.0]), 20)
    ghost = a[:2] * np.array([1.0, 1.0, -1.0])                     # multipath, mirrored below the road
    labels = cluster_points(np.concatenate([a, b, ghost]), radius=2.5, z_scale=0.25)
    assert len(set(labels[:24])) == 1 and len(set(labels[24:44])) == 1 and labels[0] != labels[24]
    assert set(labels[44:]) == {labels[0]}
    tall = np.array([[10.0, 0.0, 0.0], [10.0, 0.0, 3.0]])
    assert cluster_points(tall, 2.5, 0.25)[0] == cluster_points(tall, 2.5, 0.25)[1]
    assert cluster_points(tall, 2.5, 1.0)[0] != cluster_points(tall, 2.5, 1.0)[1]


def test_detect_objects_in_a_scan_with_a_mounted_radar():
    """Two cars and static points in the radar frame of a radar rotated 30 deg and moved in the world:
    velocities come back in world axes and the point indices partition the dynamic rows."""
    rng = np.random.default_rng(5)
    yaw = math.radians(30.0)
    radar_to_world = np.eye(4)
    radar_to_world[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    radar_to_world[:3, 3] = [100.0, 50.0, 0.5]
    cars = [(np.array([14.0, 3.0]), np.array([6.0, -2.0]), 15), (np.array([25.0, -10.0]), np.array([0.0, 8.0]), 10)]
    xyz, comp, dynamic, owner = [], [], [], []
    for k, (centre, v_world, n) in enumerate(cars):
        p = car_returns(rng, centre, n)
        d = p / np.linalg.norm(p, axis=1, keepdims=True)
        xyz.append(p)
        comp.append((d @ radar_to_world[:3, :3].T)[:, :2] @ v_world)
        dynamic.append(np.ones(n, bool))
        owner.append(np.full(n, k))
    xyz.append(rng.uniform([5, -20, 0], [40, 20, 2], (20, 3)))
    comp.append(np.zeros(20))
    dynamic.append(np.zeros(20, bool))
    owner.append(np.full(20, -1))
    xyz, comp, dynamic, owner = (np.concatenate(x) for x in (xyz, comp, dynamic, owner))
    found = detect_objects(xyz, comp, dynamic, radar_to_world, RadarObjectConfig(), seed=0)
    assert len(found) == 2
    for det, (_, v_world, n) in zip(found, cars, strict=True):
        assert len(det.points) == n and len(set(owner[det.points])) == 1 and len(det.outliers) == 0
        np.testing.assert_allclose(det.fit.velocity, v_world, atol=1e-8)
    np.testing.assert_allclose(found[0].centroid, xyz[owner == 0].mean(0) @ radar_to_world[:3, :3].T
                               + radar_to_world[:3, 3], atol=1e-9)


def test_two_movers_in_one_cluster_come_apart_with_split_outliers():
    """A lead car driving away and an oncoming car passing 1.2 m beside it (one radius-graph cluster):
    the cluster's fit keeps one and drops the other's returns as outliers; with ``split_outliers``
    they are fitted again into a second object with its own exact velocity, and no further object
    comes from what is left."""
    rng = np.random.default_rng(3)
    cars = [(np.array([15.0, -1.5]), np.array([6.0, 0.5]), 40), (np.array([16.0, 1.5]), np.array([-8.0, 0.0]), 30)]
    xyz, comp, owner = [], [], []
    for k, (centre, v, n) in enumerate(cars):
        p = car_returns(rng, centre, n)
        xyz.append(p)
        comp.append(planar_system(p, v)[1])
        owner.append(np.full(n, k))
    xyz, comp, owner = (np.concatenate(x) for x in (xyz, comp, owner))
    assert len(np.unique(cluster_points(xyz, RadarObjectConfig().radius, RadarObjectConfig().z_scale))) == 1
    dynamic = np.ones(len(xyz), bool)
    one = detect_objects(xyz, comp, dynamic, np.eye(4), RadarObjectConfig(), seed=0)
    assert len(one) == 1 and len(one[0].outliers) == 30
    both = detect_objects(xyz, comp, dynamic, np.eye(4), RadarObjectConfig(split_outliers=True), seed=0)
    assert len(both) == 2
    for det, (_, v, n) in zip(both, cars, strict=True):
        assert len(det.points) == n and len(set(owner[det.points])) == 1
        np.testing.assert_allclose(det.fit.velocity, v, atol=1e-6)


def test_three_chance_outliers_of_one_car_need_split_min_returns_to_stay_outliers():
    """A car whose fit leaves three outlier returns that happen to agree on another velocity: a further object
    needs ``split_min_returns`` inliers, so at 3 they become a spurious second object on top of the car and at
    4 they stay the car's outliers."""
    rng = np.random.default_rng(5)
    body = car_returns(rng, np.array([20.0, 0.0]), 40)
    odd = car_returns(rng, np.array([20.0, 0.0]), 3)
    xyz = np.concatenate([body, odd])
    comp = np.concatenate([planar_system(body, [8.0, 0.0])[1], planar_system(odd, [-5.0, 9.0])[1]])
    dynamic = np.ones(len(xyz), bool)
    configs = (RadarObjectConfig(split_outliers=True, split_min_returns=k) for k in (3, 4))
    loose, strict = (detect_objects(xyz, comp, dynamic, np.eye(4), config, seed=0) for config in configs)
    assert len(loose) == 2 and len(loose[1].points) == 3
    assert np.linalg.norm(loose[1].centroid[:2] - loose[0].centroid[:2]) < 2.5  # on the same car
    assert len(strict) == 1 and len(strict[0].outliers) == 3
    np.testing.assert_allclose(strict[0].fit.velocity, [8.0, 0.0], atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(v=st.tuples(st.floats(-25, 25), st.floats(-25, 25)), v_s=st.tuples(st.floats(-30, 30), st.floats(-5, 5)),
       noise_deg=st.floats(0.05, 1.0), seed=st.integers(0, 2 ** 16))
def test_corrected_least_squares_is_exact_where_the_noise_averages_out(v, v_s, noise_deg, seed):
    """Returns in pairs with opposite direction errors +-delta: the scatter of the noisy directions is the
    true one plus exactly ``sum delta delta^T`` and the cross terms cancel, so the correction recovers
    the velocity to rounding, while plain least squares leans toward the radar's velocity."""
    rng = np.random.default_rng(seed)
    v, v_s = np.array(v), np.array(v_s)
    azimuth = rng.uniform(-0.05, 0.05, 10) + 0.2                     # a car ~4 m wide at 40 m
    true = np.column_stack([np.cos(azimuth), np.sin(azimuth)])
    delta = np.radians(noise_deg) * rng.choice([-1.0, 1.0], (10, 1)) * np.column_stack([-true[:, 1], true[:, 0]])
    A = np.concatenate([true + delta, true - delta])
    b = np.concatenate([true @ v + delta @ v_s, true @ v - delta @ v_s])   # compensated with the noisy d
    jacobians = np.concatenate([delta, delta])[None]                     # one angle, std = |delta|
    np.testing.assert_allclose(direction_noise_gram(jacobians), 2 * delta.T @ delta, rtol=1e-12)
    found = corrected_least_squares(A, b, direction_noise_gram(jacobians), v_s)
    np.testing.assert_allclose(found, v, atol=1e-6 * (1 + np.abs(v).max() + np.abs(v_s).max()))
    plain = np.linalg.lstsq(A, b, rcond=None)[0]
    across = np.array([-math.sin(0.2), math.cos(0.2)])
    gap = (v_s - v) @ across
    if abs(gap) > 1.0:                                                   # pulled toward v_s, not past it
        assert 0 < (plain - v) @ across / gap < 1


def test_corrected_least_squares_refuses_a_spread_no_wider_than_the_noise():
    A = np.array([[1.0, 0.0], [1.0, 0.001]])
    assert corrected_least_squares(A, np.zeros(2), np.diag([0.0, 1e-4]), np.zeros(2)) is None


def test_crossing_car_is_not_slowed_by_azimuth_noise():
    """A car crossing 40 m ahead at 10 m/s while the radar drives 15 m/s, its returns 0.57 deg noisy in
    azimuth, seen by a radar rotated 30 deg in the world: over 200 scans plain least squares is
    1.3 m/s too slow across the line of sight, the corrected fit is unbiased within its sampling error."""
    rng = np.random.default_rng(6)
    yaw, sigma = math.radians(30.0), 0.01
    radar_to_world = np.eye(4)
    radar_to_world[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    v_car, v_radar = np.array([0.0, -10.0]), np.array([15.0, 0.0, 0.0])   # world; the radar's own frame
    errors = {True: [], False: []}
    for trial in range(200):
        points = np.column_stack([40 + rng.uniform(-1, 1, 15), -8 + rng.uniform(-2.2, 2.2, 15),
                                  rng.uniform(0.3, 1.4, 15)])
        d = points / np.linalg.norm(points, axis=1, keepdims=True)
        raw = (d @ radar_to_world[:3, :3].T)[:, :2] @ v_car - d @ v_radar + rng.normal(0.0, 0.08, 15)
        r = np.linalg.norm(points, axis=1)
        azimuth = np.arctan2(points[:, 1], points[:, 0]) + rng.normal(0.0, sigma, 15)
        elevation = np.arcsin(points[:, 2] / r)
        noisy = r[:, None] * np.column_stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                                              np.sin(elevation)])
        compensated = raw + (noisy / r[:, None]) @ v_radar
        for correct in (True, False):
            found = detect_objects(noisy, compensated, np.ones(15, bool), radar_to_world,
                                   RadarObjectConfig(correct_direction_noise=correct), seed=trial,
                                   radar_velocity=v_radar, angle_std=(sigma, 0.0))
            errors[correct].append(found[0].fit.velocity - v_car)
    bias = {correct: np.linalg.norm(np.mean(e, axis=0)) for correct, e in errors.items()}
    assert bias[False] > 0.9 and bias[True] < 0.4


def constant_velocity_measurements(frames, v, start, noise, rng, missing=()):
    z, R = [], []
    for t in range(frames):
        if t in missing:
            z.append(np.zeros((0, 4)))
            R.append(np.zeros((0, 4, 4)))
            continue
        truth = np.concatenate([start + v * 0.1 * t, v])
        z.append((truth + rng.normal(0.0, noise)).reshape(1, 4))
        R.append(np.diag(np.square(noise)).reshape(1, 4, 4))
    return z, R


def test_kalman_filter_tracks_through_a_missed_frame():
    rng = np.random.default_rng(6)
    v = np.array([7.0, -3.0])
    noise = np.array([1.0, 1.0, 0.5, 0.5])
    z, R = constant_velocity_measurements(12, v, np.array([20.0, 5.0]), noise, rng, missing=(6,))
    out = track_detections(np.arange(12) * 0.1, z, R, RadarObjectConfig())
    assert [len(f.ids) for f in out] == [1] * 6 + [0] + [1] * 5
    assert {int(f.ids[0]) for f in out if len(f.ids)} == {0}
    # Filtering beats one measurement: the velocity std shrinks below the measurement's 0.5 m/s.
    final = out[-1]
    assert np.sqrt(final.covariances[0, 2, 2]) < 0.35
    assert np.linalg.norm(final.states[0, 2:4] - v) < 3 * np.sqrt(np.trace(final.covariances[0, 2:4, 2:4]))


def test_tracks_end_after_too_many_missed_frames_and_far_detections_start_new_ones():
    rng = np.random.default_rng(7)
    noise = np.array([0.3, 0.3, 0.2, 0.2])
    config = RadarObjectConfig(max_missed=2)
    z, R = constant_velocity_measurements(10, np.array([5.0, 0.0]), np.array([10.0, 0.0]), noise, rng,
                                          missing=(3, 4, 5))
    ids = [int(f.ids[0]) for f in track_detections(np.arange(10) * 0.1, z, R, config) if len(f.ids)]
    assert ids == [0, 0, 0, 1, 1, 1, 1]
    z2 = [np.array([[0.0, 0.0, 1.0, 0.0], [50.0, 0.0, 1.0, 0.0]])] * 2
    R2 = [np.tile(np.diag(np.square(noise)), (2, 1, 1))] * 2
    out = track_detections(np.array([0.0, 0.1]), z2, R2, config)
    assert out[1].ids.tolist() == [0, 1]


def test_objects_document_round_trips(tmp_path):
    rng = np.random.default_rng(8)
    frames, names = [], []
    for t in range(3):
        p = car_returns(rng, np.array([15.0 + 0.5 * t, 2.0]), 12)
        d = p / np.linalg.norm(p, axis=1, keepdims=True)
        frames.append(detect_objects(p, d[:, :2] @ [5.0, 1.0], np.ones(12, bool), np.eye(4)))
        names.append(f"{t:06d}")
    document = track_objects(names, np.arange(3) * 0.1, frames)
    (tmp_path / "radar").mkdir()
    (tmp_path / "radar" / OBJECTS_FILE).write_text(json.dumps(document, allow_nan=False))
    loaded = load_radar_objects(tmp_path)
    assert [len(f) for f in loaded] == [1, 1, 1] and {f[0].track for f in loaded} == {0}
    obj = loaded[2][0]
    assert obj.velocity.shape == (3,) and obj.velocity[2] == 0.0 and obj.velocity_covariance.shape == (2, 2)
    np.testing.assert_allclose(obj.frame_velocity[:2], [5.0, 1.0], atol=1e-8)
    assert obj.points.dtype == np.int64 and obj.num_returns == 12 and obj.observable
    # The stages that work without radar objects get them only when they are current.
    assert optional_radar_objects(tmp_path, 3)[0] is not None and optional_radar_objects(tmp_path, 3)[1] is None
    stale = f"{tmp_path / 'radar' / OBJECTS_FILE}: has 3 frames, the scene 4 (stale: rerun `radar4dgs prepare"
    assert optional_radar_objects(tmp_path, 4) == (None, stale + " --only radar --force`)")
    assert optional_radar_objects(None, 3) == (None, "no prepared folder")
    (tmp_path / "radar" / OBJECTS_FILE).write_text(json.dumps({"format": "other"}))
    with pytest.raises(ValueError, match="not a radar4dgs-radar-objects file"):
        load_radar_objects(tmp_path)
    assert "not a radar4dgs-radar-objects file" in optional_radar_objects(tmp_path, 3)[1]
    with pytest.raises(FileNotFoundError, match="objects.json: missing file"):
        load_radar_objects(tmp_path / "nowhere")
    assert "objects.json: missing file" in optional_radar_objects(tmp_path / "nowhere", 3)[1]


def test_prepare_writes_objects_for_a_synthetic_scene(tmp_path):
    from radar4dgs.config import preset
    from radar4dgs.datasets.synth import SynthConfig, synthesize
    from radar4dgs.io.scene import read_scene
    from radar4dgs.radar.process import prepare_radar

    root = synthesize(preset(SynthConfig, "tiny", seed=1, num_frames=6), tmp_path / "scene", progress=False)
    scene = read_scene(root)
    prepare_radar(scene, tmp_path / "prepared" / "radar", preset(RadarConfig, "tiny"))
    loaded = load_radar_objects(tmp_path / "prepared")
    assert len(loaded) == len(scene) and sum(map(len, loaded)) > 0
    for i, objects in enumerate(loaded):
        n = len(scene.load_radar(i))
        for obj in objects:
            assert obj.num_returns == len(obj.points) >= RadarObjectConfig().min_returns
            assert obj.points.max(initial=-1) < n and not set(obj.points) & set(obj.outliers)
    # Beside them the split objects: each cluster's first fit is the same object, its outliers may make more.
    split = load_radar_objects(tmp_path / "prepared", SPLIT_OBJECTS_FILE)
    assert len(split) == len(loaded)
    for objects, finer in zip(loaded, split, strict=True):
        assert len(finer) >= len(objects)
        assert {tuple(o.points) for o in objects} <= {tuple(o.points) for o in finer}
    # With split_outliers on, objects.json is already split and the second file is the same.
    config = preset(RadarConfig, "tiny")
    config.objects.split_outliers = True
    prepare_radar(scene, tmp_path / "split" / "radar", config)
    written = tmp_path / "split" / "radar"
    assert (written / SPLIT_OBJECTS_FILE).read_bytes() == (written / OBJECTS_FILE).read_bytes()
