"""The run folder's format and its loader: what ``radar4dgs train`` writes and what evaluation,
trajectory rendering, export and the viewer reload.

RUN/
  run.json        {"scene": ..., "prepared": ...}: the inputs the run was trained on
  config.json     the resolved :class:`~radar4dgs.model.config.TrainConfig`
  model.pt        the final :class:`~radar4dgs.model.scene_model.SceneModel`
  history.json    the logged loss terms (LOSS_TERMS) and timings per step
  poses.json      runs that refine poses or appearance (issue 27): per training frame the learned
                  correction (translation m, rotation rad, camera axes), the corrected and the
                  recorded world_to_camera, and the colour transform
  checkpoints/last.pt   the latest resumable state

:func:`load_run` returns the scene with its training frames at the refined poses (poses.json), so
``render``, ``export``, the viewer and ``eval`` use them with no change of their own; test frames
keep their recorded poses.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from radar4dgs.config import load_config
from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.io.devices import resolve_device
from radar4dgs.io.scene import read_scene
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.scene_model import SceneModel, load_model

RUN_FILE = "run.json"
CONFIG_FILE = "config.json"
MODEL_FILE = "model.pt"
CHECKPOINT_DIR = "checkpoints"
LAST_CHECKPOINT = "last.pt"
HISTORY_FILE = "history.json"
POSES_FILE = "poses.json"
# The named terms of the training loss, as logged in history.json.
# pose_smooth, pose_prior, appearance: the regularisers of pose refinement and exposure
# compensation (logged only by runs that refine).
LOSS_TERMS = ("l1", "ssim", "depth", "dynamic_depth", "object", "sky", "over_movers", "flow", "radar", "velocity",
              "acceleration", "pose_smooth", "pose_prior", "appearance", "actor_smooth",
              "actor_heading")


@dataclass
class Run:
    """A trained run folder, reloaded: the scene, its prepared folder, config and model."""

    root: Path
    scene: Any
    prepared: Path
    config: TrainConfig
    model: SceneModel


def load_run(run_dir: str | Path, device: str | None = None) -> Run:
    """Reload ``run_dir`` (written by ``radar4dgs train``); errors name the missing file."""
    root = Path(run_dir)
    for name in (RUN_FILE, CONFIG_FILE, MODEL_FILE):
        if not (root / name).is_file():
            raise FileNotFoundError(f"{root / name}: missing; is {root} a finished `radar4dgs train` run?")
    paths = json.loads((root / RUN_FILE).read_text())
    config = load_config(TrainConfig, root / CONFIG_FILE)
    scene = read_scene(paths["scene"])
    model = load_model(root / MODEL_FILE, device=resolve_device(device or config.device))
    if (root / POSES_FILE).is_file():
        scene = refined_scene(scene, read_refined_poses(root / POSES_FILE))
    return Run(root, scene, Path(paths["prepared"]), config, model)


def read_refined_poses(path: Path) -> dict[int, np.ndarray]:
    """Frame index -> corrected (4, 4) world_to_camera from ``RUN/poses.json`` (empty when the run
    learned only the colour transforms)."""
    try:
        payload = json.loads(Path(path).read_text(encoding="utf-8"))
        if not payload.get("poses_refined", True):
            return {}
        return {int(f["index"]): np.asarray(f["world_to_camera"], dtype=np.float64) for f in payload["frames"]}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: unreadable refined poses ({exc})") from exc


def refined_scene(scene: Any, world_to_camera: dict[int, np.ndarray]) -> Any:
    """``scene`` with frame ``i``'s camera at ``world_to_camera[i]`` (4, 4): its ego pose moved so
    that the camera lands there, and its radar pose moved with it (the radar stays where it was
    relative to the camera)."""
    frames = list(scene.frames)
    ego_from_cam = np.linalg.inv(scene.camera.cam_to_ego)
    for index, w2c in world_to_camera.items():
        frame = frames[index]
        ego_to_world = np.linalg.inv(w2c) @ ego_from_cam
        moved = ego_to_world @ np.linalg.inv(frame.ego_to_world)
        frames[index] = dataclasses.replace(frame, ego_to_world=ego_to_world,
                                            radar_ego_to_world=moved @ frame.radar_ego_to_world)
    return dataclasses.replace(scene, frames=tuple(frames))


def write_refined_poses(root: Path, scene: Any, train_indices: list[int], corrections: np.ndarray | None,
                        appearance: dict[str, Any] | None) -> Path:
    """``RUN/poses.json``: per training frame (rows of ``corrections`` (N, 6) and of the colour
    transforms ``appearance`` {"matrix": (N, 3, 3), "bias": (N, 3)}) the correction, the corrected
    and the recorded world_to_camera, and the transform. ``corrections`` None: poses not refined."""
    import torch

    from radar4dgs.model.pose_refine import correction_summary, se3_exp

    frames = []
    for row, index in enumerate(train_indices):
        recorded = scene.world_to_camera(index)
        entry: dict[str, Any] = {"index": int(index), "name": scene.frames[index].name,
                                 "timestamp": float(scene.frames[index].timestamp),
                                 "recorded_world_to_camera": recorded.tolist()}
        corrected = recorded
        if corrections is not None:
            xi = np.asarray(corrections[row], dtype=np.float64)
            corrected = se3_exp(torch.as_tensor(xi)).numpy() @ recorded
            entry["correction"] = {"translation_m": xi[:3].tolist(), "rotation_rad": xi[3:].tolist()}
        entry["world_to_camera"] = corrected.tolist()
        if appearance is not None:
            entry["appearance"] = {"matrix": np.asarray(appearance["matrix"][row]).tolist(),
                                   "bias": np.asarray(appearance["bias"][row]).tolist()}
        frames.append(entry)
    payload = {"convention": "world_to_camera' = exp(xi) @ world_to_camera, xi = (translation m, rotation rad) "
                             "in camera axes; colours' = (I + matrix) rgb + bias (training frames only)",
               "poses_refined": corrections is not None, "appearance_refined": appearance is not None,
               "summary": None if corrections is None else correction_summary(corrections),
               "frames": frames}
    return atomic_write_json(Path(root) / POSES_FILE, payload)
