"""Radar-object mask completion: grow the network's mask over the image hull of a tracked object's returns.

The network segments 26 px patches around dynamic radar points; a car passing close by fills much
more of the image than the patches cover, and its motion blur between frames hides its edges, so
its mask often covers a third of it (issue 24). The radar stage has already grouped its returns into
an object (``<prepared>/radar/objects.json``), so the object's extent in the image is known from the
returns themselves: the convex hull of their projections, grown by ``margin_m`` (metres at the
object's depth, so a near car grows more pixels than a far one). Inside that hull a pixel is added
when its prepared metric depth lies within ``depth_tolerance_m`` of the returns' depth range (the
buildings seen through the hull's corners stay out) and its back-projected point stands at least
``min_height_m`` above the ego frame's ground plane ``z = 0`` (assumed at road level, as in the
synthetic scenes; an origin above the road only drops the lowest part of a car). The height gate
matters most: on realistic seed 101 the depth gate alone let in 4.5 road
pixels per car pixel gained (the road under a car is at the car's depth); above 0.15 m only 1 % of
those remain and 98 % of the car pixels.
"""

from __future__ import annotations

import warnings

import cv2
import numpy as np

from radar4dgs.io.preview import radar_points_in_camera
from radar4dgs.io.scene import SceneWarning
from radar4dgs.segment.config import CompletionConfig


def project_points(cam: np.ndarray, K: np.ndarray, min_depth: float) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) camera-frame points (OpenCV axes) → (M, 2) pixel positions and (M,) depths of the
    points at least ``min_depth`` in front of the camera."""
    cam = np.asarray(cam, dtype=np.float64)
    front = cam[:, 2] >= min_depth
    z = cam[front, 2]
    uv = cam[front] @ np.asarray(K, dtype=np.float64).T
    return uv[:, :2] / z[:, None], z


def object_hull_mask(uv: np.ndarray, z: np.ndarray, K: np.ndarray, shape: tuple[int, int],
                     config: CompletionConfig) -> np.ndarray:
    """(H, W) bool: the convex hull of one object's projected returns ``uv`` (M, 2), grown by
    ``margin_m`` at their median depth ``z`` (M,), kept where nothing says it is not that object
    (the depth gate is applied by :func:`complete_mask`). Empty with fewer than ``min_returns``."""
    height, width = shape
    hull_mask = np.zeros(shape, np.uint8)
    if len(uv) < config.min_returns:
        return hull_mask.astype(bool)
    hull = cv2.convexHull(np.round(uv).astype(np.int32).reshape(-1, 1, 2))
    cv2.fillConvexPoly(hull_mask, hull, 1)
    margin = int(round(config.margin_m * float(K[0, 0]) / max(float(np.median(z)), 1e-3)))
    if margin > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
        hull_mask = cv2.dilate(hull_mask, kernel)
    return hull_mask.astype(bool)


def pixel_heights(depth: np.ndarray, K: np.ndarray, cam_to_ego: np.ndarray) -> np.ndarray:
    """(H, W) height (m, ego z) of each pixel's back-projected point at metric ``depth`` (H, W)."""
    height, width = depth.shape
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    K = np.asarray(K, dtype=np.float64)
    rot, shift = np.asarray(cam_to_ego, dtype=np.float64)[2, :3], float(cam_to_ego[2, 3])
    ray_z = rot[0] * (u - K[0, 2]) / K[0, 0] + rot[1] * (v - K[1, 2]) / K[1, 1] + rot[2]
    with np.errstate(invalid="ignore"):
        return ray_z * depth + shift


def complete_mask(mask: np.ndarray, depth: np.ndarray | None, objects: list[tuple[np.ndarray, np.ndarray]],
                  K: np.ndarray, cam_to_ego: np.ndarray, config: CompletionConfig,
                  small: list[tuple[np.ndarray, np.ndarray]] = ()) -> np.ndarray:
    """The base ``mask`` (H, W) bool or-ed with every object's depth- and height-gated hull, and with the
    body-sized window of every ``small`` object (:func:`body_window`).

    Args:
        depth: (H, W) metric depth of the frame (the depth stage's), or None (then no completion:
            an ungated hull would swallow the road around the car).
        objects: per object, (M, 2) projected returns and (M,) their depths (:func:`project_points`).
        cam_to_ego: (4, 4) camera (OpenCV axes) to ego transform, for the height gate.
        small: the same for the objects completed over a body-sized window (``config.small_objects``).
    """
    if depth is None or not (objects or small):
        return mask
    out = mask.copy()
    heights = pixel_heights(depth, K, cam_to_ego)
    regions = [(object_hull_mask(uv, z, K, mask.shape, config), z, np.inf) for uv, z in objects]
    regions += [(body_window(uv, z, K, mask.shape, config), z, config.body_height_m) for uv, z in small]
    for region, z, top in regions:
        if not region.any():
            continue
        near, far = float(np.min(z)) - config.depth_tolerance_m, float(np.max(z)) + config.depth_tolerance_m
        with np.errstate(invalid="ignore"):
            out |= region & (heights >= config.min_height_m) & (heights <= top) & (depth >= near) & (depth <= far)
    return out


def body_window(uv: np.ndarray, z: np.ndarray, K: np.ndarray, shape: tuple[int, int],
                config: CompletionConfig) -> np.ndarray:
    """(H, W) bool: the image columns within ``body_width_m / 2`` (at the returns' median depth ``z`` (M,))
    of the mean column of an object's projected returns ``uv`` (M, 2), every row (the height gate of
    :func:`complete_mask` bounds them). Empty without returns in the image."""
    window = np.zeros(shape, dtype=bool)
    if len(uv) == 0:
        return window
    centre = float(np.mean(uv[:, 0]))
    half = 0.5 * config.body_width_m * float(K[0, 0]) / max(float(np.median(z)), 1e-3)
    low, high = max(int(np.ceil(centre - half)), 0), min(int(np.floor(centre + half)) + 1, shape[1])
    if high > low and 0 <= np.mean(uv[:, 1]) < shape[0]:
        window[:, low:high] = True
    return window


def lasting_tracks(objects: list[list], min_frames: int) -> set[int]:
    """Track ids seen in at least ``min_frames`` frames of ``objects`` (per frame, its radar objects;
    in the camera's view or not)."""
    from collections import Counter

    counts = Counter(track for frame in objects for track in {o.track for o in frame})
    return {track for track, count in counts.items() if count >= min_frames}


def frame_objects(scene, index: int, objects: list, min_depth: float = 0.5) -> list[tuple[np.ndarray, np.ndarray]]:
    """Projected returns (uv (M, 2), depth (M,)) of each radar object of frame ``index``; ``objects``
    are that frame's :class:`radar4dgs.radar.objects.RadarObject` (their inlier and outlier rows
    index ``scene.load_radar(index)``, the clock-synced scene the masks stage gets)."""
    if not objects:
        return []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)  # shown at prepare time already
        xyz = scene.load_radar(index).xyz.astype(np.float64)
    out = []
    for obj in objects:
        rows = np.concatenate([obj.points, obj.outliers]).astype(np.int64)
        rows = rows[(rows >= 0) & (rows < len(xyz))]
        out.append(project_points(radar_points_in_camera(scene, index, xyz[rows]), scene.camera.K, min_depth))
    return out
