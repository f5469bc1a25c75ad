"""Differentiable Gaussian rasterization: one API (:func:`rasterize`), two backends.

gsplat 1.5.3 on CUDA (imported lazily, only for CUDA tensors) and a hand-written tile-based
pure-PyTorch rasterizer everywhere else (:mod:`radar4dgs.render.torch_backend`).
"""

from radar4dgs.render.api import RENDER_MODES, RasterConfig, rasterize, select_backend

__all__ = ["RENDER_MODES", "RasterConfig", "rasterize", "select_backend"]
