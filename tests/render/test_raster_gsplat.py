"""The torch backend against gsplat 1.5.3 on CUDA. Skipped without a GPU; gsplat is imported
inside the tests only (importing it without a GPU starts a doomed CUDA compile)."""

from __future__ import annotations

import pytest
import torch

from conftest import PARAMS, grads_of, make_scene
from radar4dgs.render import rasterize

cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")


def _on_cuda(scene: dict) -> dict:
    return {k: (v.float().cuda() if torch.is_tensor(v) else v) for k, v in scene.items()}


def _assert_backends_agree(scene: dict, **kwargs) -> tuple[torch.Tensor, dict, dict]:
    """Renders ``scene`` with gsplat and the torch backend; asserts images and alphas within 1e-4 and
    every parameter's gradient at cosine >= 0.999. Returns gsplat's colours and both metas."""
    c_g, a_g, g_g, (meta_g,) = grads_of(rasterize, scene, backend="gsplat", **kwargs)
    c_t, a_t, g_t, (meta_t,) = grads_of(rasterize, scene, backend="torch", **kwargs)
    assert (c_g - c_t).abs().max() <= 1e-4 and (a_g - a_t).abs().max() <= 1e-4
    for k in PARAMS:
        cos = torch.nn.functional.cosine_similarity(g_g[k].flatten(), g_t[k].flatten(), dim=0)
        assert cos >= 0.999, (k, float(cos))
    return c_g, meta_g, meta_t


@cuda
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("mode", ["RGB", "RGB+ED"])
def test_torch_backend_matches_gsplat(seed, mode):
    pytest.importorskip("gsplat")
    scene = _on_cuda(make_scene(seed, n=200, width=64, height=48, opaque=seed == 2))
    _, meta_g, meta_t = _assert_backends_agree(scene, render_mode=mode, backgrounds=scene["backgrounds"])
    assert meta_g["backend"] == "gsplat" and meta_t["backend"] == "torch"
    # radii are ceil()s of float32 values: allow a rare off-by-one at the rounding edge
    assert (meta_g["radii"] != meta_t["radii"]).float().mean() < 0.01


@cuda
@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("channels", [4, 5])
def test_torch_backend_matches_gsplat_on_the_scene_models_channels(seed, channels):
    """SceneModel.render draws colours, the dynamic weight and (with the dynamic layer drawn ahead) a
    depth correction, plus gsplat's expected depth: 5 or 6 channels, which gsplat pads to a size it
    compiles, with no background."""
    pytest.importorskip("gsplat")
    scene = _on_cuda(make_scene(seed, n=200, width=64, height=48))
    extra = torch.rand(len(scene["colors"]), channels - 3, generator=torch.Generator().manual_seed(seed))
    scene = {**scene, "colors": torch.cat([scene["colors"], extra.cuda()], dim=1), "backgrounds": None}
    colors, _, _ = _assert_backends_agree(scene, render_mode="RGB+ED")
    assert colors.shape[-1] == channels + 1
