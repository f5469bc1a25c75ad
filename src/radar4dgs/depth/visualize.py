"""Figures of the depth front end: radar pairs on the image, metric depth, error map."""

from __future__ import annotations

import cv2
import numpy as np

from radar4dgs.depth.pairs import DYNAMIC, VALID, FrameFit

# BGR-free RGB colours of the radar pair classes.
INLIER, OUTLIER, REJECTED, MOVING = (40, 220, 40), (255, 40, 40), (160, 160, 160), (40, 120, 255)


def colorize(values: np.ndarray, lo: float, hi: float, colormap: int = cv2.COLORMAP_TURBO,
             invalid: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB of (H, W) ``values`` mapped linearly from [lo, hi]; ``invalid`` black."""
    scaled = np.clip((np.nan_to_num(values, nan=lo, posinf=lo, neginf=lo) - lo) / max(hi - lo, 1e-12), 0, 1)
    rgb = cv2.applyColorMap((scaled * 255).astype(np.uint8), colormap)[..., ::-1].copy()
    if invalid is not None:
        rgb[invalid] = 0
    return rgb


def depth_image(depth: np.ndarray, max_depth: float = 80.0) -> np.ndarray:
    """(H, W, 3) uint8: inverse depth in turbo (near = red, far = blue), sky / invalid black."""
    invalid = ~np.isfinite(depth)
    with np.errstate(divide="ignore"):
        inverse = np.where(invalid, 0.0, 1.0 / np.maximum(depth, 1e-3))
    return colorize(inverse, 1.0 / max_depth, 1.0 / 3.0, invalid=invalid)


def error_image(depth: np.ndarray, truth: np.ndarray, max_error: float = 0.3) -> np.ndarray:
    """(H, W, 3) uint8: |z - z_gt| / z_gt from 0 (dark) to ``max_error`` (bright); no gt black,
    predicted sky over gt surface magenta."""
    scored = np.isfinite(truth) & (truth > 0) & np.isfinite(depth)
    with np.errstate(divide="ignore", invalid="ignore"):
        error = np.where(scored, np.abs(depth - truth) / truth, 0.0)
    rgb = colorize(error, 0.0, max_error, cv2.COLORMAP_INFERNO, invalid=~scored)
    rgb[np.isfinite(truth) & ~np.isfinite(depth)] = (255, 0, 255)
    return rgb


def pairs_image(image: np.ndarray, fit: FrameFit, radius: int = 2) -> np.ndarray:
    """(H, W, 3) uint8: the image with the radar points: inliers green, validated outliers red,
    moving blue, rejected by the checks grey."""
    out = (image.astype(np.float32) * 0.6).astype(np.uint8).copy()
    pairs = fit.pairs
    height, width = image.shape[:2]
    order = np.argsort(fit.inliers.astype(int))  # inliers drawn last, on top
    for k in order:
        u, v = pairs.uv[k]
        if not (np.isfinite(u) and np.isfinite(v) and 0 <= u < width and 0 <= v < height and pairs.z[k] > 0):
            continue
        if fit.inliers[k]:
            colour = INLIER
        elif pairs.reason[k] == VALID:
            colour = OUTLIER
        elif pairs.reason[k] == DYNAMIC:
            colour = MOVING
        else:
            colour = REJECTED
        cv2.circle(out, (int(round(u)), int(round(v))), radius, colour, -1, lineType=cv2.LINE_AA)
    return out


def _label(panel: np.ndarray, text: str) -> np.ndarray:
    """The panel under a black caption strip with ``text`` in white."""
    scale = max(0.4, panel.shape[1] / 800)
    strip_height = int(round(24 * scale / 0.5))
    strip = np.zeros((strip_height, panel.shape[1], 3), np.uint8)
    cv2.putText(strip, text, (6, int(strip_height * 0.72)), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1,
                cv2.LINE_AA)
    return np.concatenate([strip, panel], axis=0)


def depth_figure(image: np.ndarray, fit: FrameFit, depth: np.ndarray, truth: np.ndarray | None,
                 labels: tuple[str, str, str] = ("radar pairs", "metric depth", "AbsRel error (0-0.3)"),
                 upscale: int = 2) -> np.ndarray:
    """One row of captioned panels (3 W * upscale wide) uint8: radar pairs on the image (green
    inliers, red validated outliers, blue moving, grey rejected by the checks), the metric depth
    (inverse depth in turbo, sky black) and (with ``truth``) the relative error map (inferno,
    0 to 0.3; magenta: surface called sky)."""
    panels = [pairs_image(image, fit), depth_image(depth)]
    if truth is not None:
        panels.append(error_image(depth, truth))
    if upscale > 1:
        panels = [cv2.resize(p, None, fx=upscale, fy=upscale, interpolation=cv2.INTER_NEAREST) for p in panels]
    return np.concatenate([_label(p, t) for p, t in zip(panels, labels, strict=False)], axis=1)
