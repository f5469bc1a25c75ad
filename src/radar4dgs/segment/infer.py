"""Dynamic masks for a scene: anchors → patches → network → paste-back by max → threshold.

:func:`prepare_masks` is the front-end step ``prepare`` calls; it writes
``<prepared>/masks/<frame>.png`` (uint8 0/255, 255 = moving object) and, when
``save_prob``, ``<prepared>/masks/<frame>_prob.npy`` (float16 (H, W) probabilities), and
``<prepared>/masks/summary.json``. The shipped checkpoint is loaded unless one is named. With
``config.completion.enabled`` (off by default) the masks are completed with the radar objects of
``<prepared>/radar/objects.json`` (``segment/complete.py``); with ``completion.for_flow`` (on by default) and
``enabled`` off, the completed masks go to ``<prepared>/masks/flow/<frame>.png`` instead, which only
the flow stage reads (``radar4dgs.io.scene_files.FLOW_MASKS``). With ``completion.small_objects`` (on by
default) the masks get a body-sized window at each object of a lasting radar track (a pedestrian's few
returns span no hull), whatever ``enabled`` says.
"""

from __future__ import annotations

import importlib.resources
import io
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import cv2
import numpy as np
import torch

from radar4dgs.config import to_dict
from radar4dgs.io.atomic import atomic_save_npy, atomic_write_bytes, atomic_write_json
from radar4dgs.io.scene import Scene
from radar4dgs.io.scene_files import FLOW_MASKS
from radar4dgs.radar.objects import OBJECTS_FILE, load_radar_objects
from radar4dgs.segment.baseline import BaselineConfig, baseline_frame, depth_for_baseline
from radar4dgs.segment.complete import complete_mask, frame_objects, lasting_tracks
from radar4dgs.segment.config import SegInferConfig
from radar4dgs.segment.dataset import load_radar_frame
from radar4dgs.segment.model import RadarCameraSegNet, model_from_checkpoint
from radar4dgs.segment.patches import (
    RadarFrame,
    candidate_anchors,
    extract_patches,
    paste_max,
    patch_boxes,
    patch_side,
    radar_features,
    resize_patches,
    sample_anchors,
)
from radar4dgs.segment.propagate import propagate_masks

# The checkpoint shipped in the package (segment/weights/), and its card.
DEFAULT_WEIGHTS = "segnet-small.pt"
DEFAULT_CARD = "segnet-small.json"


@dataclass
class FrameSegmentation:
    """One frame's result: ``prob`` (H, W) float32 pasted probabilities, ``anchors`` (K, 2) pixel
    positions of the anchors, ``boxes`` (K, 4) their patches."""

    prob: np.ndarray
    anchors: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))

    def mask(self, threshold: float) -> np.ndarray:
        return self.prob > threshold


def shipped_weight_names() -> list[str]:
    """Names of the weights shipped in the package (``segnet-small``, ``segnet-small-traffic``)."""
    folder = importlib.resources.files("radar4dgs.segment").joinpath("weights")
    return sorted(entry.name[:-3] for entry in folder.iterdir() if entry.name.endswith(".pt"))


def default_checkpoint_bytes(name: str = DEFAULT_WEIGHTS) -> bytes:
    """The bytes of shipped weights ``name`` (``importlib.resources``; the default ones unless named)."""
    resource = importlib.resources.files("radar4dgs.segment").joinpath("weights", name)
    if not resource.is_file():
        raise FileNotFoundError(f"the package ships no segmentation weights {name} (it ships "
                                f"{', '.join(shipped_weight_names()) or 'none'}); train one with "
                                f"`radar4dgs seg-train` and pass its best.pt")
    return resource.read_bytes()


def load_model(checkpoint: Path | str | None = None, device: torch.device | str = "cpu",
               dtype: torch.dtype = torch.float32) -> RadarCameraSegNet:
    """The network of ``checkpoint``: a seg-train checkpoint file, the name of weights shipped in
    the package (:func:`shipped_weight_names`), or the default shipped weights when None."""
    if checkpoint is None:
        payload = torch.load(io.BytesIO(default_checkpoint_bytes()), map_location="cpu", weights_only=True)
    elif not Path(checkpoint).exists() and str(checkpoint) in shipped_weight_names():
        payload = torch.load(io.BytesIO(default_checkpoint_bytes(f"{checkpoint}.pt")), map_location="cpu",
                             weights_only=True)
    elif not Path(checkpoint).is_file():
        raise FileNotFoundError(f"{checkpoint}: no such segmentation checkpoint, and not the name of shipped "
                                f"weights ({', '.join(shipped_weight_names())})")
    else:
        payload = torch.load(checkpoint, map_location="cpu", weights_only=True)
    return model_from_checkpoint(payload, device, dtype)


