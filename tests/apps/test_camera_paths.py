"""`radar4dgs render RUN --trajectory nerfstudio:camera_path.json`: one image per camera, and a path
made of the scene's own cameras reproduces the eval render of each frame."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from radar4dgs.apps.camera_paths import camera_path_views, nerfstudio_intrinsics, read_camera_path, write_camera_path
from radar4dgs.apps.render import render_trajectory
from radar4dgs.cli import main
from radar4dgs.evaluate.reconstruction import render_view, to_uint8
from radar4dgs.io.scene import normalized_times
from radar4dgs.model.run import load_run
from radar4dgs.model.view import frame_view

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def run(tiny_trained_run):
    return load_run(tiny_trained_run / "run")


def scene_path(run, path, indices, scale: float = 1.0):
    """A nerfstudio camera path through the scene's recorded cameras ``indices``."""
    camera = run.scene.camera
    fov = math.degrees(2 * math.atan(0.5 * camera.height / camera.K[1, 1]))
    times = normalized_times(run.scene)
    return write_camera_path(path, [run.scene.world_to_camera(i) for i in indices], [fov] * len(indices),
                             [times[i] for i in indices], round(camera.width * scale), round(camera.height * scale))


def test_scene_cameras_as_a_nerfstudio_path_give_back_the_scene_views(run, tmp_path):
    indices = list(range(len(run.scene)))
    views = camera_path_views(scene_path(run, tmp_path / "path.json", indices), run.scene.camera)
    times = normalized_times(run.scene)
    for i, view in zip(indices, views, strict=True):
        expected = frame_view(run.scene, i, 1.0, times)
        np.testing.assert_allclose(view.world_to_camera, expected.world_to_camera, atol=1e-9)
        np.testing.assert_allclose(view.K, expected.K, atol=1e-9)  # the synthetic K is centred, square
        assert (view.width, view.height, view.time) == (expected.width, expected.height, pytest.approx(expected.time))


def test_render_writes_one_image_per_camera_and_reproduces_the_frame(run, tmp_path, capsys):
    frame = run.scene.train_indices[1]
    path = scene_path(run, tmp_path / "orbit.json", [frame, frame, 0])
    assert main(["render", str(run.root), "--trajectory", f"nerfstudio:{path}", "--out", str(tmp_path / "out"),
                 "--no-video", "--quiet", "--threads", "1"]) == 0
    assert "rendered 3 views (160x90)" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "out").glob("?????.png")) == ["00000.png", "00001.png", "00002.png"]
    from PIL import Image

    with Image.open(tmp_path / "out" / "00000.png") as image:
        rendered = np.asarray(image.convert("RGB"))
    with torch.no_grad():
        expected = to_uint8(render_view(run, frame_view(run.scene, frame, 1.0, normalized_times(run.scene)))["rgb"])
    # The same camera up to float rounding of fov -> focal: at most one grey level anywhere.
    assert np.abs(rendered.astype(int) - expected.astype(int)).max() <= 1
    assert (rendered == expected).mean() > 0.99


def test_render_size_scale_time_and_bad_files(run, tmp_path):
    path = scene_path(run, tmp_path / "half.json", [0, 3], scale=0.5)
    result = render_trajectory(run, f"nerfstudio:{path}", video=False, progress=False, out=tmp_path / "r", scale=2.0)
    assert (result.width, result.height, result.poses, result.slug) == (160, 90, 2, "nerfstudio_half_s2")
    data = json.loads(path.read_text())
    del data["render_width"], data["render_height"]
    for camera in data["camera_path"]:
        camera["fov"] = 60.0
    path.write_text(json.dumps(data))
    views = camera_path_views(path, run.scene.camera, 0.5)
    assert (views[0].width, views[0].height) == (80, 45)  # the scene camera's size when the file has none
    np.testing.assert_allclose(views[0].K, nerfstudio_intrinsics(60.0, 80, 45))
    assert views[1].time == pytest.approx(normalized_times(run.scene)[3])

    data["camera_path"][1]["camera_to_world"] = [1.0] * 16
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match="camera 1: 'camera_to_world' is not a rigid transform"):
        read_camera_path(path)
    with pytest.raises(ValueError, match="nerfstudio camera path file not found"):
        render_trajectory(run, "nerfstudio:/nonexistent/path.json", progress=False)
    with pytest.raises(ValueError, match="--interpolate applies to the recorded-camera specs"):
        render_trajectory(run, f"nerfstudio:{path}", interpolate=2, progress=False)
