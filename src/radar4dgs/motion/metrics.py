"""Front-end metrics of the pseudo scene flow in ``<prepared>/flow`` against the scene's ground
truth (evaluation only): 2D end-point error, scene-flow end-point error and coverage on dynamic
pixels."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from radar4dgs.io.image_motion import lands_in_image
from radar4dgs.motion.flow import load_flow_pairs
from radar4dgs.motion.sampling import pixel_grid
from radar4dgs.motion.truth import gt_scene_flow, image_flow


def gt_flow_2d(scene, index: int, next_index: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth 2D flow of frame ``index`` to ``next_index`` (default ``index + 1``) from
    gt/depth and gt/flow (evaluation): each pixel's surface point moved by the true motion
    (:func:`radar4dgs.motion.truth.gt_scene_flow`, composed over skipped frames) and projected
    into frame ``next_index``.

    Returns:
        flow (H, W, 2) float64 and valid (H, W) bool (finite depth, visible through any skipped
        frame, in front of camera j).
    """
    j = index + 1 if next_index is None else next_index
    _, moved, valid = gt_scene_flow(scene, index, j)
    return image_flow(moved, valid, scene, j)


def motion_frontend_metrics(scene, prepared_dir: str | Path, max_pairs: int | None = None) -> dict:
    """Front-end metrics of the pseudo scene flow in ``<prepared>/flow`` against the scene's gt/.

    Only pairs of adjacent frames (``index_j = index_i + 1``) are scored, since gt/flow is a
    one-frame displacement.

    - ``flow2d_epe_dynamic`` (px): mean over the gt-dynamic pixels with finite gt depth whose
      point lands inside the next image, pooled over pairs, of |stored 2D flow - gt 2D flow| (gt 2D
      flow from :func:`gt_flow_2d`). Pixels whose point leaves the image (an oncoming car passing
      the camera) have no correspondence to find and a gt "flow" of up to thousands of pixels that
      would dominate any mean; they are counted in ``flow2d_out_of_view``, as KITTI and the image
      motion statistics (``radar4dgs.io.image_motion``) leave them out.
    - ``flow2d_epe_dynamic_p50`` / ``_p90`` (px): median and 90th percentile of the same errors.
    - ``flow2d_out_of_view``: fraction of those gt-dynamic pixels left out for leaving the image.
    - ``flow2d_kept_share``: fraction of the scored pixels whose flow passed the forward-backward and
      photometric checks (``consistent & reliable`` in the stored pair), the flow that can be lifted;
      ``flow2d_epe_dynamic_kept`` / ``_rejected`` (px): the mean error over those and over the others.
      The flow of rejected pixels is stored but never lifted, so it never reaches training; None when
      the stored pairs carry no check flags.
    - ``sceneflow_epe_dynamic`` (m): mean over the stored lifted pairs whose pixel is gt-dynamic
      of |(points_j - points_i) - gt/flow[pixel]|.
    - ``sceneflow_coverage``: fraction of gt-dynamic pixels (finite depth) that got a lifted pair.
    - ``flow2d_pairs``: pairs scored.
    - ``sceneflow_epe_dynamic_two_frame`` (m, over the pair's span): the same error for the stored pairs
      that skip a frame (around each held-out frame, ``FlowConfig.skip_test_frames``), which train
      the field as much as the others: |(points_j - points_i) - true motion| with the true motion
      composed over the skipped frame (:func:`radar4dgs.motion.truth.gt_scene_flow`), on pixels
      whose point stays visible through it; None when no pair skips. ``sceneflow_two_frame_pairs``:
      how many lifted points that scored. ``flow2d_epe_dynamic_two_frame`` (px, over the pair's span):
      those pairs' stored 2D flow against the true one (:func:`gt_flow_2d` with the skipped frame), on
      the same pixels as ``flow2d_epe_dynamic``; None when no pair skips.
    """
    stored = load_flow_pairs(prepared_dir)
    pairs = [p for p in stored if int(p["index_j"]) == int(p["index_i"]) + 1]
    if max_pairs is not None:
        pairs = pairs[:max_pairs]
    errors_2d, errors_3d, kept_2d = [], [], []
    dynamic_total, covered, out_of_view = 0, 0, 0
    for pair in pairs:
        i = int(pair["index_i"])
        gt2d, valid = gt_flow_2d(scene, i)
        dynamic = scene.load_optional("gt/dynamic_mask", i) & valid
        errors, left, in_view = in_view_flow_errors(pair["flow"], gt2d, dynamic)
        out_of_view += left
        errors_2d.append(errors)
        if "consistent" in pair and "reliable" in pair:
            kept_2d.append((pair["consistent"] & pair["reliable"])[in_view])
        errors_3d.append(lifted_motion_errors(pair, scene.load_optional("gt/flow", i), dynamic))
        dynamic_total += int(dynamic.sum())
        covered += len(errors_3d[-1])
    e2 = np.concatenate(errors_2d) if errors_2d else np.zeros(0)
    e3 = np.concatenate(errors_3d) if errors_3d else np.zeros(0)
    p50, p90 = np.percentile(e2, [50, 90]) if len(e2) else (None, None)
    kept = np.concatenate(kept_2d) if kept_2d and len(kept_2d) == len(errors_2d) else None
    return {"flow2d_epe_dynamic": float(e2.mean()) if len(e2) else None,
            "flow2d_epe_dynamic_p50": None if p50 is None else float(p50),
            "flow2d_epe_dynamic_p90": None if p90 is None else float(p90),
            "flow2d_out_of_view": out_of_view / dynamic_total if dynamic_total else None,
            **kept_split(e2, kept),
            "sceneflow_epe_dynamic": float(e3.mean()) if len(e3) else None,
            "sceneflow_coverage": covered / dynamic_total if dynamic_total else None,
            "flow2d_pairs": len(pairs), **two_frame_scene_flow(scene, stored, max_pairs)}


