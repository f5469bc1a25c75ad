"""Front-end metrics of the dynamic masks, for ``frontend-eval``.

``mask_iou``: accumulated over the scene, Σ_frames |pred ∧ gt| / Σ_frames |pred ∨ gt| against
``gt/dynamic_mask`` (a frame with no moving object counts through its false positives only).

``static_vehicle_fp``: the fraction of parked-car pixels (summed over frames) marked dynamic.
Parked-car pixels come from the synthetic generator's metadata (``scene.json`` → ``synthetic`` →
``objects`` of ``kind`` ``parked``, with boxes in the car frame and a world pose per frame): a
pixel is a parked-car pixel when its camera ray hits one of those boxes at the depth ``gt/depth``
records there (so occluded boxes do not count). Scenes without that metadata report ``None``.

Both are reported for the model (the masks ``prepare`` wrote to ``<prepared>/masks``, or computed
here when absent) and for the non-learned baseline (computed here).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from radar4dgs.io.scene import Scene, read_mask_png
from radar4dgs.segment.infer import SegInferConfig, segment_scene

# A box hit counts as the visible surface when it agrees with gt depth within this (relative + absolute).
DEPTH_MATCH_REL = 0.01
DEPTH_MATCH_ABS = 0.05


def ray_box_depth(origin: np.ndarray, directions: np.ndarray, box_to_world: np.ndarray,
                  half: np.ndarray) -> np.ndarray:
    """Ray parameter of the first hit of rays ``origin + t · d`` with an oriented box (slab method).

    Args:
        origin: (3,) world ray origin; directions: (N, 3) world directions (unit z in the camera
            frame, so t is the z-depth); box_to_world: (4, 4) pose of the box centre; half: (3,).

    Returns:
        (N,) t of the entry point (exit point from inside), +inf where the ray misses.
    """
    rot, centre = box_to_world[:3, :3], box_to_world[:3, 3]
    o = rot.T @ (origin - centre)
    d = directions @ rot  # rows: rot.T @ d
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half - o) / d
        t2 = (half - o) / d
    t_near = np.nanmax(np.minimum(t1, t2), axis=1)
    t_far = np.nanmin(np.maximum(t1, t2), axis=1)
    hit = (t_near <= t_far) & (t_far > 0)
    return np.where(hit, np.where(t_near > 0, t_near, t_far), np.inf)


def parked_car_pixels(scene: Scene, index: int) -> np.ndarray | None:
    """(H, W) bool pixels that see a parked car in frame ``index``; None without synthetic metadata
    or gt depth."""
    objects = (scene.extra.get("synthetic") or {}).get("objects")
    if objects is None or not scene.has("gt/depth"):
        return None
    width, height, K = scene.camera.width, scene.camera.height, scene.camera.K
    u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1).reshape(-1, 3)
    cam_to_world = np.linalg.inv(scene.world_to_camera(index))
    origin, directions = cam_to_world[:3, 3], rays @ cam_to_world[:3, :3].T
    nearest = np.full(len(rays), np.inf)
    for obj in objects:
        if obj.get("kind") != "parked":
            continue
        pose = np.asarray(obj["poses"][index], float)
        for box in obj["boxes"]:
            local = np.eye(4)
            local[:3, 3] = box["center"]
            nearest = np.minimum(nearest, ray_box_depth(origin, directions, pose @ local, np.asarray(box["half_size"])))
    depth = scene.load_optional("gt/depth", index).reshape(-1)
    with np.errstate(invalid="ignore"):  # inf - inf where a miss meets the sky
        visible = np.isfinite(nearest) & (np.abs(nearest - depth) <= DEPTH_MATCH_REL * depth + DEPTH_MATCH_ABS)
    return visible.reshape(height, width)


def ground_truth_masks(scene: Scene, count: int) -> tuple[list[np.ndarray], list[np.ndarray | None]]:
    """The first ``count`` frames' gt dynamic masks and parked-car pixels (:func:`parked_car_pixels`),
    computed once so that several methods can be scored against them."""
    return ([scene.load_optional("gt/dynamic_mask", i) for i in range(count)],
            [parked_car_pixels(scene, i) for i in range(count)])


def mask_scores(scene: Scene, masks: list[np.ndarray],
                truth: tuple[list[np.ndarray], list[np.ndarray | None]] | None = None) -> dict[str, Any]:
    """``mask_iou``, ``static_vehicle_fp`` and pixel counts (``intersection``, ``union``,
    ``gt_pixels``, ``parked_car_pixels``) of per-frame (H, W) bool masks;
    ``truth`` is :func:`ground_truth_masks` when the caller already has it."""
    gts, parked_cars = truth if truth is not None else ground_truth_masks(scene, len(masks))
    inter = union = gt_pixels = parked = parked_marked = 0
    has_parked = True
    for pred, gt, cars in zip(masks, gts, parked_cars, strict=True):
        inter += int((pred & gt).sum())
        union += int((pred | gt).sum())
        gt_pixels += int(gt.sum())
        if cars is None:
            has_parked = False
            continue
        parked += int(cars.sum())
        parked_marked += int((cars & pred).sum())
    return {"mask_iou": inter / union if union else None,
            "static_vehicle_fp": (parked_marked / parked if parked else 0.0) if has_parked else None,
            "parked_car_pixels": parked if has_parked else None, "intersection": inter, "union": union,
            "gt_pixels": gt_pixels}


def segmentation_frontend_metrics(scene: Scene, prepared_dir: str | Path | None,
                                  config: SegInferConfig | None = None) -> dict[str, Any]:
    """Mask metrics of the model and the baseline (module doc); ``{}`` without ``gt/dynamic_mask``.

    The model's masks are read from ``<prepared>/masks/<frame>.png`` when all exist, else computed
    with ``config`` (default: the shipped checkpoint).
    """
    if not scene.has("gt/dynamic_mask"):
        return {}
    prepared = None if prepared_dir is None else Path(prepared_dir)
    config = config or SegInferConfig()
    files = [prepared / "masks" / f"{f.name}.png" for f in scene.frames] if prepared is not None else []
    result: dict[str, Any] = {}
    if files and all(p.is_file() for p in files):
        model_masks, source = [read_mask_png(p) for p in files], str(prepared / "masks")
        seconds = None
    else:
        start = time.perf_counter()
        model_masks = [r.mask(config.threshold) for _, r in segment_scene(scene, prepared, config)]
        seconds, source = (time.perf_counter() - start) / max(len(scene), 1), "computed (shipped or given checkpoint)"
    truth = ground_truth_masks(scene, len(scene))
    result["model"] = {**mask_scores(scene, model_masks, truth), "source": source, "seconds_per_frame": seconds}
    start = time.perf_counter()
    baseline_config = SegInferConfig(method="baseline", dynamic_source=config.dynamic_source)
    baseline_masks = [r.mask(0.5) for _, r in segment_scene(scene, prepared, baseline_config)]
    result["baseline"] = {**mask_scores(scene, baseline_masks, truth), "source": "radar-prompted flood fill",
                          "seconds_per_frame": (time.perf_counter() - start) / max(len(scene), 1)}
    result["mask_iou"] = result["model"]["mask_iou"]
    result["static_vehicle_fp"] = result["model"]["static_vehicle_fp"]
    return result
