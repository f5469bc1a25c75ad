"""The OmniHD-Scenes converter on a tiny fake clip written here in the NewScenes layout: a static
world of radar targets seen from an ego driving straight at 10 m/s, each sensor at its own time."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from _convert_helpers import rigid, yaw

from radar4dgs.apps.inspect import InspectCommand
from radar4dgs.apps.prepare import run_prepare
from radar4dgs.cli import main
from radar4dgs.datasets.convert.omnihd import CAMERA, LIDAR, RADAR, convert_omnihd
from radar4dgs.depth import DepthWarning
from radar4dgs.io.preview import summarize_scene
from radar4dgs.io.scene import SceneError, read_scene

CLIP = "1693714828633418"
T0 = int(CLIP)
FRAMES = 6
WIDTH, HEIGHT = 64, 48
K = np.array([[50.0, 0.0, 32.0], [0.0, 50.0, 24.0], [0.0, 0.0, 1.0]])
SPEED = 10.0
# Sensor times after the frame's LiDAR time (us): the radar 20 ms late, the camera 5 ms late.
RADAR_DELAY, CAMERA_DELAY = 20_000, 5_000
CAM_T = np.array([1.5, 0.0, 1.6])
RADAR_T = np.array([3.6, 0.0, 0.5])
# The marker target, in the ego frame at the first frame's camera time (x fwd, y left, z up).
MARKER = np.array([20.0, 2.0, 1.0])
N_INVALID, N_NAN = 3, 1
CV_TO_EGO = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


# Global frame: far from the origin and turned, so re-basing is tested.
GLOBAL_FROM_EGO0 = rigid(yaw(np.radians(30.0)), [1000.0, 2000.0, 5.0])
CAM_TO_EGO = rigid(CV_TO_EGO, CAM_T)
RADAR_TO_EGO = rigid(np.eye(3), RADAR_T)


def ego_pose(t_us: int) -> np.ndarray:
    """(4, 4) ego -> global at time ``t_us``: straight along the first ego x axis at SPEED."""
    t = (t_us - (T0 + CAMERA_DELAY)) * 1e-6
    return GLOBAL_FROM_EGO0 @ rigid(np.eye(3), [SPEED * t, 0.0, 0.0])


def static_targets(marker: np.ndarray = MARKER) -> np.ndarray:
    """(M, 3) target positions in the first camera-time ego frame: the marker and a spread of others."""
    rng = np.random.default_rng(3)
    others = np.column_stack([rng.uniform(12, 40, 24), rng.uniform(-10, 10, 24), rng.uniform(-0.5, 2.5, 24)])
    return np.vstack([marker, others])


def write_clip(root: Path, doppler_sign: float = 1.0, distortion=(0.0, 0.0, 0.0, 0.0, 0.0),
               camera_pose: bool = True, marker: np.ndarray = MARKER) -> Path:
    """Write a fake OmniHD-Scenes root with one clip of FRAMES frames; returns the root.

    Radar rows: the static targets (raw Doppler = ``doppler_sign`` x the true v_r), then N_INVALID
    rows flagged invalid and N_NAN valid-flagged rows with NaN x. Images are black with a white dot
    where the (distorted) camera sees the marker.
    """
    clip = root / CLIP
    for sub in ("cameras/camera_front", "radars/radar_front", "lidar/lidar_top_compensation"):
        (clip / sub).mkdir(parents=True)
    tables = root / "v1.0-trainval"
    tables.mkdir()
    targets_global = static_targets(marker) @ GLOBAL_FROM_EGO0[:3, :3].T + GLOBAL_FROM_EGO0[:3, 3]
    sample_data, poses, imu = [], [], []
    for k in range(FRAMES):
        t_lidar = T0 + k * 100_000
        t_cam, t_radar = t_lidar + CAMERA_DELAY, t_lidar + RADAR_DELAY
        # Camera image: the marker seen through the distorted lens.
        world_to_cam = np.linalg.inv(ego_pose(t_cam) @ CAM_TO_EGO)
        marker_cam = world_to_cam[:3, :3] @ targets_global[0] + world_to_cam[:3, 3]
        uv, _ = cv2.projectPoints(marker_cam[None], np.zeros(3), np.zeros(3), K, np.asarray(distortion, float))
        image = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
        # Sub-pixel dot (4 fractional bits), so its centroid is the projection itself.
        centre = tuple(int(round(c * 16)) for c in uv[0, 0])
        cv2.circle(image, centre, 24, (255, 255, 255), -1, lineType=cv2.LINE_AA, shift=4)
        cv2.imwrite(str(clip / "cameras" / "camera_front" / f"{t_cam}.jpg"), image, [cv2.IMWRITE_JPEG_QUALITY, 100])
        # Radar: static targets in the radar frame at the radar's own time.
        world_to_radar = np.linalg.inv(ego_pose(t_radar) @ RADAR_TO_EGO)
        xyz = targets_global @ world_to_radar[:3, :3].T + world_to_radar[:3, 3]
        v_s = RADAR_TO_EGO[:3, :3].T @ np.array([SPEED, 0.0, 0.0])
        v_r = -(xyz / np.linalg.norm(xyz, axis=1, keepdims=True)) @ v_s
        rows = np.column_stack([xyz, doppler_sign * v_r, np.full(len(xyz), 50.0), np.full(len(xyz), 1.0),
                                np.full(len(xyz), 12.0), np.ones(len(xyz))])
        junk = np.tile([5.0, 1.0, 0.0, 99.0, 1.0, 0.0, 1.0, 0.0], (N_INVALID, 1))
        nan = np.array([[np.nan, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0, 1.0]] * N_NAN)
        np.vstack([rows, junk, nan]).astype("<f4").tofile(clip / "radars" / "radar_front" / f"{t_radar}.bin")
        # LiDAR: the targets in the ego frame at the LiDAR's time, 5 columns.
        world_to_ego = np.linalg.inv(ego_pose(t_lidar))
        lidar_xyz = targets_global @ world_to_ego[:3, :3].T + world_to_ego[:3, 3]
        lidar = np.column_stack([lidar_xyz, np.full(len(lidar_xyz), 7.0), np.zeros(len(lidar_xyz))])
        lidar.astype("<f4").tofile(clip / "lidar" / "lidar_top_compensation" / f"{t_lidar}.bin")

        tokens = {RADAR: str(t_radar), LIDAR: str(t_lidar)}
        if camera_pose:
            tokens[CAMERA] = str(t_cam)
        sample_data.append({
            "token": str(t_lidar), "prev": "", "next": "",
            "cameras": {CAMERA: f"{CLIP}/cameras/camera_front/{t_cam}.jpg"},
            "radars": {RADAR: f"{CLIP}/radars/radar_front/{t_radar}.bin"},
            "lidar": {LIDAR: f"{CLIP}/lidar/lidar_top_compensation/{t_lidar}.bin"},
            "ego_pose": tokens})
        for t in (t_cam, t_radar, t_lidar):
            poses.append({"scene_token": CLIP, "token": str(t), "pose": ego_pose(t).ravel().tolist()})
            imu.append({"scene_token": CLIP, "token": str(t), "velocity_ego": [SPEED, 0.0, 0.0]})
    # A record of another clip, listed first, must not be picked up.
    sample_data.insert(0, {"token": "1", "scene_token": "999", "cameras": {}, "radars": {}, "ego_pose": {}})
    calib = {"token": CLIP, "calib": {
        CAMERA: {"intrinsic": K.tolist(), "distortion": list(distortion), "camera2ego": CAM_TO_EGO.ravel().tolist()},
        RADAR: {"radar2ego": RADAR_TO_EGO.ravel().tolist()}}}
    for name, rows in (("sample_data", sample_data[::-1]), ("ego_pose", poses), ("imu", imu),
                       ("sensor_calibration", [calib]), ("sample", [])):
        (tables / f"{name}.json").write_text(json.dumps(rows))
    return root


def frame_time(k: int, delay: int) -> int:
    return T0 + k * 100_000 + delay


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    base = tmp_path_factory.mktemp("omnihd")
    root = write_clip(base / "root")
    out = convert_omnihd(root, base / "scene", CLIP, start=1, frames=4, width=32, height=24, progress=False)
    return root, read_scene(out)


def test_geometry_poses_and_sizes(converted):
    _, scene = converted
    assert len(scene) == 4 and [f.name for f in scene.frames] == ["000001", "000002", "000003", "000004"]
    assert (scene.camera.width, scene.camera.height) == (32, 24)
    # Halved image: focal halves, pixel centres at integer coordinates.
    np.testing.assert_allclose(scene.camera.K, [[25, 0, 15.75], [0, 25, 11.75], [0, 0, 1]])
    np.testing.assert_allclose(scene.camera.cam_to_ego, CAM_TO_EGO)
    np.testing.assert_allclose(scene.radar.radar_to_ego, RADAR_TO_EGO)
    origin = np.linalg.inv(ego_pose(frame_time(1, CAMERA_DELAY)))
    for i, frame in enumerate(scene.frames):
        k = i + 1
        assert frame.timestamp == pytest.approx(frame_time(k, CAMERA_DELAY) * 1e-6, abs=1e-6)
        assert frame.radar_timestamp == pytest.approx(frame_time(k, RADAR_DELAY) * 1e-6, abs=1e-6)
        np.testing.assert_allclose(frame.ego_to_world, origin @ ego_pose(frame_time(k, CAMERA_DELAY)), atol=1e-6)
        np.testing.assert_allclose(frame.radar_ego_to_world, origin @ ego_pose(frame_time(k, RADAR_DELAY)),
                                   atol=1e-6)
        np.testing.assert_allclose(frame.ego_velocity, [SPEED, 0, 0])
    np.testing.assert_allclose(scene.frames[0].ego_to_world, np.eye(4), atol=1e-9)
    assert scene.source["camera_pose"].startswith("own ego pose")


def test_radar_points_land_on_the_marker(converted):
    _, scene = converted
    marker_world = MARKER - np.array([SPEED * 0.1, 0.0, 0.0])  # the world is frame 1's ego frame
    for i in range(len(scene)):
        scan = scene.load_radar(i)
        # Through the radar's own pose, the first row is the marker, static in the world.
        to_world = scene.radar_to_world(i)
        np.testing.assert_allclose(to_world[:3, :3] @ scan.xyz[0] + to_world[:3, 3], marker_world, atol=1e-4)
        # By hand: the camera-time ego is i * 1 m past the world origin; camera axes: X = -y,
        # Y = -(z - 1.6), Z = x - 1.5; pixel = 25 X / Z + 15.75, 25 Y / Z + 11.75.
        x, y, z = marker_world - np.array([SPEED * 0.1 * i, 0.0, 0.0])
        X, Y, Z = -y, -(z - 1.6), x - 1.5
        expected = np.array([25 * X / Z + 15.75, 25 * Y / Z + 11.75])
        to_cam = scene.radar_to_camera(i)
        uv, _ = scene.camera.project((to_cam[:3, :3] @ scan.xyz[:1].T).T + to_cam[:3, 3])
        np.testing.assert_allclose(uv[0], expected, atol=1e-3)


def test_doppler_sign_and_dropped_rows(converted):
    _, scene = converted
    n_targets = len(static_targets())
    assert scene.radar.fields == ("x", "y", "z", "v_r", "power", "snr", "motion_state")
    for i in range(len(scene)):
        scan = scene.load_radar(i)
        assert len(scan) == n_targets
        d = scan.xyz / np.linalg.norm(scan.xyz, axis=1, keepdims=True)
        # Static targets ahead, approached at 10 m/s: negative, = -d . v_s.
        assert np.all(scan.v_r < 0)
        np.testing.assert_allclose(scan.v_r, -d @ [SPEED, 0, 0], atol=1e-4)
        np.testing.assert_allclose(scan.column("snr"), 12.0)
        np.testing.assert_allclose(scan.column("motion_state"), 1.0)
        assert scene.frames[i].extra["radar_invalid_dropped"] == N_INVALID
        assert scene.frames[i].extra["radar_nonfinite_dropped"] == N_NAN
    rows = scene.source["radar_rows"]
    assert rows == {"read": 4 * (n_targets + N_INVALID + N_NAN), "kept": 4 * n_targets,
                    "invalid_dropped": 4 * N_INVALID, "nonfinite_dropped": 4 * N_NAN}
    assert scene.source["doppler_sign"]["checked"] and scene.source["doppler_sign"]["sign"] == 1


def test_lidar_is_in_the_camera_time_ego_frame(converted):
    _, scene = converted
    for i in range(len(scene)):
        lidar = scene.load_optional("lidar", i)
        assert lidar.shape == (len(static_targets()), 4)
        expected = MARKER - np.array([SPEED * 0.1 * (i + 1), 0.0, 0.0])
        np.testing.assert_allclose(lidar[0, :3], expected, atol=1e-4)
        assert lidar[0, 3] == 7.0


def test_inspect_and_prepare_accept_the_scene(converted, tmp_path):
    _, scene = converted
    summary = summarize_scene(scene)
    assert summary["frames"] == 4 and summary["warnings"] == []
    assert summary["ego_speed_from_poses_mps"]["mean"] == pytest.approx(SPEED, rel=1e-3)
    assert InspectCommand(scene.root, sheet=tmp_path / "sheet.png", frames=2).run() == 0
    assert (tmp_path / "sheet.png").is_file()
    # The whole front end runs (depth falls back to the weight-free flat-world prior).
    with pytest.warns(DepthWarning) as record:  # no prior, no weights, no radar fit on these few points
        status = run_prepare(scene.root, tmp_path / "prepared", progress=False)
    assert any("flat-world" in str(r.message) for r in record)
    assert status == {"radar": "ran", "depth": "ran", "masks": "ran", "object_depth": "ran", "flow": "ran"}
    radar_summary = json.loads((tmp_path / "prepared" / "radar" / "summary.json").read_text())
    assert radar_summary["num_ok"] == 4
    # The Doppler fit agrees with the poses: the sign and the radar's own times are right.
    assert radar_summary["disagreement"]["rmse"] < 0.05


def test_reversed_doppler_is_detected(tmp_path):
    root = write_clip(tmp_path / "root", doppler_sign=-1.0, camera_pose=False)
    scene = read_scene(convert_omnihd(root, tmp_path / "scene", CLIP, frames=3, width=32, height=24,
                                      lidar=False, progress=False))
    assert scene.source["doppler_sign"]["sign"] == -1
    assert np.all(scene.load_radar(0).v_r < 0)
    assert not scene.has("lidar")
    # Without ego_pose.camera_front the camera takes the LiDAR's pose, as the devkit does.
    assert scene.source["camera_pose"].startswith("the LiDAR's")
    np.testing.assert_allclose(scene.frames[1].ego_to_world[0, 3], SPEED * 0.1, atol=1e-6)


def test_forced_sign_through_the_command_line(tmp_path, capsys):
    root = write_clip(tmp_path / "root")
    args = ["convert", "omnihd", str(root), str(tmp_path / "scene"), "--clip", CLIP, "--frames", "2",
            "--width", "32", "--height", "24", "--no-lidar", "--doppler-sign", "-1", "--quiet"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert f"dropped {2 * N_INVALID} invalid" in out and "sign -1 (not checked)" in out
    assert np.all(read_scene(tmp_path / "scene").load_radar(0).v_r > 0)


def test_undistortion_keeps_the_marker_under_its_radar_point(tmp_path):
    # Off-centre marker: the lens moves it ~1 px there, so skipping the undistortion would show.
    root = write_clip(tmp_path / "root", distortion=(-0.3, 0.08, 0.0, 0.0, 0.0), marker=np.array([10.0, 3.0, 2.5]))
    scene = read_scene(convert_omnihd(root, tmp_path / "scene", CLIP, frames=2, width=WIDTH, height=HEIGHT,
                                      lidar=False, progress=False))
    image = scene.load_image(1).astype(float).sum(axis=2)
    ys, xs = np.nonzero(image > 0.5 * image.max())
    weights = image[ys, xs]
    spot = np.array([np.sum(xs * weights), np.sum(ys * weights)]) / weights.sum()
    to_cam = scene.radar_to_camera(1)
    uv, _ = scene.camera.project((to_cam[:3, :3] @ scene.load_radar(1).xyz[:1].T).T + to_cam[:3, 3])
    assert np.linalg.norm(spot - uv[0]) < 0.4


def test_errors_name_what_is_missing(tmp_path, capsys):
    root = write_clip(tmp_path / "root")
    with pytest.raises(SceneError, match="1693000000000000: missing clip folder"):
        convert_omnihd(root, tmp_path / "s", "1693000000000000", progress=False)
    with pytest.raises(SceneError, match=f"clip '{CLIP}' has {FRAMES} frames; --start 4 --frames 3"):
        convert_omnihd(root, tmp_path / "s", CLIP, start=4, frames=3, progress=False)
    radar_file = root / CLIP / "radars" / "radar_front" / f"{frame_time(1, RADAR_DELAY)}.bin"
    radar_file.unlink()
    with pytest.raises(SceneError, match=f"{frame_time(1, RADAR_DELAY)}.bin: missing file"):
        convert_omnihd(root, tmp_path / "s", CLIP, frames=2, width=32, height=24, progress=False)

    tables = root / "v1.0-trainval"
    calib = json.loads((tables / "sensor_calibration.json").read_text())
    del calib[0]["calib"][RADAR]["radar2ego"]
    (tables / "sensor_calibration.json").write_text(json.dumps(calib))
    with pytest.raises(SceneError, match=r"sensor_calibration.json: .* no key 'calib.radar_front.radar2ego'"):
        convert_omnihd(root, tmp_path / "s", CLIP, frames=2, progress=False)

    poses = json.loads((tables / "ego_pose.json").read_text())
    (tables / "ego_pose.json").write_text(json.dumps([p for p in poses if p["token"] != str(T0 + CAMERA_DELAY)]))
    calib[0]["calib"][RADAR]["radar2ego"] = RADAR_TO_EGO.ravel().tolist()
    (tables / "sensor_calibration.json").write_text(json.dumps(calib))
    with pytest.raises(SceneError, match=rf"ego_pose.json: no record .* token '{T0 + CAMERA_DELAY}'"):
        convert_omnihd(root, tmp_path / "s", CLIP, frames=1, progress=False)

    (tables / "sample_data.json").unlink()
    assert main(["convert", "omnihd", str(root), str(tmp_path / "s"), "--clip", CLIP, "--quiet"]) == 1
    assert "sample_data.json: missing table" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()
