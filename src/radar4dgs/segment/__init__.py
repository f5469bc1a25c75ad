"""Stage 4: the radar–camera dynamic segmentation model (4DRadar-GS).

Dynamic radar points are sampled as anchors; a square patch around each goes through a truncated
ResNet, the radar points in the patch are mean-pooled into one token, LoFTR-style linear
self/cross-attention fuses the two, a U-Net decoder outputs a per-patch probability, and patches
are pasted into a frame-wide map by per-pixel maximum and thresholded.

Public entry points::

    from radar4dgs.segment import prepare_masks, segmentation_frontend_metrics
    prepare_masks(scene, prepared_dir, SegInferConfig())      # <prepared>/masks/<frame>.png
    segmentation_frontend_metrics(scene, prepared_dir)       # mask_iou, static_vehicle_fp

Training: ``radar4dgs seg-train`` (:class:`radar4dgs.segment.command.SegTrainCommand`).
"""

from radar4dgs.segment.baseline import BaselineConfig, baseline_frame
from radar4dgs.segment.infer import SegInferConfig, load_model, prepare_masks, segment_frame
from radar4dgs.segment.metrics import segmentation_frontend_metrics
from radar4dgs.segment.model import RadarCameraSegNet, SegModelConfig
from radar4dgs.segment.train import SegTrainConfig, train_segmentation

__all__ = ["BaselineConfig", "baseline_frame", "SegInferConfig", "load_model", "prepare_masks", "segment_frame",
           "segmentation_frontend_metrics", "RadarCameraSegNet", "SegModelConfig", "SegTrainConfig",
           "train_segmentation"]
