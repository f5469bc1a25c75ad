"""Sky masks without any network weights.

Fallback detector (used when the scene has no ``priors/sky_mask``): a pixel is sky when

1. it is at the far end of the depth prior: its relative inverse depth lies in the lowest
   ``far_fraction`` of the frame's range ``[x_min, x_99.5]`` (Depth-Anything-like priors put the
   sky at their minimum) AND its metric depth after scale recovery is at least ``min_depth`` (or
   the fitted inverse depth is non-positive), so that a far wall in a scene with no sky is kept;
2. its colour fits a Gaussian sky model (RGB mean and covariance) fitted on the far pixels of the
   top ``top_rows`` fraction of rows: squared Mahalanobis distance below ``color_threshold``;
3. it belongs to a connected component (8-connectivity, OpenCV) of such pixels touching the top
   border: the sky is seen above the scene, never enclosed by it.

No far pixels in the top rows (fewer than ``min_seed_pixels``) means no sky in the frame.
"""

from __future__ import annotations

import cv2
import numpy as np


def far_candidates(x: np.ndarray, far_fraction: float, depth: np.ndarray | None = None,
                   depth_valid: np.ndarray | None = None, min_depth: float = 0.0) -> np.ndarray:
    """(H, W) bool: pixels at the far end of relative inverse depth ``x`` (H, W).

    Non-finite or non-positive ``x`` counts as far. With ``depth`` (H, W metric, from the scale
    fit) and ``depth_valid`` (False where the fitted inverse depth was non-positive), a far pixel
    must also be at least ``min_depth`` away or invalid.
    """
    finite = np.isfinite(x)
    far = ~finite | (x <= 0)
    if finite.any():
        values = x[finite]
        lo, hi = float(values.min()), float(np.percentile(values, 99.5))
        far |= finite & (x <= lo + far_fraction * (hi - lo))
    if depth is not None:
        metric_far = depth >= min_depth
        if depth_valid is not None:
            metric_far |= ~depth_valid
        far &= metric_far
    return far


def fit_color_model(image: np.ndarray, seeds: np.ndarray, regularization: float
                    ) -> tuple[np.ndarray, np.ndarray] | None:
    """Gaussian colour model of the ``seeds`` (H, W bool) pixels of ``image`` (H, W, 3 uint8).

    Returns (mean (3,), inverse covariance (3, 3)) in 0-255 units, or None without seeds.
    """
    samples = image[seeds].astype(np.float64)
    if len(samples) == 0:
        return None
    mean = samples.mean(axis=0)
    cov = np.cov(samples, rowvar=False) if len(samples) > 1 else np.zeros((3, 3))
    cov = cov + regularization * np.eye(3)
    return mean, np.linalg.inv(cov)


def mahalanobis2(image: np.ndarray, mean: np.ndarray, inv_cov: np.ndarray) -> np.ndarray:
    """(H, W) squared Mahalanobis distance of every pixel's RGB to the model."""
    diff = image.reshape(-1, 3).astype(np.float64) - mean
    return np.einsum("ij,jk,ik->i", diff, inv_cov, diff).reshape(image.shape[:2])


def top_connected(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of ``mask`` in 8-connected components that touch the top row."""
    count, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    if count <= 1:
        return np.zeros_like(mask, dtype=bool)
    touching = np.unique(labels[0][mask[0]])
    return np.isin(labels, touching[touching > 0])


def fallback_sky_mask(image: np.ndarray, x: np.ndarray, depth: np.ndarray | None = None,
                      depth_valid: np.ndarray | None = None, *, far_fraction: float = 0.04,
                      min_depth: float = 40.0, top_rows: float = 0.1, min_seed_pixels: int = 20,
                      color_threshold: float = 25.0, regularization: float = 36.0) -> np.ndarray:
    """Weight-free sky mask (H, W) bool of one frame (see the module docstring).

    Args:
        image: (H, W, 3) uint8 RGB.
        x: (H, W) relative inverse depth (larger = closer).
        depth, depth_valid: (H, W) metric depth and its validity from the scale fit, or None.
    """
    height = x.shape[0]
    far = far_candidates(x, far_fraction, depth, depth_valid, min_depth)
    rows = max(1, int(round(top_rows * height)))
    seeds = np.zeros_like(far)
    seeds[:rows] = far[:rows]
    if seeds.sum() < min_seed_pixels:
        return np.zeros_like(far)
    model = fit_color_model(image, seeds, regularization)
    sky_colour = mahalanobis2(image, *model) <= color_threshold
    candidates = far & sky_colour
    # Close one-pixel gaps (noise, thin wires) before the connectivity test; never grow beyond
    # the far pixels, where closing could swallow a roof line.
    closed = cv2.morphologyEx(candidates.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8)) > 0
    return top_connected(closed & far)


def mask_iou(prediction: np.ndarray, truth: np.ndarray) -> float:
    """Intersection over union of two (H, W) bool masks; 1.0 when both are empty."""
    prediction, truth = np.asarray(prediction, bool), np.asarray(truth, bool)
    union = np.logical_or(prediction, truth).sum()
    if union == 0:
        return 1.0
    return float(np.logical_and(prediction, truth).sum() / union)
