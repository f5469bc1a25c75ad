"""Depth front-end metrics against the scene's ground truth (evaluation only).

Definitions (each frame scored alone, then averaged over frames, as the KITTI depth benchmark):

* pixels scored: ``gt/depth`` finite and > 0 (not sky in the ground truth) where the prediction is
  finite (not declared sky); ``depth_coverage`` is the scored fraction of the gt non-sky pixels,
  so a method cannot hide errors by calling them sky.
* ``depth_absrel`` = mean |z - z_gt| / z_gt; ``depth_rmse`` = sqrt(mean (z - z_gt)^2) (m);
  ``depth_delta1`` = fraction with max(z / z_gt, z_gt / z) < 1.25.
* ``scale_error_median``: when every frame's relative prior ``x`` is a pure scaling of the
  ground truth's inverse depth, ``x = s / z_gt`` (median |log(x z_gt) - log s| below
  ``PURE_SCALE_TOLERANCE``, with ``s = median(x z_gt)``), the median over frames of
  |s_hat / s - 1| with ``s_hat = 1 / scale`` the recovered depth scale; otherwise None. Needs the
  relative prior (``<prepared>/depth/relative``, kept by default).
* ``depth_ratio_jitter``: RMS over consecutive frames of the change of median(z / z_gt) over the
  scored pixels with z_gt < ``JITTER_MAX_DEPTH`` (frame-to-frame scale jitter: scene flow lifted
  with two frames' depths turns it into motion along the ray); ``depth_ratio_jitter_dynamic`` the
  same over ``gt/dynamic_mask`` pixels (frames with fewer than 20 such pixels skipped; None without
  the mask).
* ``sky_iou``: mean over frames of IoU(sky, gt/sky_mask) (a frame where both are empty counts 1).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from radar4dgs.depth.sky import mask_iou
from radar4dgs.io.scene import read_mask_png

# A frame counts as "pure scale" when its log depth ratios spread less than this (0.2 %).
PURE_SCALE_TOLERANCE = 2e-3
# Depth jitter is measured on pixels nearer than this (m).
JITTER_MAX_DEPTH = 60.0


def _median_ratio(prediction: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None) -> float:
    scored = np.isfinite(truth) & (truth > 0) & (truth < JITTER_MAX_DEPTH) & np.isfinite(prediction) & (prediction > 0)
    if mask is not None:
        scored &= mask
    return float(np.median(prediction[scored] / truth[scored])) if scored.sum() >= 20 else float("nan")


def ratio_jitter(ratios: Sequence[float]) -> float | None:
    """RMS of the change of per-frame ratios between consecutive frames (NaN frames skipped)."""
    steps = np.diff(np.asarray(ratios, dtype=np.float64))
    steps = steps[np.isfinite(steps)]
    return float(np.sqrt(np.mean(steps ** 2))) if len(steps) else None


def frame_depth_errors(prediction: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Errors of one (H, W) depth map against (H, W) ground truth (see the module docstring).

    Returns absrel, rmse, delta1, coverage, log_ratio_median, log_ratio_spread (NaN when no pixel
    is scored).
    """
    reference = np.isfinite(truth) & (truth > 0)
    scored = reference & np.isfinite(prediction) & (prediction > 0)
    total = int(reference.sum())
    out = {"coverage": float(scored.sum() / total) if total else float("nan")}
    if not scored.any():
        return {**out, "absrel": np.nan, "rmse": np.nan, "delta1": np.nan, "log_ratio_median": np.nan,
                "log_ratio_spread": np.nan}
    z, g = prediction[scored].astype(np.float64), truth[scored].astype(np.float64)
    log_ratio = np.log(z / g)
    median = float(np.median(log_ratio))
    return {**out,
            "absrel": float(np.mean(np.abs(z - g) / g)),
            "rmse": float(np.sqrt(np.mean((z - g) ** 2))),
            "delta1": float(np.mean(np.maximum(z / g, g / z) < 1.25)),
            "log_ratio_median": median,
            "log_ratio_spread": float(np.median(np.abs(log_ratio - median)))}


def frame_scale_error(relative: np.ndarray, truth: np.ndarray, scale: float) -> float | None:
    """|s_hat / s - 1| of one frame when ``relative`` (H, W) is ``s / truth``, else None;
    ``s_hat = 1 / scale`` (``scale``: the fitted a of ``1/z = a x + b``)."""
    valid = np.isfinite(truth) & (truth > 0) & np.isfinite(relative) & (relative > 0)
    if not valid.any() or not (scale > 0):
        return None
    log_s = np.log(relative[valid].astype(np.float64) * truth[valid])
    median = float(np.median(log_s))
    if np.median(np.abs(log_s - median)) >= PURE_SCALE_TOLERANCE:
        return None
    return abs(1.0 / (scale * np.exp(median)) - 1.0)


