"""`radar4dgs render RUN --trajectory ...` on one tiny trained run: pixels against eval and direct
renders, frame counts, bullet time, scale, custom paths, bad inputs."""

from __future__ import annotations

import json
from dataclasses import replace

import imageio.v2 as imageio
import numpy as np
import pytest
import torch
from PIL import Image

from radar4dgs.apps.render import NonFiniteRenderError, render_trajectory, trajectory_slug
from radar4dgs.apps.trajectory import CameraPose, parse_trajectory, write_custom_trajectory
from radar4dgs.cli import main
from radar4dgs.evaluate.reconstruction import evaluate_run, load_run, to_uint8
from radar4dgs.io.scene import normalized_times
from radar4dgs.model.view import frame_view

N_FRAMES = 8  # frames of the shared tiny run (tests/conftest.py)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def trained(tiny_trained_run):
    """The shared tiny run, evaluated (eval's PNGs are the reference of the recorded path)."""
    evaluate_run(tiny_trained_run / "run", lpips=False, video=False, report=False, progress=False)
    return tiny_trained_run / "run"


@pytest.fixture(scope="module")
def run(trained):
    return load_run(trained)


def png(path) -> np.ndarray:
    with Image.open(path) as image:
        return np.asarray(image.convert("RGB"))


@torch.no_grad()
def direct(run, index: int, time: float, scale: float = 1.0) -> dict:
    """The model's render of recorded camera ``index`` at ``time`` (bypassing the command)."""
    view = replace(frame_view(run.scene, index, scale, normalized_times(run.scene)), time=time)
    out = run.model.render(view, run.config.raster)
    return {"rgb": to_uint8(out["rgb"]), "dynamic": out["dynamic"].cpu().numpy() > 0.5}


def test_recorded_path_reproduces_eval_renders_pixel_for_pixel(trained, run):
    result = render_trajectory(run, "recorded", video=False, progress=False)
    assert result.frames == trained / "renders" / "recorded" and result.poses == N_FRAMES
    assert result.video is None and not (trained / "recorded.mp4").exists()
    test = set(run.scene.test_indices)
    for i in range(N_FRAMES):
        split = "nvs" if i in test else "recon"
        np.testing.assert_array_equal(png(result.frames / f"{i:05d}.png"),
                                      png(trained / "renders" / split / f"{run.scene.frames[i].name}.png"))
    poses = json.loads((result.frames / "trajectory.json").read_text())
    times = normalized_times(run.scene)
    assert [p["time"] for p in poses] == pytest.approx(times.tolist(), abs=0)
    np.testing.assert_array_equal(np.array(poses[3]["world_to_camera"]), run.scene.world_to_camera(3))


def test_lane_shift_cli_writes_every_view_differs_from_recorded_and_makes_a_video(trained, capsys):
    assert main(["render", str(trained), "--trajectory", "lane-shift:2", "--interpolate", "2", "--with-depth",
                 "--quiet", "--threads", "1"]) == 0
    assert "rendered 15 views (160x90)" in capsys.readouterr().out
    frames = trained / "renders" / "lane-shift_2_x2"
    expected = (N_FRAMES - 1) * 2 + 1
    for suffix in ("", "_depth", "_dynamic"):
        assert len(list(frames.glob(f"?????{suffix}.png"))) == expected
    recorded = render_trajectory(trained, "recorded", video=False, progress=False, out=trained / "rec_ref")
    for i in range(N_FRAMES):
        shifted = png(frames / f"{2 * i:05d}.png")
        assert shifted.shape == (90, 160, 3)
        # 2 m sideways moves every near surface by many pixels: most of the image changes.
        assert (shifted != png(recorded.frames / f"{i:05d}.png")).any(axis=2).mean() > 0.2
    reader = imageio.get_reader(trained / "lane-shift_2_x2.mp4")
    try:
        video = [frame for frame in reader]
    finally:
        reader.close()
    assert len(video) == expected and video[0].shape == (90, 3 * 160, 3)  # rgb | depth | dynamic


