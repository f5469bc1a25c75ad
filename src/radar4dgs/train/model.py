"""The reconstructed scene: static Gaussians, canonical dynamic Gaussians moved by the VGPT field,
and a sky environment map; one render function shared by training, evaluation and rendering.

A render composites every Gaussian once with four feature channels ``(r, g, b, is_dynamic)`` and
the expected depth, so the dynamic-mask render (for the object loss and the evaluation pictures)
costs nothing extra; the sky fills ``1 - alpha`` of each pixel.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from radar4dgs.config import from_dict, to_dict
from radar4dgs.motion.field import DeformationField, FieldConfig
from radar4dgs.render.api import RasterConfig, rasterize
from radar4dgs.train.gaussians import GaussianSet
from radar4dgs.train.sky import SkyEnvironment, camera_ray_directions

# The rasterizer's depth range: the synthetic and real scenes reach ~150 m; sky is left to the map.
NEAR_PLANE = 0.05
FAR_PLANE = 1000.0


@dataclass
class View:
    """One camera to render: ``world_to_camera`` (4, 4) OpenCV axes, ``K`` (3, 3) in the scene's
    convention (pixel centres at integer coordinates), ``width`` x ``height`` pixels, normalised
    time ``time`` in [0, 1]."""

    world_to_camera: np.ndarray
    K: np.ndarray
    width: int
    height: int
    time: float


def scale_intrinsics(K: np.ndarray, scale: float) -> np.ndarray:
    """(3, 3) intrinsics of the image resized by ``scale`` (integer pixel centres kept: pixel
    ``u`` of the resized image covers ``(u + 0.5) / scale - 0.5`` of the original)."""
    K = np.asarray(K, dtype=np.float64).copy()
    K[0, 0] *= scale
    K[1, 1] *= scale
    K[0, 2] = (K[0, 2] + 0.5) * scale - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * scale - 0.5
    return K


def rasterizer_intrinsics(K: np.ndarray) -> np.ndarray:
    """The scene's K with pixel centres moved to +0.5, the rasterizer's (gsplat's) convention."""
    K = np.asarray(K, dtype=np.float64).copy()
    K[0, 2] += 0.5
    K[1, 2] += 0.5
    return K


class SceneModel(nn.Module):
    """Static Gaussians, dynamic Gaussians (canonical; None before stage 2 and for the "static"
    method), the deformation field (None for "static") and the sky map."""

    def __init__(self, static: GaussianSet, sky: SkyEnvironment, field: DeformationField | None = None,
                 dynamic: GaussianSet | None = None):
        super().__init__()
        self.static = static
        self.sky = sky
        self.field = field
        self.dynamic = dynamic

    @property
    def num_gaussians(self) -> int:
        return len(self.static) + (len(self.dynamic) if self.dynamic is not None else 0)

    def gaussians_at(self, time: float, include_static: bool = True, include_dynamic: bool = True,
                     detach_static: bool = False) -> dict[str, Tensor]:
        """Activated Gaussians of the scene at normalised ``time``: ``means`` (N, 3), ``quats``
        (N, 4), ``scales`` (N, 3), ``opacities`` (N,), ``colors`` (N, 3), ``dynamic`` (N,) bool;
        static ones first. Dynamic means are ``D_t(canonical)`` (differentiable in the field)."""
        parts = []
        if include_static:
            static = self.static.activated()
            if detach_static:
                static = {k: v.detach() for k, v in static.items()}
            static["dynamic"] = torch.zeros(len(self.static), dtype=torch.bool, device=static["means"].device)
            parts.append(static)
        if include_dynamic and self.dynamic is not None and len(self.dynamic) > 0:
            dynamic = self.dynamic.activated()
            if self.field is not None:
                dynamic["means"] = self.field(dynamic["means"], float(time))
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
        ``means2d`` for densification) and ``n_static`` / ``n_dynamic``.
        """
        raster = raster or RasterConfig()
        g = self.gaussians_at(view.time, include_static, include_dynamic, detach_static)
        device, dtype = g["means"].device, g["means"].dtype
        opacities = g["opacities"]
        if keep is not None:
            opacities = torch.where(keep, (opacities * dropout_scale).clamp(max=1.0), torch.zeros_like(opacities))
        features = torch.cat([g["colors"], g["dynamic"].to(dtype)[:, None]], dim=1)
        viewmat = torch.as_tensor(view.world_to_camera, dtype=dtype, device=device)[None]
        K = torch.as_tensor(rasterizer_intrinsics(view.K), dtype=dtype, device=device)[None]
        out, alpha, meta = rasterize(g["means"], g["quats"], g["scales"], opacities, features, viewmat, K,
                                     view.width, view.height, near_plane=NEAR_PLANE, far_plane=FAR_PLANE,
                                     render_mode="RGB+ED", **raster.kwargs())
        out, alpha = out[0], alpha[0, ..., 0]
        if directions is None:
            directions = camera_ray_directions(view.K, view.world_to_camera, view.height, view.width,
                                               device=device, dtype=dtype)
        sky = self.sky(directions)
        rgb = out[..., :3] + (1.0 - alpha)[..., None] * sky
        n_dynamic = int(g["dynamic"].sum())
        return {"rgb": rgb, "alpha": alpha, "depth": out[..., 4], "dynamic": out[..., 3], "sky": sky,
                "meta": meta, "n_static": len(g["dynamic"]) - n_dynamic, "n_dynamic": n_dynamic}

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
        return cls(gaussians(payload["static"]), sky, field, gaussians(payload.get("dynamic")))


def load_model(path: str | Path, device: torch.device | str = "cpu") -> SceneModel:
    """A model saved as ``{"model": payload, ...}`` (``RUN/model.pt`` or a checkpoint)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no model file (has `radar4dgs train` finished?)")
    saved = torch.load(path, map_location="cpu", weights_only=True)
    if "model" not in saved:
        raise ValueError(f"{path}: not a radar4dgs model file (no 'model' entry)")
    return SceneModel.from_payload(saved["model"], device=device).eval()