def patch_batch(image: torch.Tensor, radar: RadarFrame, anchors: np.ndarray, side: int, input_size: int,
                max_points: int, use_rcs: bool) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, np.ndarray]:
    """Network inputs for the anchors of one frame.

    Args:
        image: (3, H, W) float in [0, 1]; radar: projected points; anchors: (K,) point indices.

    Returns:
        patches (K, 3, S, S), points (K, P, F), valid (K, P) bool on ``image``'s device and dtype,
        and boxes (K, 4) int64.
    """
    boxes = patch_boxes(radar.uv[anchors], side)
    patches = extract_patches(image, boxes, input_size)
    feats, valid = radar_features(radar, boxes, anchors, max_points, use_rcs)
    points = torch.as_tensor(feats, device=image.device, dtype=image.dtype)
    return patches, points, torch.as_tensor(valid, device=image.device), boxes


def image_tensor(image: np.ndarray, device: torch.device | str, dtype: torch.dtype) -> torch.Tensor:
    """(H, W, 3) uint8 → (3, H, W) in [0, 1]."""
    return torch.tensor(image, device=device).permute(2, 0, 1).to(dtype) / 255.0


@torch.no_grad()
def segment_frame(model: RadarCameraSegNet, image: np.ndarray, radar: RadarFrame, config: SegInferConfig,
                  rng: np.random.Generator) -> FrameSegmentation:
    """Pasted dynamic probability of one frame; all zeros when no dynamic point is in view.

    Args:
        image: (H, W, 3) uint8 RGB. radar: the frame's projected points. rng: anchor sampling.
    """
    height, width = image.shape[:2]
    candidates = candidate_anchors(radar, width, height)
    if len(candidates) == 0:
        return FrameSegmentation(np.zeros((height, width), np.float32))
    side = patch_side(width, config.patch_scale)
    anchors = sample_anchors(radar.uv, candidates, config.num_anchors, rng, config.anchor_sampling,
                             config.cover_radius * side)
    param = next(model.parameters())
    tensor = image_tensor(image, param.device, param.dtype)
    patches, points, valid, boxes = patch_batch(tensor, radar, anchors, side, model.config.input_size,
                                                config.max_points, model.config.use_rcs)
    prob = resize_patches(torch.sigmoid(model(patches, points, valid)), side)
    if config.anchor_connected:
        prob = prob * torch.as_tensor(anchor_regions(prob.float().cpu().numpy() > config.threshold,
                                                     int(round(config.anchor_radius * side))), device=prob.device)
    pasted = paste_max(prob, boxes, height, width)
    return FrameSegmentation(pasted.float().cpu().numpy(), radar.uv[anchors].copy(), boxes)


def anchor_regions(masks: np.ndarray, radius: int) -> np.ndarray:
    """(K, s, s) bool → the same masks keeping only the 8-connected regions that come within
    ``radius`` px (Chebyshev) of the patch centre pixel ``(s // 2, s // 2)``, where the anchor is.

    A patch should segment the object its anchor lies on; regions elsewhere in the patch (a
    parked car next to a falsely dynamic radar point) are dropped.
    """
    out = np.zeros_like(masks)
    for k, mask in enumerate(masks):
        if not mask.any():
            continue
        _, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
        c = mask.shape[0] // 2
        near = np.unique(labels[max(c - radius, 0):c + radius + 1, max(c - radius, 0):c + radius + 1])
        out[k] = np.isin(labels, near[near > 0])
    return out


def frame_rng(seed: int, index: int) -> np.random.Generator:
    """Anchor sampling generator of frame ``index``: reproducible, independent across frames."""
    return np.random.default_rng([seed, index])


def encode_png(mask: np.ndarray) -> bytes:
    """(H, W) bool → PNG bytes of a uint8 0/255 image."""
    ok, data = cv2.imencode(".png", np.where(mask, 255, 0).astype(np.uint8))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return data.tobytes()


def segment_scene(scene: Scene, prepared_dir: Path | None, config: SegInferConfig,
                  model: RadarCameraSegNet | None = None):
    """Yield (index, FrameSegmentation) for every frame, with the method of ``config``."""
    if config.method == "model" and model is None:
        model = load_model(config.checkpoint, config.device)
    for i in range(len(scene)):
        radar = load_radar_frame(scene, i, config.dynamic_source, prepared_dir)
        image = scene.load_image(i)
        if config.method == "model":
            yield i, segment_frame(model, image, radar, config, frame_rng(config.seed, i))
        else:
            mask = baseline_frame(image, depth_for_baseline(scene, i, prepared_dir), radar, scene.camera.K,
                                  BaselineConfig())
            yield i, FrameSegmentation(mask.astype(np.float32))


