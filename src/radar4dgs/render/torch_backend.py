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
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from typing import Iterator

import torch
import torch.nn.functional as F
from torch import Tensor

# The skip threshold (`#define ALPHA_THRESHOLD (1.f / 255.f)`) is shared with the projection's cull.
from radar4dgs.render.projection import ALPHA_THRESHOLD

# gsplat 1.5.3 constants (gsplat/cuda/csrc/RasterizeToPixels3DGSFwd.cu, cuda/include/Common.h).
MAX_ALPHA = 0.999  # `min(0.999f, opac * __expf(-sigma))`
TRANSMITTANCE_THRESHOLD = 1e-4  # `if (next_T <= 1e-4f)`: stop, that Gaussian not blended
# alpha is evaluated as exp2 of a base-2 logit: exp2 is ~2x cheaper than exp on CPU (AVX2).
LOG2_E = 1.0 / math.log(2.0)
LOG2_MAX_ALPHA = math.log2(MAX_ALPHA)
# Binning uses int32 intersection arrays below this size (tests lower it to cover int64).
_INT32_LIMIT = 2**31
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
        order = torch.sort(depths.detach().reshape(-1).index_select(0, pairs), stable=True).indices
        pairs = pairs.index_select(0, order)
        counts = flat_count.index_select(0, pairs)
        # Per-intersection arrays are int32 where the sizes allow (half the memory traffic).
        total = int(counts.sum())
        small = max(total, C * n_tiles, len(pairs)) < _INT32_LIMIT
        itype = torch.int32 if small else torch.int64
        nx_p = nx.reshape(-1).index_select(0, pairs).to(itype)
        # first tile of each pair's box; entry `local` of a box sits at row local // nx, column
        # local % nx: tile = first + local + (local // nx) (tiles_x - nx)
        cam = torch.div(pairs, max(N, 1), rounding_mode="floor")
        first = (cam * n_tiles + lo_y.reshape(-1).index_select(0, pairs) * tiles_x
                 + lo_x.reshape(-1).index_select(0, pairs)).to(itype)  # fmt: skip
        counts = counts.to(itype)
        owner = torch.repeat_interleave(torch.arange(len(pairs), device=device, dtype=itype),
                                        counts, output_size=total)  # fmt: skip
        starts = (torch.cumsum(counts, 0) - counts).to(itype)
        local = torch.arange(total, device=device, dtype=itype) - starts.index_select(0, owner)
        nx_o = nx_p.index_select(0, owner)
        row = torch.div(local, nx_o.clamp(min=1), rounding_mode="floor")
        tile_key = first.index_select(0, owner) + local + row * (tiles_x - nx_o)
        tile_key, perm = torch.sort(tile_key, stable=True)
        flatten_ids = pairs.index_select(0, owner.index_select(0, perm))
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
            _rows(bins.flatten_ids, slot.clamp(max=len(bins.flatten_ids) - 1)),
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


