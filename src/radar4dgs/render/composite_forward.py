"""Forward compositing of one chunk of tiles: alpha, transmittance scan, stop rule, blending.

Follows gsplat 1.5.3's ``RasterizeToPixels3DGSFwd.cu`` (see :mod:`radar4dgs.render.torch_backend`
for the rules and the algorithm). A chunk is composited ``block_k`` list entries at a time on
(tiles, pixels, entries) tensors; per block, the blending weights and clamped transmittances can be
recorded (:class:`Block`) for the hand-written backward in
:mod:`radar4dgs.render.composite_backward`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

# The skip threshold (`#define ALPHA_THRESHOLD (1.f / 255.f)`) is shared with the projection's cull.
from radar4dgs.render.projection import ALPHA_THRESHOLD
from radar4dgs.render.tile_bins import Chunk, gather_rows

# gsplat 1.5.3 constants (gsplat/cuda/csrc/RasterizeToPixels3DGSFwd.cu, cuda/include/Common.h).
MAX_ALPHA = 0.999  # `min(0.999f, opac * __expf(-sigma))`
TRANSMITTANCE_THRESHOLD = 1e-4  # `if (next_T <= 1e-4f)`: stop, that Gaussian not blended
# alpha is evaluated as exp2 of a base-2 logit: exp2 is ~2x cheaper than exp on CPU (AVX2).
LOG2_E = 1.0 / math.log(2.0)
LOG2_MAX_ALPHA = math.log2(MAX_ALPHA)
# log-opacity given to padding slots of a chunk: exp() of it is exactly 0 in float32/64.
_PAD_LOG_OPACITY = -1.0e4


def pixel_monomials(tile_size: int, dtype: torch.dtype, device: torch.device) -> Tensor:
    """(P, 6) monomials (1, x, y, x^2, y^2, x y) of the P = ts^2 pixel centres of a tile,
    in coordinates relative to the tile centre (row-major pixels)."""
    r = torch.arange(tile_size, dtype=dtype, device=device) + 0.5 - 0.5 * tile_size
    y, x = torch.meshgrid(r, r, indexing="ij")
    x, y = x.reshape(-1), y.reshape(-1)
    return torch.stack((torch.ones_like(x), x, y, x * x, y * y, x * y), dim=-1)


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


@dataclass
class _Active:
    """The tiles of a chunk still compositing and their running state (T tiles, P pixels)."""

    tiles: Tensor  # (T,) flat tile ids
    ids: Tensor  # (T, K) flat pair ids
    origin: Tensor  # (T, 2) tile centres
    counts: Tensor  # (T,) list lengths
    t_run: Tensor  # (T, P) transmittance so far; 0 once a pixel stopped
    t_fin: Tensor  # (T, P) transmittance after the last blended entry
    coef: Tensor  # (T, 6, K') coefficients of the first K' slots (see _chunk_coefs)
    col_t: Tensor | None  # (T, D, K') colours of the first K' slots; None: no colour output
    rows: Tensor | None  # (T,) rows in the chunk; None: all rows of the chunk


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
    skip_below = _skip_threshold(mono.dtype)
    one = mono.new_ones(())
    K = chunk.ids.shape[1]
    # Per-Gaussian coefficients of the chunk, computed a few blocks at a time (lists are much
    # longer than the part composited before the tiles saturate); sliced per block.
    seg = 4 * block_k
    st = _start_chunk(chunk, prm, colors, mono, seg, with_colour=out is not None)
    # Opacities >= 0.999 can hit the alpha clamp: only blocks holding one record the clamp mask.
    clamp_upto = (
        (gather_rows(prm[:, 6], chunk.ids) >= MAX_ALPHA).any(dim=0).cumsum(dim=0).tolist()
    )
    records: list[Block] = []
    for k0 in range(0, K, block_k):
        if k0 > 0:
            kept = _drop_finished(st, k0, t_final)
            if kept is None:
                break
            st = kept
            if k0 % seg == 0:
                _extend_slots(st, prm, colors, k0, seg)
        k1 = min(K, k0 + block_k)
        clampable = clamp_upto[k1 - 1] > (clamp_upto[k0 - 1] if k0 > 0 else 0)
        alpha, live = _block_alpha(mono, st.coef[:, :, k0:k1], skip_below, clampable)
        t_ext = _transmittance_factors(alpha, st.t_run, one)
        del alpha
        weight, t_after, st.t_run, st.t_fin = _blend_weights(t_ext, st.t_fin)
        if st.col_t is not None:
            out.index_add_(0, st.tiles, torch.bmm(st.col_t[:, :, k0:k1], weight.transpose(1, 2)))
        if keep:
            records.append(Block(st.tiles, st.rows, k0, weight, t_after, live))
    if t_final is not None:
        t_final.index_copy_(0, st.tiles, st.t_fin)
    return records


def _skip_threshold(dtype: torch.dtype) -> float:
    """The largest float below 1/255: threshold() keeps x > th, so this keeps alpha >= 1/255."""
    return torch.nextafter(
        torch.tensor(ALPHA_THRESHOLD, dtype=dtype), torch.tensor(0.0, dtype=dtype)
    ).item()


def _start_chunk(
    chunk: Chunk, prm: Tensor, colors: Tensor, mono: Tensor, seg: int, with_colour: bool
) -> _Active:
    """All tiles of the chunk, nothing blended yet, with the first ``seg`` slots' coefficients
    (and colours (T, D, seg) when ``with_colour``)."""
    n, P = len(chunk.tiles), mono.shape[0]
    ids = chunk.ids
    coef = _chunk_coefs(prm, ids[:, :seg], chunk.origin)
    # colours (T, D, K') of the first K' slots, extended with the coefficients
    col_t = gather_rows(colors, ids[:, :seg]).transpose(1, 2) if with_colour else None
    return _Active(
        tiles=chunk.tiles, ids=ids, origin=chunk.origin, counts=chunk.counts,
        t_run=mono.new_ones((n, P)), t_fin=mono.new_ones((n, P)),
        coef=coef, col_t=col_t, rows=None,
    )  # fmt: skip


def _drop_finished(st: _Active, k0: int, t_final: Tensor | None) -> _Active | None:
    """Keep the tiles with a pixel still compositing and entries from slot ``k0`` on.

    Returns ``st`` itself when all stay, None when none does; the final transmittances of the
    tiles are written to t_final (tiles, P) first whenever some leave.
    """
    alive = (st.t_run.amax(dim=1) > 0) & (st.counts > k0)
    if bool(alive.all()):
        return st
    if t_final is not None:
        t_final.index_copy_(0, st.tiles, st.t_fin)
    sel = torch.nonzero(alive, as_tuple=True)[0]
    if len(sel) == 0:
        return None
    return _Active(
        tiles=st.tiles[sel], ids=st.ids[sel], origin=st.origin[sel], counts=st.counts[sel],
        t_run=st.t_run[sel], t_fin=st.t_fin[sel], coef=st.coef[sel],
        col_t=None if st.col_t is None else st.col_t[sel],
        rows=sel if st.rows is None else st.rows[sel],
    )  # fmt: skip


def _extend_slots(st: _Active, prm: Tensor, colors: Tensor, k0: int, seg: int) -> None:
    """Append the coefficients (and colours) of slots ``k0 .. k0 + seg`` to ``st`` in place."""
    ids_s = st.ids[:, k0 : k0 + seg]
    st.coef = torch.cat((st.coef, _chunk_coefs(prm, ids_s, st.origin)), -1)
    if st.col_t is not None:
        st.col_t = torch.cat((st.col_t, gather_rows(colors, ids_s).transpose(1, 2)), -1)


def _block_alpha(
    mono: Tensor, coef: Tensor, skip_below: float, clampable: bool
) -> tuple[Tensor, Tensor | None]:
    """alpha (T, P, B) of a block from mono (P, 6) and its coefficients coef (T, 6, B), and the
    (T, P, B) mask of alphas below the 0.999 clamp (None when ``clampable`` is False)."""
    logit = torch.matmul(mono, coef)  # log2(o) - sigma / ln 2, (T, P, B)
    live = logit < LOG2_MAX_ALPHA if clampable else None
    # alpha = min(0.999, o exp(-sigma)); clamping the logit first keeps it to one pass.
    # Clamped alphas get no gradient; only Gaussians with o >= 0.999 can clamp.
    # The lower clamp keeps exp2 out of denormals (2^-100 is skipped as < 1/255 anyway).
    alpha = torch.exp2(logit.clamp_(min=-100.0, max=LOG2_MAX_ALPHA), out=logit)
    F.threshold_(alpha, skip_below, 0.0)  # skip alpha < 1/255
    return alpha, live


def _transmittance_factors(alpha: Tensor, t_run: Tensor, one: Tensor) -> Tensor:
    """(T, P, B + 1) buffer ``[T_run, 1 - alpha_0, ..., 1 - alpha_{B-1}]`` for the scan.

    alpha (T, P, B), t_run (T, P), one: a scalar 1 tensor.
    """
    T, P, B = alpha.shape
    # t_ext[..., k]: T before entry k; t_ext[..., k + 1]: T after it. One buffer, one scan.
    t_ext = alpha.new_empty((T, P, B + 1))
    t_ext[..., 0] = t_run
    torch.sub(one, alpha, out=t_ext[..., 1:])
    return t_ext


def _blend_weights(t_ext: Tensor, t_fin: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Scan t_ext (T, P, B + 1) in place into transmittances and apply gsplat's stop rule.

    Returns the blending weights (T, P, B), the transmittances after each entry clamped at
    the stop (T, P, B), and the new running and final transmittances (T, P).
    """
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
    return weight, u[..., 1:], t_run, t_fin


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
    prm_c = gather_rows(prm, ids)  # (T, K, 7)
    ux = prm_c[..., 0] - origin[:, None, 0]
    uy = prm_c[..., 1] - origin[:, None, 1]
    a, b, c, log_o = prm_c[..., 2], prm_c[..., 3], prm_c[..., 4], prm_c[..., 5]
    sig0 = 0.5 * a * ux * ux + b * ux * uy + 0.5 * c * uy * uy
    return torch.stack(
        (log_o - sig0, a * ux + b * uy, b * ux + c * uy, -0.5 * a, -0.5 * c, -b), dim=-2
    ).mul_(LOG2_E)
