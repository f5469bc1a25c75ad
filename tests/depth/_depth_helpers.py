"""Hand-made geometry and tiny scene folders for the depth tests (no synthetic generator needed)."""

from __future__ import annotations

import numpy as np

from radar4dgs.depth.geometry import pixel_grid, pixel_rays
from radar4dgs.io.scene import Camera, Frame, RadarSpec, SceneWriter

WIDTH, HEIGHT = 160, 90
K = np.array([[100.0, 0.0, 79.5], [0.0, 100.0, 44.5], [0.0, 0.0, 1.0]])


def tilted_plane_depth(normal=(0.2, 0.5, 1.0), offset=10.0, width=WIDTH, height=HEIGHT, K=K) -> np.ndarray:
    """(H, W) z-depth of the camera-frame plane n . X = offset (positive over the whole image)."""
    v, u = pixel_grid(width, height)
    rays = pixel_rays(K, u, v)
    return (offset / (rays @ np.asarray(normal, dtype=np.float64))).astype(np.float64)


def points_on_plane(normal, offset: float, count: int, rng: np.random.Generator, width=WIDTH, height=HEIGHT,
                    K=K, margin: float = 2.0) -> np.ndarray:
    """(count, 3) camera points on the plane n . X = offset at random sub-pixel positions."""
    u = rng.uniform(margin, width - 1 - margin, count)
    v = rng.uniform(margin, height - 1 - margin, count)
    rays = pixel_rays(K, u, v)
    return rays * (offset / (rays @ np.asarray(normal, dtype=np.float64)))[:, None]


def road_and_wall_depth(height_m: float = 1.5, wall_z: float = 40.0, wall_top: float = -8.0,
                        width=WIDTH, height=HEIGHT, K=K) -> np.ndarray:
    """(H, W) depth of a flat road (camera y = height_m) and a fronto-parallel wall at z = wall_z
    up to camera y = wall_top; +inf above the wall (sky)."""
    v, u = pixel_grid(width, height)
    rays = pixel_rays(K, u, v)
    depth = np.full((height, width), np.inf)
    with np.errstate(divide="ignore"):
        road = np.where(rays[..., 1] > 0, height_m / rays[..., 1], np.inf)
    wall_hit_y = rays[..., 1] * wall_z
    wall = np.where(wall_hit_y >= wall_top, wall_z, np.inf)
    depth = np.minimum(road, wall)
    return depth


def surface_points(depth: np.ndarray, count: int, rng: np.random.Generator, K=K) -> np.ndarray:
    """(count, 3) camera points on the finite surface of ``depth`` at pixel centres (exact)."""
    v, u = np.nonzero(np.isfinite(depth))
    pick = rng.choice(len(u), size=count, replace=False)
    u, v = u[pick], v[pick]
    rays = pixel_rays(K, u.astype(float), v.astype(float))
    return rays * depth[v, u][:, None]


# ---------------------------------------------------------------------------------------------
# A tiny scene folder: ego drives along world x over a flat road towards a wall, sky above.

CAM_TO_EGO = np.array([[0.0, 0.0, 1.0, 1.5], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 1.5], [0.0, 0.0, 0.0, 1.0]])
RADAR_TO_EGO = np.array([[1.0, 0.0, 0.0, 3.6], [0.0, 1.0, 0.0, 0.2], [0.0, 0.0, 1.0, 0.6], [0.0, 0.0, 0.0, 1.0]])
WALL_X, WALL_TOP = 60.0, 10.0  # world x of the wall, its top height (m)
SPEED = 5.0  # m/s along world x


def ego_pose(t: float) -> np.ndarray:
    pose = np.eye(4)
    pose[0, 3] = SPEED * t
    return pose


