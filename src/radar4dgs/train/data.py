"""What the trainer supervises with, from the scene and its prepared folder.

Per training frame: the image, the radar-scaled depth, the sky mask and the predicted dynamic mask
(all at the training resolution), the camera and its pixel ray directions, read from disk when the
frame is drawn and kept in a bounded cache (:class:`FrameTargetCache`), so that memory does not grow
with the length of the drive; the dynamic masks are read when asked for (:class:`FrameMasks`). For
the field (loaded once: a few samples per dynamic pixel, not per pixel): the
lifted pseudo scene-flow pairs of ``prepared/flow`` and the radar-associated dynamic points
(the standalone motion fit's own samplers, so the two fits see the same data).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Iterator, Mapping, Sequence

import numpy as np
import torch
from torch import Tensor

from radar4dgs.io.scene import SceneError, normalized_times, read_mask_png
from radar4dgs.io.scene_files import prepared_depth_path
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.gaussians import require_prepared
from radar4dgs.model.sky import camera_ray_directions
from radar4dgs.model.view import View, frame_view, resize_image, resize_nearest
from radar4dgs.motion.config import FlowConfig
from radar4dgs.motion.flow import load_flow_pairs
from radar4dgs.train.fit_motion import (
    FitConfig,
    FlowSamples,
    RadarSamples,
    VelocitySamples,
    collect_radar_samples,
    collect_velocity_samples,
    flow_samples_from_pairs,
)
from radar4dgs.train.path_prior import PathSamples, observed_path_samples


@dataclass
class FrameTargets:
    """Supervision of one frame: ``image`` (H, W, 3) in [0, 1], ``depth`` (H, W) metres (NaN where
    unknown), ``sky`` (H, W) bool, ``dynamic`` (H, W) bool, ``directions`` (H, W, 3) world rays."""

    index: int
    name: str
    view: View
    image: Tensor
    depth: Tensor
    sky: Tensor
    dynamic: Tensor
    directions: Tensor


BASELINE_MASK_DIR = "masks_baseline"


def baseline_mask_dir(scene, prepared: Path, progress: bool = False) -> Path:
    """``prepared/masks_baseline``: the non-learned radar flood-fill masks of every frame, computed
    once (atomically, from the prepared radar and depth) and reused after."""
    from radar4dgs.io.atomic import atomic_directory
    from radar4dgs.segment.infer import SegInferConfig, prepare_masks

    folder = Path(prepared) / BASELINE_MASK_DIR
    if (folder / "summary.json").is_file():
        return folder
    with atomic_directory(folder, overwrite=True) as tmp:
        wrap = None
        if progress:
            from tqdm import tqdm

            def wrap(items):
                return tqdm(items, total=len(scene), desc="baseline masks", unit="frame", leave=False)
        prepare_masks(scene, prepared, SegInferConfig(method="baseline", save_prob=False), out_dir=tmp, progress=wrap)
    return folder


class FrameMasks(Mapping[int, np.ndarray]):
    """Frame index -> its (H, W) bool dynamic mask, read by ``read(index)`` each time it is asked
    for: the masks of a long drive are never all in memory at once."""

    def __init__(self, read: Callable[[int], np.ndarray], indices: Iterable[int]):
        self._read, self._indices = read, list(indices)
        self._known = set(self._indices)

    def __getitem__(self, index: int) -> np.ndarray:
        if index not in self._known:
            raise KeyError(index)
        return self._read(index)

    def __iter__(self) -> Iterator[int]:
        return iter(self._indices)

    def __len__(self) -> int:
        return len(self._indices)


def dynamic_masks(scene, prepared: Path, source: str, indices, progress: bool = False) -> FrameMasks:
    """The (H, W) bool dynamic mask of each frame in ``indices`` from ``source``: "predicted"
    (``prepared/masks``), "baseline" (:func:`baseline_mask_dir`) or "gt" (``gt/dynamic_mask``),
    read when asked for; a missing mask file is named here, before training starts."""
    prepared = Path(prepared)
    shape = (scene.camera.height, scene.camera.width)
    if source == "gt":
        if not scene.has("gt/dynamic_mask"):
            raise FileNotFoundError(f"{scene.root / 'gt' / 'dynamic_mask'}: the scene has no ground-truth "
                                    f"masks for mask_source gt")
        return FrameMasks(lambda i: scene.load_optional("gt/dynamic_mask", i).astype(bool), indices)
    if source == "baseline":
        folder = baseline_mask_dir(scene, prepared, progress)
    elif source == "predicted":
        folder = prepared / "masks"
    else:
        raise ValueError(f"unknown mask source {source!r}; choose predicted, baseline or gt")
    for i in indices:
        require_prepared(folder / f"{scene.frames[i].name}.png", "dynamic mask")
    return FrameMasks(lambda i: read_mask_png(folder / f"{scene.frames[i].name}.png", shape), indices)


class FrameTargetCache(Sequence[FrameTargets]):
    """The training frames' :class:`FrameTargets`: item ``k`` is loaded by ``load(k)`` when asked
    for and kept among the ``size`` most recently used ones (0 keeps every frame), so that a long
    drive's images, depth and masks are not all held in memory. ``loads`` counts the loads."""

    def __init__(self, load: Callable[[int], FrameTargets], count: int, size: int):
        if size < 0:
            raise ValueError(f"frame_cache must be >= 0, got {size}")
        self._load, self._count, self.size = load, int(count), int(size)
        self._cached = functools.lru_cache(maxsize=self.size or None)(self._counted_load)
        self.loads = 0

    def _counted_load(self, k: int) -> FrameTargets:
        self.loads += 1
        return self._load(k)

    def __len__(self) -> int:
        return self._count

    @property
    def held(self) -> int:
        """How many frames' targets are in memory now."""
        return self._cached.cache_info().currsize

    def __getitem__(self, k):  # type: ignore[override]
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(self._count))]
        if not -self._count <= k < self._count:
            raise IndexError(f"frame {k} of {self._count}")
        return self._cached(int(k) % self._count)


