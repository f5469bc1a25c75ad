"""Camera geometry for scale recovery: radar-to-camera transforms, pixel rays, back-projection."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def radar_to_camera(cam_to_ego: np.ndarray, radar_to_ego: np.ndarray, ego_to_world: np.ndarray | None = None,
                    radar_ego_to_world: np.ndarray | None = None) -> np.ndarray:
    """(4, 4) transform from the radar frame to the camera frame (OpenCV axes).

    When the radar was captured at another ego pose than the camera (``radar_ego_to_world`` differs
    from ``ego_to_world``), static points are carried through the world frame, which compensates
    the ego motion between the two capture times.
    """
    radar_to_cam = np.linalg.inv(cam_to_ego) @ radar_to_ego
    if ego_to_world is None or radar_ego_to_world is None:
        return radar_to_cam
    ego_cam_from_ego_radar = np.linalg.inv(ego_to_world) @ radar_ego_to_world
    return np.linalg.inv(cam_to_ego) @ ego_cam_from_ego_radar @ radar_to_ego


def transform_points(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (4, 4) transform to (N, 3) points; returns (N, 3) float64."""
    points = np.asarray(points, dtype=np.float64)
    return points @ transform[:3, :3].T + transform[:3, 3]


def pixel_grid(width: int, height: int, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Integer pixel coordinates (v, u) of the (possibly strided) grid, each (h', w') int arrays.

    Pixel centres sit at integer coordinates (OpenCV convention, as ``K`` in the scene format).
    """
    v, u = np.mgrid[0:height:stride, 0:width:stride]
    return v, u


def pixel_rays(K: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., 3) camera rays with z = 1 through pixel coordinates ``u``, ``v`` (same shape)."""
    fx, fy, cx, cy, skew = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    y = (np.asarray(v, dtype=np.float64) - cy) / fy
    x = (np.asarray(u, dtype=np.float64) - cx - skew * y) / fx
    return np.stack([x, y, np.ones_like(x)], axis=-1)


def unit(vectors: np.ndarray) -> np.ndarray:
    """(N, 3) vectors scaled to unit length (zero vectors stay zero)."""
    norm = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return vectors / np.where(norm > 0, norm, 1.0)


class DirectionIndex:
    """The unit-sphere directions of a camera's (strided) pixel grid and their ``cKDTree``.

    The directions depend only on the intrinsics, so one index serves every frame of a scene; a
    frame's visual points are these rays times its (unscaled) depth, and pixels without depth are
    rejected after the query instead of rebuilding the tree per frame.

    Attributes:
        rays: (M, 3) z = 1 rays of the grid pixels (M = h' * w', row-major).
        directions: (M, 3) unit directions.
        flat_index: (M,) index of each grid pixel in the full (H * W) image, row-major.
        tree: ``cKDTree`` over ``directions``.
    """

    def __init__(self, K: np.ndarray, width: int, height: int, stride: int = 1):
        v, u = pixel_grid(width, height, stride)
        self.K = np.asarray(K, dtype=np.float64)
        self.width, self.height, self.stride = int(width), int(height), int(stride)
        self.rays = pixel_rays(self.K, u, v).reshape(-1, 3)
        self.directions = unit(self.rays)
        self.flat_index = (v * width + u).reshape(-1)
        self.tree = cKDTree(self.directions)

    def matches(self, K: np.ndarray, width: int, height: int, stride: int) -> bool:
        return (self.width, self.height, self.stride) == (width, height, stride) and np.allclose(self.K, K)


def project(K: np.ndarray, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project (N, 3) camera points: (N, 2) pixel coordinates (u, v) and (N,) z-depth."""
    z = points_cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (points_cam @ K.T)[:, :2] / z[:, None]
    return uv, z


def bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Sample (H, W) ``image`` at (N, 2) sub-pixel coordinates; NaN outside the image or where a
    contributing pixel is not finite."""
    height, width = image.shape
    u, v = uv[:, 0], uv[:, 1]
    inside = (u >= 0) & (u <= width - 1) & (v >= 0) & (v <= height - 1)
    out = np.full(len(uv), np.nan)
    if not inside.any():
        return out
    u, v = u[inside], v[inside]
    u0 = np.clip(np.floor(u).astype(np.int64), 0, max(width - 2, 0))
    v0 = np.clip(np.floor(v).astype(np.int64), 0, max(height - 2, 0))
    u1, v1 = np.minimum(u0 + 1, width - 1), np.minimum(v0 + 1, height - 1)
    du, dv = u - u0, v - v0
    out[inside] = (image[v0, u0] * (1 - du) * (1 - dv) + image[v0, u1] * du * (1 - dv)
                   + image[v1, u0] * (1 - du) * dv + image[v1, u1] * du * dv)
    return out
