"""Hand-written backward of the chunk compositing in :mod:`radar4dgs.render.composite_forward`.

Works from the blending weights and clamped transmittances the forward records per block
(:class:`~radar4dgs.render.composite_forward.Block`), visiting the blocks back to front: per block
only pixel sums are formed, and the chain rule to the 2D mean, conic and opacity runs once per
chunk.
"""

from __future__ import annotations

import torch
from torch import Tensor

from radar4dgs.render.composite_forward import Block
from radar4dgs.render.tile_bins import Chunk, gather_rows


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
    col_t = gather_rows(colors, ids).transpose(1, 2)  # (T0, D, K)
    acc = grads.new_zeros((ids.shape[0], 6 + D, n_used))  # pixel sums per (tile, slot)
    mono_t = mono.transpose(0, 1)
    for blk in reversed(blocks):
        k0, k1 = blk.k0, blk.k0 + blk.weight.shape[-1]
        col_b = col_t[:, :, k0:k1] if blk.rows is None else col_t[blk.rows, :, k0:k1]
        sums = _block_pixel_sums(blk, col_b, mono_t, grad_px, grad_t, later)
        if blk.rows is None:
            acc[:, :, k0:k1] = sums
        else:
            acc[:, :, k0:k1].index_copy_(0, blk.rows, sums)
    g = _chain_rule(gather_rows(prm, ids), chunk.origin, acc)  # (T0, K, 6 + D)
    grads.index_add_(0, ids.reshape(-1), g.reshape(-1, 6 + D))


def _block_pixel_sums(
    blk: Block, col_b: Tensor, mono_t: Tensor, grad_px: Tensor, grad_t: Tensor, later: Tensor
) -> Tensor:
    """(T, 6 + D, B) pixel sums of one block: six moments of dL/dsigma, the colour gradient.

    col_b (T, D, B) colours of the block's entries, mono_t (6, P) pixel monomials; ``later``
    (tiles, P) is advanced in place past the block's entries (see :func:`backward_blocks`).
    """
    tiles = blk.tiles
    qw = torch.bmm(grad_px.index_select(0, tiles), col_b)  # (T, P, B)
    qw.mul_(blk.weight)
    cum = torch.cumsum(qw, dim=-1)
    base = later.index_select(0, tiles) + cum[..., -1]
    later.index_copy_(0, tiles, base)
    lat = torch.rsub(cum, base[..., None])  # sum over entries after k, (T, P, B)
    d_sigma = lat.mul_(blk.weight).div_(blk.t_after).sub_(qw)
    if blk.live is not None:
        d_sigma.mul_(blk.live)
    return torch.cat(
        (torch.matmul(mono_t, d_sigma), torch.bmm(grad_t.index_select(0, tiles), blk.weight)),
        dim=1,
    )  # (T, 6 + D, B)


def _chain_rule(prm_c: Tensor, origin: Tensor, acc: Tensor) -> Tensor:
    """Per-(tile, slot) gradients (T0, K, 6 + D) [d mx, d my, d a, d b, d c, d o, d colour].

    prm_c (T0, K, 7) parameter rows of the slots, origin (T0, 2) tile centres, acc (T0, 6 + D, K)
    the pixel sums of :func:`_block_pixel_sums`.
    """
    ux = prm_c[..., 0] - origin[:, None, 0]
    uy = prm_c[..., 1] - origin[:, None, 1]
    a, b, c, o = prm_c[..., 2], prm_c[..., 3], prm_c[..., 4], prm_c[..., 6]
    m0, m1, m2, m3, m4, m5 = acc[:, :6].unbind(dim=1)
    # sums over pixels of dx^k dy^l dL/dsigma, with dx = ux - x, dy = uy - y
    sdx = ux * m0 - m1
    sdy = uy * m0 - m2
    sdxx = ux * ux * m0 - 2 * ux * m1 + m3
    sdyy = uy * uy * m0 - 2 * uy * m2 + m4
    sdxy = ux * uy * m0 - ux * m2 - uy * m1 + m5
    return torch.cat(
        (
            torch.stack(
                (a * sdx + b * sdy, b * sdx + c * sdy, 0.5 * sdxx, sdxy, 0.5 * sdyy, -m0 / o),
                dim=-1,
            ),
            acc[:, 6:].transpose(1, 2),
        ),
        dim=-1,
    )
