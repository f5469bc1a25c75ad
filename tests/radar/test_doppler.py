import numpy as np
import pytest
from _radar_helpers import directions

from radar4dgs.radar import RadarConfig
from radar4dgs.radar.doppler import angle_jacobians, angular_weights, band_sq, inliers_of, unit_directions


def test_unit_directions_validity():
    xyz = np.array([[3.0, 4.0, 0.0], [np.nan, 0.0, 0.0], [0.0, 0.0, 0.0], [0.5, 0.0, 0.0]])
    d, valid = unit_directions(xyz, min_range=1.0)
    assert valid.tolist() == [True, False, False, False]
    np.testing.assert_allclose(d[0], [0.6, 0.8, 0.0])
    assert (d[1:] == 0).all()


def test_angle_jacobians_are_scaled_derivatives():
    a, e, h = 0.3, -0.2, 1e-6
    def direction(a, e):
        return np.array([[np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)]])
    J = angle_jacobians(direction(a, e), 0.5, 2.0)
    assert J.shape == (2, 1, 3)
    np.testing.assert_allclose(J[0, 0], 0.5 * (direction(a + h, e) - direction(a - h, e))[0] / (2 * h), atol=1e-8)
    np.testing.assert_allclose(J[1, 0], 2.0 * (direction(a, e + h) - direction(a, e - h))[0] / (2 * h), atol=1e-8)


def test_band_sq_batches_hypotheses():
    d = directions(np.random.default_rng(0), 20)
    J = angle_jacobians(d, 0.01, 0.02)
    hyps = np.array([[10.0, 0.0, 0.0], [0.0, 5.0, 1.0]])
    batched = band_sq(J, hyps.T, 0.1, 3.0)
    assert batched.shape == (20, 2)
    for s, v in enumerate(hyps):
        np.testing.assert_allclose(batched[:, s], band_sq(J, v, 0.1, 3.0))
    # At zero velocity only the Doppler noise is left.
    np.testing.assert_allclose(band_sq(J, np.zeros(3), 0.1, 3.0), 0.09)


def test_angular_weights_sum_to_one_per_bin():
    d = directions(np.random.default_rng(1), 200)
    w = angular_weights(d, 5.0)
    assert w.shape == (200,) and (w > 0).all() and (w <= 1).all()
    # Each occupied 5 x 5 deg azimuth-elevation bin contributes a total weight of one.
    az, el = np.degrees(np.arctan2(d[:, 1], d[:, 0])), np.degrees(np.arcsin(d[:, 2]))
    bins = {(int(np.floor(a / 5.0)), int(np.floor(e / 5.0))) for a, e in zip(az, el, strict=True)}
    assert w.sum() == pytest.approx(len(bins))
    assert (angular_weights(d, 0.0) == 1.0).all()
    assert angular_weights(np.zeros((0, 3)), 5.0).shape == (0,)


def test_inliers_of_noise_band():
    d = directions(np.random.default_rng(2), 50)
    v = np.array([10.0, 1.0, 0.0])
    J = angle_jacobians(d, 0.005, 0.017)
    v_r = -d @ v
    v_r[:5] += 5.0
    inl = inliers_of(d, J, v_r, v, RadarConfig())
    assert not inl[:5].any() and inl[5:].all()
