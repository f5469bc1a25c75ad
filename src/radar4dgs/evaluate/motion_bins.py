"""PSNR of the dynamic pixels, binned by how far they move in the image: does the reconstruction
keep up with fast movers, or only with the slow ones?

PSNR* pools every dynamic pixel; in real traffic most of them belong to slow or distant movers (a
lead car the ego follows), so a car that crosses half the image in a few frames can be smeared
while PSNR* barely moves. Binning by the ground-truth image motion of each pixel
(:func:`~radar4dgs.io.image_motion.dynamic_pixel_motion_map`, px per frame) separates the two.
The MSE is pooled over all pixels of a bin across frames (not a mean of per-frame PSNRs), so a
frame with a handful of fast pixels does not dominate.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Sequence

import numpy as np

from radar4dgs.io.image_motion import IMAGE_MOTION_EDGES, dynamic_pixel_motion_map, image_motion_edges
from radar4dgs.io.scene import read_scene

DEFAULT_EDGES = IMAGE_MOTION_EDGES
RENDERS_DIR = "renders"  # as evaluate.reconstruction writes them: renders/{recon,nvs}/<frame>.png


def motion_bin_index(motion: np.ndarray, edges: Sequence[float]) -> np.ndarray:
    """(N,) int bin of each of (N,) image motions (px per frame): b where edges[b] <= motion < edges[b + 1];
    -1 below the first edge, ``len(edges) - 1`` at or beyond the last."""
    return np.digitize(motion, np.asarray(edges, dtype=np.float64)) - 1


def binned_squared_error(render: np.ndarray, gt: np.ndarray, motion: np.ndarray,
                         edges: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Per-bin sums of the squared error and pixel counts of one frame.

    Args:
        render, gt: (H, W, 3) uint8 or float in [0, 1].
        motion: (H, W) image motion (px per frame), NaN where the pixel is not counted.
        edges: (B + 1,) increasing bin edges; bin b holds edges[b] <= motion < edges[b + 1].
    Returns:
        (B,) sum over the bin's pixels of the mean-over-channels squared error, (B,) pixel counts.
    """
    def unit(image: np.ndarray) -> np.ndarray:
        return image.astype(np.float64) / 255.0 if image.dtype == np.uint8 else image.astype(np.float64)

    if render.shape != gt.shape or render.shape[:2] != motion.shape:
        raise ValueError(f"render {render.shape}, gt {gt.shape} and motion {motion.shape} do not match")
    error = ((unit(render) - unit(gt)) ** 2).mean(axis=-1)
    counted = np.isfinite(motion)
    index = motion_bin_index(motion[counted], edges)
    bins = len(edges) - 1
    inside = (index >= 0) & (index < bins)
    sums = np.bincount(index[inside], weights=error[counted][inside], minlength=bins)
    counts = np.bincount(index[inside], minlength=bins)
    return sums, counts


def bins_to_psnr(sums: np.ndarray, counts: np.ndarray, edges: Sequence[float]) -> list[dict]:
    """One ``{"low", "high", "pixels", "psnr"}`` per bin (psnr None for an empty bin; high None for
    an open bin)."""
    rows = []
    for b in range(len(edges) - 1):
        mse = sums[b] / counts[b] if counts[b] else None
        psnr = None if mse is None else (100.0 if mse <= 1e-10 else -10.0 * math.log10(mse))
        rows.append({"low": float(edges[b]), "high": None if math.isinf(edges[b + 1]) else float(edges[b + 1]),
                     "pixels": int(counts[b]), "psnr": psnr})
    return rows


def run_psnr_by_image_motion(run_dir: str | Path, edges: Sequence[float] = DEFAULT_EDGES) -> dict:
    """PSNR of a run's gt-dynamic pixels per image-motion bin, per split (``recon``, ``nvs``), from
    the renders `radar4dgs eval` wrote. Edges are scaled from a 320 px wide image to the scene's.

    Returns ``{"edges_px": [...], "recon": [bin rows], "nvs": [bin rows]}``; raises
    FileNotFoundError naming the first missing render (run `radar4dgs eval` first).
    """
    root = Path(run_dir)
    scene = read_scene(json.loads((root / "run.json").read_text())["scene"])
    if not scene.has("gt/flow"):
        raise ValueError(f"{scene.root}: no gt/flow, so no image motion to bin by")
    scaled = image_motion_edges(scene.camera.width, tuple(edges))
    test = set(scene.test_indices)
    totals = {split: (np.zeros(len(edges) - 1), np.zeros(len(edges) - 1, dtype=np.int64)) for split in ("recon", "nvs")}
    for index in range(len(scene) - 1):  # the last frame has no next one, so no motion
        split = "nvs" if index in test else "recon"
        path = root / RENDERS_DIR / split / f"{scene.frames[index].name}.png"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: missing render; run `radar4dgs eval {root}` first")
        from PIL import Image

        with Image.open(path) as image:
            render = np.asarray(image.convert("RGB"))
        sums, counts = binned_squared_error(render, scene.load_image(index), dynamic_pixel_motion_map(scene, index),
                                            scaled)
        totals[split][0][:] += sums
        totals[split][1][:] += counts
    return {"edges_px": [None if math.isinf(e) else e for e in scaled],
            **{split: bins_to_psnr(s, c, scaled) for split, (s, c) in totals.items()}}
