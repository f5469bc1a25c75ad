"""Differentiable Gaussian rasterization: one API (:func:`rasterize`), two backends.

gsplat 1.5.3 on CUDA (imported lazily, only for CUDA tensors) and a hand-written tile-based
pure-PyTorch rasterizer everywhere else (:mod:`radar4dgs.render.torch_backend`). Importing this
package does not import torch: :func:`rasterize` and :func:`select_backend` load the backends on
first use, so configurations (:class:`RasterConfig`) stay cheap to import for the CLI.
"""

from __future__ import annotations

import importlib
from typing import Any

from radar4dgs.render.config import RENDER_MODES, RasterConfig

_LAZY = {"rasterize": "radar4dgs.render.api", "select_backend": "radar4dgs.render.api"}

__all__ = ["RENDER_MODES", "RasterConfig", "rasterize", "select_backend"]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
