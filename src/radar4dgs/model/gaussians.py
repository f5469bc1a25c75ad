"""Gaussian components and their initialisation from the prepared metric depth (issue 8, stage 7).

Every training frame's metric depth (``prepared/depth/<frame>.npy``) is back-projected into world
points; sky pixels (``prepared/depth/sky/<frame>.png`` or non-finite depth) are dropped, the rest
subsampled deterministically, coloured from the image and split by the predicted dynamic masks
(``prepared/masks/<frame>.png``) into a static and a dynamic :class:`GaussianSet`. Dynamic points
keep the normalised time of their frame, so the trainer can move them into the canonical space of
the deformation field with :func:`to_canonical`.

Pixel convention: the scene's intrinsics put pixel centres at integer coordinates (OpenCV), so the
pixel in row ``v``, column ``u`` back-projects along ``K^-1 (u, v, 1)``. (The rasterizer puts pixel
centres at ``+0.5``: the trainer shifts ``cx, cy`` by 0.5 when it renders.)

Like drivestudio's components, a :class:`GaussianSet` holds its parameters in a
``torch.nn.ParameterDict``, hands out activated tensors (:meth:`GaussianSet.activated`) and its
optimizer parameter groups (:meth:`GaussianSet.param_groups`); densification lives elsewhere.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor, nn

from radar4dgs.io.scene import normalized_times, read_mask_png
from radar4dgs.io.scene_files import prepared_depth_path
from radar4dgs.model.config import GaussianInitConfig
from radar4dgs.motion.lift import backproject

PARAM_NAMES: tuple[str, ...] = ("means", "quats", "log_scales", "opacity_logits", "colors")
# Optional per-Gaussian motion parameters of the baselines (model.motion_models): ``velocity``
# (N, 3), ``tau`` (N,) life peak, ``log_lifespan`` (N,), ``control`` (N, K, 3) B-spline offsets;
# and ``actor`` (N,), never optimised: the rigid actor (model.actor_motion) a dynamic Gaussian moves
# with, -1 for the field. A parameter so that densification clones, splits and prunes it with the rest.
MOTION_PARAM_NAMES: tuple[str, ...] = ("velocity", "tau", "log_lifespan", "control", "actor")


# --------------------------------------------------------------------------------------------
# Back-projection


def require_prepared(path: Path, what: str) -> Path:
    """``path``, or a FileNotFoundError naming it and the command that makes it."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing {what} (run `radar4dgs prepare` on the scene first)")
    return path


