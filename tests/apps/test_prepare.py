"""`radar4dgs prepare` across stages: radar, depth and masks on a synthetic scene, caching between
runs, and a clear error when a scene has no depth source."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from radar4dgs.cli import main
from radar4dgs.config import preset
from radar4dgs.datasets.synth import SynthConfig, synthesize
from radar4dgs.io.scene import read_scene

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "radar"))
from _radar_helpers import write_tiny_scene  # noqa: E402


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory) -> Path:
    config = preset(SynthConfig, "tiny", seed=7, num_frames=6)
    return synthesize(config, tmp_path_factory.mktemp("prepare") / "scene", progress=False)


def test_prepare_runs_radar_then_depth_and_frontend_eval_scores_both(tiny_scene, tmp_path, capsys):
    assert main(["prepare", str(tiny_scene), "--preset", "tiny", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "radar: ran" in out and "depth: ran" in out and "masks: ran" in out
    scene = read_scene(tiny_scene)
    depth = np.load(tiny_scene / "prepared" / "depth" / f"{scene.frames[0].name}.npy")
    truth = scene.load_optional("gt/depth", 0)
    valid = np.isfinite(depth) & np.isfinite(truth)
    assert np.median(np.abs(depth[valid] / truth[valid] - 1)) < 0.05
    assert main(["frontend-eval", str(tiny_scene), "--json", str(tmp_path / "fe.json")]) == 0
    out = capsys.readouterr().out
    assert "radar.dynamic_recall" in out and "depth.depth_absrel" in out and "masks.mask_iou" in out
    assert main(["prepare", str(tiny_scene), "--preset", "tiny", "--quiet"]) == 0
    assert "radar: skipped" in capsys.readouterr().out
    # A changed depth config reruns depth and the masks that read it, not the radar before it.
    assert main(["prepare", str(tiny_scene), "--preset", "tiny", "--quiet",
                 "--config.depth.scale-method", "paper"]) == 0
    out = capsys.readouterr().out
    assert "radar: skipped" in out and "depth: ran" in out and "masks: ran" in out


def test_scene_without_a_depth_source_fails_clearly(tmp_path, capsys):
    root = write_tiny_scene(tmp_path / "scene", frames=3)
    assert main(["prepare", str(root), "--quiet", "--config.depth.source", "depth-anything-v2",
                 "--config.depth.model", str(tmp_path / "no-such-model")]) == 1
    err = capsys.readouterr().err
    assert "no-such-model does not exist" in err and "priors/mono_depth" in err


def test_a_stage_alone_refuses_earlier_stages_of_another_config(tmp_path, capsys):
    root = write_tiny_scene(tmp_path / "scene", frames=3)
    assert main(["prepare", str(root), "--preset", "tiny", "--only", "radar", "--quiet"]) == 0
    capsys.readouterr()
    # depth alone, asked with another radar config than the radar stage was made with: refused in
    # one line naming the stage and what differs, before anything runs.
    assert main(["prepare", str(root), "--preset", "tiny", "--only", "depth", "--quiet",
                 "--config.radar.max-iterations", "7"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{root / 'prepared' / 'radar'}: prepared with another config" in err
    assert "max_iterations: 200 != 7" in err and "add radar to --only" in err
    assert not (root / "prepared" / "depth").exists()


def test_a_stage_redone_alone_makes_the_later_stages_stale(tmp_path, capsys):
    from radar4dgs.apps.train import check_prepared_scene

    root = write_tiny_scene(tmp_path / "scene", frames=3)
    prepared = root / "prepared"
    assert main(["prepare", str(root), "--preset", "tiny", "--quiet"]) == 0
    check_prepared_scene(root, prepared)
    capsys.readouterr()
    # The radar redone alone with another config: the depth, masks and flow on disk were made from the old
    # radar outputs, and their own configs did not change.
    other = ["--config.radar.max-iterations", "7"]
    assert main(["prepare", str(root), "--preset", "tiny", "--only", "radar", "--quiet", *other]) == 0
    capsys.readouterr()
    with pytest.raises(ValueError, match="prepared/depth: made from radar outputs that were redone since"):
        check_prepared_scene(root, prepared)
    # A later stage alone refuses, naming the stale one before it; so does one after a stage redone in the same call.
    for only in (["flow"], ["radar", "flow"]):
        assert main(["prepare", str(root), "--preset", "tiny", "--only", *only, "--quiet", *other]) == 1
        err = capsys.readouterr().err
        assert "depth: made from radar outputs that were redone since" in err and "add depth to --only" in err
    assert main(["prepare", str(root), "--preset", "tiny", "--quiet", *other]) == 0
    out = capsys.readouterr().out
    assert "radar: skipped" in out and "depth: ran" in out and "flow: ran" in out
    check_prepared_scene(root, prepared)
    # Redone with the same config, the radar's outputs and stamp are the same: nothing after it is stale.
    assert main(["prepare", str(root), "--preset", "tiny", "--only", "radar", "--force", "--quiet", *other]) == 0
    assert main(["prepare", str(root), "--preset", "tiny", "--quiet", *other]) == 0
    assert "depth: skipped" in capsys.readouterr().out.split("radar: ran")[-1]
