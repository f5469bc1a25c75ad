"""How far dynamic pixels move in the image from one frame to the next, from a scene's ground truth.

A pixel ``p`` of frame ``i`` marked in ``gt/dynamic_mask`` sees the world point ``X`` (its
``gt/depth`` along the camera ray, through the camera pose); the point moves to ``X + flow``
(``gt/flow``) by frame ``i + 1``, where it projects to ``p'``. The image motion is ``|p' - p|``
in pixels: object motion and ego motion together, as an optical-flow network or a renderer sees
it. Real traffic at 10 Hz moves dynamic pixels by tens to hundreds of pixels per frame.
"""

from __future__ import annotations

import math

import numpy as np

from radar4dgs.io.scene_types import Scene

MIN_DEPTH = 0.1  # a moved point closer than this to the next camera's plane does not project (m)
# Bins of image motion (px per frame at a 320 px wide image) that errors are reported in: still to
# barely moving, a lead car closing in, a car crossing a lane's width, a car passing close.
# Scaled with the image width (:func:`image_motion_edges`), so a bin means the same motion at any size.
IMAGE_MOTION_EDGES = (0.0, 2.0, 10.0, 30.0, math.inf)
IMAGE_MOTION_REFERENCE_WIDTH = 320


def image_motion_edges(width: int, edges: tuple[float, ...] = IMAGE_MOTION_EDGES) -> list[float]:
    """``edges`` (px per frame at a 320 px wide image) for an image ``width`` px wide."""
    return [e * width / IMAGE_MOTION_REFERENCE_WIDTH for e in edges]


def lands_in_image(positions: np.ndarray, width: int, height: int) -> np.ndarray:
    """(...) bool: which (..., 2) pixel positions (u, v) land inside a ``width`` x ``height`` image
    (pixel centres at integers, edges inclusive)."""
    u, v = positions[..., 0], positions[..., 1]
    return (u >= -0.5) & (u <= width - 0.5) & (v >= -0.5) & (v <= height - 0.5)


def project_motion(K: np.ndarray, cam_to_world: np.ndarray, world_to_next_cam: np.ndarray, uv: np.ndarray,
                   depth: np.ndarray, flow: np.ndarray, inside: tuple[int, int] | None,
                   with_keep: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """(K,) image displacement (px) of pixels moved by their world flow into the next camera.

    Args:
        K: (3, 3) intrinsics (both frames). cam_to_world: (4, 4) camera of the first frame.
        world_to_next_cam: (4, 4) camera of the next frame. uv: (N, 2) pixel coordinates.
        depth: (N,) z-depth. flow: (N, 3) world-frame displacement (m).
        inside: (width, height) to keep only pixels that land inside the next image; None: keep
            every pixel in front of the next camera.
    Returns:
        (K,) float64, K <= N: the displacement of the kept pixels, in input order; with
        ``with_keep``, first the (N,) bool of the kept pixels.
    """
    rays = np.column_stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(uv))])
    world = (rays * depth[:, None]) @ cam_to_world[:3, :3].T + cam_to_world[:3, 3] + flow
    cam = world @ world_to_next_cam[:3, :3].T + world_to_next_cam[:3, 3]
    front = cam[:, 2] > MIN_DEPTH
    with np.errstate(divide="ignore", invalid="ignore"):
        moved = (cam @ K.T)[:, :2] / cam[:, 2:3]
    keep = front
    if inside is not None:
        keep = keep & lands_in_image(moved, *inside)
    displacement = np.linalg.norm(moved[keep] - uv[keep], axis=1)
    return (keep, displacement) if with_keep else displacement


def dynamic_pixel_motion_map(scene: Scene, index: int, inside_only: bool = True) -> np.ndarray:
    """(H, W) float64 image motion (px) from frame ``index`` to ``index + 1`` of the pixels that
    ``gt/dynamic_mask`` marks, from ``gt/depth`` and ``gt/flow``; NaN elsewhere (static pixels, no
    depth, no correspondence) and on the whole last frame, which has no next frame.

    ``inside_only``: keep only pixels whose point lands inside the next image (an image
    correspondence exists); otherwise every pixel whose point stays in front of the next camera.
    Raises the scene's error when a gt folder is missing.
    """
    camera = scene.camera
    motion = np.full((camera.height, camera.width), np.nan)
    if index >= len(scene) - 1:
        return motion
    mask = scene.load_optional("gt/dynamic_mask", index)
    depth = scene.load_optional("gt/depth", index).astype(np.float64)
    mask = mask & np.isfinite(depth)
    if not mask.any():
        return motion
    flow = scene.load_optional("gt/flow", index).astype(np.float64)
    v, u = np.nonzero(mask)
    cam_to_world = np.linalg.inv(scene.world_to_camera(index))
    inside = (camera.width, camera.height) if inside_only else None
    keep, displacement = project_motion(camera.K, cam_to_world, scene.world_to_camera(index + 1),
                                        np.column_stack([u, v]).astype(np.float64), depth[v, u], flow[v, u],
                                        inside, with_keep=True)
    motion[v[keep], u[keep]] = displacement
    return motion


def dynamic_pixel_motion(scene: Scene, index: int, inside_only: bool = True) -> np.ndarray:
    """(K,) the finite values of :func:`dynamic_pixel_motion_map`, in row-major pixel order; the
    last frame gives an empty array."""
    motion = dynamic_pixel_motion_map(scene, index, inside_only)
    return motion[np.isfinite(motion)]


def scene_dynamic_pixel_motion(scene: Scene, inside_only: bool = True) -> np.ndarray:
    """(K,) the displacements of :func:`dynamic_pixel_motion` over every frame of ``scene``, pooled."""
    parts = [dynamic_pixel_motion(scene, i, inside_only) for i in range(len(scene) - 1)]
    return np.concatenate(parts) if parts else np.zeros(0)
