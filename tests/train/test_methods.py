"""Every method of the bench grid inside the one trainer: the baselines train, save, reload and
resume exactly; the ablations are the config changes their names say; the mask sources and the
LiDAR initialisation read what they should."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from radar4dgs.config import preset, to_dict
from radar4dgs.io.scene import read_scene
from radar4dgs.model.config import DensifyConfig, TrainConfig
from radar4dgs.model.gaussians import GaussianInitConfig, backproject_frames
from radar4dgs.model.scene_model import load_model
from radar4dgs.train.data import BASELINE_MASK_DIR, dynamic_masks
from radar4dgs.train.trainer import train_run
from radar4dgs.train.variants import METHOD_NAMES, VARIANTS, apply_variant, variant_config


def small_config(method: str, **overrides) -> TrainConfig:
    values = {"threads": 1, "optim": {"iterations": 12}, "checkpoint_every": 4, "log_every": 1,
              "init": {"points_per_frame": 500, "max_static": 2500, "max_dynamic": 500},
              "densify": {"every": 4, "start": 0.0, "stop": 1.0, "grad_threshold": 1e-6, "max_gaussians": 3500},
              "losses": {"motion_batch": 64, "radar_points_per_frame": 100}}
    values.update(overrides)
    return variant_config("tiny", method, **values)


def test_every_method_name_has_a_description_and_valid_config():
    assert set(METHOD_NAMES) == set(VARIANTS)
    for name in METHOD_NAMES:
        config = variant_config("tiny", name)
        assert isinstance(config, TrainConfig) and VARIANTS[name][0]
    with pytest.raises(ValueError, match="unknown method 'nope'.*ours-gt-masks"):
        variant_config("tiny", "nope")


def test_ablations_change_only_their_own_fields():
    base = to_dict(preset(TrainConfig, "small"))
    expected = {
        "ours": {}, "static": {("method",): "static"}, "pvg": {("method",): "pvg"},
        "ours-no-radar": {("losses", "radar_weight"): 0.0},
        "ours-no-flow": {("losses", "flow_weight"): 0.0},
        "ours-field-only": {("losses", "flow_weight"): 0.0, ("losses", "radar_weight"): 0.0},
        "ours-no-dropout": {("optim", "dropout"): 0.0},
        "ours-no-depth": {("losses", "depth_weight"): 0.0},
        "ours-no-masks": {("losses", "object_weight"): 0.0, ("losses", "sky_weight"): 0.0,
                          ("losses", "dynamic_l1_weight"): 0.0},
        "ours-no-lifespan": {("dynamic_lifespan",): 0.0},
        "ours-lidar-init": {("init", "source"): "lidar"},
        "ours-radar-masks": {("mask_source",): "baseline"}, "ours-gt-masks": {("mask_source",): "gt"},
    }

    def flat(d, prefix=()):
        for k, v in d.items():
            yield from flat(v, prefix + (k,)) if isinstance(v, dict) else [(prefix + (k,), v)]

    base_flat = dict(flat(base))
    for name, changes in expected.items():
        got = dict(flat(to_dict(variant_config("small", name))))
        assert {k: v for k, v in got.items() if base_flat[k] != v} == changes, name
    # A method's fields win over the same option given by the user; other options stay.
    config = apply_variant(preset(TrainConfig, "small", losses={"radar_weight": 0.3, "flow_weight": 2.0}),
                           "ours-no-radar")
    assert config.losses.radar_weight == 0.0 and config.losses.flow_weight == 2.0


@pytest.mark.parametrize("method", ["deformable", "pvg", "bspline"])
def test_baseline_trains_reloads_and_resumes_exactly(tiny_trained_run, tmp_path, one_torch_thread, method):
    scene = tiny_trained_run / "scene"
    config = small_config(method)
    unbroken = train_run(scene, scene / "prepared", tmp_path / "a", config, progress=False)
    model = unbroken.model
    assert model.field is None
    if method == "deformable":
        assert model.offsets is not None and model.dynamic is None
        assert any(p.abs().max() > 0 for p in model.offsets.mlp[-1].parameters())  # it learned offsets
    if method == "pvg":
        assert model.dynamic is None and model.static.has("velocity") and model.static.has("tau")
        assert float(model.static.params["velocity"].detach().abs().max()) > 0
    if method == "bspline":
        assert model.dynamic is not None and len(model.dynamic) > 0 and model.dynamic.has("control")
        assert float(model.dynamic.params["control"].detach().abs().max()) > 0
    # Reloaded from model.pt, it places the Gaussians exactly as the trained one at any time.
    loaded = load_model(tmp_path / "a" / "model.pt")
    for t in (0.0, 0.43, 1.0):
        a, b = model.gaussians_at(t), loaded.gaussians_at(t)
        for key in ("means", "opacities", "colors"):
            torch.testing.assert_close(a[key].detach(), b[key].detach())
    # Killed after 6 iterations and resumed (with another thread count): the same model.
    train_run(scene, scene / "prepared", tmp_path / "b", config, progress=False, stop_after=6)
    resumed = train_run(scene, scene / "prepared", tmp_path / "b", apply_variant(
        small_config(method, threads=2), method), resume=True, progress=False)
    for t in (0.0, 0.5):
        a, b = model.gaussians_at(t), resumed.model.gaussians_at(t)
        torch.testing.assert_close(a["means"].detach(), b["means"].detach(), rtol=1e-5, atol=1e-6)


def test_pvg_life_peaks_start_at_their_frame_times(tiny_trained_run, tmp_path, one_torch_thread):
    scene_dir = tiny_trained_run / "scene"
    state = train_run(scene_dir, scene_dir / "prepared", tmp_path / "pvg",
                      small_config("pvg", optim={"iterations": 1}), progress=False)
    scene = read_scene(scene_dir)
    times = np.array([f.timestamp for f in scene.frames])
    times = (times - times[0]) / (times[-1] - times[0])
    tau = state.model.static.params["tau"].detach().numpy()
    # Every life peak starts at the time of a training frame (one Adam step of time_lr from it).
    distance = np.abs(tau[:, None] - times[scene.train_indices][None])
    assert distance.min(axis=1).max() <= 1.1e-3
    assert len(np.unique(distance.argmin(axis=1))) == len(scene.train_indices)  # every frame has some


def test_mask_sources(tiny_trained_run):
    scene_dir = tiny_trained_run / "scene"
    scene = read_scene(scene_dir)
    prepared = scene_dir / "prepared"
    frames = scene.train_indices[:3]
    gt = dynamic_masks(scene, prepared, "gt", frames)
    for i in frames:
        np.testing.assert_array_equal(gt[i], scene.load_optional("gt/dynamic_mask", i).astype(bool))
    baseline = dynamic_masks(scene, prepared, "baseline", frames)
    summary = prepared / BASELINE_MASK_DIR / "summary.json"
    stamp = summary.stat().st_mtime_ns
    again = dynamic_masks(scene, prepared, "baseline", frames)
    assert summary.stat().st_mtime_ns == stamp  # computed once, then reused
    for i in frames:
        np.testing.assert_array_equal(baseline[i], again[i])
    # The radar flood fill finds the moving cars: it overlaps the true masks where they exist.
    union_gt = sum(int(gt[i].sum()) for i in frames)
    overlap = sum(int((gt[i] & baseline[i]).sum()) for i in frames)
    assert union_gt > 0 and overlap > 0.3 * union_gt
    with pytest.raises(ValueError, match="unknown mask source"):
        dynamic_masks(scene, prepared, "magic", frames)


def test_lidar_initialisation_lands_on_the_true_surfaces(tiny_trained_run):
    scene_dir = tiny_trained_run / "scene"
    scene = read_scene(scene_dir)
    config = GaussianInitConfig(source="lidar", points_per_frame=0)
    frames = scene.train_indices[:2]
    masks = {i: scene.load_optional("gt/dynamic_mask", i).astype(bool) for i in frames}
    points = backproject_frames(scene, scene_dir / "prepared", config, frames=frames, masks=masks)
    assert len(points["points"]) > 100
    for i in frames:
        mine = points["frame"] == i
        w2c = scene.world_to_camera(i)
        cam = points["points"][mine] @ w2c[:3, :3].T + w2c[:3, 3]
        u, v = points["pixels"][mine].T
        truth = scene.load_optional("gt/depth", i)[v, u]
        ok = np.isfinite(truth)
        # LiDAR depth (with its range noise) agrees with the true depth of the pixel it lands on,
        # away from depth edges, where a rounded pixel may fall on the other surface.
        relative = np.abs(cam[ok, 2] - truth[ok]) / truth[ok]
        assert np.median(relative) < 0.02
        np.testing.assert_array_equal(points["dynamic"][mine], masks[i][v, u])


@pytest.mark.parametrize("dynamic_stop, densified", [(0.0, False), (1.0, True)])
def test_dynamic_gaussians_densify_only_in_their_own_window(tiny_trained_run, tmp_path, one_torch_thread,
                                                             dynamic_stop, densified):
    scene = tiny_trained_run / "scene"
    config = small_config("ours", densify={"every": 2, "start": 0.0, "stop": 0.5, "grad_threshold": 1e-9,
                                           "max_gaussians": 3500, "dynamic_stop": dynamic_stop})
    state = train_run(scene, scene / "prepared", tmp_path / "run", config, progress=False)
    rounds = [h for h in state.history if h.get("densify") == "dynamic"]
    assert bool(rounds) == densified
    assert all(6 <= h["step"] < 12 for h in rounds)  # stage 2 starts at 6 of 12
    assert any(h.get("densify") == "static" for h in state.history)


@pytest.mark.parametrize("dynamic_grad_threshold, dynamic_grows", [(0.0, False), (1e-9, True)])
def test_dynamic_gaussians_grow_at_their_own_gradient_threshold(tiny_trained_run, tmp_path, one_torch_thread,
                                                                dynamic_grad_threshold, dynamic_grows):
    scene = tiny_trained_run / "scene"
    config = small_config("ours", densify={"every": 2, "start": 0.0, "stop": 1.0, "grad_threshold": 1e9,
                                           "max_gaussians": 3500, "dynamic_grad_threshold": dynamic_grad_threshold})
    state = train_run(scene, scene / "prepared", tmp_path / "run", config, progress=False)
    grown = {name: sum(h["cloned"] + h["split"] for h in state.history if h.get("densify") == name)
             for name in ("static", "dynamic")}
    assert grown["static"] == 0  # no gradient passes 1e9
    assert (grown["dynamic"] > 0) == dynamic_grows


def test_a_negative_densification_threshold_is_refused():
    with pytest.raises(ValueError, match="dynamic_grad_threshold must be >= 0, got 0.0002, -1e-05"):
        preset(TrainConfig, "tiny", densify={"dynamic_grad_threshold": -1e-5})
    with pytest.raises(ValueError, match="dynamic_clone_max_scale must be >= 0, got -0.001"):
        preset(TrainConfig, "tiny", densify={"dynamic_clone_max_scale": -0.001})


def test_the_dynamic_set_takes_its_own_densification_rules_where_set():
    d = DensifyConfig(stop=0.5, dynamic_stop=0.8, grad_threshold=2e-4, dynamic_grad_threshold=5e-5,
                      clone_max_scale=0.01, dynamic_clone_max_scale=0.001)
    assert d.for_set("static") == d
    dynamic = d.for_set("dynamic")
    assert (dynamic.stop, dynamic.grad_threshold, dynamic.clone_max_scale) == (0.8, 5e-5, 0.001)
    unset = DensifyConfig(stop=0.5).for_set("dynamic")  # 0 keeps the static set's rule, a later stop wins
    assert (unset.stop, unset.grad_threshold, unset.clone_max_scale) == (0.5, 2e-4, 0.01)


def test_dynamic_gaussians_split_below_their_own_clone_line(tiny_trained_run, tmp_path, one_torch_thread):
    scene = tiny_trained_run / "scene"
    config = small_config("ours", densify={"every": 2, "start": 0.0, "stop": 1.0, "grad_threshold": 1e9,
                                           "max_gaussians": 3500, "dynamic_grad_threshold": 1e-9,
                                           "dynamic_clone_max_scale": 1e-9})
    state = train_run(scene, scene / "prepared", tmp_path / "run", config, progress=False)
    rounds = [h for h in state.history if h.get("densify") == "dynamic"]
    assert sum(h["split"] for h in rounds) > 0 and sum(h["cloned"] for h in rounds) == 0
