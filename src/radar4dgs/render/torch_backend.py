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
is sorted by depth. Tiles are sorted by list length and grouped into chunks of up to 64 tiles, a
dense padded (tiles, K) index matrix each. A chunk is composited ``block_k`` (32) list entries
at a time, so each step works on (64 tiles, 64 pixels, 32 entries) tensors that stay in cache,
and a tile leaves the loop once all its pixels stopped or its list ended (gsplat's early exit:
in dense scenes most of a list lies behind opaque content). In a step, ``log(o) - sigma`` at all
(tile, pixel, entry) triples is one batched matmul of six pixel monomials (1, x, y, x^2, y^2, xy,
relative to the tile centre to keep float32 cancellation small) with six per-Gaussian
coefficients. The transmittance is a cumulative product along the list; because it only
decreases, gsplat's stop rule blends exactly a prefix, and the blending weights are the
decrements of the transmittance clamped from below at its value after that prefix. Every step is
a handful of full-size passes without boolean masks (masks cost 5-20x an arithmetic pass on
CPU). The colour is one more batched matmul. The backward pass is written by hand (a
``torch.autograd.Function``) from the saved alphas and weights, visiting the steps back to
front with a running sum for the "later Gaussians" term, and reduces the per-pixel gradient of
sigma to six pixel moments (again one batched matmul), from which the gradients of the 2D mean,
conic and opacity follow per Gaussian.

Memory: by default the forward keeps each step's alphas and weights (two (tiles, 64, block_k)
tensors per step, only for tiles still compositing) for the backward; ``checkpoint=True`` keeps
nothing per chunk and recomputes them chunk by chunk in the backward (activation checkpointing
done by hand, because the backward is hand-written), capping memory at about one chunk.

Denormals: transmittances decay towards 0 and products of tiny floats go denormal, which is
~100x slower on x86. ``rasterize_pixels`` turns on ``torch.set_flush_denormal(True)`` for the
duration of each forward and backward call and restores the previous setting afterwards (no
global state change on import).
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from typing import Iterator

import torch
import torch.nn.functional as F
from torch import Tensor

# gsplat 1.5.3 constants (gsplat/cuda/csrc/RasterizeToPixels3DGSFwd.cu, cuda/include/Common.h).
MAX_ALPHA = 0.999  # `min(0.999f, opac * __expf(-sigma))`
ALPHA_THRESHOLD = 1.0 / 255.0  # `#define ALPHA_THRESHOLD (1.f / 255.f)`, skip below
TRANSMITTANCE_THRESHOLD = 1e-4  # `if (next_T <= 1e-4f)`: stop, that Gaussian not blended
LOG_MAX_ALPHA = math.log(MAX_ALPHA)
# log-opacity given to padding slots of a chunk: exp() of it is exactly 0 in float32/64.
_PAD_LOG_OPACITY = -1.0e4


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
# Tile binning
# --------------------------------------------------------------------------------------------


@dataclass
class TileBins:
    """Depth-sorted per-tile lists of (camera, Gaussian) pairs, flat over all cameras.

    Flat pair index ``f = c * N + n``; flat tile index ``c * tiles_y * tiles_x + ty * tiles_x + tx``.
    """

    flatten_ids: Tensor  # (n_isects,) int64 flat pair index, grouped by tile, depth-sorted
    tile_offsets: Tensor  # (n_tiles_total,) int64 start of each tile in flatten_ids
    tile_counts: Tensor  # (n_tiles_total,) int64 list length per tile
    tiles_per_gauss: Tensor  # (C, N) int64
    tiles_x: int
    tiles_y: int


