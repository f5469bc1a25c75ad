"""The View-of-Delft converter on a tiny fake dataset written here in the KITTI layout: two
sequences (the odometry restarts between them) and a gap in the frame numbers."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from _convert_helpers import rigid, yaw

from radar4dgs.apps.prepare import run_prepare
from radar4dgs.cli import main
from radar4dgs.datasets.convert.vod import convert_vod, parse_range, sequence_breaks
from radar4dgs.depth import DepthWarning
from radar4dgs.io.preview import summarize_scene
from radar4dgs.io.scene import SceneError, read_scene

WIDTH, HEIGHT = 64, 48
P2 = np.array([[50.0, 0.0, 32.0, 0.0], [0.0, 50.0, 24.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
SPEED = 8.0
CV_TO_FLU = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
# Frame numbers: sequence A, sequence B (odometry restarts), then C after a missing number.
SEQ_A, SEQ_B, SEQ_C = range(10, 16), range(16, 20), range(21, 24)
# The marker target in the radar (= ego) frame of frame 11, the first converted one.
MARKER = np.array([20.0, 2.0, 0.5])
MOVER_V_R_COMP = 3.0
N_OLDER, N_NAN = 2, 1


# Camera 2 m behind, 0.1 m left of and 0.9 m above the radar, looking along the radar's x axis.
CAM_TO_RADAR = rigid(CV_TO_FLU, [-2.0, 0.1, 0.9])
RADAR_TO_CAM = np.linalg.inv(CAM_TO_RADAR)
LIDAR_TO_RADAR = rigid(np.eye(3), [-1.0, 0.0, 1.2])


def radar_pose(n: int) -> np.ndarray:
    """(4, 4) radar -> odometry world of frame ``n``: each sequence's odometry starts at its own
    origin and drives straight at SPEED along a heading of 20 deg; sequence A had already driven
    150 m before frame 10 (its earlier frames are not in the fake folder)."""
    start = next(s for s in (SEQ_A, SEQ_B, SEQ_C) if n in s).start
    driven = SPEED * 0.1 * (n - start) + (150.0 if n in SEQ_A else 0.0)
    return rigid(yaw(np.radians(20.0)), [3.0, -4.0, 0.0]) @ rigid(np.eye(3), [driven, 0.0, 0.0])


def targets_world(n: int) -> np.ndarray:
    """(M, 3) static targets in frame n's sequence's odometry world; row 0 is the marker, given in
    the radar frame of the sequence's second frame (frame 11 for sequence A)."""
    rng = np.random.default_rng(5)
    local = np.vstack([MARKER, np.column_stack([rng.uniform(8, 40, 20), rng.uniform(-8, 8, 20),
                                                rng.uniform(-1.0, 2.0, 20)])])
    anchor = radar_pose(next(s for s in (SEQ_A, SEQ_B, SEQ_C) if n in s).start + 1)
    return local @ anchor[:3, :3].T + anchor[:3, 3]


def _calib_text(velo_to_cam: np.ndarray) -> str:
    lines = [f"P{i}: " + " ".join(f"{v:.10g}" for v in P2.ravel()) for i in range(4)]
    lines.append("R0_rect: 1 0 0 0 1 0 0 0 1")
    lines.append("Tr_velo_to_cam: " + " ".join(f"{v:.10g}" for v in velo_to_cam[:3].ravel()))
    lines.append("Tr_imu_to_velo: ")
    return "\n".join(lines) + "\n"


