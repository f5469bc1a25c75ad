"""How well the training frames around a held-out frame saw its moving objects (scenes with ``gt/``).

A held-out frame is drawn from the copies of the training frames around it. At 5 Hz an oncoming car passing the
ego can be large in the image in the held-out frame only: 15 px wide in the training frame before, 100 px in the
held-out one, gone in the one after. There a model must invent detail no training frame showed and carry the car
past the last frame that saw it, so PSNR* on such a frame says more about the protocol than about the method.
:func:`closest_seen` measures it from the generator's truth: for each moving pixel of a frame, how much farther from
the camera its surface point was in the adjacent training frames that see it (a ratio of 2: seen at half this size).

Only the adjacent frames are used, because ``gt/flow`` links a frame to the next one alone; with every 4th frame held
out, they are the training frames around it.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from radar4dgs.motion.lift import backproject
from radar4dgs.motion.truth import project, visible_surface

# A moving pixel seen at less than 1 / UNSEEN_RATIO of its size (or not at all) counts as never seen close.
UNSEEN_RATIO = 2.0
# A held-out frame whose moving pixels are at least this share never seen close is left out of PSNR*_seen.
UNSEEN_FRAME_SHARE = 0.2
# Metres added to the nearest-point distance that counts as the same surface in the previous frame.
NEIGHBOUR_MARGIN = 0.05


def moving_points(scene, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Frame ``index``'s true moving pixels with a depth: ``(mask (H, W), rows (N,), cols (N,), world (N, 3),
    depth (N,))``."""
    depth = scene.load_optional("gt/depth", index).astype(np.float64)
    mask = (scene.load_optional("gt/dynamic_mask", index) > 0) & np.isfinite(depth) & (depth > 0)
    rows, cols = np.nonzero(mask)
    world = backproject(np.stack([cols, rows], axis=1).astype(np.float64), depth[rows, cols], scene.camera.K,
                        scene.world_to_camera(index))
    return mask, rows, cols, world, depth[rows, cols]


def closest_seen(scene, index: int, train_indices) -> np.ndarray:
    """(H, W): for each true moving pixel of frame ``index``, the smallest ratio of its surface point's depth in
    an adjacent training frame that shows it to its depth here (1: seen as large; 2: at half the size; inf: no
    adjacent training frame shows it); NaN off the moving pixels."""
    train = set(int(i) for i in train_indices)
    K = scene.camera.K
    mask, rows, cols, world, here = moving_points(scene, index)
    ratio = np.full(mask.shape, np.nan)
    ratio[mask] = np.inf
    if index + 1 < len(scene) and index + 1 in train:  # this frame's points carried to the next one
        moved = world + scene.load_optional("gt/flow", index).astype(np.float64)[mask]
        keep, _ = visible_surface(moved, scene, index + 1)
        z = project(moved, K, scene.world_to_camera(index + 1))[1]
        at = rows[keep], cols[keep]
        ratio[at] = np.minimum(ratio[at], z[keep] / here[keep])
    if index >= 1 and index - 1 in train:
        # The previous frame's points carried to this time, and for each moving pixel here the nearest of them.
        # Looked up, not splatted: a mover that came closer covers more pixels here than it had points there.
        before_mask, _, _, before, before_depth = moving_points(scene, index - 1)
        if len(before):
            moved = before + scene.load_optional("gt/flow", index - 1).astype(np.float64)[before_mask]
            distance, nearest = cKDTree(moved).query(world)
            # Within two of that frame's pixel footprints (plus rounding): the same surface, seen there.
            footprint = before_depth[nearest] / scene.camera.K[0, 0]
            seen = distance < 2.0 * footprint + NEIGHBOUR_MARGIN
            at = rows[seen], cols[seen]
            ratio[at] = np.minimum(ratio[at], before_depth[nearest[seen]] / here[seen])
    return ratio


def unseen_close_share(scene, index: int, train_indices) -> float | None:
    """The share of frame ``index``'s true moving pixels that no adjacent training frame showed at least
    1 / :data:`UNSEEN_RATIO` as large; None where the scene lacks the truth or the frame has no moving pixel."""
    if not all(scene.has(name) for name in ("gt/depth", "gt/flow", "gt/dynamic_mask")):
        return None
    return unseen_share(closest_seen(scene, index, train_indices))


def unseen_share(ratio: np.ndarray) -> float | None:
    """The share of the moving pixels of a :func:`closest_seen` map (H, W) seen at under 1 / :data:`UNSEEN_RATIO`
    of their size or not at all; None without moving pixels."""
    moving = ~np.isnan(ratio)
    return float((ratio[moving] > UNSEEN_RATIO).mean()) if moving.any() else None


def seen_summary(per_frame: list[dict]) -> dict | None:
    """PSNR* over the frames of a split whose ``unseen_close_share`` is below :data:`UNSEEN_FRAME_SHARE`
    (``psnr_dyn``, their mean; ``n_frames``) and the ``unseen_frames`` left out; None when no frame has the share."""
    scored = [f for f in per_frame if f.get("unseen_close_share") is not None and f.get("psnr_dyn") is not None]
    if not scored:
        return None
    seen = [f["psnr_dyn"] for f in scored if f["unseen_close_share"] < UNSEEN_FRAME_SHARE]
    return {"psnr_dyn": float(np.mean(seen)) if seen else None, "n_frames": len(seen),
            "unseen_frames": [f["frame"] for f in scored if f["unseen_close_share"] >= UNSEEN_FRAME_SHARE]}


def seen_caveats(summary: dict | None, psnr_dyn: float | None) -> list[str]:
    """The caveat on novel-view PSNR* (``psnr_dyn``, all frames) when some held-out frames show movers no training
    frame around them saw close (``summary``: :func:`seen_summary`)."""
    if not summary or not summary["unseen_frames"] or psnr_dyn is None:
        return []
    without = "n/a" if summary["psnr_dyn"] is None else f"{summary['psnr_dyn']:.2f} dB"
    return [f"PSNR* (nvs): in {len(summary['unseen_frames'])} test frame(s) ({', '.join(summary['unseen_frames'])}) "
            f"at least {UNSEEN_FRAME_SHARE:.0%} of the moving pixels were never seen by the adjacent training frames "
            f"at even 1/{UNSEEN_RATIO:g} of their size (a mover passing close between them): detail no training frame "
            f"showed. PSNR* is {psnr_dyn:.2f} dB over all test frames, {without} over the other "
            f"{summary['n_frames']} (nvs_seen)"]