def _mean(values: Sequence[float]) -> float | None:
    values = np.asarray([v for v in values if v is not None and np.isfinite(v)], dtype=np.float64)
    return float(values.mean()) if len(values) else None


def score_frames(scene, depths: Sequence[np.ndarray], skies: Sequence[np.ndarray] | None = None,
                 relatives: Sequence[np.ndarray] | None = None, scales: Sequence[float] | None = None) -> dict:
    """Scene metrics of per-frame predictions (depth (H, W) with +inf on sky; sky (H, W) bool);
    ``relatives`` (H, W) and ``scales`` (the fitted a per frame) enable ``scale_error_median``."""
    result: dict = {"depth_absrel": None, "depth_rmse": None, "depth_delta1": None, "depth_coverage": None,
                    "scale_error_median": None, "sky_iou": None}
    if scene.has("gt/depth"):
        truths = [scene.load_optional("gt/depth", i) for i in range(len(depths))]
        errors = [frame_depth_errors(d, g) for d, g in zip(depths, truths, strict=True)]
        result["depth_absrel"] = _mean([e["absrel"] for e in errors])
        result["depth_rmse"] = _mean([e["rmse"] for e in errors])
        result["depth_delta1"] = _mean([e["delta1"] for e in errors])
        result["depth_coverage"] = _mean([e["coverage"] for e in errors])
        result["depth_absrel_frames"] = [e["absrel"] for e in errors]
        result["depth_ratio_jitter"] = ratio_jitter([_median_ratio(d, g) for d, g in zip(depths, truths, strict=True)])
        result["depth_ratio_jitter_dynamic"] = None
        if scene.has("gt/dynamic_mask"):
            result["depth_ratio_jitter_dynamic"] = ratio_jitter(
                [_median_ratio(d, g, np.asarray(scene.load_optional("gt/dynamic_mask", i)) > 0)
                 for i, (d, g) in enumerate(zip(depths, truths, strict=True))])
        if relatives is not None and scales is not None:
            scale_errors = [frame_scale_error(x, g, a) for x, g, a in zip(relatives, truths, scales, strict=True)]
            if all(e is not None for e in scale_errors):
                result["scale_error_median"] = float(np.median(scale_errors))
    if skies is not None and scene.has("gt/sky_mask"):
        result["sky_iou"] = _mean([mask_iou(s, scene.load_optional("gt/sky_mask", i)) for i, s in enumerate(skies)])
    return result


def load_prepared(scene, prepared_dir: str | Path, index: int) -> tuple[np.ndarray, np.ndarray]:
    """(depth (H, W) float32, sky (H, W) bool) of frame ``index`` from a prepared folder
    (``<prepared>/depth/<name>.npy`` and ``<prepared>/depth/sky/<name>.png``)."""
    name = scene.frames[index].name
    prepared = Path(prepared_dir)
    depth = np.load(prepared / "depth" / f"{name}.npy", allow_pickle=False)
    return depth, read_mask_png(prepared / "depth" / "sky" / f"{name}.png", depth.shape)


def depth_frontend_metrics(scene, prepared_dir: str | Path) -> dict:
    """Depth and sky metrics of the outputs of :func:`~radar4dgs.depth.prepare_depth`.

    Returns ``depth_absrel``, ``depth_rmse``, ``depth_delta1``, ``depth_coverage``,
    ``scale_error_median`` (None unless the kept relative prior is gt depth up to a pure scale),
    ``sky_iou`` (None without ``gt/sky_mask``), ``depth_absrel_frames``, and from the stage's
    summary ``depth_method``, ``depth_source``, ``depth_fallback_frames``. Depth metrics are None
    when the scene has no ``gt/depth``.
    """
    import json

    prepared = Path(prepared_dir)
    loaded = [load_prepared(scene, prepared, i) for i in range(len(scene))]
    summary_path = prepared / "depth" / "summary.json"
    summary = json.loads(summary_path.read_text(encoding="utf-8")) if summary_path.is_file() else None
    relatives = scales = None
    relative_paths = [prepared / "depth" / "relative" / f"{f.name}.npy" for f in scene.frames]
    if summary is not None and all(p.is_file() for p in relative_paths):
        relatives = (np.load(p, allow_pickle=False) for p in relative_paths)  # lazily, one at a time
        scales = [f["scale"] if f["scale"] is not None else float("nan") for f in summary["frames"]]
    result = score_frames(scene, [d for d, _ in loaded], [s for _, s in loaded], relatives, scales)
    if summary is not None:
        result["depth_method"] = summary.get("method")
        result["depth_source"] = summary.get("source")
        result["depth_fallback_frames"] = len(summary.get("fallbacks", []))
    return result
