"""``radar4dgs view RUN``: browse a trained run in a web browser (optional; needs ``viser``).

The scene is sent to the browser as Gaussian splats (viser's WebGL splat renderer: fast, but its
own blending, no sky map), with the recorded cameras as frustums. A time slider moves the dynamic
Gaussians with the deformation field. The display can be switched to "radar4dgs render": every
camera change of a browser is then rendered by this package's own rasterizer (the one training
and ``radar4dgs render`` use, sky included) at a reduced resolution and shown as the background,
so what is seen is exactly what the model renders.

Install the dependency with ``pip install radar4dgs[viewer]`` (or ``pip install viser``).
"""

from __future__ import annotations

import math
import sys
import threading
from typing import Any, Callable

import numpy as np
import torch
from scipy.spatial.transform import Rotation

INSTALL_HINT = "the viewer needs the optional dependency viser: pip install 'radar4dgs[viewer]' (or: pip install viser)"
DISPLAY_SPLATS = "splats (browser)"
DISPLAY_RENDER = "radar4dgs render (CPU)"
# Distance (metres) of the initial look-at point in front of the first camera: far enough that
# orbiting turns about the road ahead rather than about the camera itself.
_LOOK_DISTANCE = 10.0


class ViewerUnavailable(ImportError):
    """viser is not installed."""


def require_viser():
    """Import and return ``viser``, or raise :class:`ViewerUnavailable` telling how to install it."""
    try:
        import viser
    except ImportError as exc:
        raise ViewerUnavailable(f"{INSTALL_HINT} ({exc})") from None
    return viser


def camera_to_viser(world_to_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """viser's camera pose of ``world_to_camera`` (4, 4) (OpenCV axes, like viser's cameras):
    ``wxyz`` (4,) the camera-to-world rotation, ``position`` (3,) the camera centre."""
    w2c = np.asarray(world_to_camera, dtype=np.float64)
    R = w2c[:3, :3].T
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z]), -R @ w2c[:3, 3]


def viser_to_world_to_camera(wxyz: Any, position: Any) -> np.ndarray:
    """(4, 4) world-to-camera of a viser camera ``wxyz`` (4,) camera-to-world rotation and
    ``position`` (3,) centre."""
    w, x, y, z = np.asarray(wxyz, dtype=np.float64)
    R = Rotation.from_quat([x, y, z, w]).as_matrix()
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ np.asarray(position, dtype=np.float64)
    return out


def pinhole_intrinsics(fov_y: float, width: int, height: int) -> np.ndarray:
    """(3, 3) K of a centred pinhole camera with vertical field of view ``fov_y`` (radians), square
    pixels, in the scene's convention (pixel centres at integer coordinates: centre ``(W-1)/2``)."""
    f = 0.5 * height / math.tan(0.5 * fov_y)
    return np.array([[f, 0.0, 0.5 * (width - 1)], [0.0, f, 0.5 * (height - 1)], [0.0, 0.0, 1.0]])


def splat_covariances(quats: torch.Tensor, scales: torch.Tensor) -> np.ndarray:
    """(N, 3, 3) float32 world covariances ``R diag(s^2) R^T`` of Gaussians with unit ``quats``
    (N, 4) wxyz and ``scales`` (N, 3) (activated, metres)."""
    q = quats.detach().double().cpu().numpy()
    R = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()
    s2 = scales.detach().double().cpu().numpy() ** 2
    return np.einsum("nij,nj,nkj->nik", R, s2, R).astype(np.float32)


class _LatestOnly:
    """Run ``fn`` for the latest request only: requests arriving while it runs collapse into one
    more run, so a burst of camera messages costs one or two renders, not one each."""

    def __init__(self, fn: Callable[[], None]):
        self._fn = fn
        self._lock = threading.Lock()
        self._pending = False
        self._running = False

    def request(self) -> None:
        with self._lock:
            self._pending = True
            if self._running:
                return
            self._running = True
        while True:
            with self._lock:
                if not self._pending:
                    self._running = False
                    return
                self._pending = False
            try:
                self._fn()
            except Exception as exc:  # noqa: BLE001 - a failed render must not kill the server thread
                print(f"radar4dgs view: render failed: {exc}", file=sys.stderr)