def load_frame_targets(scene, prepared: Path, index: int, scale: float, times: np.ndarray,
                       device: torch.device, dtype: torch.dtype, dynamic: np.ndarray) -> FrameTargets:
    """:class:`FrameTargets` of frame ``index`` from the scene and ``prepared``; ``dynamic`` (H, W)
    bool is its dynamic mask (from :func:`dynamic_masks`, read once per run)."""
    name = scene.frames[index].name
    H, W = scene.camera.height, scene.camera.width
    view = frame_view(scene, index, scale, times)
    size = (view.width, view.height)
    image = resize_image(scene.load_image(index).astype(np.float32) / 255.0, size)
    depth_path = require_prepared(prepared_depth_path(prepared, name), "depth")
    depth = np.load(depth_path).astype(np.float32)
    if depth.shape != (H, W):
        raise ValueError(f"{depth_path}: shape {depth.shape}, expected {(H, W)}")
    sky = read_mask_png(require_prepared(prepared / "depth" / "sky" / f"{name}.png", "sky mask"), (H, W))
    depth, sky, dynamic = (resize_nearest(a, size) for a in (depth, sky, dynamic))
    kw = {"device": device}
    return FrameTargets(
        index=index, name=name, view=view,
        image=torch.as_tensor(image, dtype=dtype, **kw),
        depth=torch.as_tensor(depth, dtype=dtype, **kw),
        sky=torch.as_tensor(sky, **kw), dynamic=torch.as_tensor(dynamic, **kw),
        directions=camera_ray_directions(view.K, view.world_to_camera, view.height, view.width,
                                         device=device, dtype=dtype),
    )


@dataclass
class MotionTargets:
    """The field's supervision as arrays (each may be None when absent); ``velocity_*`` the
    ``L_vel`` settings (FitConfig's) it was sampled with."""

    flow: FlowSamples | None
    radar: RadarSamples | None
    stats: dict
    velocity: VelocitySamples | None = None
    velocity_position_std: float = FitConfig.velocity_position_std
    velocity_huber: float = FitConfig.velocity_huber
    path: PathSamples | None = None


def load_motion_targets(scene, prepared: Path, config: TrainConfig) -> MotionTargets:
    """Lifted flow pairs (``prepared/flow``) and radar-associated dynamic points of every training
    frame pair, and (``losses.velocity_weight > 0``) the radar objects' points with their velocity;
    each is None when the scene has none (no dynamic pixels, no flow folder, no objects.json).
    A scene without radar is refused (a SceneError naming it): its masks are empty and it has no
    L_rad, so the field would learn nothing."""
    if not scene.has_radar:
        raise SceneError(scene.root, "has no radar (--method ours and its ours-* ablations need it: it finds "
                                     "the moving objects); train it with --method static, deformable or pvg")
    times = normalized_times(scene)
    flow = None
    stats: dict = {}
    if (prepared / "flow").is_dir():
        flow = flow_samples_from_pairs(load_flow_pairs(prepared), times)
        stats["flow_pairs"] = len(flow)
    fit = FitConfig(radar_gate=config.losses.radar_gate, radar_points_per_frame=config.losses.radar_points_per_frame,
                    radar_returns_as_points=config.losses.radar_returns_as_points, seed=config.seed)
    radar, radar_stats = collect_radar_samples(scene, prepared, FlowConfig(), fit, times)
    stats.update(radar_stats)
    velocity = None
    if config.losses.velocity_weight > 0:
        velocity, velocity_stats = collect_velocity_samples(scene, prepared, FlowConfig(), fit, times)
        stats.update(velocity_stats)
    flow = flow if flow is not None and len(flow) else None
    path = None
    if config.losses.acceleration_weight > 0:
        path = observed_path_samples(flow, radar, times, config.losses.acceleration_reach)
    return MotionTargets(flow, radar if len(radar) else None, stats,
                         velocity if velocity is not None and len(velocity) else None,
                         fit.velocity_position_std, fit.velocity_huber, path)
