"""Three-stage training of the Gaussian scene (DESIGN.md stage 7).

Stage 1: static Gaussians, sky and the deformation field (the field by ``L_flow`` and ``L_rad``
only; the dynamic pixels are left out of the image losses, since no Gaussian explains them yet).
Stage 2 adds the dynamic Gaussians (in the field's canonical space, or at their frames' times); static
Gaussians frozen, dynamic Gaussians, sky and field trained.
Stage 3: everything, plus the object loss.

Loss per iteration (one training image):
``(1 - l_r) L1 + l_r (1 - SSIM) + l_d L_invdepth + l_obj BCE(dyn, mask) [stage 3] + l_sky BCE(alpha,
not sky) + w_flow L_flow + w_rad L_rad``. Every term is checked for NaN / inf before the step.

Determinism: the camera order of an epoch and every random draw of a step come from generators
seeded by ``(seed, epoch)`` and ``(seed, step)``, so a run resumed from a checkpoint (parameters,
Adam moments, densification statistics) continues exactly as the unbroken run would.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
from torch import Tensor

from radar4dgs.config import read_config_dict, save_config, to_dict
from radar4dgs.io.atomic import atomic_save_torch, atomic_write_json
from radar4dgs.io.devices import resolve_device
from radar4dgs.io.image_motion import IMAGE_MOTION_REFERENCE_WIDTH
from radar4dgs.io.scene import normalized_times, read_scene
from radar4dgs.metrics.image import psnr
from radar4dgs.model.appearance import FrameAppearance
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.gaussians import GaussianSet, backproject_frames, dynamic_cap_note
from radar4dgs.model.pose_refine import PoseCorrections, corrected_directions, refinement_switches, trajectory_target
from radar4dgs.model.run import (
    CHECKPOINT_DIR,
    CONFIG_FILE,
    HISTORY_FILE,
    LAST_CHECKPOINT,
    LOSS_TERMS,
    MODEL_FILE,
    RUN_FILE,
    write_refined_poses,
)
from radar4dgs.model.run_log import TrainLog, history_payload
from radar4dgs.model.scene_model import SceneModel
from radar4dgs.model.sky import SkyEnvironment
from radar4dgs.radar.sync import prepared_synced_scene
from radar4dgs.train.data import FrameTargetCache, FrameTargets, dynamic_masks, load_frame_targets, load_motion_targets
from radar4dgs.train.densify import GradientStats, densify_and_prune, reset_opacities
from radar4dgs.train.determinism import frame_order, step_generator
from radar4dgs.train.fit_motion import torch_threads
from radar4dgs.train.model_init import (
    dynamic_gaussians,
    gaussian_kwargs,
    image_speeds,
    new_field,
    offset_field,
    scene_extent,
    speed_scaled_lifespans,
    with_lifespans,
)
from radar4dgs.train.objective import image_losses, image_phase, motion_losses, refinement_losses, total_loss
from radar4dgs.train.optimizers import (
    make_optimizer,
    make_optimizers,
    make_refine_optimizers,
    pose_lr_scale,
    set_learning_rates,
    set_refine_learning_rates,
)
from radar4dgs.train.rigid_actors import start_rigid_actors
from radar4dgs.train.run_config import run_config_difference, same_run_config

# The public entry point of training; LOSS_TERMS and the run-config checks are re-exported for
# the callers that compare runs (evaluate, bench).
__all__ = ["LOSS_TERMS", "RunState", "Trainer", "TrainingError", "run_config_difference", "same_run_config",
           "train_run"]


class TrainingError(RuntimeError):
    """A training run cannot go on (non-finite loss, inconsistent run folder)."""


# --------------------------------------------------------------------------------------------
# Pure pieces


def check_finite(losses: dict[str, Tensor], step: int) -> None:
    bad = {name: float(v.detach()) for name, v in losses.items() if not torch.isfinite(v)}
    if bad:
        raise TrainingError(f"non-finite loss at iteration {step}: {bad}; the last checkpoint is kept "
                            f"(resume with --resume after changing the config)")


# --------------------------------------------------------------------------------------------
# The loop


@dataclass
class RunState:
    """Everything a checkpoint holds besides the config."""

    step: int
    model: SceneModel
    optimizers: dict[str, torch.optim.Optimizer]
    stats: dict[str, GradientStats]
    history: list[dict] = field(default_factory=list)
    # Pose corrections and per-frame colour transforms of the training frames (None = not refined).
    poses: PoseCorrections | None = None
    appearance: FrameAppearance | None = None


class Trainer:
    """Trains one run folder. ``train()`` starts fresh or, with ``resume``, from the last checkpoint."""

    def __init__(self, scene_path: Path, prepared: Path, out: Path, config: TrainConfig,
                 progress: bool = True, log: Callable[[str], None] = print, tensorboard: bool = True):
        self.scene_path, self.prepared, self.out = Path(scene_path), Path(prepared), Path(out)
        self.config = config
        self.progress = progress
        self.log = log
        # history.json at every log step, and TensorBoard in RUN/tb unless tensorboard is False.
        self.tensorboard = tensorboard
        self.train_log: TrainLog | None = None
        self.device = resolve_device(config.device)
        self.dtype = torch.float32
        self._points: dict[str, np.ndarray] | None = None
        # Discovery ran once for the rigid actors (it found none, or the model holds them now).
        self._rigid_actors_tried = False

    # ---- set-up
    def _load(self) -> None:
        # Radar scans re-stamped by the camera-radar clock offset that prepare applied (radar/sync.py).
        self.scene = prepared_synced_scene(read_scene(self.scene_path), self.prepared / "radar")
        if not (self.prepared / "depth").is_dir():
            raise FileNotFoundError(f"{self.prepared}: no prepared depth (run `radar4dgs prepare "
                                    f"{self.scene_path}` first)")
        self.times = normalized_times(self.scene)
        self.unit_seconds = float(self.scene.frames[-1].timestamp - self.scene.frames[0].timestamp)
        self.extent = scene_extent(self.scene)
        self.train_indices = self.scene.train_indices
        self.masks = dynamic_masks(self.scene, self.prepared, self.config.mask_source, self.train_indices,
                                   self.progress)
        self.targets = self._targets(self.config.resolution_scale)
        self.coarse_targets = self._targets(self.config.resolution_scale * self.config.coarse_scale) \
            if self.config.coarse_scale < 1.0 and self.config.coarse_until > 0 else self.targets
        self.motion = load_motion_targets(self.scene, self.prepared, self.config) \
            if self.config.method == "ours" else None

    def _initial_points(self) -> dict[str, np.ndarray]:
        """The back-projected training frames (deterministic given the init seed), computed once:
        the static Gaussians start from them and, at stage 2, the dynamic ones."""
        if self._points is None:
            self._points = backproject_frames(self.scene, self.prepared, self.config.init, masks=self.masks)
        return self._points

    def _targets(self, scale: float) -> FrameTargetCache:
        """The training frames' targets at ``scale``, read from disk when a frame is drawn and kept
        among the ``config.frame_cache`` most recently used (memory does not grow with the drive)."""
        def load(k: int) -> FrameTargets:
            i = self.train_indices[k]
            return load_frame_targets(self.scene, self.prepared, i, scale, self.times, self.device, self.dtype,
                                      dynamic=self.masks[i])

        return FrameTargetCache(load, len(self.train_indices), self.config.frame_cache)

    def _fresh_state(self) -> RunState:
        config, device, dtype = self.config, self.device, self.dtype
        method = config.method
        points = self._initial_points()
        # Only the methods that separate moving objects use the masks for the split.
        dyn = points["dynamic"] if method in ("ours", "bspline") else np.zeros(len(points["dynamic"]), bool)
        static = GaussianSet.from_points(points["points"][~dyn], points["colors"][~dyn],
                                         **gaussian_kwargs(config, device, dtype))
        if method == "pvg":
            static = with_lifespans(static, self.times[points["frame"][~dyn]], config.baselines.initial_lifespan,
                                    velocity=torch.zeros(len(static), 3))
        # One frame at a time (the cache returns the frame the images read for its sky mask).
        images = ((t.image.cpu().numpy() * 255).astype(np.uint8) for t in self.targets)
        sky = SkyEnvironment.from_sky_pixels(images, (t.sky.cpu().numpy() for t in self.targets),
                                             height=config.sky_height, width=config.sky_width,
                                             device=device, dtype=dtype)
        deformation, dynamic, offsets = None, None, None
        stats = {"static": GradientStats(len(static), device)}
        if method == "ours":
            deformation = new_field(config, self.motion, points["points"][dyn], device, dtype, self.progress)
        elif method == "deformable":
            offsets = offset_field(config, points["points"], device, dtype)
        elif method == "bspline":
            dynamic = GaussianSet.from_points(points["points"][dyn], points["colors"][dyn],
                                              **gaussian_kwargs(config, device, dtype))
            control = torch.zeros(len(dynamic), config.baselines.control_points, 3)
            dynamic = with_lifespans(dynamic, self.times[points["frame"][dyn]], config.baselines.initial_lifespan,
                                     control=control)
            stats["dynamic"] = GradientStats(len(dynamic), device)
        model = SceneModel(static, sky, deformation, dynamic, offsets, config.baselines)
        optimizers = make_optimizers(model, config, self.extent)
        return self._with_refinement(RunState(0, model, optimizers, stats))

    def _with_refinement(self, state: RunState, saved: dict[str, Any] | None = None) -> RunState:
        """``state`` with the pose corrections and colour transforms this run learns (as
        ``config.poses`` and the scene's ``source`` say), fresh or from checkpoint ``saved``."""
        poses_on, appearance_on = refinement_switches(self.config.poses.refine, self.config.poses.appearance,
                                                      self.scene.source)
        n, saved = len(self.train_indices), saved or {}
        if poses_on:
            state.poses = PoseCorrections.from_state(saved["poses"], self.device, self.dtype) \
                if saved.get("poses") is not None else PoseCorrections(n, self.device, self.dtype, self._pose_target())
        if appearance_on:
            state.appearance = FrameAppearance.from_state(saved["appearance"], self.device, self.dtype) \
                if saved.get("appearance") is not None else FrameAppearance(n, self.device, self.dtype)
        state.optimizers.update(make_refine_optimizers(state.poses, state.appearance, self.config))
        return state

    def _pose_target(self) -> np.ndarray | None:
        """(N, 6) where the training frames' pose corrections start and are pulled to: onto the
        smoothed trajectory (``poses.smooth_trajectory``), else None (the recorded poses)."""
        if not self.config.poses.smooth_trajectory:
            return None
        times = np.array([self.scene.frames[i].timestamp for i in self.train_indices])
        return trajectory_target(times, np.stack([self.scene.world_to_camera(i) for i in self.train_indices]))

    def _start_dynamic(self, state: RunState) -> None:
        """Stage 2 begins: dynamic Gaussians into the canonical space of the current field."""
        points = self._initial_points()
        dynamic = dynamic_gaussians(points, self.times, state.model.field, self.config, self.device, self.dtype)
        if self.config.dynamic_lifespan > 0:
            frames = points["frame"][points["dynamic"]]
            lifespan: float | np.ndarray = self.config.dynamic_lifespan
            if self.config.dynamic_lifespan_reference_px > 0 and len(frames):
                speeds = image_speeds(points["points"][points["dynamic"]], frames, self.times, state.model.field,
                                      self.scene)
                width_scale = self.scene.camera.width / IMAGE_MOTION_REFERENCE_WIDTH
                reference = self.config.dynamic_lifespan_reference_px * width_scale
                lifespan = speed_scaled_lifespans(speeds, lifespan, reference, float(np.min(np.diff(self.times))))
                self.log(f"stage 2: dynamic life spans {lifespan.min():.3f}-{lifespan.max():.3f} "
                         f"(median speed {np.median(speeds):.1f} px per frame)")
            dynamic = with_lifespans(dynamic, self.times[frames], lifespan)
        state.model.dynamic = dynamic
        state.model.key_times = tuple(float(self.times[i]) for i in self.train_indices)
        state.model.window_fraction = self.config.held_out_window
        state.model.own_time_means = self.config.dynamic_positions == "own-time"
        state.model.dynamic_in_front = self.config.dynamic_in_front
        state.optimizers["dynamic"] = make_optimizer(dynamic, self.config, self.extent, "dynamic.")
        state.stats["dynamic"] = GradientStats(len(dynamic), self.device)
        note = dynamic_cap_note(points, self.masks, self.train_indices, self.config.init)
        self.log(f"stage 2: {len(dynamic)} dynamic Gaussians ({self.config.dynamic_positions} means){note}")

    def _start_rigid_actors(self, state: RunState) -> None:
        """The dynamic Gaussians grouped into actors, each actor's moved by a rigid motion of its
        own from now on (``rigid_actors_at``; train.rigid_actors)."""
        self._rigid_actors_tried = True
        c = self.config
        self.log(start_rigid_actors(state.model, self.scene, self.prepared, np.asarray(self.train_indices),
                                    state.optimizers, c.rigid_actors_lr, c.rigid_actors_min_motion,
                                    c.rigid_actors_extrapolate, c.rigid_actors_radar_path, c.rigid_actors_attach,
                                    c.rigid_actors_flat))

    # ---- checkpoints
    def checkpoint_payload(self, state: RunState) -> dict[str, Any]:
        return {"step": state.step, "model": state.model.payload(),
                "optimizers": {k: v.state_dict() for k, v in state.optimizers.items()},
                "stats": {k: v.state_dict() for k, v in state.stats.items()},
                "history": state.history, "config": to_dict(self.config), **self._refinement_payload(state)}

    @staticmethod
    def _refinement_payload(state: RunState) -> dict[str, Any]:
        return {"poses": None if state.poses is None else state.poses.state(),
                "appearance": None if state.appearance is None else state.appearance.state()}

    def save_checkpoint(self, state: RunState) -> Path:
        directory = self.out / CHECKPOINT_DIR
        directory.mkdir(parents=True, exist_ok=True)
        payload = self.checkpoint_payload(state)
        atomic_save_torch(directory / LAST_CHECKPOINT, payload)
        return directory / LAST_CHECKPOINT

    def load_checkpoint(self, path: Path) -> RunState:
        saved = torch.load(path, map_location="cpu", weights_only=True)
        if not same_run_config(saved.get("config") or {}, self.config):
            raise TrainingError(f"{path}: saved with a different configuration than "
                                f"{self.out / CONFIG_FILE}; resume with the run's own config")
        model = SceneModel.from_payload(saved["model"], self.device, self.dtype)
        state = RunState(int(saved["step"]), model, {}, {}, list(saved.get("history", [])))
        state.optimizers.update(make_optimizers(model, self.config, self.extent))
        self._with_refinement(state, saved)
        for name, optimizer in state.optimizers.items():
            optimizer.load_state_dict(saved["optimizers"][name])
        for name, stats in saved["stats"].items():
            state.stats[name] = GradientStats(0, self.device)
            state.stats[name].load_state_dict(stats)
        return state

    # ---- the run
    def _write_run_files(self) -> None:
        self.out.mkdir(parents=True, exist_ok=True)
        save_config(self.config, self.out / CONFIG_FILE)
        atomic_write_json(self.out / RUN_FILE, {"scene": str(self.scene_path.resolve()),
                                                "prepared": str(self.prepared.resolve())})

    def train(self, resume: bool = False, stop_after: int | None = None) -> RunState:
        """Train; with ``resume`` continue from ``checkpoints/last.pt``. ``stop_after`` stops after
        that many iterations of this call (as if killed right after a checkpoint; tests, benchmarks)."""
        with torch_threads(self.config.threads):
            return self._train(resume, stop_after)

    def _train(self, resume: bool, stop_after: int | None) -> RunState:
        last = self.out / CHECKPOINT_DIR / LAST_CHECKPOINT
        if resume and (self.out / CONFIG_FILE).is_file():
            changed = run_config_difference(read_config_dict(TrainConfig, self.out / CONFIG_FILE), self.config)
            if changed:
                raise TrainingError(f"{self.out / CONFIG_FILE}: the run was started with another configuration "
                                    f"({'; '.join(changed[:4])}); resume with the run's options (or train into "
                                    "a new --out)")
        elif not resume and last.is_file():
            raise TrainingError(f"{self.out}: holds a run already (checkpoint {last}); pass --resume to "
                                "continue it or choose another --out")
        self._load()
        self._write_run_files()
        if resume and last.is_file():
            state = self.load_checkpoint(last)
            self.log(f"resuming {self.out} at iteration {state.step}")
        else:
            state = self._fresh_state()
        config = self.config
        total = config.optim.iterations
        end = total if stop_after is None else min(total, state.step + stop_after)
        self.train_log = TrainLog(self.out, self.device, LOSS_TERMS, HISTORY_FILE, self.tensorboard, state.step,
                                  self.log)
        bar = None
        if self.progress:
            from tqdm import tqdm

            bar = tqdm(total=total, initial=state.step, desc="train", unit="it", dynamic_ncols=True)
        started = time.perf_counter()
        try:
            self._loop(state, end, bar)
        finally:
            self.train_log.close()
        if state.step >= total:
            self.finish(state, time.perf_counter() - started)
        return state

    def _loop(self, state: RunState, end: int, bar) -> None:
        while state.step < end:
            self._iteration(state)
            state.step += 1
            if bar is not None:
                bar.update(1)
                if state.history and "psnr" in state.history[-1]:
                    h = state.history[-1]
                    bar.set_postfix({"stage": h["stage"], "psnr": f"{h['psnr']:.2f}", "loss": f"{h['total']:.4f}",
                                     "N": state.model.num_gaussians}, refresh=False)
            every = self.config.checkpoint_every
            if (every > 0 and state.step % every == 0) or state.step == end:
                self.save_checkpoint(state)
        if bar is not None:
            bar.close()

    def finish(self, state: RunState, seconds: float) -> None:
        if state.model.dynamic is not None and self.config.method == "ours":
            state.model.dynamic_in_front = self.config.render_in_front
        atomic_save_torch(self.out / MODEL_FILE, {"model": state.model.payload(), "step": state.step,
                                                  "config": to_dict(self.config), **self._refinement_payload(state)})
        if state.poses is not None or state.appearance is not None:
            write_refined_poses(self.out, self.scene, self.train_indices,
                                None if state.poses is None else state.poses.xi.detach().cpu().numpy(),
                                None if state.appearance is None else state.appearance.state())
        atomic_write_json(self.out / HISTORY_FILE, history_payload(state.history, *self._counts(state), seconds))

    @staticmethod
    def _counts(state: RunState) -> tuple[int, int]:
        """(static, dynamic) Gaussians."""
        return len(state.model.static), 0 if state.model.dynamic is None else len(state.model.dynamic)

    def _iteration(self, state: RunState) -> None:
        config, step = self.config, state.step
        stage = config.stage_at(step)
        if config.method == "ours" and stage >= 2 and state.model.dynamic is None:
            self._start_dynamic(state)
        if (config.rigid_actors_at > 0 and config.method == "ours" and state.model.dynamic is not None
                and state.model.actor_motion is None
                and not self._rigid_actors_tried and step >= round(config.rigid_actors_at * config.optim.iterations)):
            self._start_rigid_actors(state)
        set_learning_rates(state.optimizers, config, self.extent, step)
        set_refine_learning_rates(state.optimizers, config, step)
        n = len(self.targets)
        targets = self.coarse_targets if step < config.coarse_until * config.optim.iterations else self.targets
        row = int(frame_order(config.seed, step // n, n)[step % n])
        target = targets[row]
        generator = step_generator(config.seed, step)
        model = state.model
        ours = config.method == "ours"
        with_dynamic = (ours and stage >= 2) or config.method == "bspline"
        keep, scale = None, 1.0
        if config.optim.dropout > 0 and step < config.optim.dropout_until * config.optim.iterations:
            keep = torch.rand(model.num_gaussians if with_dynamic else len(model.static),
                              generator=generator) >= config.optim.dropout
            keep = keep.to(self.device)
            scale = 1.0 / (1.0 - config.optim.dropout)
        view, directions = self._camera(state, row, target)
        ignore_dynamic, detach_static = image_phase(config, stage, step)
        render = model.render(view, config.raster, directions, keep, scale,
                              include_dynamic=with_dynamic, detach_static=detach_static)
        if state.appearance is not None:
            render = {**render, "rgb": state.appearance(render["rgb"], row)}
        means2d = render["meta"]["means2d"]
        if means2d.requires_grad:
            means2d.retain_grad()
        losses = image_losses(render, target, config, stage, ignore_dynamic=ignore_dynamic)
        if ours and self.motion is not None:
            losses.update(motion_losses(model.field, self.motion, config.losses.motion_batch, generator,
                                        self.device, self.dtype))
        losses.update(refinement_losses(state.poses, state.appearance))
        if model.actor_motion is not None:
            losses["actor_smooth"] = model.actor_motion.acceleration()
            if config.rigid_actors_heading > 0:
                losses["actor_heading"] = model.actor_motion.heading_mismatch(self.unit_seconds)
        check_finite(losses, step)
        loss = total_loss(losses, config)
        for optimizer in state.optimizers.values():
            optimizer.zero_grad(set_to_none=True)
        loss.backward()
        trainable = ["sky", "field", "offsets", "appearance", "actors"] + (["static"] if not detach_static else []) + \
            (["dynamic"] if with_dynamic else []) + (["poses"] if pose_lr_scale(config, step) > 0 else [])
        for name in trainable:
            if name in state.optimizers:
                state.optimizers[name].step()
        if config.poses.zero_mean:  # the gauge (PoseRefineConfig.zero_mean)
            for part in (state.poses if "poses" in trainable else None, state.appearance):
                if part is not None:
                    part.remove_mean()
        self._densify(state, render, stage, trainable, generator)
        if step % config.log_every == 0 or step == config.optim.iterations - 1:
            state.history.append({"step": step, "stage": stage, "frame": target.name, "width": target.view.width,
                                  "total": float(loss.detach()),
                                  "psnr": psnr(render["rgb"].detach().clamp(0, 1), target.image),
                                  "num_gaussians": model.num_gaussians,
                                  **{k: float(v.detach()) for k, v in losses.items()}})
            if self.train_log is not None:
                self.train_log.step(state.history, *self._counts(state))

    @staticmethod
    def _camera(state: RunState, row: int, target: FrameTargets):
        """The view and world ray directions training row ``row`` renders: the recorded ones, or,
        when the run refines poses, the corrected (differentiable) pose and its turned rays."""
        if state.poses is None:
            return target.view, target.directions
        recorded = torch.as_tensor(target.view.world_to_camera, dtype=state.poses.translation.dtype,
                                   device=state.poses.translation.device)
        delta = state.poses.delta(row)
        view = dataclasses.replace(target.view, world_to_camera=delta @ recorded)
        return view, corrected_directions(target.directions, recorded, delta)

    def _densify(self, state: RunState, render: dict, stage: int, trainable: list[str],
                 generator: torch.Generator) -> None:
        config, step = self.config, state.step
        means2d = render["meta"]["means2d"]
        if means2d.grad is None:
            return
        grad = means2d.grad[0]
        visible = (render["meta"]["radii"][0] > 0).all(dim=-1)
        width, height = render["meta"]["width"], render["meta"]["height"]
        bounds = {"static": (0, render["n_static"]),
                  "dynamic": (render["n_static"], render["n_static"] + render["n_dynamic"])}
        for name, (lo, hi) in bounds.items():
            if name in state.stats and name in trainable and hi > lo and len(state.stats[name].grad) == hi - lo:
                state.stats[name].add(grad[lo:hi], visible[lo:hi], width, height)
        d = config.densify
        total = config.optim.iterations
        if d.every <= 0 or (step + 1) % d.every != 0:
            return
        for name in ("static", "dynamic"):
            rules = d.for_set(name)
            in_window = rules.start * total <= step < rules.stop * total
            if name not in trainable or name not in state.stats or not in_window:
                continue
            gaussians = getattr(state.model, name)
            counts = densify_and_prune(gaussians, state.optimizers[name], state.stats[name], self.extent, rules,
                                       generator, prune_large=d.reset_every > 0 and step >= d.reset_every)
            if d.reset_every > 0 and (step + 1) % d.reset_every == 0:
                reset_opacities(gaussians, state.optimizers[name], d.reset_value)
            state.history.append({"step": step, "stage": stage, "densify": name, **counts,
                                  "num_gaussians": len(gaussians)})


def train_run(scene_path: Path, prepared: Path, out: Path, config: TrainConfig, resume: bool = False,
              progress: bool = True, stop_after: int | None = None, tensorboard: bool = True) -> RunState:
    """Train ``scene_path`` with its ``prepared`` folder into run folder ``out`` (TensorBoard
    events in ``out/tb`` unless ``tensorboard`` is False)."""
    return Trainer(scene_path, prepared, out, config, progress=progress,
                   tensorboard=tensorboard).train(resume=resume, stop_after=stop_after)
