"""`radar4dgs demo` on the tiny preset: every built stage runs and its numbers meet the ground truth;
a demo folder is reused only for the same request, never reported under another's name."""

from __future__ import annotations

import json

from radar4dgs.cli import main


def test_demo_tiny(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--preset", "tiny", "--seed", "2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "PSNR*" in printed
    # The config it runs with is printed first; its train hash is the one the run records.
    config_line = printed.splitlines()[1]
    assert config_line.startswith("    config: scene 160x90, 20 frames (synth config ")
    assert "train method ours" in config_line and "mask source predicted" in config_line
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
    assert "radar: skipped, depth: skipped, masks: skipped, object_depth: skipped, flow: skipped" in again
    assert "reusing the finished run" in again

    # What made it is recorded, and shown.
    assert json.loads((out / "demo.json").read_text())["preset"] == "tiny"
    provenance = json.loads((out / "run" / "provenance.json").read_text())
    assert provenance["preset"] == "tiny" and provenance["method"] == "ours"
    assert metrics["run"]["preset"] == "tiny" and metrics["run"]["config_hash"]
    assert f"(config hash {metrics['run']['config_hash']})" in config_line
    assert "<td>preset</td><td>tiny</td>" in (out / "run" / "report.html").read_text()
    assert "preset 'tiny', seed 2" in again

    # Another seed, or another preset, into the same folder: refused in one line saying what
    # differs, before any step, so no number of seed 2 is printed under seed 3's name.
    assert main(["demo", "--preset", "tiny", "--seed", "3", "--out", str(out)]) == 1
    refused = capsys.readouterr()
    assert refused.err.count("\n") == 1
    assert "preset 'tiny', seed 2, not preset 'tiny', seed 3" in refused.err and "pass --force" in refused.err
    assert "PSNR" not in refused.out and "[1]" not in refused.out
    assert main(["demo", "--preset", "small", "--seed", "2", "--out", str(out)]) == 1
    assert "not preset 'small', seed 2" in capsys.readouterr().err
    # A folder from before demo.json existed: the scene itself says what made it.
    (out / "demo.json").unlink()
    assert main(["demo", "--preset", "small", "--seed", "2", "--out", str(out)]) == 1
    assert "scene was made with preset 'tiny', seed 2, not preset 'small', seed 2" in capsys.readouterr().err
    # A run trained with another config than the preset's is not reused either.
    config = json.loads((out / "run" / "config.json").read_text())
    config["config"]["optim"]["iterations"] += 1
    (out / "run" / "config.json").write_text(json.dumps(config))
    assert main(["demo", "--preset", "tiny", "--seed", "2", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "run/config.json: the run was trained with another config (optim.iterations" in err


class _Stop(Exception):
    pass


def test_demo_force_removes_only_what_the_demo_wrote(tmp_path, monkeypatch):
    """--force clears the demo's own outputs before the first step (a full rerun is the test
    above's first half), and leaves anything else in the folder alone."""
    from radar4dgs.apps.demo import DEMO_OUTPUTS, DemoCommand

    out = tmp_path / "demo"
    for name in DEMO_OUTPUTS:
        (out / name).mkdir(parents=True) if "." not in name else (out / name).write_text("{}")
    (out / "run" / "model.pt").write_text("old")
    (out / "notes.txt").write_text("mine")

    def stop(self, config, scene_dir):
        raise _Stop

    monkeypatch.setattr(DemoCommand, "synthesise", stop)
    try:
        main(["demo", "--preset", "tiny", "--seed", "2", "--out", str(out), "--force", "--debug"])
    except _Stop:
        pass
    assert not any((out / name).exists() for name in DEMO_OUTPUTS)
    assert (out / "notes.txt").read_text() == "mine"
