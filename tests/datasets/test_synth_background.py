"""The generator's render of a scene without its moving objects (issue 24's ground truth for the static
layer under removed actors)."""

from __future__ import annotations

import json

import numpy as np

from radar4dgs.cli import main
from radar4dgs.datasets.synth.background import background_frame, render_background, scene_config


def test_background_differs_from_the_frame_exactly_where_movers_were(motion_scene):
    config = scene_config(motion_scene.root)
    for index in (0, len(motion_scene) - 1):
        background = render_background(config, index)
        moving = motion_scene.load_optional("gt/dynamic_mask", index) > 0
        changed = np.any(background != motion_scene.load_image(index), axis=-1)
        # Same camera-noise stream: every pixel no mover covers is the recorded pixel, bit for bit.
        assert moving.any() and np.array_equal(changed, moving)


def test_background_depth_lies_behind_the_movers_and_equals_the_frame_elsewhere(motion_scene):
    config = scene_config(motion_scene.root)
    index = len(motion_scene) // 2
    frame = background_frame(config, index)
    depth = motion_scene.load_optional("gt/depth", index)
    moving = motion_scene.load_optional("gt/dynamic_mask", index) > 0
    finite = np.isfinite(frame.depth) & np.isfinite(depth)
    # What a mover hid is farther than the mover; where nothing moved the surface is the same one.
    assert moving.any() and (frame.depth[moving & finite] > depth[moving & finite]).all()
    assert np.allclose(frame.depth[~moving & finite], depth[~moving & finite], rtol=1e-4)
    assert np.array_equal(frame.image, render_background(config, index))


def test_synth_background_flag_writes_every_frame(tmp_path, capsys):
    out = tmp_path / "scene"
    assert main(["synth", str(out), "--preset", "tiny", "--seed", "3", "--scene.num-frames", "2",
                 "--background"]) == 0
    assert sorted(p.name for p in (out / "gt" / "background").iterdir()) == ["000000.png", "000001.png"]
    assert "without its moving objects" in capsys.readouterr().out


def test_scene_without_movers_is_the_background_render_with_no_moving_returns(motion_scene, tmp_path):
    from dataclasses import replace

    from radar4dgs.datasets.synth import synthesize
    from radar4dgs.datasets.synth.radar import MOVING
    from radar4dgs.io.scene import read_scene

    config = scene_config(motion_scene.root)
    twin = read_scene(synthesize(replace(config, without_movers=True), tmp_path / "twin", progress=False))
    assert (motion_scene.load_optional("gt/dynamic_mask", 0) > 0).any()
    for index in (0, len(twin) - 1):
        # The twin's frames are the scene's background renders, bit for bit, and nothing in them moves.
        assert np.array_equal(twin.load_image(index), render_background(config, index))
        assert not (twin.load_optional("gt/dynamic_mask", index) > 0).any()
        assert not (twin.load_optional("gt/radar_labels", index) == MOVING).any()
        assert (motion_scene.load_optional("gt/radar_labels", index) == MOVING).any()
    assert scene_config(twin.root).without_movers
    # Scenes with their movers keep the scene.json they had before the option existed.
    assert "without_movers" not in json.loads((motion_scene.root / "scene.json").read_text())["synthetic"]["config"]
    assert np.allclose(twin.world_to_camera(7), motion_scene.world_to_camera(7))