def write_vod(root: Path, doppler_sign: float = 1.0, with_lidar: bool = True) -> Path:
    """Write a fake VoD root; returns it. The raw v_r is ``doppler_sign`` x the true one."""
    base = root / "radar" / "training"
    for sub in ("image_2", "velodyne", "calib", "pose"):
        (base / sub).mkdir(parents=True)
    if with_lidar:
        for sub in ("velodyne", "calib"):
            (root / "lidar" / "training" / sub).mkdir(parents=True)
    for n in [*SEQ_A, *SEQ_B, *SEQ_C]:
        name = f"{n:05d}"
        pose = radar_pose(n)
        xyz = (targets_world(n) - pose[:3, 3]) @ pose[:3, :3]
        d = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
        v_r = -d @ [SPEED, 0.0, 0.0]
        comp = np.zeros(len(xyz))
        # The last target moves: 3 m/s away from the radar on top of the ego-motion.
        v_r[-1] += MOVER_V_R_COMP
        comp[-1] = MOVER_V_R_COMP
        rows = np.column_stack([xyz, np.full(len(xyz), -5.0), doppler_sign * v_r, doppler_sign * comp,
                                np.zeros(len(xyz))])
        older = np.tile([10.0, 0.0, 0.0, 1.0, 50.0, 50.0, -1.0], (N_OLDER, 1))
        nan = np.array([[np.nan, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0]] * N_NAN)
        np.vstack([rows, older, nan]).astype("<f4").tofile(base / "velodyne" / f"{name}.bin")
        (base / "calib" / f"{name}.txt").write_text(_calib_text(RADAR_TO_CAM))
        cam_to_odom = pose @ CAM_TO_RADAR
        lines = [json.dumps({key: (cam_to_odom if key == "odomToCamera" else np.eye(4)).ravel().tolist()})
                 for key in ("odomToCamera", "mapToCamera", "UTMToCamera")]
        (base / "pose" / f"{name}.json").write_text("\n".join(lines))
        marker_cam = RADAR_TO_CAM[:3, :3] @ xyz[0] + RADAR_TO_CAM[:3, 3]
        uv = P2[:, :3] @ marker_cam
        image = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
        cv2.circle(image, tuple(int(round(c * 16)) for c in uv[:2] / uv[2]), 24, (255, 255, 255), -1,
                   lineType=cv2.LINE_AA, shift=4)
        cv2.imwrite(str(base / "image_2" / f"{name}.jpg"), image, [cv2.IMWRITE_JPEG_QUALITY, 100])
        if with_lidar:
            lidar_xyz = (xyz - LIDAR_TO_RADAR[:3, 3]) @ LIDAR_TO_RADAR[:3, :3]
            np.column_stack([lidar_xyz, np.full(len(xyz), 0.25)]).astype("<f4").tofile(
                root / "lidar" / "training" / "velodyne" / f"{name}.bin")
            (root / "lidar" / "training" / "calib" / f"{name}.txt").write_text(
                _calib_text(RADAR_TO_CAM @ LIDAR_TO_RADAR))
    return root


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    base = tmp_path_factory.mktemp("vod")
    root = write_vod(base / "root")
    return root, read_scene(convert_vod(root, base / "scene", "11:15", progress=False))


def test_frames_poses_and_camera(converted):
    _, scene = converted
    assert [f.name for f in scene.frames] == ["00011", "00012", "00013", "00014"]
    assert [f.timestamp for f in scene.frames] == pytest.approx([1.1, 1.2, 1.3, 1.4])
    assert (scene.camera.width, scene.camera.height) == (WIDTH, HEIGHT)
    np.testing.assert_allclose(scene.camera.K, P2[:, :3])
    np.testing.assert_allclose(scene.camera.cam_to_ego, CAM_TO_RADAR, atol=1e-9)
    np.testing.assert_allclose(scene.radar.radar_to_ego, np.eye(4))
    origin = np.linalg.inv(radar_pose(11))
    for i, frame in enumerate(scene.frames):
        np.testing.assert_allclose(frame.ego_to_world, origin @ radar_pose(11 + i), atol=1e-9)
        np.testing.assert_allclose(frame.radar_ego_to_world, frame.ego_to_world)
        # World camera pose = the fake odometry camera pose, re-based.
        np.testing.assert_allclose(frame.ego_to_world @ scene.camera.cam_to_ego,
                                   origin @ radar_pose(11 + i) @ CAM_TO_RADAR, atol=1e-9)


