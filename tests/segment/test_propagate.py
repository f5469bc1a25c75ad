"""Carrying small mask components to neighbouring frames, on a textured blob moving over texture."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.segment.config import PropagationConfig
from radar4dgs.segment.propagate import propagate_masks, scaled_pixels

HEIGHT, WIDTH, FRAMES = 90, 160, 7


def moving_blob(velocity: tuple[int, int], start: tuple[int, int] = (40, 60), size: int = 6, seed: int = 0):
    """Frames (T, H, W, 3) uint8 of a bright textured square moving ``velocity`` (rows, cols) px a
    frame over a darker textured background, and its true masks (T, H, W) bool."""
    rng = np.random.default_rng(seed)
    pad = 4 * size  # the blob may leave the image: draw on a larger canvas, then crop
    background = rng.integers(20, 110, (HEIGHT + 2 * pad, WIDTH + 2 * pad), dtype=np.uint8)
    texture = rng.integers(150, 255, (size, size), dtype=np.uint8)
    images, truth = [], []
    for t in range(FRAMES):
        gray, mask = background.copy(), np.zeros(background.shape, bool)
        row, col = pad + start[0] + velocity[0] * t, pad + start[1] + velocity[1] * t
        gray[row:row + size, col:col + size] = texture
        mask[row:row + size, col:col + size] = True
        images.append(np.repeat(gray[pad:-pad, pad:-pad, None], 3, axis=2))
        truth.append(mask[pad:-pad, pad:-pad])
    return images, truth


def only_frame(truth: list[np.ndarray], frame: int) -> list[np.ndarray]:
    return [mask if t == frame else np.zeros_like(mask) for t, mask in enumerate(truth)]


def centre_point(mask: np.ndarray) -> np.ndarray:
    rows, cols = np.nonzero(mask)
    return np.array([[cols.mean(), rows.mean()]])


CONFIG = PropagationConfig(enabled=True, frames=5, min_pixels=4, max_pixels=400, search_px=6)


@settings(max_examples=20, deadline=None)
@given(st.integers(-3, 3), st.integers(-3, 3))  # the window: 6 px at 320 px width, 3 here
def test_a_blob_seen_in_one_frame_is_found_in_its_neighbours(dv, du):
    images, truth = moving_blob((dv, du))
    points = [centre_point(truth[3]) if t == 3 else np.zeros((0, 2)) for t in range(FRAMES)]
    carried = propagate_masks(images, only_frame(truth, 3), points, CONFIG)
    for t in range(FRAMES):  # within 5 frames both ways of frame 3: all of them, pixel for pixel
        assert (carried[t] == truth[t]).all(), t


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="search_px > 0"):
        PropagationConfig(search_px=0)
    with pytest.raises(ValueError, match="min_pixels <= max_pixels, got 500, 400"):
        PropagationConfig(min_pixels=500)


def test_no_radar_point_no_carrying_and_large_components_stay():
    images, truth = moving_blob((0, 2))
    nothing = [np.zeros((0, 2)) for _ in range(FRAMES)]
    assert not any(m.any() for t, m in enumerate(propagate_masks(images, only_frame(truth, 3), nothing, CONFIG))
                   if t != 3)
    points = [centre_point(truth[3]) if t == 3 else np.zeros((0, 2)) for t in range(FRAMES)]
    small = PropagationConfig(enabled=True, frames=5, min_pixels=4, max_pixels=20)
    carried = propagate_masks(images, only_frame(truth, 3), points, small)  # 36 px > 20 * (160/320)^2
    assert sum(int(m.sum()) for m in carried) == int(truth[3].sum())
    assert scaled_pixels(400, 640) == 1600


def test_tracks_stop_at_the_frame_limit_the_border_and_existing_masks():
    images, truth = moving_blob((0, 3), start=(40, 142))  # its search window leaves the image in frame 4
    points = [centre_point(truth[0]) if t == 0 else np.zeros((0, 2)) for t in range(FRAMES)]
    two = PropagationConfig(enabled=True, frames=2, min_pixels=4, max_pixels=400, search_px=6)
    carried = propagate_masks(images, only_frame(truth, 0), points, two)
    assert [bool(m.any()) for m in carried] == [True, True, True, False, False, False, False]
    carried = propagate_masks(images, only_frame(truth, 0), points, CONFIG)
    assert [bool(m.any()) for m in carried] == [True, True, True, True, False, False, False]
    assert all((carried[t] == truth[t]).all() for t in range(4))
    marked = only_frame(truth, 0)
    marked[2] = truth[2]  # the network marked it in frame 2 (without a radar point): the track stops there
    carried = propagate_masks(images, marked, points, CONFIG)
    assert [bool(m.any()) for m in carried] == [True, True, True, False, False, False, False]


@pytest.mark.parametrize("velocity", [(0, 2)])
def test_a_blob_on_uniform_ground_is_not_carried_where_any_place_matches(velocity):
    images, truth = moving_blob(velocity)
    flat = [np.full_like(image, 60) for image in images]  # the blob gone: nothing distinct to find
    flat[3] = images[3]
    points = [centre_point(truth[3]) if t == 3 else np.zeros((0, 2)) for t in range(FRAMES)]
    carried = propagate_masks(flat, only_frame(truth, 3), points, CONFIG)
    assert [bool(m.any()) for m in carried] == [False, False, False, True, False, False, False]


def test_prepare_masks_writes_the_carried_pixels_beside_the_networks(tiny_trained_run, tmp_path):
    import shutil

    from radar4dgs.config import preset
    from radar4dgs.io.scene import read_mask_png, read_scene
    from radar4dgs.segment.config import SegInferConfig
    from radar4dgs.segment.infer import prepare_masks
    from radar4dgs.train.fit_motion import torch_threads

    scene = read_scene(tiny_trained_run / "scene")
    prepared = tmp_path / "prepared"
    for stage in ("radar", "depth"):
        shutil.copytree(tiny_trained_run / "scene" / "prepared" / stage, prepared / stage)
    config = preset(SegInferConfig, "tiny")
    with torch_threads(1):
        plain = prepare_masks(scene, prepared, config, out_dir=tmp_path / "plain")
        config.propagation = PropagationConfig(enabled=True, min_pixels=1, max_pixels=10**6)
        summary = prepare_masks(scene, prepared, config)
    assert plain["propagation"] == "off" and summary["propagation"] != "off"
    added = 0
    for frame, record in zip(scene.frames, summary["frames"], strict=True):
        before = read_mask_png(tmp_path / "plain" / f"{frame.name}.png")
        after = read_mask_png(prepared / "masks" / f"{frame.name}.png")
        assert (after | before).sum() == after.sum()  # the network's pixels are all kept
        assert int((after & ~before).sum()) == record["propagated_pixels"]
        assert record["dynamic_pixels"] == int(after.sum())
        prob = np.load(prepared / "masks" / f"{frame.name}_prob.npy")
        assert ((prob > config.threshold) == after).all()
        added += record["propagated_pixels"]
    assert added > 0
