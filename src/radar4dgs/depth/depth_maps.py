"""Per-frame metric depth maps and their per-pixel confidence, from the frame parameters.

:func:`metric_depth` turns a relative inverse depth into metric z-depth with a frame's
``1 / z = a * x + b``; :func:`frame_confidences` rates each frame's parameters (own fit or
neighbour fallback) and :func:`confidence_map` spreads that rating over the pixels.
"""

from __future__ import annotations

import math

import numpy as np

from radar4dgs.depth.config import DepthConfig
from radar4dgs.depth.pairs import FrameFit
from radar4dgs.depth.temporal import FrameParameters


def metric_depth(x: np.ndarray, a: float, b: float, min_depth: float, max_depth: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Metric z-depth ``z = 1 / (a x + b)`` of (H, W) relative inverse depth ``x``.

    Returns:
        depth (H, W) float32 clamped to [min_depth, max_depth], and valid (H, W) bool: False where
        ``x`` is not finite or ``a x + b`` falls below ``1 / max_depth`` (beyond range or
        non-positive: the far end of the prior); such pixels get ``max_depth``.
    """
    with np.errstate(invalid="ignore", over="ignore"):
        inverse = a * x.astype(np.float64) + b
        valid = np.isfinite(inverse) & (inverse >= 1.0 / max_depth)
        depth = np.where(valid, 1.0 / np.where(valid, inverse, 1.0), max_depth)
    return np.clip(depth, min_depth, max_depth).astype(np.float32), valid


def confidence_map(depth: np.ndarray, valid: np.ndarray, x: np.ndarray, frame_confidence: float,
                   x_range: tuple[float, float], edge_scale: float) -> np.ndarray:
    """Per-pixel confidence in [0, 1] (H, W) float32.

    The product of: the frame's confidence (inlier count, fallback); an edge term
    ``exp(-g / edge_scale)`` with ``g`` the largest |log z| step to a 4-neighbour (pixels on depth
    discontinuities mix two surfaces); a range term ``exp(-|log(x / clip(x, x_lo, x_hi))|)`` that
    decays outside the inverse-depth span the radar inliers covered (extrapolation). Zero where
    ``valid`` is False.
    """
    log_z = np.log(np.maximum(depth.astype(np.float64), 1e-6))
    step = np.zeros_like(log_z)
    dv = np.abs(np.diff(log_z, axis=0))
    du = np.abs(np.diff(log_z, axis=1))
    step[1:] = np.maximum(step[1:], dv)
    step[:-1] = np.maximum(step[:-1], dv)
    step[:, 1:] = np.maximum(step[:, 1:], du)
    step[:, :-1] = np.maximum(step[:, :-1], du)
    conf = frame_confidence * np.exp(-step / edge_scale)
    lo, hi = x_range
    if math.isfinite(lo) and math.isfinite(hi) and lo > 0:
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.abs(np.log(x / np.clip(x, lo, hi)))
        conf = conf * np.exp(-np.nan_to_num(ratio, nan=np.inf))
    conf = np.where(valid, conf, 0.0)
    return np.clip(conf, 0.0, 1.0).astype(np.float32)


def frame_confidences(fits: list[FrameFit], parameters: list[FrameParameters], config: DepthConfig
                      ) -> list[tuple[float, tuple[float, float]]]:
    """Per frame: (confidence, inverse-depth span) for :func:`confidence_map`.

    An own fit with n inliers has confidence n / (n + min_pairs) and its inliers' x span; a frame
    filled from neighbours gets ``config.fallback_confidence`` times the mean of its sources'
    confidences and the union of their spans; an unscaled metric prior gets
    ``config.fallback_confidence`` and no span.
    """
    own = [(f.num_inliers / (f.num_inliers + config.min_pairs), f.x_range) if f.ok else (0.0, (math.nan, math.nan))
           for f in fits]
    out = []
    for i, p in enumerate(parameters):
        if p.source == "fit":
            out.append(own[i])
            continue
        if p.source == "metric prior":
            out.append((config.fallback_confidence, (math.nan, math.nan)))
            continue
        sources = [own[s] for s in p.from_frames] or [(0.0, (math.nan, math.nan))]
        conf = config.fallback_confidence * float(np.mean([c for c, _ in sources]))
        lo = min((r[0] for _, r in sources if math.isfinite(r[0])), default=math.nan)
        hi = max((r[1] for _, r in sources if math.isfinite(r[1])), default=math.nan)
        out.append((conf, (lo, hi)))
    return out
