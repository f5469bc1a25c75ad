"""Validity checks of the radar-pixel pairs (dynamic, out-of-range and depth-edge points), seen
through the scale recovery."""

from __future__ import annotations

import numpy as np
import pytest
from _depth_helpers import K, points_on_plane, tilted_plane_depth

from radar4dgs.depth import DepthConfig, recover_scale
from radar4dgs.depth.geometry import DirectionIndex
from radar4dgs.depth.pairs import DYNAMIC, VALID

NORMAL, OFFSET = (0.2, 0.5, 1.0), 10.0


@pytest.fixture(scope="module")
def index():
    return DirectionIndex(K, 160, 90)


def test_dynamic_and_out_of_range_points_are_not_used(index):
    rng = np.random.default_rng(5)
    depth = tilted_plane_depth(NORMAL, OFFSET)
    points = points_on_plane(NORMAL, OFFSET, 50, rng)
    points[:5] *= 1.7  # moving: off the surface
    static = np.ones(50, bool)
    static[:5] = False
    behind = np.array([[0.0, 0.0, -5.0], [50.0, 0.0, 5.0]])  # behind the camera, outside the image
    fit = recover_scale(1 / depth, np.concatenate([points, behind]), K, DepthConfig(), "affine",
                        static=np.concatenate([static, [True, True]]), index=index)
    assert (fit.pairs.reason[:5] == DYNAMIC).all()
    assert (fit.pairs.reason[-2:] != VALID).all()
    assert fit.a == pytest.approx(1.0, rel=1e-6) and abs(fit.b) < 1e-6


def test_depth_edges_are_rejected(index):
    depth = np.full((90, 160), 10.0)
    depth[:, 80:] = 30.0
    v = np.arange(10, 80, 2, dtype=float)
    on_edge = np.stack([(79.5 - K[0, 2]) / K[0, 0] * np.ones_like(v), (v - K[1, 2]) / K[1, 1], np.ones_like(v)], 1) * 10
    fit = recover_scale(1 / depth, on_edge, K, DepthConfig(), "paper", index=index)
    assert fit.num_valid == 0 and not fit.ok
