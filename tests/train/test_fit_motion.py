"""Scene-level paths on a tiny synthetic scene: prepare_flow (oracle depth/masks), the clear
errors for missing prepared inputs, radar association, the standalone fit and the command."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radar4dgs.config import preset
from radar4dgs.io.scene import read_scene
from radar4dgs.motion.association import (RadarDynamics, associate_nearest, associate_velocities,
                                          compensated_radial_velocity, load_radar_dynamics,
                                          oracle_radar_velocity)
from radar4dgs.motion.config import FlowConfig
from radar4dgs.motion.flow import frame_pairs, load_flow_pairs, prepare_flow
from radar4dgs.motion.metrics import motion_frontend_metrics

# Tiny tensors: on the shared 2-core CI machine extra torch threads only spin.
pytestmark = pytest.mark.usefixtures("one_torch_thread")

ORACLE = {"depth_source": "oracle", "mask_source": "oracle"}


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    synth = pytest.importorskip("radar4dgs.datasets.synth")
    root = tmp_path_factory.mktemp("motion") / "scene"
    synth.synthesize(preset(synth.SynthConfig, "tiny", seed=2), root, overwrite=True, progress=False)
    return read_scene(root)


@pytest.fixture(scope="module")
def prepared(tiny_scene, tmp_path_factory):
    folder = tmp_path_factory.mktemp("prepared")
    prepare_flow(tiny_scene, folder, preset(FlowConfig, "tiny", **ORACLE))
    return folder


def test_prepare_flow_writes_pairs_of_training_frames(tiny_scene, prepared):
    pairs = load_flow_pairs(prepared)
    expected = frame_pairs(tiny_scene, skip_test_frames=True)
    assert [(int(p["index_i"]), int(p["index_j"])) for p in pairs] == expected
    assert not set(tiny_scene.test_indices) & {i for pair in expected for i in pair}
    h, w = tiny_scene.camera.height, tiny_scene.camera.width
    total = 0
    for pair in pairs:
        assert pair["flow"].shape == (h, w, 2) and pair["consistent"].shape == (h, w)
        assert pair["points_i"].shape == pair["points_j"].shape == (len(pair["pixels"]), 3)
        total += len(pair["pixels"])
    assert total > 0
    assert json.loads((prepared / "flow" / "config.json").read_text())["depth_source"] == "oracle"
    metrics = motion_frontend_metrics(tiny_scene, prepared)
    assert metrics["flow2d_pairs"] > 0
    assert 0 <= metrics["flow2d_epe_dynamic"] < 5.0  # pixels, on 160x90
    assert 0 <= metrics["sceneflow_epe_dynamic"] < 1.0  # metres


def test_missing_prepared_inputs_name_the_folder_and_the_option(tiny_scene, tmp_path):
    with pytest.raises(FileNotFoundError, match=r"depth.*depth_source='oracle'"):
        prepare_flow(tiny_scene, tmp_path, FlowConfig())
    with pytest.raises(FileNotFoundError, match=r"masks.*mask_source='oracle'"):
        prepare_flow(tiny_scene, tmp_path, FlowConfig(depth_source="oracle"))
    with pytest.raises(FileNotFoundError, match=r"radar.*radar_source='oracle'"):
        load_radar_dynamics(tiny_scene, 0, "prepared", tmp_path)
    assert not (tmp_path / "flow").exists()


def test_association_nearest_within_gate():
    radar = RadarDynamics(np.array([[10.0, 0, 0], [20.0, 0, 0]]), np.array([1.0, -2.0]), np.zeros(3))
    points = np.array([[10.5, 0, 0], [19.0, 0.5, 0], [15.0, 0, 0], [30.0, 0, 0]])
    index, distance = associate_nearest(points, radar.points, gate=2.0)
    assert index.tolist() == [0, 1, -1, -1]
    assert distance[0] == pytest.approx(0.5)
    velocity = associate_velocities(points, radar, gate=2.0)
    assert velocity[:2].tolist() == [1.0, -2.0] and np.isnan(velocity[2:]).all()
    empty = RadarDynamics(np.zeros((0, 3)), np.zeros(0), np.zeros(3))
    assert np.isnan(associate_velocities(points, empty)).all()


def test_compensated_radial_velocity_of_static_and_moving_points():
    xyz = np.array([[10.0, 0, 0], [0, 10.0, 0], [6.0, 8.0, 0]])
    radar_velocity = np.array([5.0, 0, 0])
    static_doppler = -(xyz / np.linalg.norm(xyz, axis=1, keepdims=True)) @ radar_velocity  # v_r = -d . v_s
    assert compensated_radial_velocity(xyz, static_doppler, radar_velocity) == pytest.approx([0, 0, 0])
    # a point ahead receding at 3 m/s in the world while the radar drives at 5: raw v_r = 3 - 5
    assert compensated_radial_velocity(xyz[:1], np.array([-2.0]), radar_velocity)[0] == pytest.approx(3.0)


def test_oracle_radar_dynamics_compensate_static_points(tiny_scene):
    i = 3
    scan = tiny_scene.load_radar(i)
    labels = tiny_scene.load_optional("gt/radar_labels", i)
    comp = compensated_radial_velocity(scan.xyz, scan.v_r, oracle_radar_velocity(tiny_scene, i))
    assert np.median(np.abs(comp[labels == 0])) < 0.3
    dynamics = load_radar_dynamics(tiny_scene, i, "oracle")
    assert len(dynamics) == int((labels == 1).sum())
    assert dynamics.centre == pytest.approx(tiny_scene.radar_to_world(i)[:3, 3])


def test_radar_returns_become_samples_with_their_own_doppler(tiny_scene):
    from radar4dgs.io.scene import normalized_times
    from radar4dgs.train.fit_motion import FitConfig, collect_radar_samples

    flow = FlowConfig(**ORACLE)
    times = normalized_times(tiny_scene)
    base, base_stats = collect_radar_samples(tiny_scene, None, flow,
                                             FitConfig(radar_source="oracle", radar_returns_as_points=False), times)
    more, stats = collect_radar_samples(tiny_scene, None, flow,
                                        FitConfig(radar_source="oracle", radar_returns_as_points=True), times)
    pairs = frame_pairs(tiny_scene, flow.skip_test_frames)
    returns = [load_radar_dynamics(tiny_scene, i, "oracle") for i, _ in pairs]
    assert stats["radar_returns_supervised"] == sum(len(r) for r in returns) > 0
    assert base_stats["radar_returns_supervised"] == 0 and stats["radar_matched"] == base_stats["radar_matched"]
    assert len(more) == len(base) + stats["radar_returns_supervised"]
    # The returns of the first pair follow its lifted pixels, with their own Doppler and radar centre.
    first = int(np.sum(more.t_i == times[pairs[0][0]])) - len(returns[0])
    block = slice(first, first + len(returns[0]))
    assert np.array_equal(more.x[block], returns[0].points)
    assert np.array_equal(more.v_r[block], returns[0].v_r_comp)
    assert np.allclose(more.centre[block], returns[0].centre)


def test_fit_beats_a_field_that_does_not_move(tiny_scene, prepared):
    from radar4dgs.train.fit_motion import MotionConfig, load_field, run_fit, save_field

    config = preset(MotionConfig, "tiny", flow=ORACLE, fit={"radar_source": "oracle", "iterations": 60})
    field, result = run_fit(tiny_scene, prepared, config, use_flow=True, use_radar=True)
    metrics = result["sceneflow"]
    assert metrics["points"] > 0 and metrics["epe"] < 0.8 * metrics["zero_motion_epe"]
    assert result["history"][-1]["total"] < result["history"][0]["total"]
    path = save_field(field, prepared / "field.pt")
    again = load_field(path)
    import torch

    x = torch.rand(10, 3) * 20
    assert torch.equal(again.warp(x, 0.1, 0.4), field.warp(x, 0.1, 0.4))


def test_fit_motion_command(tiny_scene, prepared, tmp_path, capsys):
    from radar4dgs.apps.fit_motion import FitMotionCommand
    from radar4dgs.train.fit_motion import MotionConfig

    config = preset(MotionConfig, "tiny", flow=ORACLE, fit={"radar_source": "oracle", "iterations": 20})
    out = tmp_path / "motion"
    command = FitMotionCommand(scene=tiny_scene.root, prepared=prepared, out=out, use_radar=False,
                               preset="tiny", config=config, quiet=True)
    assert command.run() == 0
    result = json.loads((out / "results.json").read_text())
    assert result["use_flow"] and not result["use_radar"] and result["sceneflow"]["epe"] is not None
    assert (out / "field.pt").is_file() and (out / "config.json").is_file()
    assert "scene-flow EPE" in capsys.readouterr().out
    missing = FitMotionCommand(scene=tiny_scene.root, prepared=tmp_path / "nothing", preset="tiny",
                               config=preset(MotionConfig, "tiny"), quiet=True)
    assert missing.run() == 1
    assert "depth_source='oracle'" in capsys.readouterr().err


def test_command_parses_through_the_cli(monkeypatch):
    from radar4dgs import cli

    monkeypatch.setitem(cli.COMMANDS, "fit-motion", ("radar4dgs.apps.fit_motion", "FitMotionCommand"))
    command = cli.build_command("fit-motion", ["/data/scene", "--no-use-radar", "--preset", "tiny",
                                               "--config.fit.iterations", "5", "--prepared", "/p"])
    assert str(command.scene) == "/data/scene" and str(command.prepared) == "/p"
    assert command.use_flow and not command.use_radar
    assert command.config.fit.iterations == 5
    assert command.config.field.num_layers == 3  # from the tiny preset
