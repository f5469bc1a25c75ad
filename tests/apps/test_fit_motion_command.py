"""``radar4dgs fit-motion``: the command on a tiny prepared scene, and its options through the CLI."""

from __future__ import annotations

import json

import pytest

from radar4dgs import cli
from radar4dgs.apps.fit_motion import FitMotionCommand
from radar4dgs.config import preset
from radar4dgs.train.config import MotionConfig

# Tiny tensors: on the shared 2-core CI machine extra torch threads only spin.
pytestmark = pytest.mark.usefixtures("one_torch_thread")

ORACLE = {"depth_source": "oracle", "mask_source": "oracle"}  # gt depth and masks: the tests isolate one stage


def test_fit_motion_command(motion_scene, motion_prepared, tmp_path, capsys):
    config = preset(MotionConfig, "tiny", flow=ORACLE, fit={"radar_source": "oracle", "iterations": 20})
    out = tmp_path / "motion"
    command = FitMotionCommand(scene=motion_scene.root, prepared=motion_prepared, out=out, use_radar=False,
                               preset="tiny", config=config, quiet=True)
    assert command.run() == 0
    result = json.loads((out / "results.json").read_text())
    assert result["use_flow"] and not result["use_radar"] and result["sceneflow"]["epe"] is not None
    assert (out / "field.pt").is_file() and (out / "config.json").is_file()
    # Per moving object too: the points of the objects add up to every scored moving pixel.
    objects = result["sceneflow_by_object"]["objects"]
    assert len(objects) == 2 and result["sceneflow_by_object"]["unassigned_points"] == 0
    assert sum(o["points"] for o in objects) == result["sceneflow"]["points"]
    weighted = sum(o["epe"] * o["points"] for o in objects) / result["sceneflow"]["points"]
    assert weighted == pytest.approx(result["sceneflow"]["epe"], rel=1e-4)
    printed = capsys.readouterr().out
    assert "scene-flow EPE" in printed and printed.count("field error") == 2
    missing = FitMotionCommand(scene=motion_scene.root, prepared=tmp_path / "nothing", preset="tiny",
                               config=preset(MotionConfig, "tiny"), quiet=True)
    with pytest.raises((FileNotFoundError, ValueError), match="depth_source='oracle'"):
        missing.run()  # a user error: radar4dgs.cli prints it as one line


def test_command_parses_through_the_cli():
    command = cli.build_command("fit-motion", ["/data/scene", "--no-use-radar", "--preset", "tiny",
                                               "--config.fit.iterations", "5", "--prepared", "/p"])
    assert str(command.scene) == "/data/scene" and str(command.prepared) == "/p"
    assert command.use_flow and not command.use_radar
    assert command.config.fit.iterations == 5
    assert command.config.field.num_layers == 3  # from the tiny preset