def in_view_flow_errors(flow: np.ndarray, truth: np.ndarray,
                        scored: np.ndarray) -> tuple[np.ndarray, int, np.ndarray]:
    """(|flow - truth| (K,) px on the ``scored`` pixels whose true landing lies inside the image, in
    row-major order, how many ``scored`` pixels land outside it, and those K pixels as an (H, W) bool
    mask). ``flow``, ``truth``: (H, W, 2); ``scored``: (H, W) bool."""
    height, width = scored.shape
    in_view = scored & lands_in_image(pixel_grid(height, width) + truth, width, height)
    return np.linalg.norm(flow[in_view] - truth[in_view], axis=1), int((scored & ~in_view).sum()), in_view


def kept_split(errors: np.ndarray, kept: np.ndarray | None) -> dict[str, float | None]:
    """``flow2d_kept_share``, ``flow2d_epe_dynamic_kept`` and ``flow2d_epe_dynamic_rejected`` of (K,)
    errors and their (K,) bool check flags (None: no flags, every value None)."""
    if kept is None or len(errors) == 0:
        return {"flow2d_kept_share": None, "flow2d_epe_dynamic_kept": None, "flow2d_epe_dynamic_rejected": None}
    return {"flow2d_kept_share": float(kept.mean()),
            "flow2d_epe_dynamic_kept": float(errors[kept].mean()) if kept.any() else None,
            "flow2d_epe_dynamic_rejected": float(errors[~kept].mean()) if (~kept).any() else None}


def lifted_motion_errors(pair: dict, motion: np.ndarray, scored: np.ndarray) -> np.ndarray:
    """(K,) |(points_j - points_i) - true motion| (m) of a stored pair's lifted points whose pixel is
    ``scored`` ((H, W) bool), against ``motion`` (H, W, 3), the true motion of each pixel's point."""
    cols = pair["pixels"][:, 0].astype(np.int64)
    rows = pair["pixels"][:, 1].astype(np.int64)
    keep = scored[rows, cols]
    predicted = (pair["points_j"] - pair["points_i"]).astype(np.float64)[keep]
    return np.linalg.norm(predicted - motion[rows[keep], cols[keep]], axis=1)


def two_frame_scene_flow(scene, stored: list[dict], max_pairs: int | None = None) -> dict:
    """``sceneflow_epe_dynamic_two_frame``, ``sceneflow_two_frame_pairs`` and
    ``flow2d_epe_dynamic_two_frame`` (see
    :func:`motion_frontend_metrics`) of the stored pairs that span more than one frame."""
    skipping = [p for p in stored if int(p["index_j"]) > int(p["index_i"]) + 1]
    if max_pairs is not None:
        skipping = skipping[:max_pairs]
    errors, errors_2d = [], []
    for pair in skipping:
        i, j = int(pair["index_i"]), int(pair["index_j"])
        world_i, world_j, valid = gt_scene_flow(scene, i, j)
        dynamic = scene.load_optional("gt/dynamic_mask", i) & valid
        errors.append(lifted_motion_errors(pair, world_j - world_i, dynamic))
        truth_2d, landed = image_flow(world_j, valid, scene, j)
        errors_2d.append(in_view_flow_errors(pair["flow"], truth_2d, dynamic & landed)[0])
    e = np.concatenate(errors) if errors else np.zeros(0)
    e2 = np.concatenate(errors_2d) if errors_2d else np.zeros(0)
    return {"sceneflow_epe_dynamic_two_frame": float(e.mean()) if len(e) else None,
            "sceneflow_two_frame_pairs": int(len(e)),
            "flow2d_epe_dynamic_two_frame": float(e2.mean()) if len(e2) else None}