def lidar_frame(scene, index: int, config: GaussianInitConfig, dynamic: np.ndarray,
                rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Frame ``index``'s LiDAR points (``lidar/``, ego frame) in the world, keeping those that
    project into the image in front of the camera (only they get a colour), coloured by the pixel
    they fall on and flagged dynamic by ``dynamic`` (H, W) bool; keys as :func:`backproject_frame`."""
    H, W = scene.camera.height, scene.camera.width
    ego = scene.load_optional("lidar", index)[:, :3].astype(np.float64)
    world = ego @ scene.frames[index].ego_to_world[:3, :3].T + scene.frames[index].ego_to_world[:3, 3]
    world_to_camera = scene.world_to_camera(index)
    uv, z = scene.camera.project(world @ world_to_camera[:3, :3].T + world_to_camera[:3, 3])
    u, v = np.round(uv[:, 0]).astype(np.int64), np.round(uv[:, 1]).astype(np.int64)
    keep = (z > 0.1) & (z <= config.max_depth) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
    idx = np.nonzero(keep)[0]
    if 0 < config.points_per_frame < len(idx):
        idx = np.sort(rng.choice(idx, size=config.points_per_frame, replace=False))
    u, v = u[idx], v[idx]
    image = scene.load_image(index)
    return {"points": world[idx], "colors": image[v, u].astype(np.float64) / 255.0,
            "frame": np.full(len(idx), index, dtype=np.int64), "dynamic": dynamic[v, u],
            "pixels": np.stack([u, v], axis=1).astype(np.int64)}


def backproject_frame(scene, prepared_dir: Path | str, index: int, config: GaussianInitConfig,
                      rng: np.random.Generator, dynamic: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Back-project one frame; keys as :func:`backproject_frames` plus ``pixels`` (M, 2) (u, v) ints.
    ``dynamic`` (H, W) bool is the frame's dynamic mask (default: ``prepared/masks``)."""
    prepared = Path(prepared_dir)
    name = scene.frames[index].name
    H, W = scene.camera.height, scene.camera.width
    if dynamic is None:
        dynamic = read_mask_png(require_prepared(prepared / "masks" / f"{name}.png", "dynamic mask"), (H, W))
    if config.source == "lidar":
        return lidar_frame(scene, index, config, dynamic, rng)
    depth_path = require_prepared(prepared_depth_path(prepared, name), "depth")
    depth = np.load(depth_path).astype(np.float64)
    if depth.shape != (H, W):
        raise ValueError(f"{depth_path}: depth has shape {depth.shape}, expected {(H, W)}")
    keep = np.isfinite(depth) & (depth > 0) & (depth <= config.max_depth)
    keep &= ~read_mask_png(require_prepared(prepared / "depth" / "sky" / f"{name}.png", "sky mask"), (H, W))
    if config.min_confidence > 0:
        conf_path = prepared / "depth" / f"{name}_confidence.npy"
        keep &= np.load(conf_path) >= config.min_confidence
    grid = np.zeros((H, W), dtype=bool)
    grid[::config.pixel_stride, ::config.pixel_stride] = True
    step = config.dynamic_pixel_stride
    grid[::step, ::step] |= dynamic[::step, ::step]
    v, u = np.nonzero(keep & grid)  # row-major order: deterministic
    if 0 < config.points_per_frame < len(u):
        chosen = np.sort(rng.choice(len(u), size=config.points_per_frame, replace=False))
        v, u = v[chosen], u[chosen]
    points = backproject(np.stack([u, v], axis=1).astype(np.float64), depth[v, u], scene.camera.K,
                         scene.world_to_camera(index))
    image = scene.load_image(index)
    return {
        "points": points,
        "colors": image[v, u].astype(np.float64) / 255.0,
        "frame": np.full(len(u), index, dtype=np.int64),
        "dynamic": dynamic[v, u],
        "pixels": np.stack([u, v], axis=1).astype(np.int64),
    }


def backproject_frames(scene, prepared_dir: Path | str, config: GaussianInitConfig,
                       frames: Sequence[int] | None = None,
                       masks: Mapping[int, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Back-project the training frames' (or ``frames``') prepared metric depth into world points.

    Returns numpy arrays: ``points`` (M, 3) float64 world, ``colors`` (M, 3) float64 in [0, 1],
    ``frame`` (M,) int64 frame index, ``dynamic`` (M,) bool (predicted dynamic mask), ``pixels``
    (M, 2) int64 (u, v). Sky pixels (sky mask or non-finite depth) never appear. The subsampling is
    deterministic given ``config.seed``; the per-type caps are applied afterwards. ``masks`` maps a
    frame index to its (H, W) bool dynamic mask (default: each frame's ``prepared/masks``).
    With ``config.source == "lidar"`` the points are the frames' LiDAR points instead.
    """
    frames = list(scene.train_indices if frames is None else frames)
    rng = np.random.default_rng(config.seed)
    if config.source == "lidar" and not scene.has("lidar"):
        raise FileNotFoundError(f"{scene.root / 'lidar'}: the scene has no LiDAR to initialise from "
                                f"(init.source lidar); use init.source depth")
    parts = [backproject_frame(scene, prepared_dir, i, config, rng, None if masks is None else masks[i])
             for i in frames]
    keys = ("points", "colors", "frame", "dynamic", "pixels")
    empty = {"points": np.zeros((0, 3)), "colors": np.zeros((0, 3)), "frame": np.zeros(0, np.int64),
             "dynamic": np.zeros(0, bool), "pixels": np.zeros((0, 2), np.int64)}
    out = {k: np.concatenate([p[k] for p in parts], axis=0) if parts else empty[k] for k in keys}
    # Caps: uniform random subsets of each type, order preserved.
    keep = np.ones(len(out["frame"]), dtype=bool)
    for flag, cap in ((False, config.max_static), (True, config.max_dynamic)):
        idx = np.nonzero(out["dynamic"] == flag)[0]
        if len(idx) > cap:
            drop = np.setdiff1d(idx, rng.choice(idx, size=cap, replace=False))
            keep[drop] = False
    return {k: v[keep] for k, v in out.items()}


def dynamic_cap_note(points: Mapping[str, np.ndarray], masks: Mapping[int, np.ndarray], frames: Sequence[int],
                     config: GaussianInitConfig) -> str:
    """A note for the log when ``points`` (from :func:`backproject_frames`) hold fewer dynamic points than
    ``max_dynamic`` allows because ``points_per_frame`` subsampled each frame's candidates (static ones included),
    while the (H, W) ``masks`` of ``frames`` hold more; else "". At 640x360 the small preset's 15 000 a frame keep
    about 48 000 of a strict hard scene's 166 000 moving pixels, so a larger max_dynamic alone changes little."""
    kept = int(np.asarray(points["dynamic"]).sum())
    if config.source != "depth" or config.points_per_frame <= 0 or kept >= config.max_dynamic:
        return ""
    step = config.dynamic_pixel_stride
    on_grid = sum(int(masks[i][::step, ::step].sum()) for i in frames)
    # A tenth of slack: sky and pixels without depth inside the masks are never candidates.
    if kept >= 0.9 * min(on_grid, config.max_dynamic):
        return ""
    return (f"; max_dynamic {config.max_dynamic} not reached: init.points_per_frame {config.points_per_frame} kept "
            f"{kept} of the masks' {on_grid} pixels, raise it to keep more")


# --------------------------------------------------------------------------------------------
# Gaussian components


def knn_log_scales(points: np.ndarray, k: int = 3, min_scale: float = 1e-3,
                   max_scale: float = 3.0) -> np.ndarray:
    """(N, 3) isotropic log-scales: log of the mean distance to the ``k`` nearest other points,
    clamped to [min_scale, max_scale]. With fewer than 2 points the scale is ``max_scale``."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(points)
    if n < 2:
        mean = np.full(n, max_scale)
    else:
        kk = min(k, n - 1)
        dist, _ = cKDTree(points).query(points, k=kk + 1)
        mean = dist.reshape(n, -1)[:, 1:].mean(axis=1)  # column 0 is the point itself
    mean = np.clip(mean, min_scale, max_scale)
    return np.repeat(np.log(mean)[:, None], 3, axis=1)


def _logit(p: Tensor) -> Tensor:
    return torch.log(p) - torch.log1p(-p)


class GaussianSet(nn.Module):
    """N Gaussians with parameters in a ``ParameterDict``: ``means`` (N, 3), ``quats`` (N, 4, wxyz),
    ``log_scales`` (N, 3), ``opacity_logits`` (N,), ``colors`` (N, 3, logits of [0, 1] RGB)."""

    def __init__(self, params: Mapping[str, Tensor]):
        super().__init__()
        missing = [n for n in PARAM_NAMES if n not in params]
        if missing:
            raise KeyError(f"missing parameters {missing}; need {list(PARAM_NAMES)}")
        unknown = [n for n in params if n not in PARAM_NAMES + MOTION_PARAM_NAMES]
        if unknown:
            raise KeyError(f"unknown parameters {unknown}; known: {list(PARAM_NAMES + MOTION_PARAM_NAMES)}")
        n = params["means"].shape[0]
        shapes = {"means": (n, 3), "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,),
                  "colors": (n, 3), "velocity": (n, 3), "tau": (n,), "log_lifespan": (n,), "actor": (n,)}
        for name in params:
            shape = shapes.get(name)
            actual = tuple(params[name].shape)
            if (shape is not None and actual != shape) or (name == "control" and (len(actual) != 3 or actual[0] != n
                                                                                  or actual[2] != 3)):
                raise ValueError(f"{name} has shape {actual}, expected {shape or (n, 'K', 3)}")
        self.params = nn.ParameterDict({name: nn.Parameter(params[name].detach().clone())
                                        for name in PARAM_NAMES + MOTION_PARAM_NAMES if name in params})

    @property
    def names(self) -> tuple[str, ...]:
        """The parameter names this set holds (appearance first, then any motion parameters)."""
        return tuple(name for name in PARAM_NAMES + MOTION_PARAM_NAMES if name in self.params)

    def has(self, name: str) -> bool:
        return name in self.params

    def with_motion(self, **motion: Tensor) -> "GaussianSet":
        """A new set with the same Gaussians plus the given motion parameters (N rows each)."""
        params = {name: self.params[name].detach() for name in self.names}
        params.update({name: value.to(params["means"]) for name, value in motion.items()})
        return GaussianSet(params)

    @classmethod
    def from_points(cls, points: Any, colors: Any, *, init_opacity: float = 0.1, knn_k: int = 3,
                    min_scale: float = 1e-3, max_scale: float = 3.0,
                    device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32) -> "GaussianSet":
        """Gaussians at ``points`` (N, 3) with ``colors`` (N, 3) in [0, 1], identity rotations, kNN
        isotropic scales and opacity ``init_opacity``."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        colors = np.asarray(colors, dtype=np.float64).reshape(-1, 3)
        if len(colors) != len(points):
            raise ValueError(f"{len(points)} points but {len(colors)} colours")
        n = len(points)
        kw = {"device": device, "dtype": dtype}
        quats = torch.zeros(n, 4, **kw)
        quats[:, 0] = 1.0
        eps = 1e-4
        params = {
            "means": torch.as_tensor(points, **kw),
            "quats": quats,
            "log_scales": torch.as_tensor(knn_log_scales(points, knn_k, min_scale, max_scale), **kw),
            "opacity_logits": _logit(torch.full((n,), float(init_opacity), dtype=torch.float64)).to(**kw),
            "colors": _logit(torch.as_tensor(np.clip(colors, eps, 1 - eps), dtype=torch.float64)).to(**kw),
        }
        return cls(params)

    def __len__(self) -> int:
        return int(self.params["means"].shape[0])

    @property
    def num_gaussians(self) -> int:
        return len(self)

    def activated(self) -> dict[str, Tensor]:
        """``means`` (N, 3), ``quats`` (N, 4) unit, ``scales`` (N, 3) = exp, ``opacities`` (N,) =
        sigmoid, ``colors`` (N, 3) = sigmoid; differentiable in the parameters."""
        p = self.params
        return {
            "means": p["means"],
            "quats": p["quats"] / p["quats"].norm(dim=-1, keepdim=True).clamp_min(1e-12),
            "scales": torch.exp(p["log_scales"]),
            "opacities": torch.sigmoid(p["opacity_logits"]),
            "colors": torch.sigmoid(p["colors"]),
        }

    def param_groups(self, lrs: Mapping[str, float], prefix: str = "") -> list[dict]:
        """One optimizer group per parameter named in ``lrs`` (a name left out is not optimised):
        ``[{"params": [p], "lr": lr, "name": prefix + name}]``. Unknown names raise a KeyError."""
        unknown = [n for n in lrs if n not in PARAM_NAMES + MOTION_PARAM_NAMES]
        if unknown:
            raise KeyError(f"unknown parameter(s) {unknown}; parameters are {list(PARAM_NAMES + MOTION_PARAM_NAMES)}")
        return [{"params": [self.params[name]], "lr": float(lrs[name]), "name": prefix + name}
                for name in self.names if name in lrs]


# --------------------------------------------------------------------------------------------
# Initialisation


def initialize_gaussians(scene, prepared_dir: Path | str, config: GaussianInitConfig,
                         device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32,
                         frames: Sequence[int] | None = None) -> tuple[GaussianSet, GaussianSet, np.ndarray]:
    """Static and dynamic Gaussians from the training frames, and the dynamic ones' frame times.

    Returns ``(static, dynamic, dynamic_times)``: the dynamic Gaussians' means are the world points
    of their frames at normalised time ``dynamic_times`` (Nd,) float64; move them to the canonical
    space with :func:`to_canonical` once the deformation field is fitted.
    """
    data = backproject_frames(scene, prepared_dir, config, frames)
    # The field's own time coordinate: the dynamic points must be moved with the same t it is fitted on.
    times = normalized_times(scene)
    kw = {"init_opacity": config.init_opacity, "knn_k": config.knn_k, "min_scale": config.min_scale,
          "max_scale": config.max_scale, "device": device, "dtype": dtype}
    dyn = data["dynamic"]
    static = GaussianSet.from_points(data["points"][~dyn], data["colors"][~dyn], **kw)
    dynamic = GaussianSet.from_points(data["points"][dyn], data["colors"][dyn], **kw)
    return static, dynamic, times[data["frame"][dyn]]


@torch.no_grad()
def to_canonical(points: Any, times: Any, field: nn.Module, batch_size: int = 65_536) -> Tensor:
    """``field.inverse(x, t)`` for (N, 3) world ``points`` at (N,) normalised ``times``, in batches
    and without gradients. Computed in the field's dtype and device; returned in the dtype and on
    the device of ``points`` when it is a tensor, else in the field's."""
    ref = next(field.buffers(), None)
    if ref is None:
        ref = next(field.parameters())
    target = points if isinstance(points, Tensor) else None
    x = torch.as_tensor(points).to(device=ref.device, dtype=ref.dtype).reshape(-1, 3)
    t = torch.as_tensor(times).to(device=ref.device, dtype=ref.dtype).reshape(-1)
    if t.numel() == 1 and x.shape[0] != 1:
        t = t.expand(x.shape[0])
    if t.shape[0] != x.shape[0]:
        raise ValueError(f"{x.shape[0]} points but {t.shape[0]} times")
    out = torch.cat([field.inverse(x[s:s + batch_size], t[s:s + batch_size])
                     for s in range(0, x.shape[0], batch_size)], dim=0) if x.shape[0] else x.clone()
    if target is not None:
        out = out.to(device=target.device, dtype=target.dtype)
    return out
