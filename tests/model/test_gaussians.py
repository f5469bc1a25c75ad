"""Gaussian initialisation from the prepared depth: back-projection, split, kNN scales, activation."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image

from radar4dgs.apps.prepare import PrepareConfig, read_scene, run_prepare
from radar4dgs.config import preset
from radar4dgs.datasets.synth import SynthConfig, synthesize
from radar4dgs.io.scene import normalized_times
from radar4dgs.model.field import DeformationField
from radar4dgs.model.gaussians import (
    GaussianInitConfig,
    GaussianSet,
    backproject_frame,
    backproject_frames,
    dynamic_cap_note,
    initialize_gaussians,
    knn_log_scales,
    to_canonical,
)


@pytest.fixture(scope="module")
def prepared_scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("gauss") / "scene"
    synthesize(preset(SynthConfig, "tiny", seed=3, num_frames=6), out, progress=False)
    run_prepare(out, None, preset(PrepareConfig, "tiny"), only=("radar", "depth", "masks"), progress=False)
    return read_scene(out), out / "prepared"


def _mask(path):
    with Image.open(path) as image:
        return np.asarray(image.convert("L")) > 127


def test_backprojected_points_reproject_to_their_pixels(prepared_scene):
    scene, prepared = prepared_scene
    config = GaussianInitConfig(pixel_stride=1, points_per_frame=0)
    for i in scene.train_indices[:2]:
        data = backproject_frame(scene, prepared, i, config, np.random.default_rng(0))
        assert len(data["points"]) > 1000
        w2c = scene.world_to_camera(i)
        cam = data["points"] @ w2c[:3, :3].T + w2c[:3, 3]
        uv, z = scene.camera.project(cam)
        u, v = data["pixels"].T
        assert np.abs(uv - data["pixels"]).max() <= 1e-6
        depth = np.load(prepared / "depth" / f"{scene.frames[i].name}.npy")
        np.testing.assert_allclose(z, depth[v, u], rtol=1e-9, atol=1e-9)
        image = scene.load_image(i)
        np.testing.assert_array_equal(data["colors"], image[v, u] / 255.0)


def test_no_sky_points_and_every_ground_pixel_kept(prepared_scene):
    scene, prepared = prepared_scene
    config = GaussianInitConfig(pixel_stride=2, points_per_frame=0, max_static=10**9, max_dynamic=10**9)
    data = backproject_frames(scene, prepared, config)
    assert set(np.unique(data["frame"]).tolist()) == set(scene.train_indices)
    assert np.isfinite(data["points"]).all()
    for i in scene.train_indices:
        name = scene.frames[i].name
        sky = _mask(prepared / "depth" / "sky" / f"{name}.png")
        depth = np.load(prepared / "depth" / f"{name}.npy")
        dynamic = _mask(prepared / "masks" / f"{name}.png")
        u, v = data["pixels"][data["frame"] == i].T
        assert not sky[v, u].any()
        assert np.isfinite(depth[v, u]).all()
        # Completeness: every non-sky stride-2 pixel within max_depth is there, and every dynamic
        # one (dynamic_pixel_stride 1).
        valid = ~sky & np.isfinite(depth) & (depth <= config.max_depth)
        grid = np.zeros_like(valid)
        grid[::2, ::2] = True
        assert len(u) == int((valid & (grid | dynamic)).sum())
        assert sky.any()  # the synthetic scene has sky, so the test above means something


@pytest.mark.parametrize("dynamic_stride", [1, 2])
def test_dynamic_pixels_are_taken_on_their_own_finer_grid(prepared_scene, dynamic_stride):
    scene, prepared = prepared_scene
    config = GaussianInitConfig(pixel_stride=4, dynamic_pixel_stride=dynamic_stride, points_per_frame=0)
    i = scene.train_indices[0]
    data = backproject_frame(scene, prepared, i, config, np.random.default_rng(0))
    name = scene.frames[i].name
    depth = np.load(prepared / "depth" / f"{name}.npy")
    valid = ~_mask(prepared / "depth" / "sky" / f"{name}.png") & np.isfinite(depth) & (depth <= config.max_depth)
    dynamic = _mask(prepared / "masks" / f"{name}.png") & valid
    u, v = data["pixels"].T
    on = np.zeros_like(valid)
    on[v, u] = True
    fine = np.zeros_like(valid)
    fine[::dynamic_stride, ::dynamic_stride] = True
    coarse = np.zeros_like(valid)
    coarse[::4, ::4] = True
    assert dynamic.sum() > 20
    np.testing.assert_array_equal(on & dynamic, dynamic & (fine | coarse))
    np.testing.assert_array_equal(on & ~dynamic, valid & ~dynamic & coarse)
    assert data["dynamic"].sum() == int((dynamic & (fine | coarse)).sum())


def test_dynamic_flag_matches_ground_truth_mask(prepared_scene):
    scene, prepared = prepared_scene
    config = GaussianInitConfig(pixel_stride=1, points_per_frame=0, max_static=10**9, max_dynamic=10**9)
    data = backproject_frames(scene, prepared, config)
    dyn = data["dynamic"]
    assert dyn.sum() > 50
    on_gt = [scene.load_optional("gt/dynamic_mask", f)[v, u]
             for (u, v), f in zip(data["pixels"][dyn], data["frame"][dyn], strict=True)]
    assert np.mean(on_gt) >= 0.85


def test_subsampling_is_deterministic_and_capped(prepared_scene):
    scene, prepared = prepared_scene
    config = GaussianInitConfig(pixel_stride=1, points_per_frame=1500, max_static=5000, max_dynamic=40, seed=7)
    a = backproject_frames(scene, prepared, config)
    b = backproject_frames(scene, prepared, config)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    assert (~a["dynamic"]).sum() == 5000 and a["dynamic"].sum() == 40
    assert max(np.bincount(a["frame"])) <= 1500
    c = backproject_frames(scene, prepared, GaussianInitConfig(pixel_stride=1, points_per_frame=1500,
                                                               max_static=5000, max_dynamic=40, seed=8))
    assert not np.array_equal(a["points"], c["points"])


def test_the_log_says_when_the_per_frame_cap_holds_the_dynamic_set_below_its_cap(prepared_scene):
    scene, prepared = prepared_scene
    frames = scene.train_indices
    masks = {i: _mask(prepared / "masks" / f"{scene.frames[i].name}.png") for i in frames}
    on_grid = sum(int(masks[i].sum()) for i in frames)
    assert on_grid > 300

    def note(points_per_frame, max_dynamic):
        config = GaussianInitConfig(pixel_stride=1, points_per_frame=points_per_frame, max_static=10**6,
                                    max_dynamic=max_dynamic)
        points = backproject_frames(scene, prepared, config)
        return points, dynamic_cap_note(points, masks, frames, config)

    # 300 points a frame out of thousands of candidates keep a fraction of the masks' pixels: said, with the numbers.
    points, said = note(300, 10**6)
    assert f"kept {int(points['dynamic'].sum())} of the masks' {on_grid} pixels" in said
    # Every candidate kept, or the cap itself reached: nothing to say.
    assert note(0, 10**6)[1] == "" and note(300, int(points["dynamic"].sum()))[1] == ""


def _brute_force_log_scales(queries, points, k, lo, hi):
    d = np.linalg.norm(queries[:, None, :] - points[None, :, :], axis=-1)
    d = np.sort(d, axis=1)[:, 1:k + 1]
    return np.log(np.clip(d.mean(axis=1), lo, hi))


def test_knn_scales_equal_brute_force():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(400, 3)) * np.array([5.0, 2.0, 0.5])
    points[10] = points[11]  # a duplicate: distance 0 is clamped to min_scale
    for k in (1, 3, 5):
        got = knn_log_scales(points, k, 1e-3, 3.0)
        assert got.shape == (400, 3) and np.all(got[:, 0] == got[:, 2])
        np.testing.assert_allclose(got[:, 0], _brute_force_log_scales(points, points, k, 1e-3, 3.0), atol=1e-12)
    assert knn_log_scales(np.zeros((1, 3)), 3, 1e-3, 3.0)[0, 0] == pytest.approx(np.log(3.0))
    assert knn_log_scales(np.zeros((0, 3))).shape == (0, 3)


def test_initialize_gaussians_split_and_activation(prepared_scene):
    scene, prepared = prepared_scene
    config = preset(GaussianInitConfig, "tiny")
    static, dynamic, times = initialize_gaussians(scene, prepared, config, "cpu", torch.float32)
    data = backproject_frames(scene, prepared, config)
    dyn = data["dynamic"]
    assert len(static) == int((~dyn).sum()) and len(dynamic) == int(dyn.sum()) > 0
    assert len(static) <= config.max_static and len(dynamic) <= config.max_dynamic
    np.testing.assert_allclose(times, normalized_times(scene)[data["frame"][dyn]])
    assert times.min() >= 0 and times.max() <= 1
    for gs, sel in ((static, ~dyn), (dynamic, dyn)):
        act = gs.activated()
        assert all(v.dtype == torch.float32 for v in act.values())
        np.testing.assert_allclose(act["means"].detach().numpy(), data["points"][sel], atol=1e-4)
        np.testing.assert_allclose(act["opacities"].detach().numpy(), 0.1, atol=1e-6)
        quats = act["quats"].detach()
        np.testing.assert_allclose(quats.norm(dim=-1).numpy(), 1.0, atol=1e-6)
        np.testing.assert_allclose(quats.numpy(), np.tile([1.0, 0, 0, 0], (len(gs), 1)), atol=1e-7)
        np.testing.assert_allclose(act["colors"].detach().numpy(), np.clip(data["colors"][sel], 1e-4, 1 - 1e-4),
                                   atol=1e-5)
        scales = act["scales"].detach().numpy()
        assert scales.min() >= config.min_scale * (1 - 1e-6) and scales.max() <= config.max_scale * (1 + 1e-6)
    # kNN scales of the static set against brute force for 200 of its points.
    pts = data["points"][~dyn]
    idx = np.random.default_rng(1).choice(len(pts), 200, replace=False)
    expected = _brute_force_log_scales(pts[idx], pts, config.knn_k, config.min_scale, config.max_scale)
    got = static.params["log_scales"].detach().numpy()[idx]
    np.testing.assert_allclose(got, np.repeat(expected[:, None], 3, axis=1), atol=1e-5)


def test_param_groups_and_dtype():
    gs = GaussianSet.from_points(np.random.default_rng(0).normal(size=(50, 3)), np.full((50, 3), 0.25),
                                 dtype=torch.float64)
    assert all(p.dtype == torch.float64 for p in gs.parameters())
    lrs = {"means": 1.6e-4, "colors": 2.5e-3, "opacity_logits": 5e-2}
    groups = gs.param_groups(lrs, prefix="static.")
    assert [g["name"] for g in groups] == ["static.means", "static.opacity_logits", "static.colors"]
    assert [g["lr"] for g in groups] == [1.6e-4, 5e-2, 2.5e-3]
    optimizers = [torch.optim.Adam([g]) for g in groups]  # one optimizer per group, as gsplat
    before = gs.params["means"].detach().clone()
    loss = sum(v.sum() for v in gs.activated().values())
    loss.backward()
    for opt in optimizers:
        opt.step()
    assert not torch.equal(before, gs.params["means"].detach())
    with pytest.raises(KeyError):
        gs.param_groups({"sh": 1.0})


def test_to_canonical_identity_and_round_trip():
    rng = np.random.default_rng(0)
    points = torch.as_tensor(rng.normal(size=(3000, 3)) * 5.0, dtype=torch.float32)
    times = rng.uniform(0, 1, 3000)
    field = DeformationField()
    field.fit_normalization(points)
    out = to_canonical(points, times, field, batch_size=700)
    assert out.shape == points.shape and not out.requires_grad
    torch.testing.assert_close(out, points, atol=1e-5, rtol=0)
    # A non-trivial field: the batched inverse is exact, forward() brings the points back.
    torch.manual_seed(0)
    with torch.no_grad():
        for layer in field.layers:
            layer.last.weight.normal_(0, 0.05)
            layer.last.bias.normal_(0, 0.05)
    canon = to_canonical(points, times, field, batch_size=700)
    assert (canon - points).abs().max() > 1e-2
    torch.testing.assert_close(canon, to_canonical(points, times, field, batch_size=10**6))
    back = field(canon, torch.as_tensor(times, dtype=torch.float32))
    torch.testing.assert_close(back, points, atol=1e-4, rtol=0)
