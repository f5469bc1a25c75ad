"""The radar objects of one frame as the velocity term's samples (``L_vel``, metrics.losses): each
object's points in the world with its planar velocity and covariance, from the radar stage's
``<prepared>/radar/objects.json`` or, for an upper bound, from the synthetic generator's ground truth
(``radar_source="oracle"``). Used by :func:`radar4dgs.train.fit_motion.collect_velocity_samples`.
"""

from __future__ import annotations

import math

import numpy as np

from radar4dgs.motion.association import associate_nearest
from radar4dgs.radar.objects import RadarObject, optional_radar_objects
from radar4dgs.train.config import FitConfig

# One object of one frame for L_vel: its points (K, 3) world, velocity (2,) and covariance (2, 2).
ObjectPoints = tuple[np.ndarray, np.ndarray, np.ndarray]


def prepared_object_points(scene, index: int, objects: list[RadarObject],
                           fit: FitConfig) -> tuple[list[ObjectPoints], int]:
    """The trusted objects of frame ``index`` (``load_radar_objects`` records: at least
    ``velocity_min_returns`` returns, velocity std ``sqrt(trace S) <= velocity_max_std``) with their
    returns in the world, and how many objects were left out."""
    chosen = [o for o in objects if o.num_returns >= fit.velocity_min_returns
              and math.sqrt(max(float(np.trace(o.velocity_covariance)), 0.0)) <= fit.velocity_max_std]
    if not chosen:
        return [], len(objects)
    xyz = scene.load_radar(index).xyz.astype(np.float64)
    transform = scene.radar_to_world(index)
    frame = scene.frames[index]
    out = []
    for o in chosen:
        world = xyz[o.points] @ transform[:3, :3].T + transform[:3, 3]
        # The returns are where the object was at the radar's capture time; move them to the
        # camera's (the time t_i of the field) with the object's own velocity.
        world = world + o.velocity[None, :3] * (frame.timestamp - frame.radar_timestamp)
        out.append((world, o.velocity[:2].copy(), o.velocity_covariance.copy()))
    return out, len(objects) - len(chosen)


def _inside_boxes(local: np.ndarray, boxes: list[dict], margin: float) -> np.ndarray:
    """(N,) bool: (N, 3) object-frame points inside any of the generator's ``boxes`` grown by ``margin``."""
    inside = np.zeros(len(local), dtype=bool)
    for box in boxes:
        centre, half = np.asarray(box["center"], dtype=np.float64), np.asarray(box["half_size"], dtype=np.float64)
        inside |= (np.abs(local - centre) <= half + margin).all(axis=1)
    return inside


def oracle_object_points(scene, index: int, fit: FitConfig, margin: float = 0.5) -> list[ObjectPoints]:
    """The generator's moving objects in frame ``index`` (scene.json ``extra.synthetic.objects``): the
    gt-dynamic returns inside each object's boxes (grown by ``margin`` m), its true velocity
    (``velocities[index]`` or ``velocity``) and a zero covariance."""
    scan = scene.load_radar(index)
    dynamic = scene.load_optional("gt/radar_labels", index) == 1
    transform = scene.radar_to_world(index)
    world = scan.xyz.astype(np.float64) @ transform[:3, :3].T + transform[:3, 3]
    out = []
    for o in synthetic_objects(scene):
        poses, velocities = o.get("poses") or (), o.get("velocities") or ()
        if o.get("kind") != "moving" or len(poses) <= index or "boxes" not in o:
            continue
        pose = np.asarray(poses[index], dtype=np.float64)
        inside = dynamic & _inside_boxes((world - pose[:3, 3]) @ pose[:3, :3], o["boxes"], margin)
        velocity = np.asarray(velocities[index] if len(velocities) > index else o["velocity"], dtype=np.float64)
        if inside.sum() >= fit.velocity_min_returns:
            out.append((world[inside], velocity[:2], np.zeros((2, 2))))
    return out


def pixels_of_objects(pixels: np.ndarray, objects: list[ObjectPoints], gate: float) -> list[np.ndarray]:
    """Split (M, 3) lifted dynamic pixels (world) among the objects: each pixel goes to the object
    of its nearest return within ``gate`` (m), else to none. One (K_o, 3) array per object."""
    if not objects:
        return []
    returns = np.concatenate([o[0] for o in objects])
    owner = np.repeat(np.arange(len(objects)), [len(o[0]) for o in objects])
    index, _ = associate_nearest(pixels, returns, gate)
    owners = np.where(index >= 0, owner[np.maximum(index, 0)], -1)
    return [pixels[owners == k] for k in range(len(objects))]


def flow_near(returns: np.ndarray, flow_points: np.ndarray | None, gate: float) -> int:
    """How many flow-pair start points (F, 3) lie within ``gate`` (m) of an object's (K, 3) returns."""
    if flow_points is None or len(flow_points) == 0:
        return 0
    _, distance = associate_nearest(flow_points, returns, gate)
    return int(np.isfinite(distance).sum())


def synthetic_objects(scene) -> list[dict]:
    """The generator's object records (scene.json ``extra.synthetic.objects``); [] when absent."""
    synthetic = scene.extra.get("synthetic")
    objects = synthetic.get("objects") if isinstance(synthetic, dict) else None
    return [o for o in objects if isinstance(o, dict)] if isinstance(objects, list) else []


def frame_objects(scene, prepared_dir, fit: FitConfig) -> tuple[list | None, str | None]:
    """Every frame's radar objects from ``objects.json`` (None and a note when absent or stale);
    ``[]`` for the oracle source, whose objects come per frame from the scene."""
    if fit.radar_source == "oracle":
        if not synthetic_objects(scene) or not scene.has("gt/radar_labels"):
            return None, "velocity term off: radar_source 'oracle' needs extra.synthetic.objects and gt/radar_labels"
        return [], None
    per_frame, why = optional_radar_objects(prepared_dir, len(scene))
    return per_frame, None if per_frame is not None else f"velocity term off: {why}"
