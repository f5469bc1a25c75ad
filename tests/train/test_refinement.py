"""Pose refinement and exposure compensation in the trainer (issue 27): switched by the scene's
pose source, a zero rate changes nothing, corrections and colour transforms are checkpointed,
saved in RUN/poses.json and used by load_run."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from _prepared import prepared_tiny_scene

from radar4dgs.config import preset
from radar4dgs.io.scene import read_scene
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.pose_refine import pose_error
from radar4dgs.model.run import POSES_FILE, load_run
from radar4dgs.train.optimizers import pose_lr_scale
from radar4dgs.train.trainer import train_run

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def prepared(tmp_path_factory):
    return prepared_tiny_scene(tmp_path_factory.mktemp("refine"), seed=3)


def tiny_config(**poses) -> TrainConfig:
    return preset(TrainConfig, "tiny", threads=1, optim={"iterations": 16}, checkpoint_every=6, log_every=1,
                  init={"points_per_frame": 500, "max_static": 2000, "max_dynamic": 400},
                  densify={"every": 0}, losses={"motion_batch": 64, "radar_points_per_frame": 100},
                  poses={"warmup": 0.25, **poses})


def test_the_pose_rate_waits_for_the_warm_up_then_decays():
    config = preset(TrainConfig, "tiny", optim={"iterations": 101}, poses={"warmup": 0.2, "lr_final_ratio": 0.1})
    assert pose_lr_scale(config, 19) == 0.0
    assert pose_lr_scale(config, 20) == pytest.approx(1.0)
    assert pose_lr_scale(config, 100) == pytest.approx(0.1)
    assert pose_lr_scale(config, 60) == pytest.approx(0.1 ** 0.5)


def test_synthetic_poses_are_not_refined_by_default(prepared, tmp_path):
    scene, prep = prepared
    state = train_run(scene, prep, tmp_path / "run", tiny_config(), progress=False, tensorboard=False)
    assert state.poses is None and state.appearance is None
    assert "poses" not in state.optimizers and not (tmp_path / "run" / POSES_FILE).exists()


def test_refinement_at_a_zero_rate_trains_exactly_the_plain_run(prepared, tmp_path):
    scene, prep = prepared
    plain = train_run(scene, prep, tmp_path / "a", tiny_config(), progress=False, tensorboard=False)
    zero = train_run(scene, prep, tmp_path / "b", tiny_config(refine="on", translation_lr=0.0, rotation_lr=0.0,
                                                              smooth_trajectory=False),
                     progress=False, tensorboard=False)
    assert zero.poses is not None and torch.count_nonzero(zero.poses.xi) == 0
    for key, value in plain.model.static.params.items():
        assert torch.equal(value, zero.model.static.params[key]), key
    assert torch.equal(plain.model.sky.logits, zero.model.sky.logits)


def test_refined_poses_are_learned_checkpointed_saved_and_loaded(prepared, tmp_path):
    scene, prep = prepared
    config = tiny_config(refine="on", appearance="on", translation_lr=0.01, rotation_lr=0.002)
    unbroken = train_run(scene, prep, tmp_path / "a", config, progress=False, tensorboard=False)
    train_run(scene, prep, tmp_path / "b", config, progress=False, tensorboard=False, stop_after=9)
    resumed = train_run(scene, prep, tmp_path / "b", config, resume=True, progress=False, tensorboard=False)
    torch.testing.assert_close(unbroken.poses.xi, resumed.poses.xi, rtol=1e-5, atol=1e-7)
    torch.testing.assert_close(unbroken.appearance.matrix, resumed.appearance.matrix, rtol=1e-5, atol=1e-7)
    xi = unbroken.poses.xi.detach().numpy()
    # 12 steps after the warm-up at 0.01 m / 0.002 rad: every trained frame moved, none far.
    assert 0.005 < np.abs(xi[:, :3]).max() < 0.2 and np.abs(xi[:, 3:]).max() < 0.05
    assert torch.count_nonzero(unbroken.appearance.bias) > 0

    saved = json.loads((tmp_path / "a" / POSES_FILE).read_text())
    recorded = read_scene(scene)
    assert saved["poses_refined"] and [f["index"] for f in saved["frames"]] == recorded.train_indices
    run = load_run(tmp_path / "a")
    for row, index in enumerate(recorded.train_indices):
        w2c = run.scene.world_to_camera(index)
        np.testing.assert_allclose(w2c, saved["frames"][row]["world_to_camera"], atol=1e-9)
        t, r = pose_error(w2c, recorded.world_to_camera(index))
        assert t == pytest.approx(np.linalg.norm(xi[row, :3]), rel=1e-3, abs=1e-6)
        assert r == pytest.approx(np.degrees(np.linalg.norm(xi[row, 3:])), rel=1e-3, abs=1e-4)
        # The radar moved with the camera: radar-to-camera is what the scene recorded.
        np.testing.assert_allclose(run.scene.radar_to_camera(index), recorded.radar_to_camera(index), atol=1e-9)
    for index in recorded.test_indices:
        np.testing.assert_array_equal(run.scene.world_to_camera(index), recorded.world_to_camera(index))


def test_a_refined_run_is_evaluated_with_aligned_test_views_and_reported(prepared, tmp_path):
    from radar4dgs.evaluate.reconstruction import evaluate_run

    scene, prep = prepared
    config = tiny_config(refine="on", appearance="on", translation_lr=0.01, rotation_lr=0.002, test_steps=5)
    train_run(scene, prep, tmp_path / "run", config, progress=False, tensorboard=False)
    metrics = evaluate_run(tmp_path / "run", lpips=False, video=False, report=True, progress=False)
    n_test = metrics["nvs"]["n_frames"]
    assert set(metrics["nvs_aligned"]) == {"interpolated", "optimised"}
    for name, summary in metrics["nvs_aligned"].items():
        assert summary["n_frames"] == n_test and summary["psnr"] > 10, name
    entries = metrics["test_view_alignment"]["per_frame"]["optimised"]
    assert all(e["optimisation"]["l1_end"] <= e["optimisation"]["l1_start"] * 1.01 for e in entries)
    report = (tmp_path / "run" / "report.html").read_text()
    assert "Pose and exposure refinement" in report and 'alt="pose corrections"' in report


def test_the_mean_correction_and_colour_transform_stay_zero(prepared, tmp_path):
    """The gauge: moving every camera (or every frame's colours) together changes no training image,
    so the trainer keeps the mean deviation from the smoothed trajectory and the mean transform at zero."""
    scene, prep = prepared
    config = tiny_config(refine="on", appearance="on", translation_lr=0.01, rotation_lr=0.002)
    state = train_run(scene, prep, tmp_path / "run", config, progress=False, tensorboard=False)
    deviation = (state.poses.xi - state.poses.target).detach()
    assert float(deviation.abs().max()) > 1e-3
    torch.testing.assert_close(deviation.mean(0), torch.zeros(6), atol=1e-7, rtol=0)
    torch.testing.assert_close(state.appearance.bias.detach().mean(0), torch.zeros(3), atol=1e-7, rtol=0)
    torch.testing.assert_close(state.appearance.matrix.detach().mean(0), torch.zeros(3, 3), atol=1e-7, rtol=0)


def test_the_corrections_start_on_the_smoothed_trajectory(prepared, tmp_path):
    """At zero rates the cameras stay on the target: the smoothing spline of the recorded camera
    centres (the tiny scene's synthetic path is smooth, so within millimetres of the recorded)."""
    from radar4dgs.model.pose_refine import camera_centres, se3_exp, smoothed_series

    scene, prep = prepared
    state = train_run(scene, prep, tmp_path / "run", tiny_config(refine="on", translation_lr=0.0, rotation_lr=0.0),
                      progress=False, tensorboard=False)
    recorded = read_scene(scene)
    w2c = np.stack([recorded.world_to_camera(i) for i in recorded.train_indices])
    times = np.array([recorded.frames[i].timestamp for i in recorded.train_indices])
    moved = se3_exp(state.poses.xi.detach().double()).numpy() @ w2c
    np.testing.assert_allclose(camera_centres(moved), smoothed_series(times, camera_centres(w2c)), atol=1e-5)
    assert 0 < float(state.poses.target.abs().max()) < 0.01
