import json
import warnings

import numpy as np
import pytest
from _radar_helpers import write_tiny_scene

from radar4dgs.apps.prepare import PrepareConfig, run_prepare
from radar4dgs.cli import main
from radar4dgs.config import load_config
from radar4dgs.io.scene import read_scene
from radar4dgs.radar import RadarConfig, load_radar_outputs, prepare_radar
from radar4dgs.radar.process import load_radar_dynamics_flags


def test_prepare_radar_outputs(tmp_path):
    scene = read_scene(write_tiny_scene(tmp_path / "scene", yaw_rate=0.3))
    summary = prepare_radar(scene, tmp_path / "radar", RadarConfig())
    assert summary["num_ok"] == len(scene)
    for i, frame in enumerate(scene.frames):
        out = load_radar_outputs(tmp_path / "radar", frame.name)
        n = len(scene.load_radar(i))
        assert out["ego_velocity"].shape == (3,) and out["ego_velocity"].dtype == np.float64
        assert out["covariance"].shape == (3, 3) and bool(out["ok"])
        assert out["inliers"].shape == out["dynamic"].shape == (n,) and out["dynamic"].dtype == bool
        assert out["v_r_comp"].dtype == np.float32 and out["v_r_comp"].shape == (n,)
    # The scene's own motion (ego_velocity + yaw rate from poses, lever arm 3.5 m) agrees.
    assert summary["disagreement"]["rmse"] < 0.05
    saved = json.loads((tmp_path / "radar" / "summary.json").read_text())
    assert saved["frames"][0]["speed"] == pytest.approx(np.hypot(10, 0.3 * 3.5), abs=0.05)


def test_rows_align_with_load_radar_after_nan_drop(tmp_path):
    root = write_tiny_scene(tmp_path / "scene", frames=3)
    path = root / "radar" / "000001.npy"
    data = np.load(path)
    data[5, 0] = np.nan
    np.save(path, data)
    scene = read_scene(root)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prepare_radar(scene, tmp_path / "radar")
        n = len(scene.load_radar(1))
    assert n == len(data) - 1
    assert load_radar_outputs(tmp_path / "radar", "000001")["dynamic"].shape == (n,)


def test_dynamics_flags_reader_checks_the_file_against_the_scan(tmp_path):
    scene = read_scene(write_tiny_scene(tmp_path / "scene", frames=3))
    prepare_radar(scene, tmp_path / "radar")
    n = len(scene.load_radar(1))
    dynamic, comp = load_radar_dynamics_flags(tmp_path / "radar", "000001", n)
    saved = load_radar_outputs(tmp_path / "radar", "000001")
    assert np.array_equal(dynamic, saved["dynamic"]) and comp.dtype == np.float64
    assert np.array_equal(comp, saved["v_r_comp"].astype(np.float64))
    with pytest.raises(ValueError, match=rf"000001.npz: {n} rows, but the scan has {n + 1}"):
        load_radar_dynamics_flags(tmp_path / "radar", "000001", n + 1)
    np.savez(tmp_path / "radar" / "000002.npz", dynamic=saved["dynamic"])  # an older, partial file
    with pytest.raises(ValueError, match=r"000002.npz: missing arrays \['v_r_comp'\]"):
        load_radar_dynamics_flags(tmp_path / "radar", "000002", n)
    with pytest.raises(FileNotFoundError, match="000009.npz: missing file"):
        load_radar_dynamics_flags(tmp_path / "radar", "000009", n)


def test_smoothing_options(tmp_path):
    scene = read_scene(write_tiny_scene(tmp_path / "scene", frames=7))
    for mode in ("median", "mean"):
        summary = prepare_radar(scene, tmp_path / mode, RadarConfig(smoothing=mode, smoothing_window=3))
        speeds = [f["speed"] for f in summary["frames"]]
        assert max(abs(s - 10.0) for s in speeds) < 0.05


def test_scene_without_poses_reports_no_disagreement(tmp_path):
    scene = read_scene(write_tiny_scene(tmp_path / "scene", frames=3, ego_velocity=False, poses=False))
    summary = prepare_radar(scene, tmp_path / "radar")
    assert summary["disagreement"]["rmse"] is None and "poses never change" in summary["disagreement"]["note"]


def test_prepare_command_skips_and_forces(tmp_path, capsys):
    root = write_tiny_scene(tmp_path / "scene", frames=3)
    assert main(["prepare", str(root), "--quiet", "--only", "radar", "--preset", "tiny"]) == 0
    assert "radar: ran" in capsys.readouterr().out
    marker = root / "prepared" / "radar" / "stage.json"
    first = marker.stat().st_mtime_ns
    assert main(["prepare", str(root), "--quiet", "--only", "radar", "--preset", "tiny"]) == 0
    assert "radar: skipped" in capsys.readouterr().out and marker.stat().st_mtime_ns == first
    # A changed config reruns the stage; --force reruns it anyway.
    assert main(["prepare", str(root), "--quiet", "--only", "radar", "--preset", "tiny",
                 "--config.radar.noise-std", "0.2"]) == 0
    assert "radar: ran" in capsys.readouterr().out
    assert main(["prepare", str(root), "--quiet", "--only", "radar", "--preset", "tiny",
                 "--config.radar.noise-std", "0.2", "--force"]) == 0
    assert "radar: ran" in capsys.readouterr().out
    config = load_config(PrepareConfig, root / "prepared" / "config.json")
    assert config.radar.noise_std == 0.2 and config.radar.max_iterations == 200


def test_prepare_out_folder_and_errors(tmp_path, capsys):
    root = write_tiny_scene(tmp_path / "scene", frames=2)
    status = run_prepare(root, tmp_path / "elsewhere", PrepareConfig(), only=("radar",), progress=False)
    assert status == {"radar": "ran"} and (tmp_path / "elsewhere" / "radar" / "000000.npz").is_file()
    assert not (root / "prepared").exists()
    with pytest.raises(ValueError, match="unknown stage"):
        run_prepare(root, only=("nope",), progress=False)
    assert main(["prepare", str(tmp_path / "missing"), "--quiet"]) == 1
    assert "missing" in capsys.readouterr().err
