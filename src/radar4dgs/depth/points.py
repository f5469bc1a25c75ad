"""The depth stage of a radar-less scene (``convert nerfstudio`` / ``convert colmap``): its point
cloud (``priors/points3d.npy``) stands in for the radar.

With a monocular prior (``priors/mono_depth``, or Depth-Anything-V2 weights on this machine) the
prior is scaled as with radar, the visible points (:func:`point_anchors`) taking the radar
points' place: dense depth, confidence and the fallback sky detector as usual. Without one (the
flat-world prior needs the ground under the ego origin, which a camera-only scene does not have)
the depth is the points' own, sparse:

Each frame's depth map holds, at the pixel each point projects to, the z-depth of the nearest
point there, and NaN elsewhere (unknown: no depth loss there, no initial Gaussian). A point is
dropped as occluded when a point in its 3 x 3 pixel neighbourhood is more than 10 % nearer
(SfM clouds are seen from many viewpoints: the far side of an object projects through its near
side). The depth is in the units of the source's poses (metres only when they are). The sky is
``priors/sky_mask`` when the scene has it (``sky_source`` auto or prior), else there is none: the
weight-free sky detector needs a dense depth prior. Outputs as :func:`radar4dgs.depth.pipeline.write_depth`:
``<frame>.npy`` (NaN unknown, +inf sky), ``<frame>_confidence.npy`` (1 at points, else 0),
``sky/<frame>.png`` and ``summary.json`` with ``"source": "points"``. The radar's near limit
``min_depth`` does not apply to the points (a COLMAP world may be in any unit): any point in
front of the camera and within ``max_depth`` counts.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np
from PIL import Image
from scipy.ndimage import minimum_filter

from radar4dgs.config import save_config
from radar4dgs.depth.config import DepthConfig
from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.io.scene import POINTS_FILE, SceneError

# A point is occluded when a point within OCCLUSION_WINDOW pixels (a square) is nearer than
# 1 / OCCLUSION_RATIO of its depth.
OCCLUSION_WINDOW = 3
OCCLUSION_RATIO = 1.1


def point_depth(points_camera: np.ndarray, K: np.ndarray, height: int, width: int, min_depth: float,
                max_depth: float) -> np.ndarray:
    """(H, W) float32 z-depth of the nearest visible camera-frame point (N, 3) at each pixel it
    projects to (pixel centres at integer coordinates), NaN elsewhere; occluded points dropped."""
    z = points_camera[:, 2]
    front = (z >= min_depth) & (z <= max_depth)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = points_camera[front] @ np.asarray(K, np.float64).T
        u = np.round(uv[:, 0] / uv[:, 2]).astype(np.int64)
        v = np.round(uv[:, 1] / uv[:, 2]).astype(np.int64)
    z = z[front]
    inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    u, v, z = u[inside], v[inside], z[inside]
    depth = np.full((height, width), np.inf)
    np.minimum.at(depth, (v, u), z)
    nearest = minimum_filter(depth, size=OCCLUSION_WINDOW, mode="constant", cval=np.inf)
    depth[depth > OCCLUSION_RATIO * nearest] = np.inf
    depth[~np.isfinite(depth)] = np.nan
    return depth.astype(np.float32)


def visible_points(scene, world: np.ndarray, index: int, max_depth: float) -> np.ndarray:
    """(H, W) :func:`point_depth` of the (M, 3) ``world`` points in frame ``index``."""
    w2c = scene.world_to_camera(index)
    camera = scene.camera
    return point_depth(world @ w2c[:3, :3].T + w2c[:3, 3], camera.K, camera.height, camera.width, 1e-6, max_depth)


def point_anchors(scene, config: DepthConfig) -> Callable[[int], tuple[np.ndarray, np.ndarray, str]]:
    """For :func:`radar4dgs.depth.pipeline.fit_frames`: frame index -> the scene's visible points
    ((N, 3) camera frame, at the centres of the pixels they fall on), all static, "point cloud"."""
    world, _ = scene.load_points()
    K_inv = np.linalg.inv(scene.camera.K)

    def anchors(index: int) -> tuple[np.ndarray, np.ndarray, str]:
        depth = visible_points(scene, world, index, config.max_depth)
        v, u = np.nonzero(np.isfinite(depth))
        rays = K_inv @ np.stack([u, v, np.ones(len(u))]).astype(np.float64)
        return (rays * depth[v, u]).T, np.ones(len(u), bool), "point cloud"

    return anchors


def write_point_depth(scene, depth_dir: str | Path, sky_dir: str | Path, config: DepthConfig | None = None,
                      progress: bool | Callable = False) -> dict:
    """Write the sparse depth, confidence and sky of every frame of the radar-less ``scene`` into
    ``depth_dir`` and ``sky_dir`` (module doc) and return the summary; a :class:`SceneError` when
    the scene has no point cloud either."""
    from radar4dgs.depth.pipeline import _progress, sky_prior, uses_sky_prior

    config = config or DepthConfig()
    if not scene.has_points:
        raise SceneError(scene.root, f"has no radar and no point cloud ({POINTS_FILE}): the depth stage needs one "
                                     f"of them to make the depth metric")
    depth_dir, sky_dir = Path(depth_dir), Path(sky_dir)
    depth_dir.mkdir(parents=True, exist_ok=True)
    sky_dir.mkdir(parents=True, exist_ok=True)
    world, _ = scene.load_points()
    use_sky_prior = uses_sky_prior(scene, config) if config.sky_source != "none" else False
    entries = []
    for i in _progress(range(len(scene)), progress, "depth: points"):
        name = scene.frames[i].name
        depth = visible_points(scene, world, i, config.max_depth)
        sky = sky_prior(scene, i, config, use_sky_prior)
        if sky is None:
            sky = np.zeros(depth.shape, bool)
        depth[sky] = np.inf
        known = np.isfinite(depth)
        np.save(depth_dir / f"{name}.npy", depth)
        np.save(depth_dir / f"{name}_confidence.npy", known.astype(np.float32))
        Image.fromarray(np.where(sky, 255, 0).astype(np.uint8)).save(sky_dir / f"{name}.png")
        entries.append({"name": name, "points": int(known.sum()), "sky_source": "prior" if use_sky_prior else "none",
                        "sky_fraction": float(sky.mean()), "parameters_from": "points", "scale": None})
    summary = {"version": 1, "source": "points", "method": "points",
               "model": f"sparse depth of the scene's point cloud ({POINTS_FILE}): the scene has no radar",
               "num_points": int(len(world)), "num_frames": len(scene), "fallbacks": [],
               "sky_sources": sorted({e["sky_source"] for e in entries}), "frames": entries}
    atomic_write_json(depth_dir / "summary.json", summary)
    save_config(config, depth_dir / "config.json")
    return summary
