"""`radar4dgs demo` on the tiny preset: every built stage runs and its numbers meet the ground truth."""

from __future__ import annotations

import json

from radar4dgs.cli import main


def test_demo_tiny(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--preset", "tiny", "--seed", "2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "PSNR*" in printed
    assert (out / "inspect.png").stat().st_size > 10_000
    report = json.loads((out / "frontend_metrics.json").read_text())
    assert report["radar"]["ego_velocity_rmse"] < 0.1
    assert report["radar"]["dynamic_recall"] > 0.9
    assert report["depth"]["depth_absrel"] < 0.08
    assert report["masks"]["mask_iou"] > 0.5
    metrics = json.loads((out / "run" / "metrics.json").read_text())
    assert metrics["recon"]["n_frames"] + metrics["nvs"]["n_frames"] == 20
    assert metrics["recon"]["psnr"] > 20 and metrics["nvs"]["psnr"] > 18
    assert metrics["mask_source"] == "gt"
    assert (out / "run" / "video.mp4").stat().st_size > 10_000
    assert (out / "run" / "report.html").is_file()
    # A second run reuses the scene and the prepared stages.
    assert main(["demo", "--preset", "tiny", "--seed", "2", "--out", str(out)]) == 0
    again = capsys.readouterr().out
    assert "radar: skipped, depth: skipped, masks: skipped, flow: skipped" in again
    assert "reusing the finished run" in again
