import numpy as np
from _radar_helpers import directions

from radar4dgs.radar import RadarConfig
from radar4dgs.radar.doppler import angle_jacobians
from radar4dgs.radar.least_squares import covariance, least_squares, min_inlier_singular, normal_equations
from radar4dgs.radar.velocity_model import planar_basis


def _scan(seed, n=200, noise=0.0):
    rng = np.random.default_rng(seed)
    d = directions(rng, n)
    v = np.array([12.0, -0.4, 0.2])
    return d, angle_jacobians(d, 0.005, 0.017), -d @ v + rng.normal(0, noise, n) if noise else -d @ v, v


def test_normal_equations_plain_and_with_prior():
    d, _, v_r, v = _scan(0)
    w = np.full(len(d), 2.0)
    H, g = normal_equations(-d, v_r, w, None)
    np.testing.assert_allclose(H, 2.0 * d.T @ d)
    np.testing.assert_allclose(np.linalg.solve(H, g), v, atol=1e-9)
    axis = np.array([0.0, 0.0, 1.0])
    Hp, _ = normal_equations(-d, v_r, w, (axis, 0.1))
    np.testing.assert_allclose(Hp - H, np.outer(axis, axis) / 0.01)


def test_least_squares_recovers_noise_free_velocity():
    d, J, v_r, v = _scan(1)
    v_r[:20] += 10.0                                 # outliers
    u, inl = least_squares(d, J, v_r, v + 0.05, RadarConfig())
    np.testing.assert_allclose(u, v, atol=1e-9)
    assert not inl[:20].any() and inl[20:].all()


def test_covariance_is_symmetric_and_honest_in_2d():
    d, J, v_r, v = _scan(2, noise=0.05)
    config = RadarConfig()
    inl = np.ones(len(d), dtype=bool)
    assert min_inlier_singular(d, inl) > config.min_conditioning
    cov, residual_std = covariance(d, J, v_r, inl, v, np.eye(3), config, None)
    assert cov.shape == (3, 3)
    np.testing.assert_allclose(cov, cov.T)
    assert (np.linalg.eigvalsh(cov) > 0).all() and 0.02 < residual_std < 0.1
    B = planar_basis(None)
    cov2, _ = covariance(d @ B, J @ B, v_r, inl, v[:2], B, config, None)
    # The planar model reports the assumed vertical std, not a measured one.
    assert cov2[2, 2] == config.vertical_std_2d ** 2 and (cov2[2, :2] == 0).all()
