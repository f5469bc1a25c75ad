"""The rasterizer's options (torch-free, so configurations and the CLI load without torch)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal

RenderMode = Literal["RGB", "D", "ED", "RGB+D", "RGB+ED"]
Backend = Literal["auto", "torch", "gsplat"]
RENDER_MODES: tuple[str, ...] = ("RGB", "D", "ED", "RGB+D", "RGB+ED")


@dataclass
class RasterConfig:
    """Renderer options (the CLI's ``--rasterizer`` maps to ``backend``)."""

    # "auto": gsplat when the tensors are on CUDA and gsplat imports, else the torch backend.
    # "torch" forces the pure-PyTorch rasterizer (any device); "gsplat" requires CUDA tensors.
    backend: Backend = "auto"
    # Tile edge in pixels; None = the backend's best (8 for torch: much faster than 16 on CPU;
    # 16 for gsplat, whose CUDA kernels are tuned and tested for it). Output does not depend on it.
    tile_size: int | None = None
    # torch backend: at most this many tiles per chunk (tiles are grouped by list length).
    chunk_tiles: int = 64
    # torch backend: list entries composited per step; a step's (tiles, pixels, entries) tensors
    # are chunk_tiles * tile_size^2 * block_k floats (64 * 64 * 32 = 512 KB float32: in cache).
    # Tiles whose pixels all stopped leave after each step (gsplat's early exit).
    block_k: int = 32
    # torch backend: keep nothing per chunk for the backward and recompute it (caps memory at
    # about one chunk, costs roughly one extra forward).
    checkpoint: bool = False

    def kwargs(self) -> dict[str, Any]:
        """The options as keyword arguments of :func:`rasterize` (every field is one)."""
        return dataclasses.asdict(self)