def bin_gaussians(
    means2d: Tensor, radii: Tensor, depths: Tensor, tile_size: int, width: int, height: int
) -> TileBins:
    """Bin projected Gaussians to tiles (gsplat ``isect_tiles`` + ``isect_offset_encode``).

    means2d (C, N, 2), radii (C, N, 2) int, depths (C, N). Tile range of a Gaussian:
    ``[floor((m - r)/ts), ceil((m + r)/ts))`` clamped to the grid, as in IntersectTile.cu.
    """
    C, N = depths.shape
    device = depths.device
    tiles_x = math.ceil(width / tile_size)
    tiles_y = math.ceil(height / tile_size)
    n_tiles = tiles_x * tiles_y
    with torch.no_grad():
        m = means2d.detach() / tile_size
        r = radii.to(means2d.dtype) / tile_size
        lo = torch.floor(m - r).clamp(min=0)
        hi = torch.ceil(m + r)
        lo_x = lo[..., 0].clamp(max=tiles_x).long()
        lo_y = lo[..., 1].clamp(max=tiles_y).long()
        hi_x = hi[..., 0].clamp(min=0, max=tiles_x).long()
        hi_y = hi[..., 1].clamp(min=0, max=tiles_y).long()
        nx = (hi_x - lo_x).clamp(min=0)
        ny = (hi_y - lo_y).clamp(min=0)
        visible = (radii > 0).all(dim=-1)
        tiles_per_gauss = nx * ny * visible  # (C, N)

        flat_count = tiles_per_gauss.reshape(-1)
        pairs = torch.nonzero(flat_count, as_tuple=True)[0]  # flat pair ids with >= 1 tile
        # Visit pairs front to back (stable: ties keep index order), so that a stable sort by
        # tile afterwards leaves every tile's list depth-sorted, as gsplat's radix sort does.
        order = torch.sort(depths.detach().reshape(-1)[pairs], stable=True).indices
        pairs = pairs[order]
        counts = flat_count[pairs]
        total = int(counts.sum())
        owner = torch.repeat_interleave(torch.arange(len(pairs), device=device), counts)
        starts = torch.cumsum(counts, 0) - counts
        local = torch.arange(total, device=device) - starts[owner]
        pair_of = pairs[owner]
        nx_of = nx.reshape(-1)[pair_of]
        tx = lo_x.reshape(-1)[pair_of] + local % nx_of.clamp(min=1)
        ty = lo_y.reshape(-1)[pair_of] + local // nx_of.clamp(min=1)
        cam = pair_of // N
        tile_key = cam * n_tiles + ty * tiles_x + tx
        tile_key, perm = torch.sort(tile_key, stable=True)
        flatten_ids = pair_of[perm]
        tile_counts = torch.bincount(tile_key, minlength=C * n_tiles)
        tile_offsets = torch.cumsum(tile_counts, 0) - tile_counts
    return TileBins(flatten_ids, tile_offsets, tile_counts, tiles_per_gauss, tiles_x, tiles_y)


@dataclass
class Chunk:
    """A group of tiles with similar list lengths, as a dense padded (tiles, K) list."""

    tiles: Tensor  # (T,) int64 flat tile ids
    ids: Tensor  # (T, K) int64 flat pair ids; padding slots point at the dummy row C * N
    origin: Tensor  # (T, 2) pixel coordinates of the tile centres (x, y)
    counts: Tensor  # (T,) int64 list length per tile


