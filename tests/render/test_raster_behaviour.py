"""Behaviour of radar4dgs.render.rasterize on the torch backend (CPU): invariances, edge cases,
meta layout, backend selection."""

from __future__ import annotations

import sys

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import PARAMS, call, grads_of, make_scene
from radar4dgs.render import RasterConfig, rasterize, select_backend
from radar4dgs.render.reference import reference_rasterize


@settings(max_examples=4, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_invariant_to_tile_chunk_block_and_checkpoint(seed):
    scene = make_scene(seed, n=40, opaque=seed % 2 == 0)
    base = grads_of(rasterize, scene, backend="torch", render_mode="RGB+ED")
    for kw in (
        dict(tile_size=4), dict(tile_size=16), dict(tile_size=5, chunk_tiles=1),
        dict(chunk_tiles=2, block_k=1), dict(block_k=7, checkpoint=True), dict(checkpoint=True),
    ):  # fmt: skip
        other = grads_of(rasterize, scene, backend="torch", render_mode="RGB+ED", **kw)
        assert (other[0] - base[0]).abs().max() <= 1e-12, kw
        assert (other[1] - base[1]).abs().max() <= 1e-12, kw
        for k in PARAMS:
            assert torch.allclose(other[2][k], base[2][k], rtol=1e-9, atol=1e-10), (kw, k)


def test_ones_channel_reproduces_alpha():
    scene = make_scene(5, opaque=True)
    scene["colors"] = torch.cat((scene["colors"], torch.ones(30, 1, dtype=torch.float64)), -1)
    colors, alphas, _ = call(rasterize, scene, backend="torch")
    assert colors.shape[-1] == 4
    assert (colors[..., 3:] - alphas).abs().max() <= 1e-12


def test_wide_features_and_per_camera_colors():
    scene = make_scene(6)
    feats = torch.rand(2, 30, 40, dtype=torch.float64)  # (C, N, D), D wider than gsplat's chunk
    scene["colors"] = feats
    scene["backgrounds"] = None
    colors, _, _ = call(rasterize, scene, backend="torch", backgrounds=None)
    for c in range(2):
        single = dict(scene, colors=feats[c], viewmats=scene["viewmats"][c : c + 1],
                      Ks=scene["Ks"][c : c + 1])  # fmt: skip
        ref, _, _ = call(reference_rasterize, single)
        assert (colors[c] - ref[0]).abs().max() <= 1e-10


def test_empty_scene_returns_background():
    scene = make_scene(1)
    for k in PARAMS:
        scene[k] = scene[k][:0]
    colors, alphas, meta = call(rasterize, scene, backend="torch",
                                backgrounds=scene["backgrounds"], render_mode="RGB+ED")  # fmt: skip
    assert colors.shape == (2, 24, 32, 4) and alphas.shape == (2, 24, 32, 1)
    assert torch.equal(alphas, torch.zeros_like(alphas))
    assert torch.equal(colors[..., :3], scene["backgrounds"][:, None, None, :].expand(2, 24, 32, 3))
    assert torch.equal(colors[..., 3], torch.zeros_like(colors[..., 3]))
    assert meta["radii"].shape == (2, 0, 2)


def test_gaussians_behind_camera_are_culled_without_nan():
    scene = make_scene(2, n=20, cameras=1)
    view = scene["viewmats"][0]
    # put every Gaussian behind the camera (and one exactly in its plane, z = 0)
    cam_pos = -view[:3, :3].T @ view[:3, 3]
    back = -view[2, :3]
    scene["means"] = cam_pos + back * torch.linspace(0.0, 3.0, 20, dtype=torch.float64)[:, None]
    colors, alphas, grads, (meta,) = grads_of(rasterize, scene, backend="torch",
                                             backgrounds=scene["backgrounds"])  # fmt: skip
    assert torch.equal(meta["radii"], torch.zeros_like(meta["radii"]))
    assert torch.equal(alphas, torch.zeros_like(alphas))
    assert torch.isfinite(meta["means2d"]).all() and torch.isfinite(meta["conics"]).all()
    for k in PARAMS:
        assert torch.isfinite(grads[k]).all()
        assert torch.equal(grads[k], torch.zeros_like(grads[k]))


def test_huge_gaussians_cover_the_image_without_nan():
    scene = make_scene(4, n=5, cameras=2)
    scene["scales"] = torch.full((5, 3), 50.0, dtype=torch.float64)
    scene["opacities"] = torch.full((5,), 0.95, dtype=torch.float64)
    colors, alphas, grads, (meta,) = grads_of(rasterize, scene, backend="torch")
    assert (meta["radii"] > 0).all()
    assert torch.isfinite(colors).all() and torch.isfinite(alphas).all()
    assert alphas.min() > 0.99  # every pixel covered
    for k in PARAMS:
        assert torch.isfinite(grads[k]).all()
    ref_c, ref_a, _ = call(reference_rasterize, scene)
    assert (colors - ref_c).abs().max() <= 1e-10 and (alphas - ref_a).abs().max() <= 1e-10


@pytest.mark.parametrize("mode", ["ED", "RGB+ED"])
def test_expected_depth_of_a_flat_wall(mode):
    """A wall of flat Gaussians at z = 5 in front of the camera renders ED = 5."""
    d = 5.0
    xs = torch.linspace(-4.0, 4.0, 21, dtype=torch.float64)
    gx, gy = torch.meshgrid(xs, xs, indexing="ij")
    n = gx.numel()
    means = torch.stack((gx.reshape(-1), gy.reshape(-1), torch.full((n,), d, dtype=torch.float64)), -1)
    scene = {
        "means": means,
        "quats": torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64).repeat(n, 1),
        "scales": torch.tensor([[0.4, 0.4, 1e-4]], dtype=torch.float64).repeat(n, 1),
        "opacities": torch.full((n,), 0.8, dtype=torch.float64),
        "colors": torch.rand(n, 3, dtype=torch.float64),
        "viewmats": torch.eye(4, dtype=torch.float64)[None],
        "Ks": torch.tensor([[[20.0, 0, 16], [0, 20.0, 12], [0, 0, 1]]], dtype=torch.float64),
        "width": 32, "height": 24,
    }  # fmt: skip
    colors, alphas, _ = call(rasterize, scene, backend="torch", render_mode=mode)
    assert alphas.min() > 0.9
    assert (colors[..., -1] - d).abs().max() <= 1e-9