@dataclass
class Block:
    """What the backward needs of one (tiles, slots) block of the forward."""

    tiles: Tensor  # (T,) flat tile ids (the tiles of the chunk still compositing)
    rows: Tensor | None  # (T,) their rows in the chunk; None: all rows of the chunk
    k0: int  # first list slot of the block
    weight: Tensor  # (T, P, B) blending weight alpha * T; 0 for skipped / after the stop
    t_after: Tensor  # (T, P, B) transmittance after each entry, clamped from below at its
    # value after the stop (> 0): weight / t_after = alpha / (1 - alpha) while blending, 0 after
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

    Every op here runs once per block on (tiles, pixels, entries) tensors or is cheap and
    per chunk: the per-op dispatch cost (microseconds) matters as much as the arithmetic.
    """
    tiles, ids, origin, counts = chunk.tiles, chunk.ids, chunk.origin, chunk.counts
    n, P = len(tiles), mono.shape[0]
    dtype = mono.dtype
    t_run = mono.new_ones((n, P))  # transmittance so far; 0 once a pixel stopped
    t_fin = mono.new_ones((n, P))  # transmittance after the last blended entry
    skip_below = torch.nextafter(  # threshold() keeps x > th; this keeps alpha >= 1/255
        torch.tensor(ALPHA_THRESHOLD, dtype=dtype), torch.tensor(0.0, dtype=dtype)
    ).item()
    one = mono.new_ones(())
    K = ids.shape[1]
    # Per-Gaussian coefficients of the chunk, computed a few blocks at a time (lists are much
    # longer than the part composited before the tiles saturate); sliced per block.
    seg = 4 * block_k
    coef = _chunk_coefs(prm, ids[:, :seg], origin)
    # Opacities >= 0.999 can hit the alpha clamp: only blocks holding one record the clamp mask.
    clamp_upto = (_rows(prm[:, 6], ids) >= MAX_ALPHA).any(dim=0).cumsum(dim=0).tolist()
    # colours (T, D, K') of the first K' slots, extended with the coefficients
    col_t = _rows(colors, ids[:, :seg]).transpose(1, 2) if out is not None else None
    rows: Tensor | None = None
    records: list[Block] = []
    for k0 in range(0, K, block_k):
        if k0 > 0:
            alive = (t_run.amax(dim=1) > 0) & (counts > k0)
            if not bool(alive.all()):
                if t_final is not None:
                    t_final.index_copy_(0, tiles, t_fin)
                sel = torch.nonzero(alive, as_tuple=True)[0]
                if len(sel) == 0:
                    break
                tiles, ids, origin, counts = tiles[sel], ids[sel], origin[sel], counts[sel]
                t_run, t_fin, coef = t_run[sel], t_fin[sel], coef[sel]
                rows = sel if rows is None else rows[sel]
                if col_t is not None:
                    col_t = col_t[sel]
            if k0 % seg == 0:
                ids_s = ids[:, k0 : k0 + seg]
                coef = torch.cat((coef, _chunk_coefs(prm, ids_s, origin)), -1)
                if col_t is not None:
                    col_t = torch.cat((col_t, _rows(colors, ids_s).transpose(1, 2)), -1)
        k1 = min(K, k0 + block_k)
        B = k1 - k0
        logit = torch.matmul(mono, coef[:, :, k0:k1])  # log2(o) - sigma / ln 2, (T, P, B)
        clampable = clamp_upto[k1 - 1] > (clamp_upto[k0 - 1] if k0 > 0 else 0)
        live = logit < LOG2_MAX_ALPHA if clampable else None
        # alpha = min(0.999, o exp(-sigma)); clamping the logit first keeps it to one pass.
        # Clamped alphas get no gradient; only Gaussians with o >= 0.999 can clamp.
        # The lower clamp keeps exp2 out of denormals (2^-100 is skipped as < 1/255 anyway).
        alpha = torch.exp2(logit.clamp_(min=-100.0, max=LOG2_MAX_ALPHA), out=logit)
        F.threshold_(alpha, skip_below, 0.0)  # skip alpha < 1/255
        # t_ext[..., k]: T before entry k; t_ext[..., k + 1]: T after it. One buffer, one scan.
        t_ext = alpha.new_empty((len(tiles), P, B + 1))
        t_ext[..., 0] = t_run
        torch.sub(one, alpha, out=t_ext[..., 1:])
        del alpha, logit
        _cumprod_no_denormals_(t_ext)
        # Stop rule: an entry is blended only while T after it stays > 1e-4; T only decreases,
        # so the blended entries are a prefix and T after the last one is the smallest T > 1e-4
        # (<= 1: the min over an empty set, pixels stopped earlier, becomes 1: nothing blended).
        t_stop = F.threshold(t_ext, TRANSMITTANCE_THRESHOLD, math.inf).amin(dim=-1).clamp_(max=1)
        t_fin = torch.minimum(t_fin, t_stop)
        t_run = F.threshold(t_ext[..., -1], TRANSMITTANCE_THRESHOLD, 0.0)
        # T clamped at the stop value: its decrements are alpha_k T_k before the stop, 0 after.
        u = torch.maximum(t_ext, t_stop[..., None], out=t_ext)
        weight = u[..., :-1] - u[..., 1:]
        if col_t is not None:
            out.index_add_(0, tiles, torch.bmm(col_t[:, :, k0:k1], weight.transpose(1, 2)))
        if keep:
            records.append(Block(tiles, rows, k0, weight, u[..., 1:], live))
    if t_final is not None:
        t_final.index_copy_(0, tiles, t_fin)
    return records


# Scan length and floor of _cumprod_no_denormals_: factors 1 - alpha >= 1e-3, so 8 of them
# from >= 1e-12 stay >= 1e-36, a normal float32.
_SCAN = 8
_SCAN_FLOOR = 1e-12


def _cumprod_no_denormals_(t: Tensor) -> None:
    """In-place cumulative product along the last axis of transmittances without denormals.

    Denormal arithmetic is ~100x slower on x86, and ``set_flush_denormal`` only reaches the
    calling thread, not the intra-op worker threads. Past the stop (T <= 1e-4) the products keep
    shrinking towards underflow, so the scan runs in pieces of ``_SCAN`` entries and the running
    value is floored at ``_SCAN_FLOOR`` between pieces: a value below the floor is past the stop,
    where only "<= 1e-4" matters, so no result changes.
    """
    n = t.shape[-1]
    if n <= _SCAN + 1:
        t.cumprod_(dim=-1)
        return
    for k in range(0, n - 1, _SCAN):
        if k > 0:
            t[..., k].clamp_(min=_SCAN_FLOOR)
        t[..., k : k + _SCAN + 1].cumprod_(dim=-1)


def _chunk_coefs(prm: Tensor, ids: Tensor, origin: Tensor) -> Tensor:
    """(T, 6, K) coefficients of ``(log(o) - sigma) / ln 2`` in the pixel monomials
    (1, x, y, x^2, y^2, x y) relative to the tile centre.

    prm (CN + 1, 7) table, ids (T, K) pair ids, origin (T, 2) tile centres.
    sigma = 0.5 a (ux-x)^2 + b (ux-x)(uy-y) + 0.5 c (uy-y)^2 with (ux, uy) the mean and (x, y)
    the pixel, both relative to the tile centre, expanded as a polynomial in (x, y).
    """
    prm_c = _rows(prm, ids)  # (T, K, 7)
    ux = prm_c[..., 0] - origin[:, None, 0]
    uy = prm_c[..., 1] - origin[:, None, 1]
    a, b, c, log_o = prm_c[..., 2], prm_c[..., 3], prm_c[..., 4], prm_c[..., 5]
    sig0 = 0.5 * a * ux * ux + b * ux * uy + 0.5 * c * uy * uy
    return torch.stack(
        (log_o - sig0, a * ux + b * uy, b * ux + c * uy, -0.5 * a, -0.5 * c, -b), dim=-2
    ).mul_(LOG2_E)


def backward_blocks(
    chunk: Chunk,
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
    r = alpha / (1 - alpha) = w_k / T_{k+1} (0 after the stop, where w_k = 0).
    Per block only the pixel sums (six moments of dL/dsigma, the colour gradient) are formed,
    into a (tiles, slots) buffer of the chunk; the per-Gaussian chain rule runs once per chunk.
    """
    if not blocks:
        return
    D = colors.shape[1]
    n_used = max(blk.k0 + blk.weight.shape[-1] for blk in blocks)
    ids = chunk.ids[:, :n_used]
    col_t = _rows(colors, ids).transpose(1, 2)  # (T0, D, K)
    acc = grads.new_zeros((ids.shape[0], 6 + D, n_used))  # pixel sums per (tile, slot)
    mono_t = mono.transpose(0, 1)
    for blk in reversed(blocks):
        tiles = blk.tiles
        k0, k1 = blk.k0, blk.k0 + blk.weight.shape[-1]
        col_b = col_t[:, :, k0:k1] if blk.rows is None else col_t[blk.rows, :, k0:k1]
        qw = torch.bmm(grad_px.index_select(0, tiles), col_b)  # (T, P, B)
        qw.mul_(blk.weight)
        cum = torch.cumsum(qw, dim=-1)
        base = later.index_select(0, tiles) + cum[..., -1]
        later.index_copy_(0, tiles, base)
        lat = torch.rsub(cum, base[..., None])  # sum over entries after k, (T, P, B)
        d_sigma = lat.mul_(blk.weight).div_(blk.t_after).sub_(qw)
        if blk.live is not None:
            d_sigma.mul_(blk.live)
        sums = torch.cat(
            (torch.matmul(mono_t, d_sigma), torch.bmm(grad_t.index_select(0, tiles), blk.weight)),
            dim=1,
        )  # (T, 6 + D, B)
        if blk.rows is None:
            acc[:, :, k0:k1] = sums
        else:
            acc[:, :, k0:k1].index_copy_(0, blk.rows, sums)
    prm_c = _rows(prm, ids)  # (T0, K, 7)
    ux = prm_c[..., 0] - chunk.origin[:, None, 0]
    uy = prm_c[..., 1] - chunk.origin[:, None, 1]
    a, b, c, o = prm_c[..., 2], prm_c[..., 3], prm_c[..., 4], prm_c[..., 6]
    m0, m1, m2, m3, m4, m5 = acc[:, :6].unbind(dim=1)
    # sums over pixels of dx^k dy^l dL/dsigma, with dx = ux - x, dy = uy - y
    sdx = ux * m0 - m1
    sdy = uy * m0 - m2
    sdxx = ux * ux * m0 - 2 * ux * m1 + m3
    sdyy = uy * uy * m0 - 2 * uy * m2 + m4
    sdxy = ux * uy * m0 - ux * m2 - uy * m1 + m5
    g = torch.cat(
        (
            torch.stack(
                (a * sdx + b * sdy, b * sdx + c * sdy, 0.5 * sdxx, sdxy, 0.5 * sdyy, -m0 / o),
                dim=-1,
            ),
            acc[:, 6:].transpose(1, 2),
        ),
        dim=-1,
    )  # (T0, K, 6 + D)
    grads.index_add_(0, ids.reshape(-1), g.reshape(-1, 6 + D))


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
