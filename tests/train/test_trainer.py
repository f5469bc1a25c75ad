"""The trainer on a tiny prepared synthetic scene: stages, losses, resume, densification, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from _prepared import prepared_tiny_scene, tiny_config, trained_and_initial_psnr

from radar4dgs.config import preset
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.field import randomize_
from radar4dgs.model.gaussians import GaussianSet
from radar4dgs.model.scene_model import load_model
from radar4dgs.model.view import rasterizer_intrinsics, scale_intrinsics
from radar4dgs.train.densify import GradientStats, append_rows, densify_and_prune, keep_rows, split_samples
from radar4dgs.train.determinism import step_generator
from radar4dgs.train.trainer import Trainer, TrainingError, train_run

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def prepared(tmp_path_factory):
    return prepared_tiny_scene(tmp_path_factory.mktemp("train"), seed=2)


# ---- pure pieces --------------------------------------------------------------------------


def test_stage_boundaries_follow_the_paper_fractions():
    config = preset(TrainConfig, "paper")
    assert config.optim.iterations == 30_000
    assert [config.stage_at(s) for s in (0, 14_999, 15_000, 19_999, 20_000, 29_999)] == [1, 1, 2, 2, 3, 3]
    assert preset(TrainConfig, "tiny", method="static").stage_at(10**6) == 1
    small = preset(TrainConfig, "small")
    assert [small.stage_at(s) for s in (449, 450, 719, 720)] == [1, 2, 2, 3]


def test_bad_config_is_refused():
    with pytest.raises(ValueError, match="stage2_start"):
        preset(TrainConfig, "tiny", optim={"stage2_start": 0.8, "stage3_start": 0.5})
    with pytest.raises(ValueError, match="dropout"):
        preset(TrainConfig, "tiny", optim={"dropout": 1.0})
    with pytest.raises(ValueError, match="dynamic_lifespan"):
        preset(TrainConfig, "tiny", dynamic_lifespan=-0.1)


def test_half_pixel_conventions():
    K = np.array([[100.0, 0, 159.5], [0, 100.0, 89.5], [0, 0, 1]])
    half = scale_intrinsics(K, 0.5)
    # The centre of the 320x180 image (159.5, 89.5) is the centre of the 160x90 one (79.5, 44.5).
    np.testing.assert_allclose(half[:2, 2], [79.5, 44.5])
    np.testing.assert_allclose(np.diag(half)[:2], [50.0, 50.0])
    np.testing.assert_allclose(rasterizer_intrinsics(K)[:2, 2], [160.0, 90.0])


# ---- densification ------------------------------------------------------------------------


def _gaussians(n: int, scale: float = 0.05) -> GaussianSet:
    rng = np.random.default_rng(0)
    return GaussianSet.from_points(rng.normal(size=(n, 3)), rng.uniform(size=(n, 3)), min_scale=scale, max_scale=scale)


def test_row_edits_keep_adam_moments_aligned():
    g = _gaussians(6)
    optimizer = torch.optim.Adam(g.param_groups({"means": 0.1, "colors": 0.1}, prefix="static."))
    loss = (g.params["means"] ** 2).sum() + g.params["colors"].sum()
    loss.backward()
    optimizer.step()
    before = optimizer.state[g.params["means"]]["exp_avg"].clone()
    keep = torch.tensor([True, False, True, True, False, True])
    keep_rows(g, optimizer, keep)
    assert len(g) == 4
    torch.testing.assert_close(optimizer.state[g.params["means"]]["exp_avg"], before[keep])
    append_rows(g, optimizer, {k: v.detach()[:2].clone() for k, v in g.params.items()})
    assert len(g) == 6
    moments = optimizer.state[g.params["means"]]["exp_avg"]
    torch.testing.assert_close(moments[:4], before[keep])
    assert torch.all(moments[4:] == 0)
    assert optimizer.param_groups[0]["params"][0] is g.params["means"]
    # A step after the edit works (shapes agree).
    (g.params["means"] ** 2).sum().backward()
    optimizer.step()


def test_split_children_are_drawn_from_the_parent():
    g = _gaussians(1, scale=0.5)
    params = {k: v.detach().repeat(4000, *([1] * (v.dim() - 1))) for k, v in g.params.items()}
    children = split_samples(params, torch.Generator().manual_seed(0))
    assert children["means"].shape == (8000, 3)
    spread = (children["means"] - params["means"][0]).std(dim=0)
    torch.testing.assert_close(spread, torch.full((3,), 0.5), atol=0.03, rtol=0)
    torch.testing.assert_close(children["log_scales"], params["log_scales"].repeat(2, 1) - math.log(1.6))


def test_densify_clones_small_splits_large_prunes_transparent():
    g = _gaussians(4)
    with torch.no_grad():
        g.params["log_scales"][1] = math.log(2.0)  # large: split
        g.params["opacity_logits"][3] = -10.0  # transparent: pruned
    optimizer = torch.optim.Adam(g.param_groups({"means": 0.1}))
    stats = GradientStats(4)
    stats.add(torch.tensor([[1.0, 0.0], [1.0, 0.0], [0.0, 0.0], [0.0, 0.0]]), torch.ones(4, dtype=torch.bool), 2, 2)
    config = tiny_config().densify
    counts = densify_and_prune(g, optimizer, stats, extent=10.0, config=config, generator=torch.Generator())
    assert counts == {"cloned": 1, "split": 1, "pruned": 1}
    # 4 - split parent - pruned + clone + 2 children = 5.
    assert len(g) == 5 and len(stats.grad) == 5


# ---- training runs ------------------------------------------------------------------------


def test_training_runs_all_stages_and_improves(prepared, tmp_path):
    scene, prep = prepared
    config = tiny_config(optim={"iterations": 30})
    state = train_run(scene, prep, tmp_path / "run", config, progress=False)
    logged = [h for h in state.history if "total" in h]
    assert {h["stage"] for h in logged} == {1, 2, 3}
    assert "object" in logged[-1] and "object" not in logged[0]
    assert all(math.isfinite(h["total"]) for h in logged)
    assert state.model.dynamic is not None and len(state.model.dynamic) > 0
    # Training frames are rendered better than by the initial Gaussians.
    trained, initial = trained_and_initial_psnr(scene, prep, state.model, config, tmp_path / "unused")
    assert trained > initial + 1.0
    assert (tmp_path / "run" / "model.pt").is_file() and (tmp_path / "run" / "config.json").is_file()
    assert any("densify" in h for h in state.history)
    model = load_model(tmp_path / "run" / "model.pt")
    assert model.num_gaussians == state.model.num_gaussians


def test_velocity_term_reaches_the_trainer_only_with_a_weight(prepared):
    from radar4dgs.io.scene import read_scene
    from radar4dgs.model.field import DeformationField
    from radar4dgs.model.run import LOSS_TERMS
    from radar4dgs.train.data import load_motion_targets
    from radar4dgs.train.objective import loss_weights, motion_losses

    scene_dir, prep = prepared
    scene = read_scene(scene_dir)
    field = DeformationField(preset(TrainConfig, "tiny").field)
    off_config, on_config = tiny_config(), tiny_config(losses={"velocity_weight": 0.1})
    assert set(loss_weights(on_config)) == set(LOSS_TERMS) and loss_weights(on_config)["velocity"] == 0.1
    off, on = load_motion_targets(scene, prep, off_config), load_motion_targets(scene, prep, on_config)
    assert off.velocity is None and on.velocity is not None and on.stats["velocity_samples"] == len(on.velocity) > 0

    def losses(targets):
        return motion_losses(field, targets, 64, step_generator(0, 0), torch.device("cpu"), torch.float32)

    without, with_velocity = losses(off), losses(on)
    assert "velocity" not in without and math.isfinite(float(with_velocity["velocity"].detach()))
    # The velocity draw comes last: the flow and radar minibatches are the same with it.
    assert all(torch.equal(without[k], with_velocity[k]) for k in without)


def test_radar_term_takes_doppler_only_from_returns_within_the_training_gate(prepared):
    from radar4dgs.io.scene import normalized_times, read_scene
    from radar4dgs.motion.association import load_radar_dynamics
    from radar4dgs.train.data import load_motion_targets

    scene_dir, prep = prepared
    scene = read_scene(scene_dir)
    targets = {gate: load_motion_targets(scene, prep, tiny_config(losses={"radar_gate": gate})).radar
               for gate in (0.25, 2.0)}
    assert 0 < len(targets[0.25]) < len(targets[2.0])
    times = np.unique(targets[0.25].t_i)
    returns = {t: load_radar_dynamics(scene, i, "prepared", prep)
               for i, t in zip(scene.train_indices, normalized_times(scene)[scene.train_indices], strict=True)
               if t in times}
    for t, radar in returns.items():
        rows = targets[0.25].t_i == t
        nearest = np.linalg.norm(targets[0.25].x[rows, None] - radar.points[None], axis=2)
        assert nearest.min(axis=1).max() <= 0.25
        # Each sample's Doppler is its nearest return's.
        np.testing.assert_allclose(targets[0.25].v_r[rows], radar.v_r_comp[nearest.argmin(axis=1)])


def test_dynamic_depth_term_is_logged_only_where_the_movers_train(prepared, tmp_path):
    scene, prep = prepared
    state = train_run(scene, prep, tmp_path / "run", tiny_config(losses={"dynamic_depth_weight": 0.1}), progress=False)
    logged = [h for h in state.history if "total" in h]
    assert not any("dynamic_depth" in h for h in logged if h["stage"] == 1)
    later = [h["dynamic_depth"] for h in logged if h["stage"] > 1 and "dynamic_depth" in h]
    assert later and all(math.isfinite(v) and v > 0 for v in later)


def started_dynamic(prepared, tmp_path, **overrides):
    """A fresh tiny run's state just after stage 2 began, and the frame time of each initial
    dynamic point (N,)."""
    scene, prep = prepared
    trainer = Trainer(scene, prep, tmp_path / "run", tiny_config(**overrides), progress=False, log=lambda _: None)
    trainer._load()
    state = trainer._fresh_state()
    trainer._start_dynamic(state)
    points = trainer._initial_points()
    return state, trainer.times[points["frame"][points["dynamic"]]]


@pytest.mark.parametrize("lifespan", [0.2, 0.0])
def test_dynamic_gaussians_live_around_the_frame_that_saw_them(prepared, tmp_path, lifespan):
    # Without the held-out window: t0 + 0.4 need not be a training frame's time.
    state, frame_times = started_dynamic(prepared, tmp_path, dynamic_lifespan=lifespan, held_out_window=0.0)
    dynamic = state.model.dynamic
    assert len(dynamic) == len(frame_times) > 0
    stored = dynamic.activated()["opacities"].detach()
    t0 = float(frame_times[0])
    with torch.no_grad():
        at_own_time = state.model.set_at("dynamic", t0)["opacities"]
        later = state.model.set_at("dynamic", t0 + 0.4)["opacities"]
    same_frame = torch.as_tensor(frame_times == t0)
    if lifespan == 0.0:
        assert not dynamic.has("tau") and not dynamic.has("log_lifespan")
        torch.testing.assert_close(later, stored)
        return
    np.testing.assert_allclose(dynamic.params["tau"].detach().numpy(), frame_times, rtol=0, atol=1e-6)
    torch.testing.assert_close(dynamic.params["log_lifespan"].detach(), torch.full((len(dynamic),), math.log(lifespan)))
    torch.testing.assert_close(at_own_time[same_frame], stored[same_frame])
    # 0.4 = two life spans later: exp(-0.5 * 2^2) of the stored opacity.
    torch.testing.assert_close(later[same_frame], stored[same_frame] * math.exp(-2.0))
    # The trainer hands the model its training frames' times for the window (each copy's frame is one).
    assert set(np.round(frame_times, 9)) <= set(np.round(state.model.key_times, 9))
    assert state.model.window_fraction == 0.0


def test_own_time_dynamic_gaussians_start_at_their_frames_world_points(prepared, tmp_path):
    scene, prep = prepared
    states = {}
    for positions in ("own-time", "canonical"):
        trainer = Trainer(scene, prep, tmp_path / positions, tiny_config(dynamic_positions=positions),
                          progress=False, log=lambda _: None)
        trainer._load()
        states[positions] = state = trainer._fresh_state()
        randomize_(state.model.field, last_std=0.2, generator=torch.Generator().manual_seed(0))  # metres of motion
        trainer._start_dynamic(state)
    points = trainer._initial_points()
    own, canonical = states["own-time"].model, states["canonical"].model
    assert own.own_time_means and not canonical.own_time_means
    assert own.dynamic_in_front == canonical.dynamic_in_front == TrainConfig().dynamic_in_front == 0.1
    world = torch.as_tensor(points["points"][points["dynamic"]], dtype=torch.float32)
    frame_times = trainer.times[points["frame"][points["dynamic"]]]
    torch.testing.assert_close(own.dynamic.params["means"].detach(), world)
    with torch.no_grad():  # the canonical run's means are the same points moved by D_tau^-1
        torch.testing.assert_close(canonical.field(canonical.dynamic.params["means"],
                                                   torch.as_tensor(frame_times, dtype=torch.float32)),
                                   world, rtol=0, atol=1e-4)
    assert float((world - canonical.dynamic.params["means"].detach()).norm(dim=1).max()) > 0.1
    # At its frame's time an own-time Gaussian is drawn where that frame saw it.
    t0 = float(frame_times[0])
    same_frame = torch.as_tensor(frame_times == t0)
    with torch.no_grad():
        drawn = own.set_at("dynamic", t0)["means"][same_frame]
    torch.testing.assert_close(drawn, world[same_frame], rtol=0, atol=1e-4)


def test_resume_matches_an_unbroken_run(prepared, tmp_path):
    scene, prep = prepared
    config = tiny_config()
    unbroken = train_run(scene, prep, tmp_path / "a", config, progress=False)
    train_run(scene, prep, tmp_path / "b", config, progress=False, stop_after=14)  # "killed" in stage 2 (ckpt 8, 14)
    assert not (tmp_path / "b" / "model.pt").exists()
    assert torch.load(tmp_path / "b" / "checkpoints" / "last.pt", weights_only=True)["model"]["dynamic_in_front"] == 0.1
    resumed = train_run(scene, prep, tmp_path / "b", config, resume=True, progress=False)
    # Trained with the dynamic layer drawn 0.1 ahead, the finished model draws it 0.2 ahead.
    assert resumed.model.dynamic_in_front == unbroken.model.dynamic_in_front == config.render_in_front == 0.2
    assert load_model(tmp_path / "b" / "model.pt").dynamic_in_front == 0.2
    for name in ("static", "dynamic"):
        a, b = getattr(unbroken.model, name), getattr(resumed.model, name)
        for key in a.params:
            torch.testing.assert_close(a.params[key], b.params[key], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(unbroken.model.sky.logits, resumed.model.sky.logits)


def test_rigid_actors_take_over_their_gaussians_are_saved_and_resume(prepared, tmp_path, monkeypatch):
    from types import SimpleNamespace

    import radar4dgs.train.rigid_actors as rigid_module

    given = []

    def two_actors(model, scene, radar_objects=None, config=None):  # discovery itself: tests/actors
        given.append(radar_objects)
        half = len(model.dynamic) // 2
        return [SimpleNamespace(gaussians=np.arange(half), radar={}),
                SimpleNamespace(gaussians=np.arange(half, 2 * half), radar={})]

    monkeypatch.setattr(rigid_module, "discover_actors", two_actors)
    scene, prep = prepared
    # The switch at step 18 of 24, in stage 3; the radar path finds no radar object held and leaves the paths; the
    # Gaussians of neither actor (an odd count leaves one) may join one.
    config = tiny_config(rigid_actors_at=0.75, rigid_actors_heading=1.0, rigid_actors_radar_path=True,
                         rigid_actors_attach=0.05)
    logs: list[str] = []
    unbroken = Trainer(scene, prep, tmp_path / "a", config, progress=False, log=logs.append).train()
    headings = [h["actor_heading"] for h in unbroken.history if "actor_heading" in h]
    assert headings and all(np.isfinite(headings)) and all(h["step"] >= 18 for h in unbroken.history
                                                              if "actor_heading" in h)
    assert any(line.startswith("rigid actors: 2 of 2 actors") and "without radar" not in line
               and "joined in their own frame" in line for line in logs)
    assert given[0] is not None and len(given[0]) == len(read_scene_folder(scene))  # the prepared radar objects
    motion = unbroken.model.actor_motion
    assert len(motion) == 2 and motion.key_times.numel() == len(scene_train_indices(scene))
    assert motion.shift.abs().sum() > 0  # started from the field's motion, then learned
    actor = unbroken.model.dynamic.params["actor"]
    assert set(actor.long().unique().tolist()) <= {-1, 0, 1} and (actor >= 0).any()
    saved = load_model(tmp_path / "a" / "model.pt")
    torch.testing.assert_close(saved.actor_motion.shift, motion.shift.detach())
    train_run(scene, prep, tmp_path / "b", config, progress=False, stop_after=20)  # checkpoint after the switch
    resumed = train_run(scene, prep, tmp_path / "b", config, resume=True, progress=False)
    torch.testing.assert_close(resumed.model.actor_motion.shift, motion.shift, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(resumed.model.dynamic.params["means"], unbroken.model.dynamic.params["means"],
                               rtol=1e-5, atol=1e-6)


def test_rigid_actors_without_actors_leave_the_field_and_discover_once(prepared, tmp_path, monkeypatch):
    import radar4dgs.train.rigid_actors as rigid_module

    calls = []
    monkeypatch.setattr(rigid_module, "discover_actors", lambda *args, **kwargs: calls.append(1) or [])
    scene, prep = prepared
    logs: list[str] = []
    state = Trainer(scene, prep, tmp_path / "run", tiny_config(rigid_actors_at=0.75), progress=False,
                    log=logs.append).train()
    assert len(calls) == 1 and state.model.actor_motion is None and not state.model.dynamic.has("actor")
    assert any("no actor found" in line for line in logs)
    (prep / "radar" / "objects.json").rename(prep / "radar" / "objects.json.away")  # discovery without radar
    try:
        logs.clear()
        Trainer(scene, prep, tmp_path / "run2", tiny_config(rigid_actors_at=0.75), progress=False,
                log=logs.append).train()
    finally:
        (prep / "radar" / "objects.json.away").rename(prep / "radar" / "objects.json")
    assert any("no actor found" in line and "without radar objects" in line and "objects.json: missing file" in line
               for line in logs)


def read_scene_folder(scene):
    from radar4dgs.io.scene import read_scene

    return read_scene(scene)


def scene_train_indices(scene) -> list[int]:
    return read_scene_folder(scene).train_indices


def test_refuses_to_overwrite_a_run_or_resume_with_another_config(prepared, tmp_path):
    scene, prep = prepared
    config = tiny_config(optim={"iterations": 4})
    train_run(scene, prep, tmp_path / "run", config, progress=False)
    with pytest.raises(TrainingError, match="--resume"):
        train_run(scene, prep, tmp_path / "run", config, progress=False)
    with pytest.raises(TrainingError, match="another configuration"):
        train_run(scene, prep, tmp_path / "run", tiny_config(optim={"iterations": 5}), resume=True, progress=False)


def test_missing_prepared_folder_names_it(prepared, tmp_path):
    scene, _ = prepared
    with pytest.raises(FileNotFoundError, match="radar4dgs prepare"):
        train_run(scene, tmp_path / "nothing", tmp_path / "run", tiny_config(), progress=False)


def test_nan_loss_is_reported_with_the_step(prepared, tmp_path, monkeypatch):
    scene, prep = prepared
    import radar4dgs.train.trainer as trainer

    real = trainer.image_losses

    def broken(*args, **kwargs):
        losses = real(*args, **kwargs)
        losses["depth"] = losses["depth"] * float("nan")
        return losses

    monkeypatch.setattr(trainer, "image_losses", broken)
    with pytest.raises(TrainingError, match="non-finite loss at iteration 0.*depth"):
        train_run(scene, prep, tmp_path / "run", tiny_config(), progress=False)


def test_static_method_has_no_field_and_no_dynamic_gaussians(prepared, tmp_path):
    scene, prep = prepared
    state = train_run(scene, prep, tmp_path / "run", tiny_config(method="static", optim={"iterations": 6}),
                      progress=False)
    assert state.model.field is None and state.model.dynamic is None
    logged = [h for h in state.history if "total" in h]
    assert all("flow" not in h and "object" not in h for h in logged)


def test_coarse_to_fine_renders_early_iterations_at_the_coarse_scale(prepared, tmp_path):
    scene, prep = prepared
    config = tiny_config(coarse_scale=0.5, coarse_until=0.5, optim={"iterations": 6}, densify={"every": 0})
    trainer = Trainer(scene, prep, tmp_path / "run", config, progress=False)
    state = trainer.train()
    full, coarse = trainer.targets[0], trainer.coarse_targets[0]
    assert (coarse.view.width, coarse.view.height) == (full.view.width // 2, full.view.height // 2)
    assert coarse.image.shape == (full.view.height // 2, full.view.width // 2, 3)
    sizes = [h["width"] for h in state.history if "total" in h]
    assert sizes == [coarse.view.width] * 3 + [full.view.width] * 3

