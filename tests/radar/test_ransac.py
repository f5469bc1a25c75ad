import numpy as np
from _radar_helpers import directions

from radar4dgs.radar import RadarConfig
from radar4dgs.radar.doppler import angle_jacobians, angular_weights
from radar4dgs.radar.ransac import _needed_iterations, _solve_minimal, ransac


def test_needed_iterations():
    assert _needed_iterations(0.0, 3, 0.999, 1000) == 1000
    assert _needed_iterations(1.0, 3, 0.999, 1000) == 1
    # log(0.001) / log(1 - 0.5^3) = 51.7 -> 52
    assert _needed_iterations(0.5, 3, 0.999, 1000) == 52
    assert _needed_iterations(0.1, 3, 0.999, 1000) == 1000


def test_solve_minimal_drops_singular_samples():
    d = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [0.6, 0.8, 0]])
    v = np.array([5.0, -1.0, 0.5])
    v_r = -d @ v
    # The second sample repeats a point, the third spans only the x-y plane.
    hyps = _solve_minimal(d, v_r, np.array([[0, 1, 2], [0, 0, 2], [0, 1, 3], [3, 1, 2]]), 0.02)
    assert hyps.shape == (2, 3)
    np.testing.assert_allclose(hyps, [v, v], atol=1e-12)
    assert _solve_minimal(d, v_r, np.array([[1, 1, 1]]), 0.02).shape == (0, 3)


def _problem(seed):
    rng = np.random.default_rng(seed)
    d = directions(rng, 300)
    v = np.array([12.0, -0.4, 0.2])
    v_r = -d @ v + rng.normal(0, 0.02, 300)
    v_r[:90] = rng.uniform(-20, 20, 90)           # 30 % outliers
    J = angle_jacobians(d, 0.005, 0.017)
    M = np.ascontiguousarray(np.concatenate([d, J[0], J[1]]))
    return d, M, v_r, angular_weights(d, 5.0), v


def test_ransac_finds_the_static_world_deterministically():
    config = RadarConfig()
    d, M, v_r, w, v = _problem(1)
    best, iterations, conditioned = ransac(d, M, v_r, w, np.zeros((1, 3)), np.random.default_rng(3), config)
    assert np.linalg.norm(best - v) < 0.3
    assert 0 < conditioned <= iterations <= config.max_iterations
    again = ransac(d, M, v_r, w, np.zeros((1, 3)), np.random.default_rng(3), config)
    np.testing.assert_array_equal(again[0], best)
    assert again[1:] == (iterations, conditioned)


def test_ransac_perfect_fixed_hypothesis_needs_one_batch():
    config = RadarConfig()
    d, M, _, w, v = _problem(2)
    v_r = -d @ v                                    # noise-free, no outliers
    best, iterations, _ = ransac(d, M, v_r, w, v[None], np.random.default_rng(0), config)
    # Every point agrees with it: one batch is drawn, and no sample beats it (ties keep it).
    np.testing.assert_array_equal(best, v)
    assert iterations == config.batch_size
