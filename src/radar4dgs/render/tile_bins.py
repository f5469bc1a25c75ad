"""Tile binning of projected Gaussians and the grouping of tiles into chunks for compositing.

Reproduces gsplat 1.5.3's intersection step (``IntersectTile.cu``): a Gaussian is binned to every
tile its box ``mean +- radii`` touches; within a tile the order is by depth, ties by Gaussian
index (stable radix sort of ``tile | depth`` keys built in index order). Non-empty tiles are then
grouped, longest lists first, into chunks: dense padded (tiles, K) index matrices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

# Binning uses int32 intersection arrays below this size (tests lower it to cover int64).
_INT32_LIMIT = 2**31


def gather_rows(table: Tensor, ids: Tensor) -> Tensor:
    """table (R, X) rows at ids (T, B) -> (T, B, X); index_select is much faster than
    advanced indexing on CPU."""
    return table.index_select(0, ids.reshape(-1)).reshape(ids.shape + table.shape[1:])


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
            gather_rows(bins.flatten_ids, slot.clamp(max=len(bins.flatten_ids) - 1)),
            torch.full_like(slot, n_pairs),
        )
        local = t % n_tiles_img
        origin = torch.stack(
            ((local % bins.tiles_x) * tile_size, (local // bins.tiles_x) * tile_size), dim=-1
        ).to(dtype) + 0.5 * tile_size
        chunks.append(Chunk(tiles=t, ids=ids, origin=origin, counts=bins.tile_counts[t]))
        start = stop
    return chunks
