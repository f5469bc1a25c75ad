"""`radar4dgs view RUN`: camera conversions, the missing-viser message, and a server start/stop on
a free port (skipped where viser is not installed)."""

from __future__ import annotations

import importlib.util
import math
import socket
import sys
import urllib.error
import urllib.request

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from radar4dgs.apps.viewer import (
    DISPLAY_RENDER,
    DISPLAY_SPLATS,
    ViewerUnavailable,
    camera_to_viser,
    pinhole_intrinsics,
    require_viser,
    splat_covariances,
    viser_to_world_to_camera,
)
from radar4dgs.cli import main
from radar4dgs.evaluate.reconstruction import load_run, to_uint8
from radar4dgs.io.scene import normalized_times
from radar4dgs.model.view import frame_view

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_camera_conversions_round_trip_and_match_opencv_axes():
    rng = np.random.default_rng(0)
    for _ in range(5):
        w2c = np.eye(4)
        w2c[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        w2c[:3, 3] = rng.normal(0, 5, 3)
        wxyz, position = camera_to_viser(w2c)
        np.testing.assert_allclose(viser_to_world_to_camera(wxyz, position), w2c, atol=1e-12)
        # The camera centre maps to the camera origin; viser's +z (look direction) is OpenCV's.
        np.testing.assert_allclose((w2c @ np.r_[position, 1.0])[:3], 0.0, atol=1e-9)
        forward = Rotation.from_quat(np.r_[wxyz[1:], wxyz[0]]).as_matrix()[:, 2]
        np.testing.assert_allclose(forward, w2c[2, :3], atol=1e-12)
    K = pinhole_intrinsics(2 * math.atan(0.5), 160, 90)
    np.testing.assert_allclose(K, [[90.0, 0, 79.5], [0, 90.0, 44.5], [0, 0, 1]])


def test_splat_covariances_are_r_s2_rt():
    quats = torch.nn.functional.normalize(torch.randn(6, 4, generator=torch.Generator().manual_seed(1)), dim=1)
    scales = torch.rand(6, 3, generator=torch.Generator().manual_seed(2)) + 0.1
    cov = splat_covariances(quats, scales)
    for i in range(6):
        w, x, y, z = quats[i].double().tolist()
        R = Rotation.from_quat([x, y, z, w]).as_matrix()
        np.testing.assert_allclose(cov[i], R @ np.diag(scales[i].double().numpy() ** 2) @ R.T, rtol=1e-5, atol=1e-7)


def test_missing_viser_names_the_extra(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "viser", None)  # makes `import viser` raise ImportError
    with pytest.raises(ViewerUnavailable, match=r"pip install 'radar4dgs\[viewer\]'"):
        require_viser()
    assert main(["view", str(tmp_path)]) == 1
    assert "pip install 'radar4dgs[viewer]'" in capsys.readouterr().err


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _FakeClient:
    """Stands in for a connected browser: a camera and a scene that records background images."""

    class _Scene:
        def __init__(self):
            self.images = []

        def set_background_image(self, image, format="auto", jpeg_quality=None):
            self.images.append(image)

    class _Camera:
        pass

    def __init__(self, wxyz, position, fov, aspect):
        self.client_id = -1
        self.camera = self._Camera()
        self.camera.wxyz, self.camera.position, self.camera.fov, self.camera.aspect = wxyz, position, fov, aspect
        self.scene = self._Scene()


# A mark rather than importorskip in the body: the trained-run fixture is not built for nothing.
@pytest.mark.skipif(importlib.util.find_spec("viser") is None, reason="viser is not installed (extra 'viewer')")
def test_viewer_starts_serves_moves_dynamics_renders_and_stops(trained):
    from radar4dgs.apps.viewer import Viewer

    run = load_run(trained)
    scene = run.scene
    viewer = Viewer(run, host="127.0.0.1", port=_free_port(), render_height=scene.camera.height, verbose=False)
    port = viewer.port
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=20) as response:
            assert response.status == 200 and b"<html" in response.read().lower()
        assert len(viewer.frustums) == len(scene)
        np.testing.assert_array_equal(viewer.static_splats.centers, run.model.static.params["means"].detach().numpy())

        viewer.time_slider.value = 0.5  # the GUI callback moves the dynamic splats with the field
        assert viewer.time == 0.5
        with torch.no_grad():
            expected = run.model.field(run.model.dynamic.params["means"], 0.5).numpy()
        np.testing.assert_allclose(viewer.dynamic_splats.centers, expected, atol=1e-6)
        assert np.abs(viewer.dynamic_splats.centers - run.model.dynamic.params["means"].detach().numpy()).max() > 1e-4

        # The CPU render of a recorded camera is the model's render of that frame (up to the
        # focal length's trip through the field of view).
        index = 6
        viewer.set_time(float(normalized_times(scene)[index]))
        fov = 2 * math.atan(0.5 * scene.camera.height / scene.camera.K[1, 1])
        client = _FakeClient(*camera_to_viser(scene.world_to_camera(index)), fov,
                             scene.camera.width / scene.camera.height)
        viewer.display.value = DISPLAY_RENDER
        assert not viewer.static_splats.visible
        viewer._render_to(client)
        with torch.no_grad():
            reference = to_uint8(run.model.render(frame_view(scene, index, 1.0, normalized_times(scene)),
                                                  run.config.raster)["rgb"])
        image = client.scene.images[-1]
        assert image.shape == reference.shape
        assert np.abs(image.astype(int) - reference.astype(int)).max() <= 1
        viewer.display.value = DISPLAY_SPLATS
        assert viewer.static_splats.visible
    finally:
        viewer.stop()
    with pytest.raises((urllib.error.URLError, ConnectionError, OSError)):
        urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=5)