def world_depth(pose: np.ndarray, width=WIDTH, height=HEIGHT, K=K) -> tuple[np.ndarray, np.ndarray]:
    """Camera z-depth (H, W) (+inf for sky) and a label map (0 road, 1 wall, 2 sky)."""
    cam_to_world = pose @ CAM_TO_EGO
    v, u = pixel_grid(width, height)
    rays_cam = pixel_rays(K, u, v)
    dirs = rays_cam @ cam_to_world[:3, :3].T  # world direction for unit camera z
    origin = cam_to_world[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_road = np.where(dirs[..., 2] < 0, -origin[2] / dirs[..., 2], np.inf)
        t_wall = np.where(dirs[..., 0] > 0, (WALL_X - origin[0]) / dirs[..., 0], np.inf)
    wall_z = origin[2] + t_wall * dirs[..., 2]
    t_wall = np.where((wall_z >= 0) & (wall_z <= WALL_TOP), t_wall, np.inf)
    depth = np.minimum(t_road, t_wall)  # t is the camera z because rays have z = 1
    labels = np.where(np.isinf(depth), 2, np.where(t_wall < t_road, 1, 0))
    return depth, labels


def render_image(labels: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) uint8: grey road, brown wall, blue sky getting lighter towards the horizon."""
    height, width = labels.shape
    image = np.zeros((height, width, 3), np.float64)
    image[labels == 0] = (105, 105, 110)
    image[labels == 1] = (150, 100, 70)
    rows = np.repeat(np.linspace(0, 1, height)[:, None], width, axis=1)
    sky = labels == 2
    image[sky] = np.stack([90 + 60 * rows, 150 + 50 * rows, np.full_like(rows, 235)], axis=-1)[sky]
    image += rng.normal(0, 3, image.shape)
    return np.clip(image, 0, 255).astype(np.uint8)


def radar_scan(depth: np.ndarray, pose: np.ndarray, rng: np.random.Generator, count: int = 150,
               noise: float = 0.0, ghosts: int = 0, clutter: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(N, 5) radar rows x y z v_r rcs in the radar frame and (N,) int8 labels (0 static, -1
    ghost/clutter). Static points are surface points seen by the camera, with Gaussian noise."""
    points_cam = surface_points(depth, count, rng)
    points_cam = points_cam + rng.normal(0, noise, points_cam.shape)
    labels = [np.zeros(count, np.int8)]
    cam_to_radar = np.linalg.inv(RADAR_TO_EGO) @ CAM_TO_EGO
    points = points_cam @ cam_to_radar[:3, :3].T + cam_to_radar[:3, 3]
    extra = []
    if ghosts:  # mirror images of surface points below the road (multipath)
        src = points[rng.choice(len(points), ghosts)]
        ghost = src.copy()
        ghost[:, 2] = -2 * (RADAR_TO_EGO[2, 3]) - src[:, 2] - rng.uniform(0.5, 2.0, ghosts)
        extra.append(ghost)
        labels.append(np.full(ghosts, -1, np.int8))
    if clutter:
        r = rng.uniform(3, 60, clutter)
        az = rng.uniform(-0.6, 0.6, clutter)
        el = rng.uniform(-0.1, 0.2, clutter)
        extra.append(np.stack([r * np.cos(az) * np.cos(el), r * np.sin(az) * np.cos(el), r * np.sin(el)], 1))
        labels.append(np.full(clutter, -1, np.int8))
    points = np.concatenate([points] + extra)
    v_s = np.array([SPEED, 0.0, 0.0])  # radar velocity in its own frame (no rotation)
    d = points / np.linalg.norm(points, axis=1, keepdims=True)
    v_r = -(d @ v_s)
    rows = np.concatenate([points, v_r[:, None], np.ones((len(points), 1))], axis=1).astype(np.float32)
    return rows, np.concatenate(labels)


def write_scene(out, frames: int = 6, seed: int = 0, prior_a: float = 3.0, prior_b: float = 0.2,
                empty_radar_frames=(), noise: float = 0.02, with_sky_prior: bool = False, ghosts: int = 0,
                clutter: int = 0, prior_kind: str = "inverse") -> None:
    """Write a tiny scene folder with priors/mono_depth = prior_a / z + prior_b (sky: prior_b),
    gt/depth, gt/sky_mask, gt/radar_labels and optionally priors/sky_mask."""
    rng = np.random.default_rng(seed)
    camera = Camera(WIDTH, HEIGHT, K, CAM_TO_EGO)
    spec = RadarSpec(RADAR_TO_EGO, ("x", "y", "z", "v_r", "rcs"))
    with SceneWriter(out) as writer:
        for i in range(frames):
            t = 0.1 * i
            pose = ego_pose(t)
            depth, labels = world_depth(pose)
            image = render_image(labels, rng)
            if i in empty_radar_frames:
                radar, radar_labels = np.zeros((0, 5), np.float32), np.zeros(0, np.int8)
            else:
                radar, radar_labels = radar_scan(depth, pose, rng, noise=noise, ghosts=ghosts, clutter=clutter)
            with np.errstate(divide="ignore"):
                prior = prior_a / depth + prior_b if prior_kind == "inverse" else depth / prior_a
            optional = {"priors_mono_depth": prior.astype(np.float32), "gt_depth": depth.astype(np.float32),
                        "gt_sky_mask": labels == 2, "gt_radar_labels": radar_labels}
            if with_sky_prior:
                optional["priors_sky_mask"] = labels == 2
            frame = Frame(f"{i:06d}", t, pose, t, pose, np.array([SPEED, 0.0, 0.0]))
            writer.add_frame(frame, image, radar, **optional)
        writer.finish("depth-test", camera, spec, source={"dataset": "hand-made"})
