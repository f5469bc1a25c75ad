"""Lifting 2D flow to 3D: metric depth sampled at the flow's targets (refusing depth edges),
back-projection of both ends to world-frame point pairs (pseudo scene flow), and the rejection of
pairs that disagree with the 3D flow of their object."""

from __future__ import annotations

import numpy as np

from radar4dgs.motion.sampling import bilinear_sample


def sample_depth(depth: np.ndarray, xy: np.ndarray, edge_tolerance: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear depth at (M, 2) pixel coordinates, refusing samples across depth edges.

    Returns:
        z (M,) float64 and valid (M,) bool: inside the image, the 4 neighbours finite and positive
        and within ``edge_tolerance`` of each other (max / min - 1), so a sample never blends an
        object's depth with the background's.
    """
    depth = np.asarray(depth, dtype=np.float64)
    height, width = depth.shape
    z, inside = bilinear_sample(np.where(np.isfinite(depth), depth, 0.0), xy)
    u = np.clip(np.floor(np.where(inside, xy[:, 0], 0)).astype(np.int64), 0, max(width - 2, 0))
    v = np.clip(np.floor(np.where(inside, xy[:, 1], 0)).astype(np.int64), 0, max(height - 2, 0))
    corners = np.stack([depth[v, u], depth[v, np.minimum(u + 1, width - 1)],
                        depth[np.minimum(v + 1, height - 1), u],
                        depth[np.minimum(v + 1, height - 1), np.minimum(u + 1, width - 1)]], axis=1)
    finite = np.isfinite(corners).all(axis=1) & (corners > 0).all(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = corners.max(axis=1) / corners.min(axis=1)
    valid = inside & finite & (ratio <= 1 + edge_tolerance)
    return np.where(valid, z, np.nan), valid


def _corner_min(array: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(M,) minimum of (H, W) ``array`` over the 4 bilinear neighbours of each (u, v); -inf outside."""
    height, width = array.shape
    u, v = xy[:, 0], xy[:, 1]
    inside = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u <= width - 1) & (v <= height - 1)
    u0 = np.floor(np.where(inside, u, 0)).astype(np.int64)
    v0 = np.floor(np.where(inside, v, 0)).astype(np.int64)
    u1, v1 = np.minimum(u0 + 1, width - 1), np.minimum(v0 + 1, height - 1)
    values = np.minimum(np.minimum(array[v0, u0], array[v0, u1]), np.minimum(array[v1, u0], array[v1, u1]))
    return np.where(inside, values, -np.inf)


def backproject(pixels: np.ndarray, z: np.ndarray, K: np.ndarray, world_to_cam: np.ndarray) -> np.ndarray:
    """World points of pixels with known z-depth.

    Args:
        pixels: (M, 2) (u, v); z: (M,) z-depth along the optical axis (m); K: (3, 3);
        world_to_cam: (4, 4) OpenCV axes.
    Returns:
        (M, 3) float64 world points.
    """
    K = np.asarray(K, dtype=np.float64)
    x = (pixels[:, 0] - K[0, 2]) / K[0, 0]
    y = (pixels[:, 1] - K[1, 2]) / K[1, 1]
    cam = np.stack([x * z, y * z, z], axis=1)
    cam_to_world = np.linalg.inv(np.asarray(world_to_cam, dtype=np.float64))
    return cam @ cam_to_world[:3, :3].T + cam_to_world[:3, 3]


