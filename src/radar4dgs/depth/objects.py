"""Prepare stage "object_depth": the metric depth of each moving object rescaled by its own radar returns.

The depth stage fits one inverse-depth scale (and shift) per frame on the *static* radar returns,
because moving points break its consistency checks; the movers then take whatever the monocular
prior's distortion gives them there. On the hard synthetic scenes that is 1-4 % too deep on a car
10 m ahead, and the car's dynamic Gaussians, the depth term and the lifted flow all inherit it. A
rigid object's returns measure its range directly, so each connected component of the prepared
dynamic mask is scaled by the median ratio of its returns' depth to the prepared depth at their
pixels. A return is first moved along its ray by its compensated radial velocity times the
camera-minus-radar time, so a radar that fires before or after the camera does not bias the scale.

Outputs in ``<prepared>/object_depth/`` (written for frames where some object was rescaled; the
readers fall back to ``<prepared>/depth/`` elsewhere: :func:`radar4dgs.io.scene_files.prepared_depth_path`):

    <frame>.npy     float32 (H, W) metric z-depth, the depth stage's with the movers rescaled
    summary.json    per frame: each mask component's pixels, returns, median ratio and whether applied
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np
from scipy import ndimage

from radar4dgs.depth.config import ObjectDepthConfig
from radar4dgs.io.atomic import atomic_save_npy, atomic_write_json
from radar4dgs.io.scene import read_mask_png
from radar4dgs.radar.process import load_radar_dynamics_flags


def returns_at_camera_time(points_world: np.ndarray, radar_origin: np.ndarray, v_r: np.ndarray,
                           dt: float) -> np.ndarray:
    """(N, 3) world positions of radar returns moved along their rays by ``v_r * dt``.

    Args:
        points_world: (N, 3) returns in the world at the radar's capture time.
        radar_origin: (3,) the radar's position in the world then.
        v_r: (N,) ego-compensated radial velocity (m/s, positive away from the radar).
        dt: camera time minus radar time (s).

    Only the radial part of each object's motion is seen by the radar; the tangential part moves the
    return across the object, which changes its depth far less."""
    rays = points_world - radar_origin[None]
    unit = rays / np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-9)
    return points_world + unit * (v_r * dt)[:, None]


def component_scales(depth: np.ndarray, labels: np.ndarray, uv: np.ndarray, z: np.ndarray,
                     config: ObjectDepthConfig) -> list[dict[str, Any]]:
    """One row per mask component: ``label``, ``pixels``, ``returns``, ``ratio`` (median of
    ``z / depth`` over its returns, None without returns) and ``applied``.

    Args:
        depth: (H, W) prepared metric depth.
        labels: (H, W) int component labels (0 = background), as ``scipy.ndimage.label``.
        uv: (N, 2) int pixel (column, row) of each dynamic return, inside the image.
        z: (N,) camera z-depth of each return.
    """
    at_return = labels[uv[:, 1], uv[:, 0]]
    sizes = np.bincount(labels.ravel(), minlength=int(labels.max()) + 1)
    prepared = depth[uv[:, 1], uv[:, 0]]
    rows = []
    for label in range(1, len(sizes)):
        on = (at_return == label) & np.isfinite(prepared) & (prepared > 0)
        ratio = float(np.median(z[on] / prepared[on])) if on.any() else None
        applied = (ratio is not None and int(on.sum()) >= config.min_returns and int(sizes[label]) >= config.min_pixels
                   and abs(ratio - 1.0) <= config.max_correction)
        rows.append({"label": label, "pixels": int(sizes[label]), "returns": int(on.sum()),
                     "ratio": None if ratio is None else round(ratio, 5), "applied": bool(applied)})
    return rows


def rescale_objects(depth: np.ndarray, labels: np.ndarray, rows: list[dict[str, Any]]) -> np.ndarray:
    """(H, W) float32 ``depth`` with each applied component's pixels multiplied by its ratio."""
    factor = np.ones(len(rows) + 1)
    for row in rows:
        if row["applied"]:
            factor[row["label"]] = row["ratio"]
    return (depth * factor[labels]).astype(np.float32)


def frame_returns(scene, index: int, radar_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) int pixels and (N,) camera z-depth of frame ``index``'s dynamic returns that land in
    the image, moved to the camera's capture time (:func:`returns_at_camera_time`)."""
    name = scene.frames[index].name
    scan = scene.load_radar(index)
    dynamic, v_r = load_radar_dynamics_flags(radar_dir, name, len(scan))
    radar_to_world = scene.radar_to_world(index)
    xyz = scan.xyz[dynamic].astype(np.float64)
    world = xyz @ radar_to_world[:3, :3].T + radar_to_world[:3, 3]
    frame = scene.frames[index]
    world = returns_at_camera_time(world, radar_to_world[:3, 3], v_r[dynamic], frame.timestamp - frame.radar_timestamp)
    to_camera = scene.world_to_camera(index)
    camera = world @ to_camera[:3, :3].T + to_camera[:3, 3]
    uv, z = scene.camera.project(camera)
    W, H = scene.camera.width, scene.camera.height
    inside = (z > 0) & np.isfinite(uv).all(axis=1)
    inside &= (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
    return np.floor(uv[inside]).astype(np.int64), z[inside]


def write_object_depth(scene, out_dir: Path, config: ObjectDepthConfig,
                       progress: Callable = lambda items: items) -> dict[str, Any]:
    """Run the stage on every frame: read ``<prepared>/{depth, masks, radar}`` beside ``out_dir``,
    write the rescaled depth of frames with an applied component and ``summary.json``."""
    prepared = out_dir.parent
    shape = (scene.camera.height, scene.camera.width)
    frames = []
    for index in progress(range(len(scene))):
        name = scene.frames[index].name
        entry: dict[str, Any] = {"name": name, "objects": []}
        frames.append(entry)
        if not config.enabled:
            continue
        depth_path = prepared / "depth" / f"{name}.npy"
        depth = np.load(depth_path, allow_pickle=False)
        if depth.shape != shape:
            raise ValueError(f"{depth_path}: depth has shape {depth.shape}, expected {shape}")
        labels, count = ndimage.label(read_mask_png(prepared / "masks" / f"{name}.png", shape))
        if count == 0:
            continue
        uv, z = frame_returns(scene, index, prepared / "radar")
        entry["objects"] = component_scales(depth, labels, uv, z, config)
        if any(row["applied"] for row in entry["objects"]):
            atomic_save_npy(out_dir / f"{name}.npy", rescale_objects(depth, labels, entry["objects"]))
    objects = [row for f in frames for row in f["objects"]]
    applied = [row["ratio"] for row in objects if row["applied"]]
    summary = {"enabled": config.enabled, "frames": frames, "objects": len(objects), "rescaled": len(applied),
               "median_abs_correction": float(np.median(np.abs(np.array(applied) - 1.0))) if applied else 0.0}
    atomic_write_json(out_dir / "summary.json", summary)
    return summary
