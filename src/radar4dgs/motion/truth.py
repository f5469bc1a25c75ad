"""The generator's true motion between any two frames (evaluation and ablations only): each pixel's
surface point from ``gt/depth``, moved by ``gt/flow`` frame by frame. ``gt/flow`` holds one-frame
displacements, so a pair that skips frames (the training pairs skip the held-out test frames) is
composed through the frames in between."""

from __future__ import annotations

import numpy as np

from radar4dgs.io.image_motion import MIN_DEPTH
from radar4dgs.motion.lift import backproject
from radar4dgs.motion.sampling import pixel_grid

# A composed point must still be the visible surface at the intermediate frame (its depth there
# within this many metres of gt/depth) to read that frame's displacement there: gt/flow only holds
# the displacement of what each pixel shows. Occluded or out-of-view points are marked invalid.
VISIBLE_TOLERANCE = 0.3


def project(world: np.ndarray, K: np.ndarray, world_to_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) pixel coordinates and (N,) z-depth of (N, 3) world points."""
    cam = world @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (cam @ np.asarray(K, dtype=np.float64).T)[:, :2] / cam[:, 2:3]
    return uv, cam[:, 2]


def visible_surface(world: np.ndarray, scene, index: int,
                    moving: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Which of (N, 3) world points are the visible surface of frame ``index`` (in view, in front,
    gt depth within VISIBLE_TOLERANCE; with ``moving`` (N,) bool, also on a pixel of the same
    gt/dynamic_mask label), and the (N,) flat pixel index each lands on (nearest).

    The label check matters where a car meets the road: there the car's points and the road's
    pixels have the same depth, and a car point read at a road pixel would stop moving."""
    depth = scene.load_optional("gt/depth", index).astype(np.float64)
    height, width = depth.shape
    uv, z = project(world, scene.camera.K, scene.world_to_camera(index))
    col, row = np.round(uv[:, 0]), np.round(uv[:, 1])
    inside = np.isfinite(uv).all(axis=1) & (col >= 0) & (col < width) & (row >= 0) & (row < height) & (z > MIN_DEPTH)
    flat = np.where(inside, row * width + col, 0).astype(np.int64)
    visible = inside & (np.abs(depth.reshape(-1)[flat] - z) < VISIBLE_TOLERANCE)
    if moving is not None:
        visible &= scene.load_optional("gt/dynamic_mask", index).reshape(-1)[flat] == moving
    return visible, flat


def gt_scene_flow(scene, index: int, next_index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each pixel's true surface point at frame ``index`` and at frame ``next_index`` (> index).

    Returns:
        world_i (H, W, 3), world_j (H, W, 3) float64, and valid (H, W) bool: finite gt depth and,
        for every frame strictly between the two, the moved point was that frame's visible surface.
    """
    if next_index <= index:
        raise ValueError(f"gt scene flow goes forward in time; got frames {index} -> {next_index}")
    depth = scene.load_optional("gt/depth", index).astype(np.float64)
    height, width = depth.shape
    z = depth.reshape(-1)
    valid = np.isfinite(z) & (z > 0)
    world_i = backproject(pixel_grid(height, width).reshape(-1, 2), np.where(valid, z, 1.0), scene.camera.K,
                          scene.world_to_camera(index))
    world = world_i + scene.load_optional("gt/flow", index).astype(np.float64).reshape(-1, 3)
    moving = scene.load_optional("gt/dynamic_mask", index).reshape(-1) if next_index > index + 1 else None
    for k in range(index + 1, next_index):
        visible, flat = visible_surface(world, scene, k, moving)
        valid &= visible
        world = world + scene.load_optional("gt/flow", k).astype(np.float64).reshape(-1, 3)[flat]
    return world_i.reshape(height, width, 3), world.reshape(height, width, 3), valid.reshape(height, width)


def moving_surface_points(scene, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The true surface points (N, 3) world of frame ``index``'s ``gt/dynamic_mask`` pixels with a
    finite positive ``gt/depth``, their one-frame displacement (N, 3) from ``gt/flow``, their pixels
    (N, 2) float64 (column, row) and z-depths (N,); None where the frame has no such pixel."""
    depth = scene.load_optional("gt/depth", index).astype(np.float64)
    mask = scene.load_optional("gt/dynamic_mask", index) & np.isfinite(depth) & (depth > 0)
    if not mask.any():
        return None
    rows, cols = np.nonzero(mask)
    pixels = np.stack([cols, rows], axis=1).astype(np.float64)
    world = backproject(pixels, depth[rows, cols], scene.camera.K, scene.world_to_camera(index))
    return world, scene.load_optional("gt/flow", index).astype(np.float64)[mask], pixels, depth[rows, cols]


def in_boxes(world: np.ndarray, poses: np.ndarray, dims: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """(M, N) bool: which of (N, 3) world points lie in each of M generator boxes at one frame: ``poses``
    (M, 4, 4) box-to-world with the origin on the ground under the box's centre, ``dims`` (M, 3) length,
    width and height in metres, each box grown by ``margin`` on every side."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    dims = np.asarray(dims, dtype=np.float64).reshape(-1, 3)
    world = np.asarray(world, dtype=np.float64)
    # World to box frame: R^T (x - t), batched over the boxes.
    local = np.einsum("mji,mpj->mpi", poses[:, :3, :3], world[None] - poses[:, None, :3, 3])
    low = np.stack([-dims[:, 0] / 2, -dims[:, 1] / 2, np.zeros(len(dims))], axis=1) - margin
    high = np.stack([dims[:, 0] / 2, dims[:, 1] / 2, dims[:, 2]], axis=1) + margin
    return ((local >= low[:, None]) & (local <= high[:, None])).all(axis=2)


def image_flow(moved: np.ndarray, valid: np.ndarray, scene, index: int) -> tuple[np.ndarray, np.ndarray]:
    """The 2D flow (H, W, 2) float64 that takes each pixel to where its moved point (H, W, 3) world
    projects in frame ``index``, and where that is defined (H, W) bool: ``valid`` and in front of
    the camera. Elsewhere the flow is 0."""
    height, width = valid.shape
    uv, z = project(moved.reshape(-1, 3), scene.camera.K, scene.world_to_camera(index))
    defined = valid.reshape(-1) & (z > MIN_DEPTH) & np.isfinite(uv).all(axis=1)
    flow = np.where(defined[:, None], uv - pixel_grid(height, width).reshape(-1, 2), 0.0)
    return flow.reshape(height, width, 2), defined.reshape(height, width)
