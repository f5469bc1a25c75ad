"""The reconstructed scene: static Gaussians, canonical dynamic Gaussians moved by the VGPT field,
and a sky environment map; one render function shared by training, evaluation and rendering.
The baselines (issue 10) use the same model: their motion is per-Gaussian parameters of a set
(PVG, B-splines; :mod:`radar4dgs.model.motion_models`) or an offset MLP over every Gaussian.

A render composites every Gaussian once with four feature channels ``(r, g, b, is_dynamic)`` and
the expected depth, so the dynamic-mask render (for the object loss and the evaluation pictures)
costs nothing extra; the sky fills ``1 - alpha`` of each pixel.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from radar4dgs.config import from_dict, to_dict
from radar4dgs.model.actor_motion import ActorMotion
from radar4dgs.model.field import DeformationField, FieldConfig
from radar4dgs.model.gaussians import GaussianSet
from radar4dgs.model.motion_models import BaselineConfig, OffsetField, bspline_means, pvg_means, temporal_visibility
from radar4dgs.model.sky import SkyEnvironment, camera_ray_directions
from radar4dgs.model.view import View, rasterizer_intrinsics
from radar4dgs.render.api import rasterize
from radar4dgs.render.config import RasterConfig

# The rasterizer's depth range: the synthetic and real scenes reach ~150 m; sky is left to the map.
NEAR_PLANE = 0.05
FAR_PLANE = 1000.0
# Dynamic Gaussians fainter than this at a time are not moved by the field there. The rasterizer culls
# opacities below 1/255 (gsplat's ALPHA_THRESHOLD); this is 39 times lower, so even Gaussian dropout's
# 1 / (1 - p) boost cannot bring a skipped one back above the rasterizer's threshold.
FIELD_CULL_OPACITY = 1e-4


class SceneModel(nn.Module):
    """Static Gaussians, dynamic Gaussians (canonical; None before stage 2 and for the methods with
    no dynamic set), the deformation field (only "ours"), the sky map, the baselines' pieces:
    ``offsets`` (deformable) and ``baseline`` (their config: PVG's period), and ``actor_motion``
    (rigid actors: the dynamic Gaussians whose ``actor`` parameter is >= 0 move with their actor's
    rigid motion instead of the field). ``key_times`` (the training frames' normalised times) and
    ``window_fraction``: at a time ``t`` between training frames each dynamic Gaussian is fully
    visible within ``window_fraction`` x (distance from ``t`` to the nearest training frame) of its life
    peak (TrainConfig.held_out_window); at a training frame nothing changes. ``own_time_means``
    (TrainConfig.dynamic_positions "own-time"): the dynamic means are positions at each Gaussian's life
    peak ``tau``, drawn at time t by the field's warp ``D_t(D_tau^-1(x))`` instead of ``D_t(x)``.
    ``dynamic_in_front`` (TrainConfig.dynamic_in_front): renders draw each dynamic Gaussian ahead of the
    static ones up to that fraction of its depth nearer."""

    def __init__(self, static: GaussianSet, sky: SkyEnvironment, field: DeformationField | None = None,
                 dynamic: GaussianSet | None = None, offsets: OffsetField | None = None,
                 baseline: BaselineConfig | None = None, actor_motion: ActorMotion | None = None,
                 key_times: tuple[float, ...] | None = None, window_fraction: float = 0.0,
                 own_time_means: bool = False, dynamic_in_front: float = 0.0):
        super().__init__()
        self.dynamic_in_front = dynamic_in_front
        self.own_time_means = own_time_means
        self.key_times = key_times
        self.window_fraction = window_fraction
        self.static = static
        self.sky = sky
        self.field = field
        self.dynamic = dynamic
        self.offsets = offsets
        self.baseline = baseline or BaselineConfig()
        self.actor_motion = actor_motion

    @property
    def num_gaussians(self) -> int:
        return len(self.static) + (len(self.dynamic) if self.dynamic is not None else 0)

    def set_at(self, name: str, time: float, cull: bool = False) -> dict[str, Tensor]:
        """Activated Gaussians of set ``name`` ("static" or "dynamic") at normalised ``time``:
        ``means`` (N, 3) moved by whatever moves this set (the VGPT field for the dynamic set,
        its B-spline or PVG parameters, the offset MLP; a rigid actor's Gaussians by their actor's
        motion), ``opacities`` (N,) times the temporal visibility where the set has a life span, and
        ``quats`` (turned with a rigid actor), ``scales``, ``colors``. With ``cull`` (renders), dynamic
        Gaussians too faint to be drawn at ``time`` keep their stored means and get opacity 0."""
        gaussians = getattr(self, name)
        g = gaussians.activated()
        p = gaussians.params
        time = float(time)
        stored = g["means"]
        # Rigid actors' Gaussians: their means are positions at their actor's reference time.
        rigid = p["actor"].detach() >= 0 if self.actor_motion is not None and gaussians.has("actor") else None
        if gaussians.has("log_lifespan"):
            flat = 0.0
            if name == "dynamic" and self.key_times and self.window_fraction > 0:
                flat = self.window_fraction * min(abs(time - key) for key in self.key_times)
            g["opacities"] = g["opacities"] * temporal_visibility(p["tau"], p["log_lifespan"], time, flat)
        if name == "dynamic" and self.field is not None:
            # A render moves only the Gaussians the rasterizer would draw (about half the dynamic set
            # at a training frame); the others get opacity 0 and are culled as before, so renders and
            # gradients do not change.
            g["means"] = stored.clone()
            moved = torch.ones_like(g["opacities"], dtype=torch.bool) if rigid is None else ~rigid
            if cull:
                drawn = g["opacities"].detach() >= FIELD_CULL_OPACITY
                moved &= drawn
                g["opacities"] = torch.where(drawn, g["opacities"], torch.zeros_like(g["opacities"]))
            if self.own_time_means:
                g["means"][moved] = self.field.warp(stored[moved], p["tau"][moved], time)
            else:
                g["means"][moved] = self.field(stored[moved], time)
        if gaussians.has("control"):
            g["means"] = bspline_means(g["means"], p["control"], time)
        if gaussians.has("velocity"):
            g["means"] = pvg_means(g["means"], p["velocity"], p["tau"], time, self.baseline.pvg_period)
        if self.offsets is not None:
            g["means"] = g["means"] + self.offsets(g["means"], time)
        if rigid is not None:
            means, quats = self.actor_motion(stored, g["quats"], p["actor"].detach().long().clamp(min=0), time)
            g["means"] = torch.where(rigid[:, None], means, g["means"])
            g["quats"] = torch.where(rigid[:, None], quats, g["quats"])
        return g

    def gaussians_at(self, time: float, include_static: bool = True, include_dynamic: bool = True,
                     detach_static: bool = False, cull: bool = False) -> dict[str, Tensor]:
        """Activated Gaussians of the scene at normalised ``time`` (:meth:`set_at` of each set):
        ``means`` (N, 3), ``quats`` (N, 4), ``scales`` (N, 3), ``opacities`` (N,), ``colors``
        (N, 3), ``dynamic`` (N,) bool; static ones first. ``cull``: as :meth:`set_at`."""
        parts = []
        if include_static:
            static = self.set_at("static", time)
            if detach_static:
                static = {k: v.detach() for k, v in static.items()}
            static["dynamic"] = torch.zeros(len(self.static), dtype=torch.bool, device=static["means"].device)
            parts.append(static)
        if include_dynamic and self.dynamic is not None and len(self.dynamic) > 0:
            dynamic = self.set_at("dynamic", time, cull)
            dynamic["dynamic"] = torch.ones(len(self.dynamic), dtype=torch.bool, device=dynamic["means"].device)
            parts.append(dynamic)
        if not parts:
            raise ValueError("nothing to render: no Gaussian set selected")
        return {k: torch.cat([p[k] for p in parts], dim=0) for k in parts[0]}

    def render(self, view: View, raster: RasterConfig | None = None, directions: Tensor | None = None,
               keep: Tensor | None = None, dropout_scale: float = 1.0, include_static: bool = True,
               include_dynamic: bool = True, detach_static: bool = False) -> dict[str, Any]:
        """Render ``view``.

        Args:
            directions: (H, W, 3) world ray directions of the pixels (computed when None).
            keep: (N,) bool Gaussian dropout mask over :meth:`gaussians_at`'s order (None = all),
                the kept opacities multiplied by ``dropout_scale`` and clamped to 1.

        Returns ``rgb`` (H, W, 3) composited with the sky, ``alpha`` (H, W), ``depth`` (H, W)
        expected depth (0 where alpha is 0), ``dynamic`` (H, W) accumulated weight of the dynamic
        Gaussians, ``sky`` (H, W, 3) the sky colour, and ``meta`` (the rasterizer's, with
        ``means2d`` for densification), ``n_static`` / ``n_dynamic`` and ``static_frozen``
        (``detach_static``).
        """
        raster = raster or RasterConfig()
        g = self.gaussians_at(view.time, include_static, include_dynamic, detach_static, cull=True)
        device, dtype = g["means"].device, g["means"].dtype
        opacities = g["opacities"]
        if keep is not None:
            opacities = torch.where(keep, (opacities * dropout_scale).clamp(max=1.0), torch.zeros_like(opacities))
        features = torch.cat([g["colors"], g["dynamic"].to(dtype)[:, None]], dim=1)
        viewmat = torch.as_tensor(view.world_to_camera, dtype=dtype, device=device)[None]
        in_front = self.dynamic_in_front > 0 and bool(g["dynamic"].any())
        if in_front:
            g, depth_fix = dynamic_drawn_in_front(g, viewmat[0], self.dynamic_in_front)
            features = torch.cat([features, depth_fix[:, None]], dim=1)
        K = torch.as_tensor(rasterizer_intrinsics(view.K), dtype=dtype, device=device)[None]
        out, alpha, meta = rasterize(g["means"], g["quats"], g["scales"], opacities, features, viewmat, K,
                                     view.width, view.height, near_plane=NEAR_PLANE, far_plane=FAR_PLANE,
                                     render_mode="RGB+ED", **raster.kwargs())
        out, alpha = out[0], alpha[0, ..., 0]
        depth = out[..., -1]
        if in_front:  # back to the true depth: the dynamic Gaussians were drawn (1 - b) of it away
            depth = depth + out[..., 4] / alpha.clamp(min=1e-10)
        if directions is None:
            directions = camera_ray_directions(view.K, view.world_to_camera, view.height, view.width,
                                               device=device, dtype=dtype)
        sky = self.sky(directions)
        rgb = out[..., :3] + (1.0 - alpha)[..., None] * sky
        n_dynamic = int(g["dynamic"].sum())
        return {"rgb": rgb, "alpha": alpha, "depth": depth, "dynamic": out[..., 3], "sky": sky,
                "meta": meta, "n_static": len(g["dynamic"]) - n_dynamic, "n_dynamic": n_dynamic,
                "static_frozen": detach_static}

    # ---- persistence
    def payload(self) -> dict[str, Any]:
        """Everything needed to rebuild the model (tensors on the CPU)."""
        def params(s: GaussianSet | None):
            return None if s is None else {k: v.detach().cpu() for k, v in s.params.items()}

        return {
            "static": params(self.static),
            "dynamic": params(self.dynamic),
            "field_config": None if self.field is None else to_dict(self.field.config),
            "field": None if self.field is None else {k: v.cpu() for k, v in self.field.state_dict().items()},
            "sky": self.sky.logits.detach().cpu(),
            "offsets": None if self.offsets is None else {k: v.cpu() for k, v in self.offsets.state_dict().items()},
            "baseline_config": to_dict(self.baseline),
            "actor_motion": None if self.actor_motion is None else self.actor_motion.state(),
            "held_out_window": None if not self.key_times else {"key_times": list(self.key_times),
                                                                 "fraction": self.window_fraction},
            "own_time_means": self.own_time_means,
            "dynamic_in_front": self.dynamic_in_front,
        }

    @classmethod
    def from_payload(cls, payload: dict[str, Any], device: torch.device | str = "cpu",
                     dtype: torch.dtype = torch.float32) -> "SceneModel":
        def gaussians(params):
            return None if params is None else GaussianSet({k: v.to(device=device, dtype=dtype)
                                                            for k, v in params.items()}).to(device)

        sky_logits = payload["sky"]
        sky = SkyEnvironment(int(sky_logits.shape[1]), int(sky_logits.shape[2]), device=device, dtype=dtype)
        with torch.no_grad():
            sky.logits.copy_(sky_logits.to(device=device, dtype=dtype))
        field = None
        if payload.get("field") is not None:
            field = DeformationField(from_dict(FieldConfig, payload["field_config"])).to(device=device, dtype=dtype)
            field.load_state_dict({k: v.to(device=device, dtype=dtype) for k, v in payload["field"].items()})
        baseline = from_dict(BaselineConfig, payload.get("baseline_config") or {})
        offsets = None
        if payload.get("offsets") is not None:
            offsets = OffsetField(baseline).to(device=device, dtype=dtype)
            offsets.load_state_dict({k: v.to(device=device, dtype=dtype) for k, v in payload["offsets"].items()})
        actor_motion = None
        if payload.get("actor_motion") is not None:
            actor_motion = ActorMotion.from_state(payload["actor_motion"], device, dtype)
        window = payload.get("held_out_window") or {}  # absent from models saved before it existed
        return cls(gaussians(payload["static"]), sky, field, gaussians(payload.get("dynamic")), offsets, baseline,
                   actor_motion, tuple(window.get("key_times", ())) or None, float(window.get("fraction", 0.0)),
                   bool(payload.get("own_time_means", False)), float(payload.get("dynamic_in_front", 0.0)))


def dynamic_drawn_in_front(g: dict[str, Tensor], world_to_camera: Tensor, fraction: float
                           ) -> tuple[dict[str, Tensor], Tensor]:
    """``g`` (:meth:`SceneModel.gaussians_at`) with each dynamic Gaussian moved toward the camera by
    ``fraction`` of its distance and its scales shrunk by as much: the same image footprint, drawn before
    any static Gaussian less than ``fraction`` of its depth nearer. Also (N,) the depth each Gaussian must
    add to the blend for the true expected depth (``z' fraction / (1 - fraction)`` for the moved ones, z' their
    new camera depth; 0 for the rest).

    Why: a car's dynamic layer and the road Gaussians just in front of it are drawn in depth order, and
    those Gaussians' footprints reach over the car's lower part (benchmarks/over_movers.py); a mover is
    not hidden by what lies within a few metres of its own surface."""
    moved = g["dynamic"][:, None]
    rotation, translation = world_to_camera[:3, :3], world_to_camera[:3, 3]
    centre = -rotation.T @ translation
    means = torch.where(moved, centre + (1.0 - fraction) * (g["means"] - centre), g["means"])
    scales = torch.where(moved, g["scales"] * (1.0 - fraction), g["scales"])
    depth = means @ rotation[2] + translation[2]
    fix = torch.where(g["dynamic"], depth * (fraction / (1.0 - fraction)), torch.zeros_like(depth))
    return {**g, "means": means, "scales": scales}, fix


def load_model(path: str | Path, device: torch.device | str = "cpu") -> SceneModel:
    """A model saved as ``{"model": payload, ...}`` (``RUN/model.pt`` or a checkpoint)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no model file (has `radar4dgs train` finished?)")
    saved = torch.load(path, map_location="cpu", weights_only=True)
    if "model" not in saved:
        raise ValueError(f"{path}: not a radar4dgs model file (no 'model' entry)")
    return SceneModel.from_payload(saved["model"], device=device).eval()
