"""Pictures for evaluation outputs: depth, masks, error maps, labelled side-by-side panels.

Every function returns an RGB ``uint8`` ``(H, W, 3)`` numpy array, ready for ``write_video`` or an
image writer. Inputs may be numpy arrays or torch tensors (any device; they are copied to the CPU).
"""

from __future__ import annotations

from typing import Any, Optional, Sequence

import cv2
import numpy as np

# Absolute error (data range 1) shown at full heat by error_to_rgb: a fixed scale keeps the frames
# of a video comparable; a typical rendering's errors are well below it.
DEFAULT_ERROR_MAX = 0.2


def _to_numpy(array: Any) -> np.ndarray:
    if hasattr(array, "detach"):  # a torch tensor; torch itself is not needed here
        array = array.detach().cpu().numpy()
    return np.asarray(array)


def _colormap(values01: np.ndarray, colormap: int) -> np.ndarray:
    """``(H, W)`` floats in [0, 1] -> ``(H, W, 3)`` RGB uint8 through an OpenCV colormap."""
    index = np.round(np.clip(values01, 0.0, 1.0) * 255.0).astype(np.uint8)
    return cv2.cvtColor(cv2.applyColorMap(index, colormap), cv2.COLOR_BGR2RGB)


def image_to_rgb(image: Any) -> np.ndarray:
    """A float ``(H, W, 3)`` image in [0, 1] (clipped) or a uint8 one -> RGB uint8 ``(H, W, 3)``."""
    image = _to_numpy(image)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {image.shape}")
    if image.dtype == np.uint8:
        return image
    return np.round(np.clip(image.astype(np.float64), 0.0, 1.0) * 255.0).astype(np.uint8)


def depth_to_rgb(depth: Any, near: Optional[float] = None, far: Optional[float] = None) -> np.ndarray:
    """Depth ``(H, W)`` (metres) -> RGB uint8 ``(H, W, 3)``: TURBO colours of the inverse depth.

    ``1/depth`` is mapped linearly from ``1/far`` (blue) to ``1/near`` (red), clipped, so that the
    near field, where the detail is, gets most of the colours. ``near``/``far`` default to the
    smallest/largest valid depth of this image; pass fixed values for a video. Pixels whose depth
    is not finite or not positive are black.
    """
    depth = _to_numpy(depth).astype(np.float64)
    if depth.ndim != 2:
        raise ValueError(f"depth_to_rgb: expected an (H, W) depth map, got shape {depth.shape}")
    valid = np.isfinite(depth) & (depth > 0)
    rgb = np.zeros((*depth.shape, 3), np.uint8)
    if not valid.any():
        return rgb
    near = float(depth[valid].min()) if near is None else float(near)
    far = float(depth[valid].max()) if far is None else float(far)
    if not (near > 0 and far > 0):
        raise ValueError(f"depth_to_rgb: near ({near}) and far ({far}) must be positive")
    inv = np.zeros_like(depth)
    inv[valid] = 1.0 / depth[valid]
    inv_near, inv_far = 1.0 / near, 1.0 / far
    span = inv_near - inv_far
    # near == far (a flat wall, one valid pixel): every valid pixel in the middle colour.
    scaled = (inv - inv_far) / span if span > 0 else np.full_like(inv, 0.5)
    rgb[valid] = _colormap(scaled, cv2.COLORMAP_TURBO)[valid]
    return rgb


def mask_to_rgb(mask: Any) -> np.ndarray:
    """Mask ``(H, W)`` -> RGB uint8 ``(H, W, 3)``: bool masks white on black; float masks (a
    rendered soft mask) as grey levels, [0, 1] clipped."""
    mask = _to_numpy(mask)
    if mask.ndim != 2:
        raise ValueError(f"mask_to_rgb: expected an (H, W) mask, got shape {mask.shape}")
    grey = np.round(np.clip(mask.astype(np.float64), 0.0, 1.0) * 255.0).astype(np.uint8)
    return np.repeat(grey[:, :, None], 3, axis=2)


def error_to_rgb(pred: Any, gt: Any, vmax: float = DEFAULT_ERROR_MAX) -> np.ndarray:
    """Per-pixel absolute error of two ``(H, W, 3)`` images -> RGB uint8 heat map ``(H, W, 3)``.

    The error is ``|pred - gt|`` averaged over the channels, on the [0, 1] scale (uint8 images are
    divided by 255), shown with OpenCV's INFERNO colormap from 0 (black) to ``vmax`` (yellow) and
    saturating above it.
    """
    pred, gt = _to_numpy(pred), _to_numpy(gt)
    if pred.shape != gt.shape or pred.ndim != 3 or pred.shape[2] != 3:
        raise ValueError(f"error_to_rgb: expected two (H, W, 3) images, got {pred.shape} and {gt.shape}")
    if vmax <= 0:
        raise ValueError(f"error_to_rgb: vmax must be positive, got {vmax}")

    def unit(image: np.ndarray) -> np.ndarray:
        return image.astype(np.float64) / 255.0 if image.dtype == np.uint8 else image.astype(np.float64)

    error = np.abs(unit(pred) - unit(gt)).mean(axis=2)
    error = np.where(np.isfinite(error), error, vmax)  # a NaN render is as wrong as it gets
    return _colormap(error / vmax, cv2.COLORMAP_INFERNO)


def _draw_label(panel: np.ndarray, text: str) -> None:
    height = panel.shape[0]
    scale = max(0.35, height / 400.0)
    thickness = max(1, int(round(scale * 1.5)))
    font = cv2.FONT_HERSHEY_SIMPLEX
    (text_w, text_h), baseline = cv2.getTextSize(text, font, scale, thickness)
    margin = max(2, int(round(4 * scale)))
    # White text on a black box: legible on any background, even at 90 pixels of height.
    cv2.rectangle(panel, (0, 0), (text_w + 2 * margin, text_h + baseline + 2 * margin), (0, 0, 0), cv2.FILLED)
    cv2.putText(panel, text, (margin, margin + text_h), font, scale, (255, 255, 255), thickness, cv2.LINE_AA)


def side_by_side(images: Sequence[np.ndarray], labels: Optional[Sequence[str]] = None) -> np.ndarray:
    """Concatenate RGB uint8 ``(H_i, W_i, 3)`` panels left to right -> ``(max H_i, sum W_i, 3)``.

    Shorter panels are padded with black at the bottom. ``labels``: one text per panel (an empty
    string for none), drawn in white on a black box in its top-left corner. The inputs are not
    modified.
    """
    if len(images) == 0:
        raise ValueError("side_by_side: no images")
    if labels is not None and len(labels) != len(images):
        raise ValueError(f"side_by_side: {len(labels)} labels for {len(images)} images")
    panels = []
    for i, image in enumerate(images):
        image = _to_numpy(image)
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"side_by_side: image {i} is {image.dtype} {image.shape}, "
                             f"expected uint8 (H, W, 3)")
        panels.append(image)
    height = max(p.shape[0] for p in panels)
    out = np.zeros((height, sum(p.shape[1] for p in panels), 3), np.uint8)
    x = 0
    for i, panel in enumerate(panels):
        h, w = panel.shape[:2]
        if labels is not None and labels[i]:
            panel = np.ascontiguousarray(panel).copy()  # cv2 draws into contiguous arrays only
            _draw_label(panel, labels[i])
        out[:h, x : x + w] = panel
        x += w
    return out
