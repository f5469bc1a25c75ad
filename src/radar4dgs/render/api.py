"""One rasterization API, two backends: gsplat on CUDA, the hand-written torch rasterizer elsewhere.

:func:`rasterize` mirrors gsplat 1.5.3's ``rasterization()`` with ``packed=False``,
``rasterize_mode="classic"``, a pinhole camera, no SH (colours are post-activation features of
any width D) and no batch dimensions. Render modes follow gsplat's ``rendering.py``:
"D" renders the accumulated z-depth ``sum_i w_i z_i``; "ED" the expected depth
``sum_i w_i z_i / max(alpha, 1e-10)``; "RGB+D" / "RGB+ED" append it as the last channel; depth
channels get a zero background.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from radar4dgs.render.config import RENDER_MODES, Backend, RenderMode
from radar4dgs.render.projection import project_gaussians
from radar4dgs.render.torch_backend import rasterize_pixels


def select_backend(backend: str, device: torch.device) -> str:
    """Resolve "auto" / check an explicit choice. Imports gsplat only for CUDA devices."""
    if backend not in ("auto", "torch", "gsplat"):
        raise ValueError(f"unknown backend {backend!r}; choose auto, torch or gsplat")
    if backend == "torch":
        return "torch"
    if device.type != "cuda":
        if backend == "gsplat":
            raise ValueError(
                f"backend='gsplat' needs CUDA tensors (got device {device}); "
                "use backend='torch' or 'auto' on CPU"
            )
        return "torch"
    from radar4dgs.render.gsplat_backend import gsplat_available

    if gsplat_available():
        return "gsplat"
    if backend == "gsplat":
        raise ImportError("backend='gsplat' requested but gsplat is not importable; "
                          "install the `cuda` extra (gsplat==1.5.3)")  # fmt: skip
    return "torch"


def rasterize(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    colors: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    backgrounds: Tensor | None = None,
    render_mode: RenderMode = "RGB",
    eps2d: float = 0.3,
    radius_clip: float = 0.0,
    backend: Backend = "auto",
    tile_size: int | None = None,
    chunk_tiles: int = 64,
    block_k: int = 32,
    checkpoint: bool = False,
) -> tuple[Tensor, Tensor, dict[str, Any]]:
    """Render N Gaussians into C cameras.

    Args:
        means: (N, 3) world positions.
        quats: (N, 4) wxyz rotations, need not be normalised.
        scales: (N, 3) activated (positive) scales.
        opacities: (N,) activated opacities in [0, 1].
        colors: (N, D) or (C, N, D) features of any width D (post-activation).
        viewmats: (C, 4, 4) world-to-camera, OpenCV axes (x right, y down, z forward).
        Ks: (C, 3, 3) pinhole intrinsics.
        width, height: image size in pixels.
        near_plane, far_plane: camera-z culling range.
        backgrounds: (C, D) colour behind the Gaussians, or None (black).
        render_mode: "RGB", "D", "ED", "RGB+D" or "RGB+ED" (see the module docstring).
        eps2d: added to the diagonal of every projected 2D covariance (low-pass filter).
        radius_clip: skip Gaussians whose pixel radii are both <= this.
        backend: "auto", "torch" or "gsplat" (see :class:`RasterConfig`).
        tile_size, chunk_tiles, block_k, checkpoint: see :class:`RasterConfig`.

    Returns:
        render_colors (C, H, W, X) with X = D, 1 or D + 1 by mode; render_alphas (C, H, W, 1);
        meta: gsplat's packed=False intermediates: ``means2d`` (C, N, 2) (call
        ``.retain_grad()`` on it before backward to read the densification gradient),
        ``radii`` (C, N, 2) int32 (0 = culled), ``depths`` (C, N), ``conics`` (C, N, 3),
        ``opacities`` (C, N), ``width``, ``height``, ``tile_size``, ``tile_width``,
        ``tile_height``, ``n_cameras``, ``n_batches``, ``gaussian_ids`` / ``camera_ids`` /
        ``batch_ids`` (None: not packed), ``tiles_per_gauss`` (C, N) and ``backend``.
    """
    if render_mode not in RENDER_MODES:
        raise ValueError(f"unknown render_mode {render_mode!r}; choose one of {RENDER_MODES}")
    N, C = means.shape[0], viewmats.shape[0]
    _check_shapes(means, quats, scales, opacities, colors, viewmats, Ks, backgrounds, N, C)
    chosen = select_backend(backend, means.device)
    if chosen == "gsplat":
        from radar4dgs.render.gsplat_backend import rasterize_gsplat

        return rasterize_gsplat(
            means, quats, scales, opacities, colors, viewmats, Ks, width, height,
            near_plane=near_plane, far_plane=far_plane, backgrounds=backgrounds,
            render_mode=render_mode, eps2d=eps2d, radius_clip=radius_clip,
            tile_size=16 if tile_size is None else tile_size,
        )  # fmt: skip
    return _rasterize_torch(
        means, quats, scales, opacities, colors, viewmats, Ks, width, height,
        near_plane, far_plane, backgrounds, render_mode, eps2d, radius_clip,
        8 if tile_size is None else tile_size, chunk_tiles, block_k, checkpoint,
    )  # fmt: skip


def _check_shapes(means, quats, scales, opacities, colors, viewmats, Ks, backgrounds, N, C):
    """Fail early with readable messages (gsplat asserts the same shapes)."""
    expect = {
        "means": (means, (N, 3)),
        "quats": (quats, (N, 4)),
        "scales": (scales, (N, 3)),
        "opacities": (opacities, (N,)),
        "viewmats": (viewmats, (C, 4, 4)),
        "Ks": (Ks, (C, 3, 3)),
    }
    for name, (t, shape) in expect.items():
        if tuple(t.shape) != shape:
            raise ValueError(f"{name} has shape {tuple(t.shape)}, expected {shape}")
    if not (colors.dim() == 2 and colors.shape[0] == N) and not (
        colors.dim() == 3 and tuple(colors.shape[:2]) == (C, N)
    ):
        raise ValueError(f"colors has shape {tuple(colors.shape)}, expected (N, D) or (C, N, D)")
    if backgrounds is not None and tuple(backgrounds.shape) != (C, colors.shape[-1]):
        raise ValueError(
            f"backgrounds has shape {tuple(backgrounds.shape)}, expected {(C, colors.shape[-1])}"
        )


def mode_features(colors: Tensor, depths: Tensor, backgrounds: Tensor | None, render_mode: str
                  ) -> tuple[Tensor, Tensor | None]:  # fmt: skip
    """Per-camera features to composite, as gsplat's rendering.py builds them.

    colors (C, N, D), depths (C, N), backgrounds (C, D) or None -> features (C, N, X),
    backgrounds (C, X) or None (zeros for the depth channel).
    """
    if render_mode in ("RGB+D", "RGB+ED"):
        feats = torch.cat((colors, depths[..., None]), dim=-1)
        if backgrounds is not None:
            backgrounds = torch.cat((backgrounds, backgrounds.new_zeros((len(backgrounds), 1))), -1)
        return feats, backgrounds
    if render_mode in ("D", "ED"):
        bg = None if backgrounds is None else backgrounds.new_zeros((len(backgrounds), 1))
        return depths[..., None], bg
    return colors, backgrounds


def expected_depth(render_colors: Tensor, render_alphas: Tensor, render_mode: str) -> Tensor:
    """Turn the accumulated depth (last channel) into the expected depth for "ED" modes."""
    if render_mode not in ("ED", "RGB+ED"):
        return render_colors
    depth = render_colors[..., -1:] / render_alphas.clamp(min=1e-10)
    return torch.cat((render_colors[..., :-1], depth), dim=-1)


def _rasterize_torch(
    means, quats, scales, opacities, colors, viewmats, Ks, width, height,
    near_plane, far_plane, backgrounds, render_mode, eps2d, radius_clip,
    tile_size, chunk_tiles, block_k, checkpoint,
) -> tuple[Tensor, Tensor, dict[str, Any]]:  # fmt: skip
    C, N = viewmats.shape[0], means.shape[0]
    proj = project_gaussians(
        means, quats, scales, opacities, viewmats, Ks, width, height,
        eps2d=eps2d, near_plane=near_plane, far_plane=far_plane, radius_clip=radius_clip,
    )  # fmt: skip
    opac_c = opacities[None, :].expand(C, N)
    colors_c = colors if colors.dim() == 3 else colors[None].expand(C, N, colors.shape[-1])
    feats, bgs = mode_features(colors_c, proj.depths, backgrounds, render_mode)
    render_colors, render_alphas, bins = rasterize_pixels(
        proj.means2d, proj.conics, opac_c, feats, proj.radii, proj.depths, width, height,
        backgrounds=bgs, tile_size=tile_size, chunk_tiles=chunk_tiles,
        block_k=block_k, checkpoint=checkpoint,
    )  # fmt: skip
    render_colors = expected_depth(render_colors, render_alphas, render_mode)
    meta = {
        "batch_ids": None,
        "camera_ids": None,
        "gaussian_ids": None,
        "radii": proj.radii,
        "means2d": proj.means2d,
        "depths": proj.depths,
        "conics": proj.conics,
        "opacities": opac_c,
        "tile_width": bins.tiles_x,
        "tile_height": bins.tiles_y,
        "tiles_per_gauss": bins.tiles_per_gauss,
        "width": width,
        "height": height,
        "tile_size": tile_size,
        "n_batches": 1,
        "n_cameras": C,
        "backend": "torch",
    }
    return render_colors, render_alphas, meta