def completion_objects(prepared_dir: Path, config: SegInferConfig) -> list | None:
    """The radar objects of every frame for the mask completion, or None when it is off (for the
    masks and for the flow stage) or the prepared folder has no ``radar/objects.json`` (masks made
    without the radar stage: oracle or estimated dynamic points)."""
    wanted = config.completion.enabled or config.completion.for_flow or config.completion.small_objects
    if not wanted or not (prepared_dir / "radar" / OBJECTS_FILE).is_file():
        return None
    return load_radar_objects(prepared_dir)


def prepare_masks(scene: Scene, prepared_dir: str | Path, config: SegInferConfig | None = None,
                  model: RadarCameraSegNet | None = None, out_dir: str | Path | None = None,
                  progress: Callable[[Iterable], Iterable] | None = None) -> dict:
    """Write ``<prepared>/masks/`` (or ``out_dir``) for every frame of ``scene`` (module doc),
    reading the radar and depth stages from ``prepared_dir``. Returns the summary.

    Frames without a dynamic radar point in view get an empty mask. ``progress`` wraps the
    per-frame iterator (a tqdm bar, for example).
    """
    config = config or SegInferConfig()
    out = Path(out_dir) if out_dir is not None else Path(prepared_dir) / "masks"
    out.mkdir(parents=True, exist_ok=True)
    objects = completion_objects(Path(prepared_dir), config)
    completion = config.completion
    hulls = objects is not None and (completion.enabled or completion.for_flow)
    flow_only = hulls and not completion.enabled  # completed masks for masks/flow/ alone
    tracks = lasting_tracks(objects, completion.small_track_frames) if objects is not None else set()
    if flow_only:
        (out / FLOW_MASKS).mkdir(exist_ok=True)
    elif (out / FLOW_MASKS).is_dir():
        shutil.rmtree(out / FLOW_MASKS)  # stale flow masks of an earlier run would mislead the flow stage
    frames, masks, start = [], [], time.perf_counter()
    results = segment_scene(scene, Path(prepared_dir), config, model)
    for i, result in (progress(results) if progress is not None else results):
        name = scene.frames[i].name
        mask = result.mask(config.threshold)
        depth = depth_for_baseline(scene, i, Path(prepared_dir)) if objects is not None else None
        if objects is not None and completion.small_objects:
            small = frame_objects(scene, i, [o for o in objects[i] if o.track in tracks])
            mask = complete_mask(mask, depth, [], scene.camera.K, scene.camera.cam_to_ego, completion, small)
        if hulls:
            completed = complete_mask(mask, depth, frame_objects(scene, i, objects[i]), scene.camera.K,
                                      scene.camera.cam_to_ego, completion)
            if flow_only:
                atomic_write_bytes(out / FLOW_MASKS / f"{name}.png", encode_png(completed))
            else:
                mask = completed
        atomic_write_bytes(out / f"{name}.png", encode_png(mask))
        if config.save_prob:  # completed pixels count as certain, so prob > threshold is the PNG
            atomic_save_npy(out / f"{name}_prob.npy", np.maximum(result.prob, mask).astype(np.float16))
        frames.append({"name": name, "anchors": int(len(result.anchors)), "dynamic_pixels": int(mask.sum())})
        masks.append(mask)
    if config.propagation.enabled:
        _write_propagated(scene, Path(prepared_dir), out, masks, frames, config)
    elapsed = time.perf_counter() - start
    summary = {"config": to_dict(config), "frames": frames, "seconds": round(elapsed, 3),
               "seconds_per_frame": round(elapsed / max(len(frames), 1), 4),
               "completion": "off" if not hulls else f"{FLOW_MASKS} masks" if flow_only else "radar objects",
               "small_objects": "radar tracks" if objects is not None and completion.small_objects else "off",
               "propagation": "small components to neighbouring frames" if config.propagation.enabled else "off"}
    atomic_write_json(out / "summary.json", summary)
    return summary


def _write_propagated(scene: Scene, prepared_dir: Path, out: Path, masks: list[np.ndarray], frames: list[dict],
                      config: SegInferConfig) -> None:
    """Rewrite the frames whose masks :func:`propagate_masks` grew (PNG, probabilities: carried
    pixels count as certain) and note the pixels it added in ``frames``."""
    points = []
    for i in range(len(scene)):
        radar = load_radar_frame(scene, i, config.dynamic_source, prepared_dir)
        points.append(radar.uv[radar.dynamic])
    carried = propagate_masks([scene.load_image(i) for i in range(len(scene))], masks, points, config.propagation)
    for mask, grown, record in zip(masks, carried, frames, strict=True):
        record["propagated_pixels"] = int((grown & ~mask).sum())
        if not record["propagated_pixels"]:
            continue
        record["dynamic_pixels"] = int(grown.sum())
        atomic_write_bytes(out / f"{record['name']}.png", encode_png(grown))
        if config.save_prob:
            prob = np.load(out / f"{record['name']}_prob.npy").astype(np.float32)
            atomic_save_npy(out / f"{record['name']}_prob.npy", np.maximum(prob, grown).astype(np.float16))
