"""The front camera: intrinsics, mounting, and an exact ray-cast render with its ground truth."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from radar4dgs.datasets.synth import world as W
from radar4dgs.datasets.synth.config import SynthConfig
from radar4dgs.datasets.synth.raycast import NO_HIT, apply, cast, pinhole_windows, rigid, rot_x
from radar4dgs.datasets.synth.shade import albedo, lit, sky_color

# OpenCV camera axes (x right, y down, z forward) expressed in ego axes (x fwd, y left, z up).
CV_TO_EGO = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def intrinsics(config: SynthConfig) -> np.ndarray:
    """(3, 3) K with square pixels and the principal point at the image centre (pixel centres at
    integer coordinates, as OpenCV)."""
    fx = (config.width / 2) / np.tan(np.radians(config.hfov_deg) / 2)
    return np.array([[fx, 0.0, (config.width - 1) / 2], [0.0, fx, (config.height - 1) / 2], [0.0, 0.0, 1.0]])


def cam_to_ego(config: SynthConfig) -> np.ndarray:
    """(4, 4) camera (OpenCV axes) to ego, pitched down by ``camera_pitch_deg``."""
    # Pitching down = rotating about the camera's x axis (right) by +pitch in OpenCV axes.
    return rigid(CV_TO_EGO @ rot_x(-np.radians(config.camera_pitch_deg)), config.camera_xyz)


def pixel_rays(K: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H, W, 3) camera-frame ray directions with unit z, so a hit's ray parameter is its z-depth."""
    u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    return np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)


@dataclass(frozen=True)
class CameraFrame:
    """One rendered frame.

    Attributes:
        image: (H, W, 3) uint8. depth: (H, W) float32 z-depth, +inf for sky.
        sky, dynamic: (H, W) bool. flow: (H, W, 3) float32 world-frame displacement to t + dt.
        points: (H, W, 3) road-frame hit points (NaN for sky). obj: (H, W) owning object (-1 static/sky).
    """

    image: np.ndarray
    depth: np.ndarray
    sky: np.ndarray
    dynamic: np.ndarray
    flow: np.ndarray
    points: np.ndarray
    obj: np.ndarray


def render(world: W.World, config: SynthConfig, K: np.ndarray, cam_to_ego_m: np.ndarray, rays_cam: np.ndarray,
           time: float, dt: float, rng: np.random.Generator) -> CameraFrame:
    """Ray-cast the camera at ``time``; flow is the motion of each seen surface point over ``dt``."""
    height, width = rays_cam.shape[:2]
    prims = world.primitives_at(time)
    cam_to_road = world.ego.pose(time) @ cam_to_ego_m
    road_to_cam = np.linalg.inv(cam_to_road)
    origin = cam_to_road[:3, 3]
    dirs = rays_cam @ cam_to_road[:3, :3].T
    box_windows = pinhole_windows(prims.box_corners(), road_to_cam, K, width, height)
    sphere_windows = pinhole_windows(prims.sphere_corners(), road_to_cam, K, width, height)
    hits = cast(origin, dirs, prims, box_windows, sphere_windows)

    sky = hits.prim == NO_HIT
    surf = ~sky
    t = hits.t[surf]
    d = dirs[surf]
    p = origin + d * t[:, None]
    n = hits.normal[surf]
    prim = hits.prim[surf]
    material, obj = prims.material[prim], prims.obj[prim]
    ray_len = np.linalg.norm(d, axis=1)
    distance = t * ray_len
    # A pixel's footprint on the surface grows with distance and with grazing incidence.
    cos_inc = np.abs(np.einsum("ij,ij->i", n, d)) / ray_len
    footprint = distance / K[0, 0] / np.maximum(cos_inc, 0.08)
    rgb = np.zeros((height, width, 3))
    base = albedo(world, material, obj, prim, prims.color[prim], p, n, footprint, time)
    rgb[surf] = lit(world, base, n, material, distance)
    unit_sky = dirs[sky] / np.linalg.norm(dirs[sky], axis=1, keepdims=True)
    rgb[sky] = sky_color(world, unit_sky)
    noise = rng.normal(0.0, config.image_noise_std, rgb.shape) if config.image_noise_std > 0 else 0.0
    image = np.clip(np.round(rgb * 255.0 + noise), 0, 255).astype(np.uint8)

    points = np.full((height, width, 3), np.nan)
    points[surf] = p
    obj_map = np.full((height, width), -1, dtype=np.int64)
    obj_map[surf] = obj
    dynamic = np.zeros((height, width), bool)
    dynamic[surf] = world.moving(obj, time)
    flow_road = np.zeros((height, width, 3))
    for mover in world.movers:
        sel = obj_map == mover.index
        if mover.moving_at(time) and sel.any():
            # Exact for any trajectory: the rigid motion from this pose to the next one.
            motion = mover.pose(time + dt) @ np.linalg.inv(mover.pose(time))
            flow_road[sel] = apply(motion, points[sel]) - points[sel]
    flow = flow_road @ world.road_to_world[:3, :3].T
    return CameraFrame(image, hits.t.astype(np.float32), sky, dynamic, flow.astype(np.float32), points, obj_map)


def supersampled_image(world: W.World, config: SynthConfig, cam_to_ego_m: np.ndarray, time: float, dt: float,
                       rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) uint8 image whose every pixel is the mean of ``config.supersample``² rays over it.

    The scene is rendered noise-free at ``supersample`` times the size (the intrinsics of that size put the
    fine pixel centres symmetric inside each coarse pixel, and the texture footprint shrinks with them), each
    block of fine pixels is averaged, then the pixel noise is added once, as a sensor adds it.
    """
    factor = config.supersample
    fine = replace(config, width=config.width * factor, height=config.height * factor, image_noise_std=0.0)
    K_fine = intrinsics(fine)
    view = render(world, fine, K_fine, cam_to_ego_m, pixel_rays(K_fine, fine.width, fine.height), time, dt, rng)
    # Averaging the fine image's 8-bit values adds at most half a level of rounding, below the sensor noise.
    mean = view.image.astype(np.float64).reshape(config.height, factor, config.width, factor, 3).mean(axis=(1, 3))
    noise = rng.normal(0.0, config.image_noise_std, mean.shape) if config.image_noise_std > 0 else 0.0
    return np.clip(np.round(mean + noise), 0, 255).astype(np.uint8)
