"""Tile binning (render.tile_bins) against a plain per-tile construction."""

from __future__ import annotations

import pytest
import torch

from radar4dgs.render import tile_bins as tb


def _naive_bins(means2d, radii, depths, ts, width, height):
    """Per tile, the flat pair ids whose box [floor((m-r)/ts), ceil((m+r)/ts)) covers it, sorted
    by depth with ties by index (gsplat's stable radix sort)."""
    C, N = depths.shape
    tx_n, ty_n = -(-width // ts), -(-height // ts)
    lists = [[] for _ in range(C * tx_n * ty_n)]
    for c in range(C):
        for n in range(N):
            if not bool((radii[c, n] > 0).all()):
                continue
            m, r = means2d[c, n].tolist(), radii[c, n].tolist()
            x0 = min(max(int(torch.floor(torch.tensor((m[0] - r[0]) / ts))), 0), tx_n)
            x1 = min(max(int(torch.ceil(torch.tensor((m[0] + r[0]) / ts))), 0), tx_n)
            y0 = min(max(int(torch.floor(torch.tensor((m[1] - r[1]) / ts))), 0), ty_n)
            y1 = min(max(int(torch.ceil(torch.tensor((m[1] + r[1]) / ts))), 0), ty_n)
            for ty in range(y0, y1):
                for tx in range(x0, x1):
                    lists[c * tx_n * ty_n + ty * tx_n + tx].append(c * N + n)
    flat_depth = depths.reshape(-1).tolist()
    return [sorted(lst, key=lambda f: (flat_depth[f], f)) for lst in lists]


@pytest.mark.parametrize("int32", [True, False])
@pytest.mark.parametrize("seed", [0, 1])
def test_binning_matches_naive_lists(seed, int32, monkeypatch):
    if not int32:
        monkeypatch.setattr(tb, "_INT32_LIMIT", 0)  # force the int64 path
    g = torch.Generator().manual_seed(seed)
    C, N, W, H, ts = 2, 60, 37, 29, 8
    means2d = torch.rand(C, N, 2, generator=g, dtype=torch.float64) * torch.tensor([W, H]) * 1.4 - 5
    radii = torch.randint(0, 12, (C, N, 2), generator=g, dtype=torch.int32)
    radii[:, ::7, 1] = 0  # culled on one axis: not binned
    depths = torch.randint(1, 6, (C, N), generator=g).to(torch.float64)  # many ties
    bins = tb.bin_gaussians(means2d, radii, depths, ts, W, H)
    expect = _naive_bins(means2d, radii, depths, ts, W, H)
    got = [
        bins.flatten_ids[o : o + k].tolist()
        for o, k in zip(bins.tile_offsets.tolist(), bins.tile_counts.tolist(), strict=True)
    ]
    assert got == expect
    assert int(bins.tiles_per_gauss.sum()) == sum(len(lst) for lst in expect)
    assert bins.flatten_ids.dtype == torch.int64