class Viewer:
    """A running viser server showing ``run`` (a loaded
    :class:`~radar4dgs.evaluate.reconstruction.Run`); :meth:`stop` shuts it down.

    ``render_height``: pixel height of the CPU renders (the width follows the browser's aspect).
    """

    def __init__(self, run, host: str = "127.0.0.1", port: int = 8080, render_height: int = 180,
                 verbose: bool = True):
        viser = require_viser()
        from radar4dgs.apps.render import recorded_cameras

        if render_height < 8:
            raise ValueError(f"render_height must be >= 8 pixels, got {render_height}")
        self.run = run
        self.render_height = int(render_height)
        self.world_to_cameras, self.times = recorded_cameras(run.scene)
        self.time = 0.0
        self._renderers: dict[int, _LatestOnly] = {}
        self.server = viser.ViserServer(host=host, port=port, verbose=verbose)
        self.server.scene.set_up_direction("+z")  # the scene's world frame: x forward, y left, z up
        self._add_scene()
        self._add_gui()
        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(lambda client: self._renderers.pop(client.client_id, None))

    @property
    def port(self) -> int:
        return self.server.get_port()

    # ---- scene
    def _add_scene(self) -> None:
        model, scene = self.run.model, self.run.scene
        with torch.no_grad():
            static = model.static.activated()
            self.static_splats = self.server.scene.add_gaussian_splats(
                "/gaussians/static", centers=static["means"].float().cpu().numpy(),
                covariances=splat_covariances(static["quats"], static["scales"]),
                rgbs=static["colors"].float().cpu().numpy(),
                opacities=static["opacities"].float().cpu().numpy()[:, None])
            self.dynamic_splats = None
            if model.dynamic is not None and len(model.dynamic) > 0:
                dynamic = model.dynamic.activated()
                self.dynamic_splats = self.server.scene.add_gaussian_splats(
                    "/gaussians/dynamic", centers=self.dynamic_means(self.time),
                    covariances=splat_covariances(dynamic["quats"], dynamic["scales"]),
                    rgbs=dynamic["colors"].float().cpu().numpy(),
                    opacities=dynamic["opacities"].float().cpu().numpy()[:, None])
        K, H = scene.camera.K, scene.camera.height
        fov = 2.0 * math.atan(0.5 * H / K[1, 1])
        aspect = scene.camera.width / H
        self.frustums = []
        for i, w2c in enumerate(self.world_to_cameras):
            wxyz, position = camera_to_viser(w2c)
            self.frustums.append(self.server.scene.add_camera_frustum(
                f"/cameras/{i:04d}", fov=fov, aspect=aspect, scale=0.4, wxyz=wxyz, position=position,
                color=(230, 120, 20)))
        wxyz, position = camera_to_viser(self.world_to_cameras[0])
        forward = Rotation.from_quat(np.r_[wxyz[1:], wxyz[0]]).as_matrix()[:, 2]
        self.server.initial_camera.position = tuple(position)
        self.server.initial_camera.look_at = tuple(position + _LOOK_DISTANCE * forward)
        self.server.initial_camera.up = (0.0, 0.0, 1.0)
        self.server.initial_camera.fov = fov

    def dynamic_means(self, time: float) -> np.ndarray:
        """(N_dyn, 3) float32 dynamic means at normalised ``time`` (empty without dynamics)."""
        model = self.run.model
        if model.dynamic is None or len(model.dynamic) == 0:
            return np.zeros((0, 3), np.float32)
        with torch.no_grad():
            return model.gaussians_at(time, include_static=False)["means"].float().cpu().numpy()

    # ---- GUI
    def _add_gui(self) -> None:
        gui = self.server.gui
        n_dyn = 0 if self.dynamic_splats is None else len(self.run.model.dynamic)
        gui.add_markdown(f"**{self.run.root.name}**: {len(self.run.model.static)} static + {n_dyn} dynamic "
                         f"Gaussians, {len(self.times)} frames")
        self.time_slider = gui.add_slider("time", min=0.0, max=1.0, step=0.001, initial_value=0.0,
                                          hint="normalised scene time of the dynamic Gaussians")
        self.frame_slider = gui.add_slider("frame", min=0, max=max(len(self.times) - 1, 1), step=1,
                                           initial_value=0, hint="jump to a recorded frame's time",
                                           disabled=len(self.times) < 2)
        self.to_camera = gui.add_button("view from this frame's camera")
        self.display = gui.add_dropdown("display", (DISPLAY_SPLATS, DISPLAY_RENDER), initial_value=DISPLAY_SPLATS)
        self.show_cameras = gui.add_checkbox("recorded cameras", True)

        @self.time_slider.on_update
        def _(_event) -> None:
            self.set_time(float(self.time_slider.value))

        @self.frame_slider.on_update
        def _(_event) -> None:
            index = int(self.frame_slider.value)
            if 0 <= index < len(self.times):
                self.time_slider.value = float(round(self.times[index], 3))

        @self.to_camera.on_click
        def _(event) -> None:
            index = min(int(self.frame_slider.value), len(self.times) - 1)
            wxyz, position = camera_to_viser(self.world_to_cameras[index])
            clients = [event.client] if event.client is not None else list(self.server.get_clients().values())
            for client in clients:
                with client.atomic():
                    client.camera.wxyz = wxyz
                    client.camera.position = position

        @self.display.on_update
        def _(_event) -> None:
            self._apply_display()

        @self.show_cameras.on_update
        def _(_event) -> None:
            for frustum in self.frustums:
                frustum.visible = bool(self.show_cameras.value)

    def _apply_display(self) -> None:
        rendering = self.display.value == DISPLAY_RENDER
        self.static_splats.visible = not rendering
        if self.dynamic_splats is not None:
            self.dynamic_splats.visible = not rendering
        for client in self.server.get_clients().values():
            if rendering:
                self._renderer(client).request()
            else:
                client.scene.set_background_image(None)

    def set_time(self, time: float) -> None:
        """Move the dynamic Gaussians (splats and CPU renders) to normalised ``time`` in [0, 1]."""
        self.time = min(max(float(time), 0.0), 1.0)
        if self.dynamic_splats is not None:
            self.dynamic_splats.centers = self.dynamic_means(self.time)
        if self.display.value == DISPLAY_RENDER:
            for client in self.server.get_clients().values():
                self._renderer(client).request()

    # ---- CPU renders
    def _renderer(self, client) -> _LatestOnly:
        if client.client_id not in self._renderers:
            self._renderers[client.client_id] = _LatestOnly(lambda: self._render_to(client))
        return self._renderers[client.client_id]

    def _on_connect(self, client) -> None:
        @client.camera.on_update
        def _(_camera) -> None:
            if self.display.value == DISPLAY_RENDER:
                self._renderer(client).request()

    def render_camera(self, wxyz: Any, position: Any, fov_y: float, aspect: float) -> np.ndarray:
        """(H, W, 3) uint8 render by the model of a viser camera (``wxyz``, ``position``, vertical
        ``fov_y`` radians, ``aspect`` = W / H) at :attr:`render_height` pixels, current time."""
        from radar4dgs.apps.render import check_finite
        from radar4dgs.evaluate.reconstruction import to_uint8
        from radar4dgs.model.view import View

        height = self.render_height
        width = max(1, round(height * float(aspect)))
        view = View(viser_to_world_to_camera(wxyz, position), pinhole_intrinsics(fov_y, width, height), width,
                    height, self.time)
        with torch.no_grad():
            out = self.run.model.render(view, self.run.config.raster)
        check_finite(out, "viewer render")
        return to_uint8(out["rgb"])

    def _render_to(self, client) -> None:
        camera = client.camera
        image = self.render_camera(camera.wxyz, camera.position, camera.fov, camera.aspect)
        if self.display.value == DISPLAY_RENDER:  # the display may have changed during the render
            client.scene.set_background_image(image, format="jpeg", jpeg_quality=90)

    def stop(self) -> None:
        self.server.stop()