def plan_chunks(
    bins: TileBins, n_pairs: int, tile_size: int, chunk_tiles: int, dtype: torch.dtype
) -> list[Chunk]:
    """Group non-empty tiles into chunks of at most ``chunk_tiles`` tiles, longest lists first.

    Sorting tiles by list length keeps the padding of each chunk's (T, K) list matrix small.
    """
    device = bins.tile_counts.device
    nonempty = torch.nonzero(bins.tile_counts, as_tuple=True)[0]
    if len(nonempty) == 0:
        return []
    counts = bins.tile_counts[nonempty]
    counts, order = torch.sort(counts, descending=True, stable=True)
    tiles = nonempty[order]
    counts_list = counts.tolist()
    n_tiles_img = bins.tiles_x * bins.tiles_y
    chunks = []
    start = 0
    while start < len(counts_list):
        k = counts_list[start]
        stop = min(len(counts_list), start + chunk_tiles)
        t = tiles[start:stop]
        arange_k = torch.arange(k, device=device)
        slot = bins.tile_offsets[t][:, None] + arange_k  # (T, K)
        valid = arange_k[None, :] < bins.tile_counts[t][:, None]
        ids = torch.where(
            valid,
            bins.flatten_ids[slot.clamp(max=len(bins.flatten_ids) - 1)],
            torch.full_like(slot, n_pairs),
        )
        local = t % n_tiles_img
        origin = torch.stack(
            ((local % bins.tiles_x) * tile_size, (local // bins.tiles_x) * tile_size), dim=-1
        ).to(dtype) + 0.5 * tile_size
        chunks.append(Chunk(tiles=t, ids=ids, origin=origin, counts=bins.tile_counts[t]))
        start = stop
    return chunks


def pixel_monomials(tile_size: int, dtype: torch.dtype, device: torch.device) -> Tensor:
    """(P, 6) monomials (1, x, y, x^2, y^2, x y) of the P = ts^2 pixel centres of a tile,
    in coordinates relative to the tile centre (row-major pixels)."""
    r = torch.arange(tile_size, dtype=dtype, device=device) + 0.5 - 0.5 * tile_size
    y, x = torch.meshgrid(r, r, indexing="ij")
    x, y = x.reshape(-1), y.reshape(-1)
    return torch.stack((torch.ones_like(x), x, y, x * x, y * y, x * y), dim=-1)


# --------------------------------------------------------------------------------------------
# Per-block forward / backward kernels
# --------------------------------------------------------------------------------------------


def _rows(table: Tensor, ids: Tensor) -> Tensor:
    """table (R, X) rows at ids (T, B) -> (T, B, X); index_select is much faster than
    advanced indexing on CPU."""
    return table.index_select(0, ids.reshape(-1)).reshape(ids.shape + table.shape[1:])


def param_table(means2d: Tensor, conics: Tensor, opacities: Tensor) -> Tensor:
    """Per-pair rows ``[mx, my, a, b, c, log o, o]``, (CN + 1, 7), one gather per block.

    The last row is the dummy that padding slots point at: log o = -1e4 makes its alpha 0.
    """
    log_o = torch.log(opacities.clamp(min=1e-30))
    rows = torch.cat((means2d, conics, log_o[:, None], opacities[:, None]), dim=1)
    dummy = rows.new_zeros((1, 7))
    dummy[0, 5] = _PAD_LOG_OPACITY
    dummy[0, 6] = 1.0
    return torch.cat((rows, dummy), dim=0)


def block_logit(prm: Tensor, origin: Tensor, mono: Tensor) -> Tensor:
    """``log(o) - sigma`` for every (tile, pixel, slot): (T, P, B).

    prm (T, B, 7) gathered rows, origin (T, 2) tile centres, mono (P, 6) pixel monomials.
    sigma = 0.5 a (ux-x)^2 + b (ux-x)(uy-y) + 0.5 c (uy-y)^2 with (ux, uy) the mean and (x, y)
    the pixel, both relative to the tile centre, expanded as a polynomial in (x, y): one matmul.
    """
    ux = prm[..., 0] - origin[:, None, 0]
    uy = prm[..., 1] - origin[:, None, 1]
    a, b, c, log_o = prm[..., 2], prm[..., 3], prm[..., 4], prm[..., 5]
    sig0 = 0.5 * a * ux * ux + b * ux * uy + 0.5 * c * uy * uy
    coef = torch.stack(
        (log_o - sig0, a * ux + b * uy, b * ux + c * uy, -0.5 * a, -0.5 * c, -b), dim=-2
    )  # (T, 6, B)
    return torch.matmul(mono, coef)


@dataclass
class Block:
    """What the backward needs of one (tiles, slots) block of the forward."""

    tiles: Tensor  # (T,) flat tile ids (the tiles of the chunk still compositing)
    ids: Tensor  # (T, B) flat pair ids
    origin: Tensor  # (T, 2)
    alpha: Tensor | None  # (T, P, B) alpha of blended entries, 0 for skipped / after the stop
    weight: Tensor | None  # (T, P, B) blending weight alpha * T
    live: Tensor | None  # (T, P, B) bool, alpha below the 0.999 clamp; None: no clamping possible


def forward_chunk(
    chunk: Chunk,
    prm: Tensor,
    colors: Tensor,
    mono: Tensor,
    block_k: int,
    out: Tensor | None,
    t_final: Tensor | None,
    keep: bool,
) -> list[Block]:
    """Composite one chunk, ``block_k`` list entries at a time, front to back.

    prm (CN + 1, 7) and colors (CN + 1, D) tables; out (tiles, D, P) accumulates colours and
    t_final (tiles, P) receives final transmittances (both may be None: recompute for the
    backward). A tile leaves the loop when all its pixels stopped or its list is exhausted,
    which is gsplat's early exit. Returns the blocks' records when ``keep``.
    """
    tiles, ids, origin, counts = chunk.tiles, chunk.ids, chunk.origin, chunk.counts
    n, P = len(tiles), mono.shape[0]
    t_run = mono.new_ones((n, P))  # transmittance so far; 0 once a pixel stopped
    t_fin = mono.new_ones((n, P))  # transmittance after the last blended entry
    skip_below = torch.nextafter(  # threshold() keeps x > th; this keeps alpha >= 1/255
        torch.tensor(ALPHA_THRESHOLD, dtype=mono.dtype), torch.tensor(0.0, dtype=mono.dtype)
    ).item()
    records: list[Block] = []
    for k0 in range(0, ids.shape[1], block_k):
        if k0 > 0:
            alive = (t_run.amax(dim=1) > 0) & (counts > k0)
            if not bool(alive.all()):
                if t_final is not None:
                    t_final[tiles] = t_fin
                sel = torch.nonzero(alive, as_tuple=True)[0]
                if len(sel) == 0:
                    break
                tiles, ids, origin, counts = tiles[sel], ids[sel], origin[sel], counts[sel]
                t_run, t_fin = t_run[sel], t_fin[sel]
        ids_b = ids[:, k0 : k0 + block_k]
        prm_b = _rows(prm, ids_b)  # (T, B, 7)
        logit = block_logit(prm_b, origin, mono)
        # alpha = min(0.999, o exp(-sigma)); clamping the logit first keeps it to one pass.
        # Clamped alphas get no gradient; only Gaussians with o >= 0.999 can clamp.
        live = logit < LOG_MAX_ALPHA if bool((prm_b[..., 6] >= MAX_ALPHA).any()) else None
        alpha = logit.clamp_(max=LOG_MAX_ALPHA).exp_()
        F.threshold_(alpha, skip_below, 0.0)  # skip alpha < 1/255
        one_minus = torch.rsub(alpha, 1.0)
        one_minus[..., 0] *= t_run
        t_incl = torch.cumprod(one_minus, dim=-1)  # T after each entry, (T, P, B)
        t_ext = torch.cat((t_run[..., None], t_incl), dim=-1)  # T before each entry, + after
        # Stop rule: an entry is blended only while T after it stays > 1e-4; T only decreases,
        # so the blended entries are a prefix and T after the last one is the smallest T > 1e-4.
        running = t_run > 0
        t_stop = F.threshold(t_ext, TRANSMITTANCE_THRESHOLD, math.inf).amin(dim=-1)
        t_stop = torch.where(running, t_stop, torch.zeros_like(t_stop))
        t_fin = torch.where(running, t_stop, t_fin)
        t_run = F.threshold(t_incl[..., -1], TRANSMITTANCE_THRESHOLD, 0.0)
        # T clamped at the stop value: its decrements are alpha_k T_k before the stop, 0 after.
        u = torch.maximum(t_ext, t_stop[..., None])
        weight = u[..., :-1] - u[..., 1:]
        if out is not None:
            col_t = _rows(colors, ids_b).transpose(1, 2)  # (T, D, B)
            out.index_add_(0, tiles, torch.bmm(col_t, weight.transpose(1, 2)))
        if keep:
            alpha_b = weight / u[..., :-1].clamp(min=torch.finfo(u.dtype).tiny)
            records.append(Block(tiles, ids_b, origin, alpha_b, weight, live))
    if t_final is not None:
        t_final[tiles] = t_fin
    return records


def backward_blocks(
    blocks: list[Block],
    prm: Tensor,
    colors: Tensor,
    mono: Tensor,
    grad_px: Tensor,
    grad_t: Tensor,
    later: Tensor,
    grads: Tensor,
) -> None:
    """Accumulate the gradients of one chunk's blocks (visited back to front) into ``grads``.

    grad_px (tiles, P, D) and grad_t (tiles, D, P): the colour gradient in both layouts;
    later (tiles, P): running sum over already visited (later) entries of <dL/dC, c_j> w_j,
    initialised with the background / alpha terms; grads (CN + 1, 6 + D) rows
    [d mx, d my, d a, d b, d c, d o, d colour].

    With q_k = <dL/dC, c_k>, w_k = alpha_k T_k and later_k = sum_{j>k} q_j w_j + T_N (<dL/dC, bg>
    - dL/dalpha_out): dL/dalpha_k = T_k q_k - later_k / (1 - alpha_k), and as
    alpha = o exp(-sigma): dL/dsigma_k = -alpha_k dL/dalpha_k = later_k r_k - q_k w_k with
    r = alpha / (1 - alpha).
    """
    for blk in reversed(blocks):
        tiles = blk.tiles
        prm_b = _rows(prm, blk.ids)  # (T, B, 7)
        col_b = _rows(colors, blk.ids)  # (T, B, D)
        qw = torch.bmm(grad_px.index_select(0, tiles), col_b.transpose(1, 2).contiguous())
        qw.mul_(blk.weight)
        cum = torch.cumsum(qw, dim=-1)
        total = cum[..., -1]
        base = later.index_select(0, tiles) + total
        later.index_copy_(0, tiles, base)
        lat = torch.rsub(cum, base[..., None])  # sum over entries after k, (T, P, B)
        r = blk.alpha / torch.rsub(blk.alpha, 1.0)
        d_sigma = lat.mul_(r).sub_(qw)
        if blk.live is not None:
            d_sigma.mul_(blk.live)
        m0, m1, m2, m3, m4, m5 = torch.matmul(mono.transpose(0, 1), d_sigma).unbind(dim=-2)
        ux = prm_b[..., 0] - blk.origin[:, None, 0]
        uy = prm_b[..., 1] - blk.origin[:, None, 1]
        a, b, c, o = prm_b[..., 2], prm_b[..., 3], prm_b[..., 4], prm_b[..., 6]
        # sums over pixels of dx^k dy^l dL/dsigma, with dx = ux - x, dy = uy - y
        sdx = ux * m0 - m1
        sdy = uy * m0 - m2
        sdxx = ux * ux * m0 - 2 * ux * m1 + m3
        sdyy = uy * uy * m0 - 2 * uy * m2 + m4
        sdxy = ux * uy * m0 - ux * m2 - uy * m1 + m5
        d_col = torch.bmm(grad_t.index_select(0, tiles), blk.weight).transpose(1, 2)  # (T, B, D)
        rows = torch.cat(
            (
                torch.stack(
                    (a * sdx + b * sdy, b * sdx + c * sdy, 0.5 * sdxx, sdxy, 0.5 * sdyy, -m0 / o),
                    dim=-1,
                ),
                d_col,
            ),
            dim=-1,
        )
        grads.index_add_(0, blk.ids.reshape(-1), rows.reshape(-1, rows.shape[-1]))


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
            for chunk, blocks in zip(plan.chunks, ctx.saved_blocks):
                if plan.checkpoint:
                    blocks = forward_chunk(chunk, prm, col, plan.mono, plan.block_k,
                                           None, None, keep=True)  # fmt: skip
                backward_blocks(blocks, prm, col, plan.mono, grad_px, grad_t, later, grads)
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
