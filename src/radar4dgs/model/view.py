"""Cameras to render: a :class:`View` (pose, intrinsics, size, normalised time) and the views of a
scene's frames at a training or evaluation resolution."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class View:
    """One camera to render: ``world_to_camera`` (4, 4) OpenCV axes, ``K`` (3, 3) in the scene's
    convention (pixel centres at integer coordinates), ``width`` x ``height`` pixels, normalised
    time ``time`` in [0, 1]."""

    world_to_camera: np.ndarray
    K: np.ndarray
    width: int
    height: int
    time: float


def scale_intrinsics(K: np.ndarray, scale: float) -> np.ndarray:
    """(3, 3) intrinsics of the image resized by ``scale`` (integer pixel centres kept: pixel
    ``u`` of the resized image covers ``(u + 0.5) / scale - 0.5`` of the original)."""
    K = np.asarray(K, dtype=np.float64).copy()
    K[0, 0] *= scale
    K[1, 1] *= scale
    K[0, 2] = (K[0, 2] + 0.5) * scale - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * scale - 0.5
    return K


def rasterizer_intrinsics(K: np.ndarray) -> np.ndarray:
    """The scene's K with pixel centres moved to +0.5, the rasterizer's (gsplat's) convention."""
    K = np.asarray(K, dtype=np.float64).copy()
    K[0, 2] += 0.5
    K[1, 2] += 0.5
    return K


def resized_size(width: int, height: int, scale: float) -> tuple[int, int]:
    """(width, height) of the image at ``scale`` (at least 1 pixel each)."""
    return max(1, round(width * scale)), max(1, round(height * scale))


def resize_image(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Area-averaged resize of an (H, W, C) or (H, W) image to ``size`` = (width, height)."""
    if image.shape[1] == size[0] and image.shape[0] == size[1]:
        return image
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def resize_nearest(array: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Nearest-neighbour resize (depth keeps real values; masks stay masks)."""
    if array.shape[1] == size[0] and array.shape[0] == size[1]:
        return array
    dtype = array.dtype
    out = cv2.resize(array.astype(np.float32), size, interpolation=cv2.INTER_NEAREST)
    return out.astype(dtype)


def camera_view(camera, world_to_camera: np.ndarray, time: float, scale: float = 1.0) -> View:
    """The :class:`View` of the scene's ``camera`` at pose ``world_to_camera`` (4, 4) and normalised
    ``time``, rendered at ``scale`` of its resolution. K is scaled by the ratio of the rounded
    widths, not by ``scale`` itself, so the focal length matches the image actually rendered."""
    width, height = resized_size(camera.width, camera.height, scale)
    return View(np.asarray(world_to_camera, dtype=np.float64), scale_intrinsics(camera.K, width / camera.width),
                width, height, float(time))


def frame_view(scene, index: int, scale: float, times: np.ndarray) -> View:
    """The :class:`View` of frame ``index`` at resolution ``scale``."""
    return camera_view(scene.camera, scene.world_to_camera(index), times[index], scale)
