"""Stage 3: scale-correct monocular depth and sky masks.

A depth source (``priors/mono_depth``, Depth-Anything-V2 through ``transformers``, the weight-free
flat-world ground plane when neither is available, or the ``gt/depth`` oracle for ablations) gives
a relative inverse depth per frame; static radar points
make it metric, per frame, with the paper's single-scale plane voting (``paper``) or a robust
scale-and-shift fit in inverse depth (``affine``, the default for relative priors); frames with
too few radar pairs take their neighbours' parameters. Sky masks come from ``priors/sky_mask`` or a
weight-free detector. :func:`prepare_depth` writes the results into the prepared folder and
:func:`depth_frontend_metrics` scores them.
"""

from radar4dgs.depth.config import DepthConfig
from radar4dgs.depth.depth_maps import metric_depth
from radar4dgs.depth.flat_world import FlatWorldDepth, flat_world_depth
from radar4dgs.depth.inverse_affine import fit_inverse_affine
from radar4dgs.depth.metrics import depth_frontend_metrics, frame_depth_errors, score_frames
from radar4dgs.depth.pairs import DepthWarning, FrameFit
from radar4dgs.depth.paper_scale import histogram_vote, plane_votes
from radar4dgs.depth.pipeline import evaluate_depth_methods, prepare_depth, static_mask, write_depth
from radar4dgs.depth.scale import recover_scale
from radar4dgs.depth.sky import fallback_sky_mask, mask_iou
from radar4dgs.depth.sources import (
                                     DepthAnythingV2,
                                     DepthModelError,
                                     build_depth_model,
                                     depth_anything_available,
                                     load_depth_anything,
)
from radar4dgs.depth.temporal import FrameParameters, fill_from_neighbours, limit_metric_correction

__all__ = [
    "DepthAnythingV2", "DepthConfig", "DepthModelError", "DepthWarning", "FlatWorldDepth", "FrameFit",
    "FrameParameters", "build_depth_model", "depth_anything_available", "depth_frontend_metrics",
    "evaluate_depth_methods", "fallback_sky_mask", "fill_from_neighbours", "fit_inverse_affine", "flat_world_depth",
    "frame_depth_errors", "histogram_vote", "limit_metric_correction", "load_depth_anything", "mask_iou",
    "metric_depth", "plane_votes", "prepare_depth", "recover_scale", "score_frames", "static_mask", "write_depth",
]