def test_radar_marker_projects_where_the_geometry_says(converted):
    _, scene = converted
    for i in range(len(scene)):
        scan = scene.load_radar(i)
        to_world = scene.radar_to_world(i)
        np.testing.assert_allclose(to_world[:3, :3] @ scan.xyz[0] + to_world[:3, 3], MARKER, atol=1e-4)
        # By hand: the marker is 0.8 m closer each frame; camera axes X = -(y - 0.1),
        # Y = -(z - 0.9), Z = x + 2 from the camera's mount in the radar frame.
        x, y, z = MARKER - [SPEED * 0.1 * i, 0.0, 0.0]
        X, Y, Z = -(y - 0.1), -(z - 0.9), x + 2.0
        expected = [50 * X / Z + 32, 50 * Y / Z + 24]
        to_cam = scene.radar_to_camera(i)
        uv, _ = scene.camera.project((to_cam[:3, :3] @ scan.xyz[:1].T).T + to_cam[:3, 3])
        np.testing.assert_allclose(uv[0], expected, atol=1e-3)
        # And the image shows the marker there.
        image = scene.load_image(i).astype(float).sum(axis=2)
        ys, xs = np.nonzero(image > 0.5 * image.max())
        w = image[ys, xs]
        np.testing.assert_allclose([np.sum(xs * w) / w.sum(), np.sum(ys * w) / w.sum()], expected, atol=0.3)


def test_doppler_columns_and_dropped_rows(converted):
    _, scene = converted
    assert scene.radar.fields == ("x", "y", "z", "v_r", "rcs", "v_r_comp")
    for i in range(len(scene)):
        scan = scene.load_radar(i)
        d = scan.xyz / np.linalg.norm(scan.xyz, axis=1, keepdims=True)
        expected = -d @ [SPEED, 0, 0]
        expected[-1] += MOVER_V_R_COMP
        np.testing.assert_allclose(scan.v_r, expected, atol=1e-4)
        assert np.all(scan.v_r[:-1] < 0)  # static targets ahead, approached
        np.testing.assert_allclose(scan.column("v_r_comp")[:-1], 0.0)
        assert scan.column("v_r_comp")[-1] == pytest.approx(MOVER_V_R_COMP)
        np.testing.assert_allclose(scan.column("rcs"), -5.0)
        assert scene.frames[i].extra == {"radar_older_scan_dropped": N_OLDER, "radar_nonfinite_dropped": N_NAN}
    assert scene.source["radar_rows"]["older_scan_dropped"] == 4 * N_OLDER
    assert scene.source["radar_rows"]["nonfinite_dropped"] == 4 * N_NAN
    assert scene.source["doppler_sign"]["checked"] and scene.source["doppler_sign"]["sign"] == 1


def test_lidar_goes_to_the_ego_frame(converted):
    _, scene = converted
    lidar = scene.load_optional("lidar", 2)
    np.testing.assert_allclose(lidar[0, :3], MARKER - [SPEED * 0.2, 0, 0], atol=1e-4)
    assert lidar[0, 3] == 0.25


def test_inspect_and_prepare_accept_the_scene(converted, tmp_path):
    _, scene = converted
    assert summarize_scene(scene)["ego_speed_from_poses_mps"]["mean"] == pytest.approx(SPEED)
    assert main(["inspect", str(scene.root), "--sheet", str(tmp_path / "sheet.png")]) == 0
    # The whole front end runs (depth falls back to the weight-free flat-world prior).
    with pytest.warns(DepthWarning) as record:  # no prior, no weights, no radar fit on these few points
        status = run_prepare(scene.root, tmp_path / "prepared", progress=False)
    assert any("flat-world" in str(r.message) for r in record)
    assert status == {"radar": "ran", "depth": "ran", "masks": "ran", "object_depth": "ran", "flow": "ran"}
    summary = json.loads((tmp_path / "prepared" / "radar" / "summary.json").read_text())
    assert summary["num_ok"] == 4 and summary["disagreement"]["rmse"] < 0.05
    assert all(f["dynamic"] == 1 for f in summary["frames"])  # the 3 m/s mover


def test_reversed_doppler_is_detected_and_lidar_is_optional(tmp_path):
    root = write_vod(tmp_path / "root", doppler_sign=-1.0, with_lidar=False)
    scene = read_scene(convert_vod(root, tmp_path / "scene", "16:20", width=32, height=24, progress=False))
    assert scene.source["doppler_sign"]["sign"] == -1
    scan = scene.load_radar(0)
    assert np.all(scan.v_r[:-1] < 0) and scan.column("v_r_comp")[-1] == pytest.approx(MOVER_V_R_COMP)
    assert not scene.has("lidar") and "missing" in scene.source["lidar"]
    np.testing.assert_allclose(scene.camera.K, [[25, 0, 15.75], [0, 25, 11.75], [0, 0, 1]])


