"""Pixel grids and bilinear sampling at continuous pixel coordinates (pixel centres at integers,
OpenCV convention), shared by the consistency check, the object matching and the lifting."""

from __future__ import annotations

import numpy as np


def pixel_grid(height: int, width: int) -> np.ndarray:
    """(H, W, 2) float64 (u, v) coordinates of every pixel centre."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    return np.stack([u, v], axis=-1)


def bilinear_sample(array: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear samples of ``array`` at continuous pixel coordinates.

    Args:
        array: (H, W) or (H, W, C).
        xy: (M, 2) (u, v) coordinates, pixel centres at integers.
    Returns:
        values (M,) or (M, C) float64 (0 where outside), inside (M,) bool: all 4 neighbours exist.
    """
    array = np.asarray(array)
    height, width = array.shape[:2]
    u, v = xy[:, 0].astype(np.float64), xy[:, 1].astype(np.float64)
    inside = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u <= width - 1) & (v <= height - 1)
    u = np.where(inside, u, 0.0)
    v = np.where(inside, v, 0.0)
    # Clamp the upper neighbour so u == W - 1 samples the last column with weight 1.
    u0 = np.minimum(np.floor(u).astype(np.int64), width - 2 if width > 1 else 0)
    v0 = np.minimum(np.floor(v).astype(np.int64), height - 2 if height > 1 else 0)
    u1, v1 = np.minimum(u0 + 1, width - 1), np.minimum(v0 + 1, height - 1)
    du, dv = u - u0, v - v0
    if array.ndim == 3:
        du, dv = du[:, None], dv[:, None]
    a = array.astype(np.float64, copy=False)
    values = ((1 - du) * (1 - dv) * a[v0, u0] + du * (1 - dv) * a[v0, u1]
              + (1 - du) * dv * a[v1, u0] + du * dv * a[v1, u1])
    values = np.where(inside[:, None] if array.ndim == 3 else inside, values, 0.0)
    return values, inside
