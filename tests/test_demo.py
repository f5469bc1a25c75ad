"""`radar4dgs demo` on the tiny preset: every built stage runs and its numbers meet the ground truth."""

from __future__ import annotations

import json

from radar4dgs.cli import main


def test_demo_tiny(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--preset", "tiny", "--seed", "2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "Not built yet" in printed
    assert (out / "inspect.png").stat().st_size > 10_000
    report = json.loads((out / "frontend_metrics.json").read_text())
    assert report["radar"]["ego_velocity_rmse"] < 0.1
    assert report["radar"]["dynamic_recall"] > 0.9
    assert report["depth"]["depth_absrel"] < 0.08
    assert report["masks"]["mask_iou"] > 0.5
    motion = json.loads((out / "motion" / "results.json").read_text())
    assert motion["sceneflow"]["epe"] < motion["sceneflow"]["zero_motion_epe"]
    # A second run reuses the scene and the prepared stages.
    assert main(["demo", "--preset", "tiny", "--seed", "2", "--out", str(out)]) == 0
    assert "radar: skipped, depth: skipped, masks: skipped, flow: skipped" in capsys.readouterr().out
