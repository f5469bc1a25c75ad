"""The non-learned comparison: a radar-prompted region-growing mask.

From each projected dynamic radar point (a seed), grow the 4-connected region of pixels whose
colour (CIE Lab distance) and depth (relative difference, any depth map: metric, or a relative
inverse depth whose ratio tolerance still separates a car from the road behind it) stay close to
the seed's, inside a window of about ``max_object_m`` metres around the seed (from the radar
point's own range), so that a leak into the road stays bounded; a region larger than a car
would appear at that range is dropped. Seeds must be supported by other dynamic points nearby
(in 3D, with a similar compensated velocity): isolated dynamic points are mostly clutter. A
morphological closing fills small holes (windows, wheels, texture). Fixed-range flood fill,
vectorised per window.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from radar4dgs.io.scene import Scene
from radar4dgs.segment.patches import RadarFrame, candidate_anchors, pixel_index


@dataclass
class BaselineConfig:
    """Radar-prompted flood fill (defaults chosen on the validation scene, synthetic seed 115)."""

    colour_tolerance: float = 18.0  # max CIE Lab distance (8-bit OpenCV Lab units) from the seed's colour
    depth_tolerance: float = 0.05  # max relative depth difference |D/D_seed - 1| (ignored without a depth map)
    max_object_m: float = 5.0  # the region stays inside a window this many metres wide around each seed
    max_area_m2: float = 4.5  # a region larger than this (m², at the seed's range) is a leak and is dropped
    min_support: int = 2  # a seed needs this many other dynamic points within support_radius_m (0 = no check)
    support_radius_m: float = 2.0  # 3D radius of the support check (m)
    support_velocity: float = 1.5  # supporting points' compensated radial velocity within this of the seed's (m/s)
    seed_radius: int = 1  # seed colour and depth are medians over a (2r+1)² neighbourhood
    closing_px: int = 3  # side of the closing kernel that fills small holes (0 = none)
    max_seeds: int = 32  # at most this many seeds per frame (nearest to the camera first)


def _seed_stats(values: np.ndarray, u: int, v: int, r: int) -> np.ndarray:
    patch = values[max(v - r, 0):v + r + 1, max(u - r, 0):u + r + 1]
    return np.median(patch.reshape(-1, patch.shape[-1]) if patch.ndim == 3 else patch.reshape(-1, 1), axis=0)


def grow_region(lab: np.ndarray, depth: np.ndarray | None, seed_uv: tuple[int, int], half: int,
                config: BaselineConfig) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """Region grown from one seed inside a window.

    Args:
        lab: (H, W, 3) float32 Lab image; depth: (H, W) depth map or None.
        seed_uv: integer pixel (u, v) inside the image; half: window half-size (px).

    Returns:
        (h, w) bool region in the window and the window ``(x0, y0, x1, y1)``.
    """
    height, width = lab.shape[:2]
    u, v = seed_uv
    x0, y0, x1, y1 = max(u - half, 0), max(v - half, 0), min(u + half + 1, width), min(v + half + 1, height)
    window_lab = lab[y0:y1, x0:x1]
    similar = np.linalg.norm(window_lab - _seed_stats(lab, u, v, config.seed_radius), axis=2) < config.colour_tolerance
    if depth is not None:
        seed_depth = float(_seed_stats(depth, u, v, config.seed_radius)[0])
        window_depth = depth[y0:y1, x0:x1]
        if np.isfinite(seed_depth) and abs(seed_depth) > 1e-6:
            with np.errstate(invalid="ignore"):
                similar &= np.abs(window_depth / seed_depth - 1.0) < config.depth_tolerance
    if not similar[v - y0, u - x0]:
        return np.zeros_like(similar), (x0, y0, x1, y1)
    _, labels = cv2.connectedComponents(similar.astype(np.uint8), connectivity=4)
    return labels == labels[v - y0, u - x0], (x0, y0, x1, y1)


def supported_seeds(radar: RadarFrame, seeds: np.ndarray, config: BaselineConfig) -> np.ndarray:
    """The seeds (M,) with at least ``min_support`` other dynamic points within
    ``support_radius_m`` (3D) whose compensated velocity is within ``support_velocity``."""
    dynamic = np.flatnonzero(radar.dynamic)
    keep = []
    for s in seeds:
        near = np.linalg.norm(radar.cam[dynamic] - radar.cam[s], axis=1) < config.support_radius_m
        similar = np.abs(radar.v_comp[dynamic] - radar.v_comp[s]) < config.support_velocity
        keep.append(int((near & similar).sum()) - 1 >= config.min_support)
    return seeds[np.asarray(keep, bool)] if len(seeds) else seeds


def baseline_frame(image: np.ndarray, depth: np.ndarray | None, radar: RadarFrame, K: np.ndarray,
                   config: BaselineConfig | None = None) -> np.ndarray:
    """(H, W) bool dynamic mask of one frame; empty without a dynamic radar point in view.

    Args:
        image: (H, W, 3) uint8 RGB. depth: (H, W) any depth-like map (or None). K: (3, 3).
    """
    config = config or BaselineConfig()
    height, width = image.shape[:2]
    mask = np.zeros((height, width), bool)
    seeds = candidate_anchors(radar, width, height)
    if len(seeds) == 0:
        return mask
    if config.min_support > 0:
        seeds = supported_seeds(radar, seeds, config)
    seeds = seeds[np.argsort(radar.cam[seeds, 2], kind="stable")[:config.max_seeds]]
    lab = cv2.cvtColor(image, cv2.COLOR_RGB2LAB).astype(np.float32)
    focal = float(K[0, 0])
    for s in seeds:
        u, v = (int(x) for x in pixel_index(radar.uv[s:s + 1])[0])
        half = int(np.clip(0.5 * focal * config.max_object_m / max(float(radar.cam[s, 2]), 0.5), 3, max(width, height)))
        region, (x0, y0, x1, y1) = grow_region(lab, depth, (u, v), half, config)
        if region.sum() > config.max_area_m2 * (focal / max(float(radar.cam[s, 2]), 0.5)) ** 2:
            continue
        mask[y0:y1, x0:x1] |= region
    if config.closing_px > 1 and mask.any():
        kernel = np.ones((config.closing_px, config.closing_px), np.uint8)
        mask = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_CLOSE, kernel).astype(bool)
    return mask


def depth_for_baseline(scene: Scene, index: int, prepared_dir: Path | None) -> np.ndarray | None:
    """The depth map the baseline grows through: the prepared metric depth
    (``<prepared>/depth/<frame>.npy``) when present, else ``priors/mono_depth``, else None."""
    if prepared_dir is not None:
        path = Path(prepared_dir) / "depth" / f"{scene.frames[index].name}.npy"
        if path.is_file():
            depth = np.load(path, allow_pickle=False)
            if depth.shape == (scene.camera.height, scene.camera.width):
                return depth.astype(np.float32)
    if scene.has("priors/mono_depth"):
        return scene.load_optional("priors/mono_depth", index).astype(np.float32)
    return None
