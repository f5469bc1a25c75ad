import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "radar"))
from _radar_helpers import write_tiny_scene  # noqa: E402

from radar4dgs.apps.prepare import run_prepare  # noqa: E402
from radar4dgs.cli import main  # noqa: E402
from radar4dgs.evaluate.frontend import SECTIONS, evaluate_frontend, evaluate_radar  # noqa: E402
from radar4dgs.io.scene import read_scene  # noqa: E402


def test_metrics_on_a_scene_with_gt(tmp_path):
    root = write_tiny_scene(tmp_path / "scene", frames=4, yaw_rate=0.2)
    run_prepare(root, only=("radar",), progress=False)
    report = evaluate_radar(read_scene(root), root / "prepared")
    assert report["ego_velocity_rmse"] < 0.05
    assert report["ego_velocity_truth"] == "ego_velocity + pose yaw rate"
    assert report["dynamic_precision"] > 0.95 and report["dynamic_recall"] > 0.9
    assert report["static_residual_median"] < 0.1
    assert report["notes"] == []


def test_scene_without_gt_reports_nulls(tmp_path):
    root = write_tiny_scene(tmp_path / "scene", frames=3, labels=False, ego_velocity=False, poses=False)
    run_prepare(root, only=("radar",), progress=False)
    report = evaluate_radar(read_scene(root), root / "prepared")
    assert report["ego_velocity_rmse"] is None
    assert report["dynamic_precision"] is None and report["dynamic_recall"] is None
    assert report["static_residual_median"] is not None and report["static_points"] == "RANSAC inliers"
    assert len(report["notes"]) == 2


def test_command_writes_json_and_sections(tmp_path):
    root = write_tiny_scene(tmp_path / "scene", frames=3)
    out = tmp_path / "eval.json"
    assert main(["frontend-eval", str(root), "--json", str(out)]) == 1  # not prepared yet
    run_prepare(root, tmp_path / "prep", only=("radar",), progress=False)
    assert main(["frontend-eval", str(root), "--json", str(out), "--prepared", str(tmp_path / "prep")]) == 0
    report = json.loads(out.read_text())
    assert set(report["radar"]) >= {"ego_velocity_rmse", "dynamic_precision", "dynamic_recall",
                                     "static_residual_median"}
    assert "radar" in SECTIONS


def test_stale_outputs_are_refused(tmp_path):
    root = write_tiny_scene(tmp_path / "scene", frames=2)
    run_prepare(root, only=("radar",), progress=False)
    path = root / "radar" / "000000.npy"
    np.save(path, np.load(path)[:-3])
    with pytest.raises(Exception, match="stale"):
        evaluate_frontend(read_scene(root), root / "prepared")
