"""Stage 3: scale-correct monocular depth and sky masks.

A depth source (``priors/mono_depth``, Depth-Anything-V2 through ``transformers``, the weight-free
flat-world ground plane when neither is available, or the ``gt/depth`` oracle for ablations) gives
a relative inverse depth per frame; static radar points
make it metric, per frame, with the paper's single-scale plane voting (``paper``) or a robust
scale-and-shift fit in inverse depth (``affine``, the default for relative priors); frames with
too few radar pairs take their neighbours' parameters. Sky masks come from ``priors/sky_mask`` or a
weight-free detector. :func:`prepare_depth` writes the results into the prepared folder and
:func:`depth_frontend_metrics` scores them.

Importing this package does not import scipy or torch: the names below load their module on
first use, so that ``radar4dgs prepare --help`` answers at once.
"""

from __future__ import annotations

import importlib
from typing import Any

from radar4dgs.depth.config import DepthConfig

_LAZY = {
    "metric_depth": "depth_maps", "FlatWorldDepth": "flat_world",
    "flat_world_depth": "flat_world", "fit_inverse_affine": "inverse_affine", "depth_frontend_metrics": "metrics",
    "frame_depth_errors": "metrics", "score_frames": "metrics", "DepthWarning": "pairs", "FrameFit": "pairs",
    "histogram_vote": "paper_scale", "plane_votes": "paper_scale", "evaluate_depth_methods": "pipeline",
    "prepare_depth": "pipeline", "static_mask": "pipeline", "write_depth": "pipeline", "recover_scale": "scale",
    "fallback_sky_mask": "sky", "mask_iou": "sky", "DepthAnythingV2": "sources", "DepthModelError": "sources",
    "build_depth_model": "sources", "depth_anything_available": "sources", "load_depth_anything": "sources",
    "FrameParameters": "temporal", "fill_from_neighbours": "temporal", "limit_metric_correction": "temporal",
}

__all__ = ["DepthConfig", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(f"radar4dgs.depth.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
