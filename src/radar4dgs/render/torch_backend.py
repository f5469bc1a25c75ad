"""Tile-based, depth-sorted, differentiable Gaussian rasterizer in pure PyTorch (CPU or any device).

Written by hand because no maintained library rasterizes 3D Gaussians on CPU: gsplat is CUDA-only
and the pure-PyTorch ports are unmaintained. It reproduces gsplat 1.5.3's ``rasterize_to_pixels``
(``gsplat/cuda/csrc/RasterizeToPixels3DGSFwd.cu``, ``packed=False``) and its intersection step
(``IntersectTile.cu``):

- pixel centres at ``(j + 0.5, i + 0.5)``; ``sigma = 0.5 (a dx^2 + c dy^2) + b dx dy`` with
  ``dx = mean - pixel`` and conic ``(a, b, c)``;
- ``alpha = min(0.999, opacity * exp(-sigma))``  (fwd kernel: ``min(0.999f, opac * __expf(-sigma))``);
- skip when ``alpha < 1/255``  (``ALPHA_THRESHOLD (1.f / 255.f)``, Common.h). gsplat also skips
  ``sigma < 0``, which for a positive-definite conic only happens through rounding at the very
  centre; sigma is evaluated here as a polynomial that rounds differently, so that test would
  reject different pixels than gsplat's and is left out;
- stop *before* a Gaussian whose ``next_T = T (1 - alpha) <= 1e-4``; that Gaussian is not
  blended ("``if (next_T <= 1e-4f) { // this pixel is done: exclusive``");
- ``render_alpha = 1 - T``, ``render_color = sum_k c_k alpha_k T_k + T * background``;
- a Gaussian is binned to every tile its box ``mean +- radii`` touches; within a tile the order is
  by depth, ties by Gaussian index (stable radix sort of ``tile | depth`` keys built in index order).

Algorithm. Visible (camera, Gaussian) pairs are binned to 8x8-pixel tiles and each tile's list
is sorted by depth (one stable sort of int32 tile keys over pairs visited front to back). Tiles
are sorted by list length and grouped into chunks of up to 64 tiles, a dense padded (tiles, K)
index matrix each. A chunk is composited ``block_k`` (32) list entries at a time, so each step
works on (64 tiles, 64 pixels, 32 entries) tensors that stay in cache, and a tile leaves the
loop once all its pixels stopped or its list ended (gsplat's early exit: in dense scenes most of
a list lies behind opaque content). In a step, ``(log(o) - sigma) / ln 2`` at all (tile, pixel,
entry) triples is one batched matmul of six pixel monomials (1, x, y, x^2, y^2, xy, relative to
the tile centre to keep float32 cancellation small) with six per-Gaussian coefficients (computed
per chunk, a few blocks ahead), and alpha is its ``exp2`` (half the cost of ``exp`` on CPU). The
transmittance is a cumulative product along the list (one in-place scan of a (tiles, pixels,
entries + 1) buffer holding T before and after every entry); because it only decreases, gsplat's
stop rule blends exactly a prefix, and the blending weights are the decrements of the
transmittance clamped from below at its value after that prefix. Every step is a handful of
full-size passes without boolean masks (masks cost 5-20x an arithmetic pass on CPU). The colour
is one more batched matmul. The backward pass is written by hand (a ``torch.autograd.Function``)
from the saved weights and clamped transmittances (their ratio is alpha / (1 - alpha) before the
stop and 0 after it), visiting the steps back to front with a running sum for the "later
Gaussians" term; per step it only reduces over pixels (six moments of the gradient of sigma and
the colour gradient, two batched matmuls) into a per-chunk (tiles, entries) buffer, and the
chain rule to the 2D mean, conic and opacity runs once per chunk. Per-op dispatch costs a few
microseconds, comparable to a full-size pass, so the per-step op count is kept small.

Memory: by default the forward keeps each step's weights and clamped transmittances (two
(tiles, 64, block_k) tensors per step, only for tiles still compositing) for the backward;
``checkpoint=True`` keeps nothing per chunk and recomputes them chunk by chunk in the backward
(activation checkpointing done by hand, because the backward is hand-written), capping memory at
about one chunk.

Denormals: transmittances decay towards 0 and products of tiny floats go denormal, which is
~100x slower on x86. ``rasterize_pixels`` turns on ``torch.set_flush_denormal(True)`` for the
duration of each forward and backward call and restores the previous setting afterwards (no
global state change on import). That mode only reaches the calling thread, not torch's intra-op
worker threads (with 2 threads, half of every large op ran with denormals: 20 s instead of
0.13 s), so the kernels also avoid producing denormals: the base-2 logit is clamped at -100
before ``exp2`` and the transmittance scan is floored past the stop (``_cumprod_no_denormals_``).

Layout: :mod:`~radar4dgs.render.tile_bins` bins and chunks the tiles,
:mod:`~radar4dgs.render.composite_forward` composites a chunk,
:mod:`~radar4dgs.render.composite_backward` is its backward; this module ties them into a
``torch.autograd.Function`` (:func:`rasterize_pixels`).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import Iterator

import torch
from torch import Tensor

from radar4dgs.render.composite_backward import backward_blocks
from radar4dgs.render.composite_forward import forward_chunk, param_table, pixel_monomials
from radar4dgs.render.tile_bins import Chunk, TileBins, bin_gaussians, plan_chunks


@contextlib.contextmanager
def flush_denormal() -> Iterator[None]:
    """Flush denormal floats to zero inside the block; restore the previous mode after.

    torch has no getter, so the previous mode is probed with a denormal literal.
    """
    tiny = torch.tensor([1e-40], dtype=torch.float32)
    was_on = bool(tiny.item() == 0.0)
    torch.set_flush_denormal(True)
    try:
        yield
    finally:
        torch.set_flush_denormal(was_on)


# --------------------------------------------------------------------------------------------
# autograd.Function over all chunks
# --------------------------------------------------------------------------------------------


@dataclass
class _Plan:
    chunks: list[Chunk]
    n_tiles_total: int
    tile_size: int
    mono: Tensor
    cam_of_tile: Tensor
    block_k: int
    checkpoint: bool


class _RasterizePixels(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, backgrounds, plan):  # type: ignore[override]
        """means2d (CN, 2), conics (CN, 3), opacities (CN,), colors (CN, D), backgrounds (C, D).
        Returns colours (tiles, D, P) and final transmittances (tiles, P)."""
        with flush_denormal():
            prm = param_table(means2d, conics, opacities)
            col = torch.cat((colors, colors.new_zeros((1, colors.shape[1]))), dim=0)
            n_tiles, P, D = plan.n_tiles_total, plan.tile_size**2, colors.shape[-1]
            out = colors.new_zeros((n_tiles, D, P))
            t_final = colors.new_ones((n_tiles, P))
            saved = []
            for chunk in plan.chunks:
                saved.append(forward_chunk(
                    chunk, prm, col, plan.mono, plan.block_k, out, t_final,
                    keep=not plan.checkpoint,
                ))  # fmt: skip
            out += t_final[:, None, :] * backgrounds[plan.cam_of_tile][:, :, None]
        ctx.plan = plan
        ctx.saved_blocks = saved
        ctx.save_for_backward(means2d, conics, opacities, colors, backgrounds, t_final)
        return out, t_final

    @staticmethod
    def backward(ctx, grad_out, grad_tfinal):  # type: ignore[override]
        plan = ctx.plan
        means2d, conics, opacities, colors, backgrounds, t_final = ctx.saved_tensors
        with flush_denormal():
            prm = param_table(means2d, conics, opacities)
            col = torch.cat((colors, colors.new_zeros((1, colors.shape[1]))), dim=0)
            D = colors.shape[-1]
            grads = colors.new_zeros((len(prm), 6 + D))
            grad_t = grad_out.contiguous()  # (tiles, D, P)
            grad_px = grad_t.transpose(1, 2).contiguous()  # (tiles, P, D)
            bg_tile = backgrounds[plan.cam_of_tile]  # (tiles, D)
            # Entries "after" the last one: the background (colour += T bg) and the alpha
            # output (alpha = 1 - T, so dL/dT from grad_tfinal): both scale with T_final.
            later = t_final * (torch.bmm(grad_px, bg_tile[:, :, None]).squeeze(-1) + grad_tfinal)
            for chunk, blocks in zip(plan.chunks, ctx.saved_blocks, strict=True):
                if plan.checkpoint:
                    blocks = forward_chunk(chunk, prm, col, plan.mono, plan.block_k,
                                           None, None, keep=True)  # fmt: skip
                backward_blocks(chunk, blocks, prm, col, plan.mono, grad_px, grad_t, later, grads)
            g_bg = backgrounds.new_zeros(backgrounds.shape).index_add_(
                0, plan.cam_of_tile, (grad_t * t_final[:, None, :]).sum(dim=-1)
            )
        ctx.saved_blocks = None
        grads = grads[:-1]
        g_means = grads[:, 0:2]
        g_conics = grads[:, 2:5]
        # d log(o) / d o enters through sigma's coefficients only via log_o, handled as d o.
        g_opac = grads[:, 5]
        g_colors = grads[:, 6:]
        return g_means, g_conics, g_opac, g_colors, g_bg, None


def rasterize_pixels(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    colors: Tensor,
    radii: Tensor,
    depths: Tensor,
    width: int,
    height: int,
    backgrounds: Tensor | None = None,
    tile_size: int = 8,
    chunk_tiles: int = 64,
    block_k: int = 32,
    checkpoint: bool = False,
) -> tuple[Tensor, Tensor, TileBins]:
    """Composite projected Gaussians into C images (gsplat ``rasterize_to_pixels``, packed=False).

    means2d (C, N, 2), conics (C, N, 3), opacities (C, N), colors (C, N, D), radii (C, N, 2),
    depths (C, N) (sort key only), backgrounds (C, D) or None.
    Returns render_colors (C, H, W, D), render_alphas (C, H, W, 1) and the tile bins.
    A chunk is up to ``chunk_tiles`` tiles of similar list length, composited ``block_k`` list
    entries at a time: a block's (tiles, pixels, entries) tensors are 64 x 64 x 32 floats
    (512 KB in float32) by default, so they stay in cache.
    """
    C, N, D = colors.shape
    bins = bin_gaussians(means2d, radii, depths, tile_size, width, height)
    n_img_tiles = bins.tiles_x * bins.tiles_y
    chunks = plan_chunks(bins, C * N, tile_size, chunk_tiles, means2d.dtype)
    device = means2d.device
    plan = _Plan(
        chunks=chunks,
        n_tiles_total=C * n_img_tiles,
        tile_size=tile_size,
        mono=pixel_monomials(tile_size, means2d.dtype, device),
        cam_of_tile=torch.arange(C, device=device).repeat_interleave(n_img_tiles),
        block_k=block_k,
        checkpoint=checkpoint,
    )
    if backgrounds is None:
        backgrounds = colors.new_zeros((C, D))
    out, t_final = _RasterizePixels.apply(
        means2d.reshape(C * N, 2),
        conics.reshape(C * N, 3),
        opacities.reshape(C * N),
        colors.reshape(C * N, D),
        backgrounds,
        plan,
    )
    render_colors = _tiles_to_image(out.transpose(1, 2), C, bins, tile_size, width, height)
    alphas = 1.0 - _tiles_to_image(t_final[..., None], C, bins, tile_size, width, height)
    return render_colors, alphas, bins


def _tiles_to_image(x: Tensor, C: int, bins: TileBins, ts: int, width: int, height: int) -> Tensor:
    """(C * ty * tx, ts * ts, D) tile-major pixels -> (C, H, W, D) image (cropped)."""
    D = x.shape[-1]
    img = x.reshape(C, bins.tiles_y, bins.tiles_x, ts, ts, D).permute(0, 1, 3, 2, 4, 5)
    img = img.reshape(C, bins.tiles_y * ts, bins.tiles_x * ts, D)
    return img[:, :height, :width]
