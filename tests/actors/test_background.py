"""Never-observed pixels (radar4dgs.actors.background) on a closed-form camera and ground plane, and the
sky map's repair behind removed actors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.actors.background import (
    TrainingView,
    background_sky,
    backproject,
    never_seen,
    repaired_sky,
    seen_in,
    sky_fit_weights,
    trusted_texels,
)

K = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
# A camera 1.5 m above the ground looking along world +x (OpenCV axes: x right, y down, z forward).
W2C = np.array([[0, -1, 0, 0], [0, 0, -1, 1.5], [1, 0, 0, 0], [0, 0, 0, 1]], dtype=float)


def ground_depth(height: int = 48, width: int = 64) -> np.ndarray:
    """(H, W) z-depth of the ground plane z = 0 seen by W2C (NaN above the horizon)."""
    rows = np.arange(height)[:, None] + np.zeros((1, width))
    slope = (rows - K[1, 2]) / K[1, 1]  # camera y / z of the ray; the ground is 1.5 m below
    return np.where(slope > 1e-6, 1.5 / np.maximum(slope, 1e-6), np.nan)


def test_backprojected_ground_pixels_lie_on_the_ground():
    depth = ground_depth()
    pixels = np.argwhere(np.isfinite(depth))
    points = backproject(depth, K, W2C, pixels)
    assert np.allclose(points[:, 2], 0.0, atol=1e-9) and (points[:, 0] > 1.5).all()


def test_a_point_is_seen_unless_outside_occluded_or_under_a_dynamic_object():
    depth = ground_depth()
    dynamic = np.zeros_like(depth)
    view = TrainingView(W2C, K, depth, dynamic)
    point = backproject(depth, K, W2C, np.array([[40, 20]]))
    assert seen_in(point, view).all()
    behind = TrainingView(W2C, K, depth * 0.5, dynamic)  # a nearer surface in front of it
    assert not seen_in(point, behind).any()
    covered = dynamic.copy()
    covered[40, 20] = 0.9  # a car over that pixel in this training frame
    assert not seen_in(point, TrainingView(W2C, K, depth, covered)).any()
    assert not seen_in(point + np.array([-10.0, 0, 0]), view).any()  # behind the camera


def test_a_surface_hidden_by_movers_in_nine_of_its_ten_frames_counts_as_never_seen():
    depth = ground_depth()
    point = backproject(depth, K, W2C, np.array([[40, 20]]))
    clear = TrainingView(W2C, K, depth, np.zeros_like(depth))
    covered = np.zeros_like(depth)
    covered[40, 20] = 0.9
    hidden = TrainingView(W2C, K, depth, covered)
    elsewhere = TrainingView(W2C, K, depth * 0.5, covered)  # a nearer static surface: not in view there
    assert never_seen(point, [hidden] * 3).all()
    assert never_seen(point, [clear] + [hidden] * 9).all()  # glimpsed once behind a followed car
    assert not never_seen(point, [clear] * 2 + [hidden] * 8).any()  # 80 % hidden: seen
    # Frames where another surface is in front count neither way.
    assert not never_seen(point, [clear] * 2 + [hidden] * 8 + [elsewhere] * 20).any()
    assert never_seen(point, [clear] * 2 + [hidden] * 8, hidden_share=0.8).all()


def test_the_default_tolerance_accepts_a_rough_static_surface_that_a_tight_one_rejects():
    # A short training's static depths are off by 10-30 %: the same surface all the same.
    depth = ground_depth()
    point = backproject(depth, K, W2C, np.array([[40, 20]]))
    rough = TrainingView(W2C, K, depth * 1.15, np.zeros_like(depth))
    assert seen_in(point, rough).all()
    assert not seen_in(point, rough, tolerance=(0.05, 0.3)).any()


def test_sky_fit_weights_split_a_texel_centre_ray_between_clean_and_dynamic_pixels():
    from radar4dgs.model.sky import SkyEnvironment

    sky = SkyEnvironment(8, 16)
    centres = sky.texel_directions().double().numpy()
    # Two pixels on texel (3, 5)'s centre (one clean, sky share 0.8; one under a car, 0.4) and one on (4, 9).
    directions = np.stack([centres[3, 5], centres[3, 5], centres[4, 9]])[None]
    clean, total = sky_fit_weights(sky, directions, np.array([[True, False, True]]), np.array([[0.8, 0.4, 1.0]]))
    texel = 3 * 16 + 5
    assert total[texel] == pytest.approx(1.2, abs=1e-6) and clean[texel] == pytest.approx(0.8, abs=1e-6)
    assert total[4 * 16 + 9] == pytest.approx(1.0, abs=1e-6)
    assert total.sum() == pytest.approx(2.2, abs=1e-6)
    trusted = trusted_texels(clean, total)
    assert trusted[texel] and trusted[4 * 16 + 9] and (trusted & (total > 1e-6)).sum() == 2  # float32 lookup
    assert not trusted_texels(clean, total, share=0.7)[texel]  # 0.8 / 1.2 of its fit was clean


@given(st.integers(0, 2**32 - 1))
@settings(max_examples=20, deadline=None)
def test_repaired_sky_gives_each_untrusted_texel_the_nearest_trusted_colour(seed):
    import torch

    from radar4dgs.model.sky import SkyEnvironment

    rng = np.random.default_rng(seed)
    sky = SkyEnvironment(6, 10)
    with torch.no_grad():
        sky.logits.copy_(torch.as_tensor(rng.normal(size=(3, 6, 10)), dtype=torch.float32))
    trusted = rng.random((6, 10)) < 0.4
    trusted[rng.integers(6), rng.integers(10)] = True
    before = sky.logits.detach().clone()
    out = repaired_sky(sky, trusted).logits.detach()
    assert torch.equal(sky.logits.detach(), before)  # the run's own map is left alone
    rows, cols = np.nonzero(trusted)
    for r in range(6):
        for c in range(10):
            if trusted[r, c]:
                assert torch.equal(out[:, r, c], before[:, r, c])
                continue
            distance = (rows - r) ** 2 + (cols - c) ** 2
            nearest = np.flatnonzero(distance == distance.min())
            assert any(torch.equal(out[:, r, c], before[:, rows[k], cols[k]]) for k in nearest)


def test_background_sky_keeps_the_trained_sky_where_the_sky_was_seen_clear(oracle, one_torch_thread):
    import torch

    from radar4dgs.io.scene import normalized_times
    from radar4dgs.model.sky import camera_ray_directions
    from radar4dgs.model.view import frame_view

    run = oracle.run
    before = run.model.sky.logits.detach().clone()
    repaired = background_sky(run)
    assert torch.equal(run.model.sky.logits.detach(), before)
    view = frame_view(run.scene, run.scene.train_indices[0], 1.0, normalized_times(run.scene))
    with torch.no_grad():
        full = run.model.render(view, run.config.raster)
        directions = camera_ray_directions(view.K, view.world_to_camera, view.height, view.width)
        clear = ((full["alpha"] < 0.05) & (full["dynamic"] < 0.01)).numpy()
        assert clear.sum() > 100  # the tiny scene shows sky
        change = (repaired(directions) - run.model.sky(directions)).abs().max(-1).values.numpy()
    assert np.quantile(change[clear], 0.99) < 1e-6


def test_fill_never_observed_restores_a_smooth_image_and_leaves_other_pixels_alone():
    from radar4dgs.actors.background import fill_never_observed

    cols = np.arange(64, dtype=np.float64)
    ramp = np.repeat(np.stack([40 + 2 * cols, 90 + cols, np.full(64, 200.0)], -1)[None], 48, axis=0)
    truth = ramp.round().astype(np.uint8)
    never = np.zeros((48, 64), dtype=bool)
    never[20:28, 30:38] = True  # an 8 x 8 hole in a horizontal ramp
    damaged = truth.copy()
    damaged[never] = 0
    filled = fill_never_observed(damaged, never)
    assert np.array_equal(filled[~never], truth[~never])
    assert np.abs(filled[never].astype(int) - truth[never].astype(int)).max() <= 4  # the ramp spans 14 levels there
    assert fill_never_observed(damaged, np.zeros_like(never)) is damaged
