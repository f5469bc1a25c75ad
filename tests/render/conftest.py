"""Small random scenes for the rasterizer tests (float64, CPU)."""

from __future__ import annotations

import math

import pytest
import torch


def look_at(eye, target, up=(0.0, -1.0, 0.0), dtype=torch.float64) -> torch.Tensor:
    """World-to-camera (4, 4), OpenCV axes (x right, y down, z forward), camera at ``eye``."""
    eye, target, up = (torch.tensor(v, dtype=dtype) for v in (eye, target, up))
    z = target - eye
    z = z / z.norm()
    x = torch.linalg.cross(z, up)
    x = x / x.norm()
    y = torch.linalg.cross(z, x)
    R = torch.stack((x, y, z))  # rows: camera axes in world
    view = torch.eye(4, dtype=dtype)
    view[:3, :3] = R
    view[:3, 3] = -R @ eye
    return view


def make_scene(seed: int, n: int = 30, width: int = 32, height: int = 24, cameras: int = 2,
               opaque: bool = False, dtype=torch.float64) -> dict:  # fmt: skip
    """n random Gaussians around the origin seen by ``cameras`` cameras ~3 m away."""
    g = torch.Generator().manual_seed(seed)

    def rand(*shape):
        return torch.rand(*shape, generator=g, dtype=dtype)

    means = (rand(n, 3) - 0.5) * 1.6
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    scales = 0.03 + 0.3 * rand(n, 3)
    opacities = rand(n)
    if opaque:  # exercises the 0.999 clamp and the transmittance stop
        opacities = 0.9 + 0.1 * opacities
        opacities[::4] = 1.0
    colors = rand(n, 3)
    views, Ks = [], []
    for c in range(cameras):
        ang = 2 * math.pi * float(rand(1)) * 0.15 + c * 0.3
        eye = (3.0 * math.sin(ang), -0.4 + 0.8 * float(rand(1)), -3.0 * math.cos(ang))
        views.append(look_at(eye, (0.0, 0.0, 0.0), dtype=dtype))
        f = 25.0 + 15.0 * float(rand(1))
        Ks.append(torch.tensor([[f, 0, width / 2 + float(rand(1)) - 0.5],
                                [0, f * 1.05, height / 2 + float(rand(1)) - 0.5],
                                [0, 0, 1]], dtype=dtype))  # fmt: skip
    return {
        "means": means, "quats": quats, "scales": scales, "opacities": opacities,
        "colors": colors, "viewmats": torch.stack(views), "Ks": torch.stack(Ks),
        "width": width, "height": height,
        "backgrounds": rand(cameras, 3),
    }  # fmt: skip


PARAMS = ("means", "quats", "scales", "opacities", "colors")


def call(fn, scene: dict, **kwargs):
    """fn(means, quats, scales, opacities, colors, viewmats, Ks, width, height, **kwargs)."""
    args = [scene[k] for k in PARAMS] + [scene["viewmats"], scene["Ks"]]
    return fn(*args, scene["width"], scene["height"], **kwargs)


def grads_of(fn, scene: dict, weights_seed: int = 0, **kwargs):
    """Outputs and gradients of a random linear loss of colours and alphas w.r.t. PARAMS."""
    leaves = {k: scene[k].detach().clone().requires_grad_(True) for k in PARAMS}
    colors, alphas, *rest = call(fn, {**scene, **leaves}, **kwargs)
    g = torch.Generator().manual_seed(weights_seed)
    wc = torch.rand(colors.shape, generator=g, dtype=colors.dtype).to(colors.device)
    wa = torch.rand(alphas.shape, generator=g, dtype=alphas.dtype).to(alphas.device)
    loss = (colors * wc).sum() + (alphas * wa).sum()
    grads = torch.autograd.grad(loss, [leaves[k] for k in PARAMS], allow_unused=True)
    grads = [torch.zeros_like(leaves[k]) if gr is None else gr for k, gr in zip(PARAMS, grads, strict=True)]
    return colors.detach(), alphas.detach(), dict(zip(PARAMS, grads, strict=True)), rest


@pytest.fixture
def scene_factory():
    return make_scene