def lift_flow(flow: np.ndarray, depth_i: np.ndarray, depth_j: np.ndarray, K: np.ndarray,
              world_to_cam_i: np.ndarray, world_to_cam_j: np.ndarray, valid: np.ndarray,
              edge_tolerance: float = 0.1, target_mask: np.ndarray | None = None,
              target_scale: np.ndarray | None = None, target_depth: np.ndarray | None = None,
              target_depth_tolerance: float = 0.2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lift 2D flow i -> j to world-frame 3D point pairs (pseudo scene flow).

    Pixel x of frame i with depth ``depth_i[x]`` gives the world point at time i; its match
    ``x + flow[x]`` in frame j, with ``depth_j`` sampled bilinearly there (see
    :func:`sample_depth`), gives the same surface point at time j. ``points_j - points_i`` is the
    world-frame scene flow.

    Args:
        flow: (H, W, 2) flow i -> j. depth_i, depth_j: (H, W) metric z-depth (inf/NaN/<=0 invalid).
        K: (3, 3). world_to_cam_i, world_to_cam_j: (4, 4).
        valid: (H, W) bool, pixels to lift (e.g. dynamic & forward-backward consistent).
        edge_tolerance: see :func:`sample_depth`.
        target_mask: optional (H, W) bool of frame j; a match must land where its 4 bilinear
            neighbours are all in it (e.g. frame j's dynamic mask).
        target_scale: optional (H, W) factor of frame i's pixels applied to the depth sampled for
            them in ``depth_j`` (one object scale for both ends of a pair).
        target_depth: optional (H, W) depth at j of frame i's pixels from elsewhere (their radar object's
            prediction; NaN: none). It replaces the sample where the two agree within
            ``target_depth_tolerance`` (relative); the sample must still be valid.
    Returns:
        points_i (M, 3), points_j (M, 3) float64 world points and pixels (M, 2) float64 (u, v) of
        the kept pixels: ``valid`` with a finite positive depth_i and a valid depth_j sample.
    """
    height, width = depth_i.shape
    if flow.shape != (height, width, 2) or depth_j.shape != (height, width) or valid.shape != (height, width):
        raise ValueError(f"shapes disagree: flow {flow.shape}, depth_i {depth_i.shape}, "
                         f"depth_j {depth_j.shape}, valid {valid.shape}")
    z_i = np.asarray(depth_i, dtype=np.float64)
    keep = np.asarray(valid, dtype=bool) & np.isfinite(z_i) & (z_i > 0)
    rows, cols = np.nonzero(keep)
    pixels = np.stack([cols, rows], axis=1).astype(np.float64)
    targets = pixels + flow[rows, cols].astype(np.float64)
    z_j, ok = sample_depth(depth_j, targets, edge_tolerance)
    if target_mask is not None:
        # All 4 neighbours inside the mask <=> the bilinear sample of the 0/1 mask is 1.
        corners = _corner_min(np.asarray(target_mask, dtype=np.float64), targets)
        ok &= corners > 0.5
    if target_scale is not None:
        z_j = z_j * np.asarray(target_scale, dtype=np.float64)[rows, cols]
    if target_depth is not None:
        given = np.asarray(target_depth, dtype=np.float64)[rows, cols]
        with np.errstate(invalid="ignore", divide="ignore"):
            agree = np.abs(given / z_j - 1.0) <= target_depth_tolerance  # NaN (none) and invalid samples: False
        z_j = np.where(ok & agree, given, z_j)
    pixels, targets, z_j = pixels[ok], targets[ok], z_j[ok]
    points_i = backproject(pixels, z_i[rows[ok], cols[ok]], K, world_to_cam_i)
    points_j = backproject(targets, z_j, K, world_to_cam_j)
    return points_i, points_j, pixels


def reject_flow_outliers(points_i: np.ndarray, points_j: np.ndarray, pixels: np.ndarray, mask: np.ndarray,
                         min_deviation: float = 0.1, mad_factor: float = 3.0, min_points: int = 3,
                         neighbours: int = 0) -> np.ndarray:
    """(M,) bool: lifted pairs consistent with the median 3D flow around them.

    Args:
        points_i, points_j: (M, 3) lifted pairs; pixels: (M, 2) their (u, v) in frame i;
        mask: (H, W) bool dynamic mask of frame i (its 8-connected components are the objects).
        neighbours: 0 compares each pair with the median flow of its whole component; k > 0 with
            the median of its k nearest pairs of the component (3D distance in frame i, itself
            included), so two objects in one component keep their own motions.
    A pair is kept when |flow - reference median| <= max(min_deviation, mad_factor * 1.4826 *
    median absolute deviation over the component) and its component has >= min_points pairs.
    """
    import cv2
    from scipy.spatial import cKDTree

    keep = np.zeros(len(points_i), dtype=bool)
    if len(points_i) == 0:
        return keep
    _, labels = cv2.connectedComponents(np.asarray(mask, dtype=np.uint8), connectivity=8)
    component = labels[pixels[:, 1].astype(np.int64), pixels[:, 0].astype(np.int64)]
    flow = points_j - points_i
    for label in np.unique(component):
        members = np.nonzero(component == label)[0]
        if label == 0 or len(members) < min_points:  # 0: not on the mask (cannot happen for masked pixels)
            continue
        if neighbours > 0 and len(members) > neighbours:
            _, nearest = cKDTree(points_i[members]).query(points_i[members], k=neighbours)
            reference = np.median(flow[members][nearest], axis=1)
        else:
            reference = np.median(flow[members], axis=0)
        deviation = np.linalg.norm(flow[members] - reference, axis=1)
        bound = max(min_deviation, mad_factor * 1.4826 * float(np.median(deviation)))
        keep[members] = deviation <= bound
    return keep
