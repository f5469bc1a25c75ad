"""Stage 4: the radar–camera dynamic segmentation model (4DRadar-GS).

Dynamic radar points are sampled as anchors; a square patch around each goes through a truncated
ResNet, the radar points in the patch are mean-pooled into one token, LoFTR-style linear
self/cross-attention fuses the two, a U-Net decoder outputs a per-patch probability, and patches
are pasted into a frame-wide map by per-pixel maximum and thresholded.

Public entry points::

    from radar4dgs.segment import prepare_masks, segmentation_frontend_metrics
    prepare_masks(scene, prepared_dir, SegInferConfig())      # <prepared>/masks/<frame>.png
    segmentation_frontend_metrics(scene, prepared_dir)       # mask_iou, static_vehicle_fp

Training: ``radar4dgs seg-train`` (:class:`radar4dgs.apps.seg_train.SegTrainCommand`).
"""

from __future__ import annotations

import importlib
from typing import Any

from radar4dgs.segment.config import SegInferConfig, SegModelConfig, SegTrainConfig

_LAZY = {"BaselineConfig": "baseline", "baseline_frame": "baseline", "load_model": "infer", "prepare_masks": "infer",
         "segment_frame": "infer", "segmentation_frontend_metrics": "metrics", "RadarCameraSegNet": "model",
         "train_segmentation": "train"}

__all__ = ["SegInferConfig", "SegModelConfig", "SegTrainConfig", *_LAZY]


def __getattr__(name: str) -> Any:
    # Lazy, so that the configurations (and the CLI built from them) load without torch.
    if name in _LAZY:
        return getattr(importlib.import_module(f"radar4dgs.segment.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
