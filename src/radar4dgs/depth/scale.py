"""Metric scale recovery of a relative depth map from static radar points.

Every prior is handled as a relative inverse depth ``x`` (H, W): larger = closer, ``x <= 0`` or
non-finite = far / no depth. Both methods produce the same per-frame model

    1 / z = a * x + b            (z: metric z-depth along the optical axis)

from the radar-pixel pairs of :func:`~radar4dgs.depth.pairs.match_radar`:

* ``paper`` (4DRadar-GS): plane votes and histogram voting for a single scale, ``b = 0``
  (:mod:`radar4dgs.depth.paper_scale`).
* ``affine``: robust fit of ``a`` and ``b`` (2-point RANSAC, then Huber IRLS) on the relative
  depth residual (:mod:`radar4dgs.depth.inverse_affine`).

:func:`recover_scale` runs one frame; :mod:`radar4dgs.depth.temporal` treats the fits across
frames and :mod:`radar4dgs.depth.depth_maps` makes the metric depth from them.
"""

from __future__ import annotations

import numpy as np

from radar4dgs.depth.config import DepthConfig
from radar4dgs.depth.geometry import DirectionIndex
from radar4dgs.depth.inverse_affine import affine_fit
from radar4dgs.depth.pairs import FrameFit, match_radar
from radar4dgs.depth.paper_scale import paper_fit


def recover_scale(x: np.ndarray, points_cam: np.ndarray, K: np.ndarray, config: DepthConfig, method: str,
                  static: np.ndarray | None = None, sky: np.ndarray | None = None,
                  index: DirectionIndex | None = None, rng: np.random.Generator | None = None) -> FrameFit:
    """Scale recovery of one frame.

    Args:
        x: (H, W) relative inverse depth (for a depth-up-to-scale map pass ``1 / depth``).
        points_cam: (N, 3) radar points in the camera frame.
        K: (3, 3) intrinsics.
        config: thresholds.
        method: "paper" or "affine".
        static: (N,) bool static-point mask (None: all static).
        sky: (H, W) bool sky mask (None: none).
        index: the camera's :class:`DirectionIndex` (built here when None; pass one per scene).
        rng: random generator for RANSAC (default: ``config.seed``).
    """
    height, width = x.shape
    if index is None or not index.matches(K, width, height, config.visual_stride):
        index = DirectionIndex(K, width, height, config.visual_stride)
    pairs = match_radar(x, points_cam, K, index, config, static, sky)
    if method == "paper":
        return paper_fit(x, pairs, index, config)
    if method == "affine":
        return affine_fit(pairs, config, rng if rng is not None else np.random.default_rng(config.seed))
    raise ValueError(f"unknown scale method {method!r}; choose 'paper' or 'affine'")