def test_means2d_gradient_and_meta_layout():
    scene = make_scene(8)
    leaves = {k: scene[k].clone().requires_grad_(True) for k in PARAMS}
    colors, alphas, meta = call(rasterize, {**scene, **leaves}, backend="torch")
    meta["means2d"].retain_grad()  # what gsplat's DefaultStrategy.step_pre_backward does
    (colors.sum() + alphas.sum()).backward()
    C, N = 2, 30
    grad = meta["means2d"].grad
    assert grad is not None and grad.shape == (C, N, 2)
    visible = (meta["radii"] > 0).all(-1)
    assert grad[visible].abs().sum() > 0 and torch.equal(grad[~visible], torch.zeros_like(grad[~visible]))
    assert meta["radii"].shape == (C, N, 2) and meta["radii"].dtype == torch.int32
    assert meta["depths"].shape == (C, N) and meta["conics"].shape == (C, N, 3)
    # the keys DefaultStrategy._update_state asserts (gsplat 1.5.3, packed=False)
    for key in ("width", "height", "n_cameras", "radii", "gaussian_ids", "means2d"):
        assert key in meta
    assert meta["gaussian_ids"] is None and meta["n_cameras"] == C
    assert (meta["width"], meta["height"], meta["tile_size"]) == (32, 24, 8)


def test_float32_close_to_float64():
    scene = make_scene(9, opaque=True)
    c64, a64, _ = call(rasterize, scene, backend="torch")
    s32 = {k: (v.float() if torch.is_tensor(v) else v) for k, v in scene.items()}
    c32, a32, _ = call(rasterize, s32, backend="torch")
    assert c32.dtype == torch.float32
    assert (c32.double() - c64).abs().max() < 1e-5 and (a32.double() - a64).abs().max() < 1e-5


def test_backend_selection_on_cpu_never_imports_gsplat():
    cpu = torch.device("cpu")
    assert select_backend("auto", cpu) == "torch"
    assert select_backend("torch", cpu) == "torch"
    with pytest.raises(ValueError, match="CUDA"):
        select_backend("gsplat", cpu)
    with pytest.raises(ValueError):
        select_backend("vulkan", cpu)
    scene = make_scene(0)
    _, _, meta = call(rasterize, scene, **RasterConfig().kwargs())
    assert meta["backend"] == "torch"
    with pytest.raises(ValueError, match="CUDA"):
        call(rasterize, scene, backend="gsplat")
    assert "gsplat" not in sys.modules


def test_bad_shapes_and_modes_raise():
    scene = make_scene(0)
    with pytest.raises(ValueError, match="render_mode"):
        call(rasterize, scene, render_mode="RGBD")
    with pytest.raises(ValueError, match="quats"):
        call(rasterize, dict(scene, quats=scene["quats"][:, :3]))