def test_range_across_sequences_is_refused(tmp_path, capsys):
    root = write_vod(tmp_path / "root", with_lidar=False)
    with pytest.raises(SceneError, match="crosses two sequences between frames 00015 and 00016: the odometry jumps"):
        convert_vod(root, tmp_path / "s", "13:18", progress=False)
    with pytest.raises(SceneError, match="frames 00020 are missing inside --frames 18:23"):
        convert_vod(root, tmp_path / "s", "18:23", progress=False)
    with pytest.raises(SceneError, match=r"no radar scans for frames 00100..00104; frames here: 00010-00019, "
                                         r"00021-00023"):
        convert_vod(root, tmp_path / "s", "100:105", progress=False)
    assert main(["convert", "vod", str(root), str(tmp_path / "s"), "--frames", "13:18", "--quiet"]) == 1
    assert "00015 and 00016" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_missing_files_and_keys_are_named(tmp_path):
    root = write_vod(tmp_path / "root", with_lidar=False)
    base = root / "radar" / "training"
    (base / "pose" / "00012.json").unlink()
    with pytest.raises(SceneError, match=r"pose/00012.json: missing file"):
        convert_vod(root, tmp_path / "s", "11:14", progress=False)
    (base / "calib" / "00017.txt").write_text(_calib_text(RADAR_TO_CAM).replace("Tr_velo_to_cam", "Tr_other"))
    with pytest.raises(SceneError, match=r"calib/00017.txt: no 'Tr_velo_to_cam' line"):
        convert_vod(root, tmp_path / "s", "16:19", progress=False)
    (base / "image_2" / "00022.jpg").unlink()
    with pytest.raises(SceneError, match=r"image_2/00022.jpg: missing file"):
        convert_vod(root, tmp_path / "s", "21:24", progress=False)
    with pytest.raises(SceneError, match=r"lidar/training/velodyne/00021.bin: missing file"):
        convert_vod(root, tmp_path / "s", "21:22", lidar="on", progress=False)
    (base / "calib").rename(base / "calib_moved")
    with pytest.raises(SceneError, match=r"radar/training/calib: missing folder"):
        convert_vod(root, tmp_path / "s", "21:22", progress=False)


def test_range_parsing_and_break_detection():
    assert parse_range("00100:00150") == (100, 150)
    with pytest.raises(ValueError, match="A:B"):
        parse_range("100-150")
    with pytest.raises(ValueError, match="after the start"):
        parse_range("5:5")
    still = [np.eye(4)] * 3
    turned = np.eye(4)
    turned[:3, :3] = yaw(1.0)
    assert sequence_breaks(["a", "b", "c"], still, 0.1, 40.0) == []
    breaks = sequence_breaks(["a", "b", "c"], [np.eye(4), turned, turned], 0.1, 40.0)
    assert [(a, b) for a, b, _ in breaks] == [("a", "b")] and "turns 57 deg" in breaks[0][2]

    def drive(xs):
        return [rigid(np.eye(3), [x, 0.0, 0.0]) for x in xs]

    names = ["a", "b", "c", "d", "e"]
    # A short sequence ends 3 m from its origin; the next starts at its own: a 3 m step back,
    # within the 4.5 m speed limit, but unlike the 1 m steps around it.
    breaks = sequence_breaks(names, drive([1.0, 2.0, 3.0, 0.0, 1.0]), 0.1, 40.0)
    assert [(a, b) for a, b, _ in breaks] == [("c", "d")] and "step differs by 4.0 m" in breaks[0][2]
    # Braking from 15 m/s to 5 m/s and pose-time jitter of +-0.25 m are not breaks.
    assert sequence_breaks(names, drive(np.cumsum([0.0, 1.5, 1.0, 0.5, 0.5])), 0.1, 40.0) == []
    assert sequence_breaks(names, drive(np.cumsum([0.0, 1.5, 1.25, 1.75, 1.5])), 0.1, 40.0) == []