def test_stop_time_freezes_the_dynamic_objects_while_the_camera_moves(trained, run):
    frozen = render_trajectory(run, "stop-time:0", with_depth=True, video=False, progress=False)
    recorded = trained / "renders" / "recorded"
    if not recorded.is_dir():
        recorded = render_trajectory(run, "recorded", video=False, progress=False).frames
    times = json.loads((frozen.frames / "trajectory.json").read_text())
    assert [p["time"] for p in times] == [0.0] * N_FRAMES
    for i in range(N_FRAMES):
        reference = direct(run, i, 0.0)
        np.testing.assert_array_equal(png(frozen.frames / f"{i:05d}.png"), reference["rgb"])
        np.testing.assert_array_equal(png(frozen.frames / f"{i:05d}_dynamic.png")[..., 0] > 127,
                                      reference["dynamic"])
    # The last camera at time 0 is not the last recorded frame (time 1): the objects stayed behind.
    assert (png(frozen.frames / f"{N_FRAMES - 1:05d}.png") != png(recorded / f"{N_FRAMES - 1:05d}.png")).any()
    # An integer freezes at that frame's time: its own view matches the recorded one, others not.
    at_5 = render_trajectory(run, "stop-time:5", video=False, progress=False)
    np.testing.assert_array_equal(png(at_5.frames / "00005.png"), png(recorded / "00005.png"))
    assert (png(at_5.frames / "00000.png") != png(recorded / "00000.png")).any()


def test_scale_renders_the_trainers_reduced_view(trained, run):
    result = render_trajectory(run, "recorded", scale=0.5, video=False, progress=False)
    assert result.frames.name == "recorded_s0.5" and (result.width, result.height) == (80, 45)
    for i in (0, 6):
        np.testing.assert_array_equal(png(result.frames / f"{i:05d}.png"),
                                      direct(run, i, float(normalized_times(run.scene)[i]), 0.5)["rgb"])


def test_custom_path_into_out_folder_and_unrelated_folders_are_protected(trained, run, tmp_path):
    w2c = run.scene.world_to_camera(2)
    path = write_custom_trajectory(tmp_path / "loop.json", [CameraPose(w2c, 0.0), CameraPose(w2c, 1.0)])
    out = tmp_path / "views"
    result = render_trajectory(run, f"custom:{path}", out=out, fps=5, progress=False)
    assert result.slug == "custom_loop" and result.video == out / "custom_loop.mp4"
    assert sorted(p.name for p in out.iterdir()) == ["00000.png", "00001.png", "custom_loop.mp4", "trajectory.json"]
    np.testing.assert_array_equal(png(out / "00000.png"), direct(run, 2, 0.0)["rgb"])
    again = render_trajectory(run, f"custom:{path}", out=out, video=False, progress=False)  # replaces its own
    assert not (again.frames / "custom_loop.mp4").exists()

    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "notes.txt").write_text("keep")
    with pytest.raises(ValueError, match="not an earlier `radar4dgs render` output"):
        render_trajectory(run, "recorded", out=precious, progress=False)
    assert (precious / "notes.txt").read_text() == "keep"


def test_slugs_are_file_names():
    assert trajectory_slug(parse_trajectory("lane-shift:-1.5")) == "lane-shift_-1.5"
    assert trajectory_slug(parse_trajectory("Stop-Time:0.25"), interpolate=4) == "stop-time_0.25_x4"
    assert trajectory_slug(parse_trajectory("height:2"), scale=0.25) == "height_2_s0.25"


def test_bad_inputs_give_clear_errors(trained, run, tmp_path, capsys):
    assert main(["render", str(trained), "--trajectory", "fly:3", "--quiet"]) == 1
    assert "unknown trajectory spec 'fly:3'" in capsys.readouterr().err
    assert main(["render", str(trained), "--trajectory", "stop-time:99", "--quiet"]) == 1
    assert "frame index 99 out of range for 8 frames" in capsys.readouterr().err
    with pytest.raises(ValueError, match="--scale must lie in"):
        render_trajectory(run, "recorded", scale=0.0, progress=False)
    with pytest.raises(ValueError, match="--interpolate must be an integer >= 1"):
        render_trajectory(run, "recorded", interpolate=0, progress=False)

    empty = tmp_path / "not_a_run"
    empty.mkdir()
    for name in ("run.json", "config.json"):
        (empty / name).write_text((trained / name).read_text())
    assert main(["render", str(empty), "--quiet"]) == 1
    assert "model.pt: missing" in capsys.readouterr().err

    broken = load_run(trained)
    with torch.no_grad():
        broken.model.sky.logits.fill_(float("nan"))  # every sky pixel becomes NaN
    with pytest.raises(NonFiniteRenderError, match=r"view 0 of trajectory 'recorded' .*non-finite pixel"):
        render_trajectory(broken, "recorded", out=tmp_path / "nan", progress=False)
    assert not (tmp_path / "nan").exists() and not list(tmp_path.glob(".nan*"))
