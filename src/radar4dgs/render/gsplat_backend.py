"""gsplat (pinned 1.5.3, the ``cuda`` extra) as the CUDA backend of :func:`radar4dgs.render.rasterize`.

gsplat is imported lazily and only for CUDA tensors: on a machine with nvcc but no GPU, importing
gsplat starts a JIT compile of its CUDA extension that cannot succeed. Nothing in this module
imports gsplat at import time.
"""

from __future__ import annotations

import functools
from typing import Any

from torch import Tensor

GSPLAT_VERSION = "1.5.3"


@functools.lru_cache(maxsize=1)
def gsplat_available() -> bool:
    """True when gsplat imports. Call only once CUDA tensors are in hand (see module docstring)."""
    try:
        import gsplat  # noqa: F401
    except Exception:  # ImportError, or a failed JIT build raising anything
        return False
    return True


def rasterize_gsplat(
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
    render_mode: str = "RGB",
    eps2d: float = 0.3,
    radius_clip: float = 0.0,
    tile_size: int = 16,
) -> tuple[Tensor, Tensor, dict[str, Any]]:
    """gsplat.rasterization with the options fixed to those the torch backend reproduces:
    packed=False (per-camera layout of meta, as densification expects), classic mode, pinhole,
    no SH. Shapes as :func:`radar4dgs.render.rasterize`."""
    if means.device.type != "cuda":
        raise ValueError(f"the gsplat backend needs CUDA tensors, got device {means.device}")
    import gsplat

    render_colors, render_alphas, meta = gsplat.rasterization(
        means=means,
        quats=quats,
        scales=scales,
        opacities=opacities,
        colors=colors,
        viewmats=viewmats,
        Ks=Ks,
        width=width,
        height=height,
        near_plane=near_plane,
        far_plane=far_plane,
        radius_clip=radius_clip,
        eps2d=eps2d,
        sh_degree=None,
        packed=False,
        tile_size=tile_size,
        backgrounds=backgrounds,
        render_mode=render_mode,
        rasterize_mode="classic",
        camera_model="pinhole",
    )
    meta["backend"] = "gsplat"
    return render_colors, render_alphas, meta
