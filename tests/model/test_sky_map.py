"""The learnable sky environment map: lookup, wrap, gradients, compositing, camera rays."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from radar4dgs.apps.prepare import read_scene
from radar4dgs.config import preset
from radar4dgs.datasets.synth import SynthConfig, synthesize
from radar4dgs.model.sky import SkyEnvironment, camera_ray_directions


def _set_colors(sky: SkyEnvironment, colors: torch.Tensor) -> None:
    with torch.no_grad():
        sky.logits.copy_(torch.logit(colors.clamp(1e-6, 1 - 1e-6)))


def _patterned(height=8, width=16, dtype=torch.float64):
    sky = SkyEnvironment(height, width, dtype=dtype)
    g = torch.Generator().manual_seed(0)
    colors = torch.rand(3, height, width, generator=g, dtype=dtype) * 0.8 + 0.1
    _set_colors(sky, colors)
    return sky, sky.colors().detach()


def test_texel_centres_return_their_texel():
    sky, colors = _patterned()
    got = sky(sky.texel_directions())
    torch.testing.assert_close(got, colors.permute(1, 2, 0), atol=1e-10, rtol=0)


def test_known_directions():
    sky, c = _patterned()
    H, W = 8, 16
    d = torch.tensor([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [-1.0, 0, 0], [0, 0, -1.0]], dtype=torch.float64)
    got = sky(d)
    # +x: longitude 0, latitude 0 sits between columns W/2-1, W/2 and rows H/2-1, H/2.
    torch.testing.assert_close(got[0], c[:, H // 2 - 1:H // 2 + 1, W // 2 - 1:W // 2 + 1].mean(dim=(1, 2)))
    # +y: longitude pi/2 -> px = 3W/4 - 0.5, between columns 3W/4-1 and 3W/4.
    torch.testing.assert_close(got[1], c[:, H // 2 - 1:H // 2 + 1, 3 * W // 4 - 1:3 * W // 4 + 1].mean(dim=(1, 2)))
    # Straight up: latitude clamps to row 0; atan2(0, 0) = 0 -> between columns W/2-1 and W/2.
    torch.testing.assert_close(got[2], c[:, 0, W // 2 - 1:W // 2 + 1].mean(dim=1))
    # -x: longitude pi wraps between the last and the first column.
    torch.testing.assert_close(got[3],
                               (c[:, H // 2 - 1:H // 2 + 1, 0] + c[:, H // 2 - 1:H // 2 + 1, -1]).mean(dim=1) / 2)
    # Straight down: the last row.
    torch.testing.assert_close(got[4], c[:, -1, W // 2 - 1:W // 2 + 1].mean(dim=1))


def test_longitude_wrap_is_continuous():
    sky, _ = _patterned()
    eps = 1e-7
    a = sky(torch.tensor([[math.cos(math.pi - eps), math.sin(math.pi - eps), 0.2]], dtype=torch.float64))
    b = sky(torch.tensor([[math.cos(-math.pi + eps), math.sin(-math.pi + eps), 0.2]], dtype=torch.float64))
    torch.testing.assert_close(a, b, atol=1e-5, rtol=0)


def test_init_color_shape_and_range():
    sky = SkyEnvironment(init_color=(0.4, 0.6, 0.9))
    assert sky.logits.shape == (3, 64, 128) and sky.logits.dtype == torch.float32
    d = torch.nn.functional.normalize(torch.randn(5, 7, 3), dim=-1)
    out = sky(d)
    assert out.shape == (5, 7, 3)
    torch.testing.assert_close(out, torch.tensor([0.4, 0.6, 0.9]).expand(5, 7, 3), atol=1e-5, rtol=0)
    image = np.zeros((4, 4, 3), np.uint8)
    image[:2] = (51, 102, 204)
    mask = np.zeros((4, 4), bool)
    mask[:2] = True
    sky2 = SkyEnvironment.from_sky_pixels([image], [mask], height=8, width=16)
    torch.testing.assert_close(sky2.colors()[:, 0, 0], torch.tensor([0.2, 0.4, 0.8]), atol=1e-5, rtol=0)


def test_gradients_flow_to_the_map():
    sky = SkyEnvironment(8, 16)
    d = torch.tensor([[1.0, 0.0, 0.0]])
    sky(d).sum().backward()
    grad = sky.logits.grad
    assert grad is not None and torch.isfinite(grad).all()
    # Only the 4 texels around +x get gradient, each a quarter of sigmoid'(0) = 0.25.
    assert int((grad.abs() > 0).sum()) == 3 * 4
    torch.testing.assert_close(grad[:, 3:5, 7:9], torch.full((3, 2, 2), 0.25 * 0.25))


def test_composite():
    sky, _ = _patterned(dtype=torch.float32)
    g = torch.Generator().manual_seed(1)
    rgb = torch.rand(6, 5, 3, generator=g)
    dirs = torch.nn.functional.normalize(torch.randn(6, 5, 3, generator=g), dim=-1)
    torch.testing.assert_close(sky.composite(rgb, torch.ones(6, 5, 1), dirs), rgb)
    torch.testing.assert_close(sky.composite(torch.zeros(6, 5, 3), torch.zeros(6, 5, 1), dirs), sky(dirs))
    half = sky.composite(rgb, torch.full((6, 5, 1), 0.5), dirs)
    torch.testing.assert_close(half, rgb + 0.5 * sky(dirs))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("sky") / "scene"
    synthesize(preset(SynthConfig, "tiny", seed=3, num_frames=6), out, progress=False)
    return read_scene(out)


def test_camera_ray_directions(scene):
    w2c = scene.world_to_camera(2)
    # An odd-sized image whose principal point is a pixel centre.
    H, W = 91, 161
    K = np.array([[120.0, 0.0, (W - 1) / 2], [0.0, 120.0, (H - 1) / 2], [0.0, 0.0, 1.0]])
    dirs = camera_ray_directions(K, w2c, H, W, dtype=torch.float64)
    assert dirs.shape == (H, W, 3)
    torch.testing.assert_close(dirs.norm(dim=-1), torch.ones(H, W, dtype=torch.float64))
    axis = np.linalg.inv(w2c)[:3, 2]  # the camera's +z in world
    np.testing.assert_allclose(dirs[H // 2, W // 2].numpy(), axis, atol=1e-12)
    # Every ray, moved along by the pixel's depth, projects back onto its pixel (scene K and size).
    cam = scene.camera
    dirs = camera_ray_directions(cam.K, w2c, cam.height, cam.width, dtype=torch.float64).numpy()
    c2w = np.linalg.inv(w2c)
    pts = c2w[:3, 3] + 7.0 * dirs.reshape(-1, 3)
    uv, z = cam.project(pts @ w2c[:3, :3].T + w2c[:3, 3])
    v, u = np.mgrid[0:cam.height, 0:cam.width]
    np.testing.assert_allclose(uv, np.stack([u.ravel(), v.ravel()], axis=1), atol=1e-9)
    assert (z > 0).all()
    # The synthetic camera looks forward and slightly down: its centre ray has a small negative z.
    centre = dirs.reshape(-1, 3).mean(axis=0)
    assert -0.3 < centre[2] < 0.0


def test_map_gradient_does_not_depend_on_the_thread_count():
    # A resumed run may use another thread count; repeated texels must sum in a fixed order.
    g = torch.Generator().manual_seed(0)
    directions = torch.nn.functional.normalize(torch.randn(20000, 3, generator=g), dim=-1)
    weights = torch.randn(20000, 3, generator=g)
    before = torch.get_num_threads()
    grads = []
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            sky = SkyEnvironment(16, 32)
            (sky(directions) * weights).sum().backward()
            grads.append(sky.logits.grad)
    finally:
        torch.set_num_threads(before)
    assert torch.equal(grads[0], grads[1])
