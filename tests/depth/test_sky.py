"""The weight-free sky fallback on synthetic images."""

from __future__ import annotations

import numpy as np

from radar4dgs.depth import fallback_sky_mask, mask_iou
from radar4dgs.depth.sky import far_candidates, top_connected


def _street(rng, blue_patch=False):
    """(90, 160) image: blue sky (gradient) above a jagged skyline, grey buildings and road below;
    relative inverse depth: 0.2 on sky, 1-8 below."""
    height, width = 90, 160
    skyline = (30 + 8 * np.sin(np.arange(width) / 9.0)).astype(int)
    rows = np.arange(height)[:, None]
    sky = rows < skyline[None, :]
    image = np.empty((height, width, 3), np.float64)
    image[:] = (110, 108, 104)
    t = rows / height
    sky_rgb = np.stack(np.broadcast_arrays(80 + 80 * t, 140 + 60 * t, np.full_like(t, 235.0)), -1)
    image[sky] = np.broadcast_to(sky_rgb, (height, width, 3))[sky]
    x = np.where(sky, 0.2, 1.0 + 7.0 * rows / height).astype(np.float64)
    if blue_patch:  # a sky-coloured, far-looking window well inside a facade: not sky
        image[55:65, 60:80] = (100, 170, 235)
        x[55:65, 60:80] = 0.2
    image += rng.normal(0, 2, image.shape)
    return np.clip(image, 0, 255).astype(np.uint8), x, sky


def test_fallback_finds_a_blue_sky():
    rng = np.random.default_rng(0)
    image, x, sky = _street(rng)
    mask = fallback_sky_mask(image, x)
    assert mask_iou(mask, sky) > 0.97


def test_fallback_ignores_sky_coloured_regions_not_connected_to_the_top():
    rng = np.random.default_rng(1)
    image, x, sky = _street(rng, blue_patch=True)
    mask = fallback_sky_mask(image, x)
    assert not mask[55:65, 60:80].any()
    assert mask_iou(mask, sky) > 0.97


def test_fallback_needs_far_pixels_in_the_top_rows():
    rng = np.random.default_rng(2)
    image, x, _ = _street(rng)
    # The far end of this prior is at the bottom of the image (a ceiling-like layout): no seeds.
    far_at_bottom = np.linspace(6.0, 1.0, 90)[:, None].repeat(160, 1)
    assert not fallback_sky_mask(image, far_at_bottom).any()


def test_metric_depth_veto_keeps_a_near_far_end():
    # A frame with no sky: the far end of the prior is a wall 20 m away, so nothing is sky.
    x = np.linspace(1, 5, 90)[:, None].repeat(160, 1)
    depth = 20.0 / x
    far = far_candidates(x, 0.04, depth, np.ones_like(x, bool), min_depth=40.0)
    assert not far.any()
    assert far_candidates(x, 0.04).any()


def test_top_connected_and_iou():
    mask = np.zeros((5, 5), bool)
    mask[0, 0] = mask[1, 1] = True  # diagonal: 8-connected to the top
    mask[4, 4] = True
    kept = top_connected(mask)
    assert kept[1, 1] and not kept[4, 4]
    assert mask_iou(np.zeros((2, 2), bool), np.zeros((2, 2), bool)) == 1.0
    assert mask_iou(mask, kept) == 2 / 3
