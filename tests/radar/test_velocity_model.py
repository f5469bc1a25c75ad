import numpy as np
from _radar_helpers import directions

from radar4dgs.radar import RadarConfig
from radar4dgs.radar.velocity_model import choose_dof, planar_basis, vz_observable


def test_planar_basis_default_is_radar_xy():
    np.testing.assert_array_equal(planar_basis(None), np.eye(3)[:, :2])


def test_planar_basis_is_orthonormal_and_orthogonal_to_vertical():
    vertical = np.array([-0.1, 0.05, 1.0])
    B = planar_basis(vertical)
    assert B.shape == (3, 2)
    np.testing.assert_allclose(B.T @ B, np.eye(2), atol=1e-12)
    np.testing.assert_allclose(vertical @ B, 0.0, atol=1e-12)
    # The first axis stays as close as possible to the radar's x axis.
    assert B[0, 0] > 0.99


def test_vz_observable_and_choose_dof():
    rng = np.random.default_rng(0)
    flat = directions(rng, 100, el=0.001)
    spread = directions(rng, 100, el=0.3)
    config = RadarConfig()
    assert not vz_observable(flat, config) and vz_observable(spread, config)
    assert not vz_observable(spread[:2], config)
    assert choose_dof(flat, config) == 2 and choose_dof(spread, config) == 3
    assert choose_dof(flat, RadarConfig(model="3d")) == 3
    assert choose_dof(spread, RadarConfig(model="2d")) == 2
