"""Per-frame inputs of the segmentation model (projected radar with dynamic flags) and the
training set built from scene folders with ``gt/dynamic_mask``.

Where the dynamic radar points come from (``source``):
    ``prepared``  ``<prepared>/radar/<frame>.npz`` (keys ``dynamic``, ``v_r_comp``; rows aligned
                  with ``scene.load_radar(i)``), written by the radar front end in ``prepare``.
    ``estimate``  the radar front end run here (``estimate_ego_motion`` + ``classify_dynamic``).
    ``oracle``    ``gt/radar_labels == 1`` (ablation only), with the compensated Doppler from the
                  scene's poses.
    ``auto``      ``prepared`` when the file exists, else ``estimate``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radar4dgs.io.preview import radar_points_in_camera
from radar4dgs.io.scene import Scene, SceneWarning
from radar4dgs.radar.classify import compensated_radial_velocity
from radar4dgs.radar.process import load_radar_dynamics_flags
from radar4dgs.segment.config import DynamicSource
from radar4dgs.segment.patches import RadarFrame, make_radar_frame


def radar_velocity_from_poses(scene: Scene, index: int) -> np.ndarray:
    """(3,) velocity (m/s) of the radar in its own axes at frame ``index``, by central finite
    differences of ``radar_to_world`` (rotation's lever-arm effect neglected)."""
    n = len(scene)
    if n < 2:
        return np.zeros(3)
    a, b = max(index - 1, 0), min(index + 1, n - 1)
    dt = scene.frames[b].radar_timestamp - scene.frames[a].radar_timestamp
    pa, pb = scene.radar_to_world(a), scene.radar_to_world(b)
    world_velocity = (pb[:3, 3] - pa[:3, 3]) / dt
    return scene.radar_to_world(index)[:3, :3].T @ world_velocity


def _estimate(xyz: np.ndarray, v_r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from radar4dgs.radar import classify_dynamic, estimate_ego_motion

    ego = estimate_ego_motion(xyz, v_r)
    dynamic, comp = classify_dynamic(xyz, v_r, ego)
    return np.asarray(dynamic, bool), np.asarray(comp, np.float64)


def dynamic_points(scene: Scene, index: int, xyz: np.ndarray, v_r: np.ndarray, source: DynamicSource,
                   prepared_dir: Path | None) -> tuple[np.ndarray, np.ndarray]:
    """(N,) dynamic flags and (N,) compensated radial velocity of frame ``index`` (module doc)."""
    npz = None if prepared_dir is None else Path(prepared_dir) / "radar" / f"{scene.frames[index].name}.npz"
    if source == "prepared" or (source == "auto" and npz is not None and npz.is_file()):
        if npz is None:
            raise FileNotFoundError("dynamic source 'prepared' needs the prepared folder")
        return load_radar_dynamics_flags(npz.parent, npz.stem, len(xyz))
    if source == "oracle":
        labels = scene.load_optional("gt/radar_labels", index)
        return labels == 1, compensated_radial_velocity(xyz, v_r, radar_velocity_from_poses(scene, index))
    if len(xyz) == 0:
        return np.zeros(0, bool), np.zeros(0)
    return _estimate(xyz, v_r)


def load_radar_frame(scene: Scene, index: int, source: DynamicSource = "auto",
                     prepared_dir: Path | None = None) -> RadarFrame:
    """Frame ``index``'s radar points projected into its camera, with dynamic flags from ``source``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)  # the loader's warnings were shown at prepare time
        scan = scene.load_radar(index)
    xyz, v_r = scan.xyz.astype(np.float64), scan.v_r.astype(np.float64)
    dynamic, comp = dynamic_points(scene, index, xyz, v_r, source, prepared_dir)
    rcs = scan.column("rcs") if "rcs" in scan.fields else None
    cam = radar_points_in_camera(scene, index, xyz)
    return make_radar_frame(cam, scene.camera.K, comp, dynamic, rcs)


@dataclass
class TrainFrame:
    """One training frame kept in memory: image (H, W, 3) uint8, gt mask (H, W) bool, radar."""

    image: np.ndarray
    mask: np.ndarray
    radar: RadarFrame
    scene: str
    name: str


def load_train_frames(scene: Scene, source: DynamicSource = "auto", prepared_dir: Path | None = None,
                      frames: list[int] | None = None) -> list[TrainFrame]:
    """Every (or the listed) frame of a scene with ``gt/dynamic_mask`` as training data."""
    if not scene.has("gt/dynamic_mask"):
        raise ValueError(f"{scene.root}: no complete gt/dynamic_mask/ folder; cannot train on it")
    out = []
    for i in frames if frames is not None else range(len(scene)):
        out.append(TrainFrame(scene.load_image(i), scene.load_optional("gt/dynamic_mask", i),
                              load_radar_frame(scene, i, source, prepared_dir), scene.name, scene.frames[i].name))
    return out
