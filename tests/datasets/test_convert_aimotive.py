"""The aiMotive converter: unit checks on its conventions, a fake minimal sequence, and (when the
shared fixture is present) the real sample."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from radar4dgs.cli import main
from radar4dgs.datasets.convert.aimotive import CAMERA, RADAR, box_labels, convert_aimotive, opencv_axes, radar_points
from radar4dgs.io.scene import SceneError, read_scene

FIXTURE = Path(__file__).resolve().parents[3] / "shared" / "fixtures" / "aimotive-night"


def test_radar_points_positive_azimuth_is_left_and_speed_is_v_r():
    pts = radar_points([{"azimuth": 0.1, "elevation": 0.0, "range": 10.0, "speed": -5.0, "rcs": 1.0,
                         "power": 2.0}], Path("x.json"))
    assert pts.shape == (1, 6)
    assert pts[0, 1] > 0 and pts[0, 0] == pytest.approx(10 * np.cos(0.1))
    assert pts[0, 3] == -5.0  # approaching stays negative: already "positive = receding"
    assert radar_points([], Path("x.json")).shape == (0, 6)


def test_opencv_axes_accepts_opencv_and_converts_flu():
    cv = np.eye(4)
    cv[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]
    np.testing.assert_array_equal(opencv_axes(cv, Path("c")), cv)
    np.testing.assert_allclose(opencv_axes(np.eye(4), Path("c")), cv)
    with pytest.raises(SceneError):
        opencv_axes(np.diag([-1.0, -1.0, 1.0, 1.0]), Path("c"))


def test_box_labels_use_world_speed():
    box = {"BoundingBox3D Origin X": 20.0, "BoundingBox3D Origin Y": 0.0, "BoundingBox3D Origin Z": 0.5,
           "BoundingBox3D Extent X": 4.0, "BoundingBox3D Extent Y": 2.0, "BoundingBox3D Extent Z": 1.5,
           "BoundingBox3D Orientation Quat W": 1.0, "BoundingBox3D Orientation Quat X": 0.0,
           "BoundingBox3D Orientation Quat Y": 0.0, "BoundingBox3D Orientation Quat Z": 0.0,
           "Relative Velocity X": -30.0, "Relative Velocity Y": 0.0, "Relative Velocity Z": 0.0}
    pts = np.array([[20.0, 0.0, 0.5], [40.0, 0.0, 0.5]])
    ego = np.array([30.0, 0.0, 0.0])
    # Relative -30 m/s at ego 30 m/s: a parked car -> 0; relative -5 m/s: moving at 25 m/s -> 1.
    assert box_labels(pts, [box], ego, 0.0).tolist() == [0, 0]
    assert box_labels(pts, [{**box, "Relative Velocity X": -5.0}], ego, 0.0).tolist() == [1, 0]


def _fake_sequence(root: Path, frames: int = 6, speed: float = 20.0) -> Path:
    """A minimal aiMotive-layout sequence: 64x32 images, static targets seen from a radar moving at
    ``speed``, one moving car box with a few targets."""
    rng = np.random.default_rng(0)
    cam_rt = np.eye(4)
    cam_rt[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]
    cam_rt[:3, 3] = [1.9, 0.1, 1.2]
    rad_rt = np.eye(4)
    rad_rt[:3, 3] = [3.8, 0.0, 0.4]
    calib = {CAMERA: {"RT_body_from_sensor": cam_rt.tolist(), "focal_length_px": [40.0, 40.0],
                      "principal_point_px": [32.0, 16.0], "distortion_coeffs": [-0.1, 0.01, 0, 0, 0],
                      "image_resolution_px": [64, 32]},
             RADAR: {"RT_body_from_sensor": rad_rt.tolist()}}
    (root / "sensor" / "calibration").mkdir(parents=True)
    (root / "sensor" / "calibration" / "calibration.json").write_text(json.dumps(calib))
    cam_dir = root / "sensor" / "camera" / CAMERA
    radar_dir = root / "sensor" / "radar" / RADAR
    box_dir = root / "dynamic" / "box" / "3d_body"
    for d in (cam_dir, radar_dir, box_dir):
        d.mkdir(parents=True)
    for i in range(frames):
        fid = f"{1000 + i:07d}"
        cv2.imwrite(str(cam_dir / f"{CAMERA}_{fid}.jpg"), rng.integers(0, 255, (32, 64, 3), dtype=np.uint8))
        az = rng.uniform(-0.25, 0.25, 40)
        targets = [{"azimuth": a, "elevation": 0.0, "range": r, "speed": -speed * np.cos(a) + rng.normal(0, 0.03),
                    "rcs": 1.0, "power": 100.0, "noise": 90.0}
                   for a, r in zip(az, rng.uniform(10, 80, 40), strict=True)]
        # A car 30 m ahead in the radar frame, driving at 15 m/s (relative -5 m/s).
        targets += [{"azimuth": 0.0, "elevation": 0.0, "range": 30.0 + k * 0.3, "speed": -5.0, "rcs": 5.0,
                     "power": 120.0, "noise": 90.0} for k in range(3)]
        (radar_dir / f"{RADAR}_{fid}.json").write_text(json.dumps({"targets": targets}))
        box = {"BoundingBox3D Origin X": 34.3, "BoundingBox3D Origin Y": 0.0, "BoundingBox3D Origin Z": 0.7,
               "BoundingBox3D Extent X": 4.5, "BoundingBox3D Extent Y": 2.0, "BoundingBox3D Extent Z": 1.5,
               "BoundingBox3D Orientation Quat W": 1.0, "BoundingBox3D Orientation Quat X": 0.0,
               "BoundingBox3D Orientation Quat Y": 0.0, "BoundingBox3D Orientation Quat Z": 0.0,
               "Relative Velocity X": -5.0, "Relative Velocity Y": 0.0, "Relative Velocity Z": 0.0,
               "ObjectType": "CAR", "ObjectId": 1}
        stamp = 5_000_000_000 + i * 66_666_667
        (box_dir / f"frame_{fid}.json").write_text(json.dumps({"CapturedObjects": [box], "Timestamp": str(stamp)}))
    return root


def test_convert_fake_sequence(tmp_path):
    src = _fake_sequence(tmp_path / "seq")
    out = convert_aimotive(src, tmp_path / "scene", scale=0.5, progress=False)
    scene = read_scene(out)
    # 64x32 at 0.5, the bottom 20 % (6 of 32 rows, the hood) cut off by default: 26 rows -> 13.
    assert (scene.camera.width, scene.camera.height) == (32, 13)
    assert scene.source["poses_from_radar"] is True
    assert scene.frames[1].timestamp - scene.frames[0].timestamp == pytest.approx(0.0667, abs=1e-3)
    # 20 m/s straight ahead for 5 frames.
    assert scene.frames[-1].ego_to_world[0, 3] == pytest.approx(20 * 5 * 0.0666667, rel=0.01)
    assert abs(scene.frames[-1].ego_to_world[1, 3]) < 0.05
    labels = scene.load_optional("gt/radar_labels", 0)
    assert labels.tolist()[-3:] == [1, 1, 1] and labels[:-3].sum() == 0
    assert scene.radar.fields == ("x", "y", "z", "v_r", "rcs", "power")


def test_missing_files_are_named(tmp_path, capsys):
    src = _fake_sequence(tmp_path / "seq", frames=3)
    (src / "dynamic" / "box" / "3d_body" / "frame_0001001.json").unlink()
    with pytest.raises(SceneError, match="frame_0001001.json"):
        convert_aimotive(src, tmp_path / "scene", progress=False)
    (src / "sensor" / "calibration" / "calibration.json").unlink()
    assert main(["convert", "aimotive", str(src), str(tmp_path / "scene"), "--quiet"]) == 1
    assert "calibration.json" in capsys.readouterr().err
    assert not (tmp_path / "scene").exists()


@pytest.mark.skipif(not FIXTURE.is_dir(), reason="shared aiMotive fixture not present")
def test_real_sample(tmp_path):
    out = convert_aimotive(FIXTURE, tmp_path / "aim", scale=0.25, progress=False)
    scene = read_scene(out)
    # 1280x704 at 0.25, the bottom 20 % (the hood) cut off by default.
    assert len(scene) == 50 and (scene.camera.width, scene.camera.height) == (320, 141)
    duration = scene.frames[-1].timestamp - scene.frames[0].timestamp
    assert duration == pytest.approx(3.27, abs=0.05)
    # ~30 m/s for 3.27 s, straight (the heading alignment removes the mount-yaw artefact).
    last = scene.frames[-1].ego_to_world
    assert last[0, 3] == pytest.approx(98.0, abs=2.0) and abs(last[1, 3]) < 2.0
    assert sum(scene.load_optional("gt/radar_labels", i).sum() for i in range(len(scene))) > 100
    # Doppler of points in moving boxes matches d . v_rel (the azimuth-sign check), see module doc.
    image = scene.load_image(0)
    assert image.shape == (141, 320, 3)


def test_real_sample_without_its_hood(tmp_path):
    full = read_scene(convert_aimotive(FIXTURE, tmp_path / "full", scale=0.25, progress=False, crop_bottom=0.0))
    cropped = read_scene(convert_aimotive(FIXTURE, tmp_path / "cropped", scale=0.25, progress=False,
                                          crop_bottom=0.2))
    assert (cropped.camera.width, cropped.camera.height) == (320, 141)
    # The same camera, shorter: focal lengths and principal point as before (the y scale differs by
    # the rounding of 563 rows to 141, 0.2 %).
    np.testing.assert_allclose(cropped.camera.K, full.camera.K, rtol=3e-3)
    # The night clip's hood is dark (mean grey ~27 at the bottom of the uncropped frames); what is
    # left at the cropped bottom is the lit road (mean ~106; > 45 even in the corners, where the
    # hood's curved edge comes highest).
    def mean_grey(scene):
        return np.mean([scene.load_image(i).mean(2) for i in range(0, len(scene), 7)], axis=0)
    assert mean_grey(full)[-4:].mean() < 40
    bottom = mean_grey(cropped)[-1]
    assert bottom.mean() > 90 and bottom.min() > 45
    assert "hood" in cropped.source["images"]
    with pytest.raises(ValueError, match="crop-bottom"):
        convert_aimotive(FIXTURE, tmp_path / "bad", crop_bottom=0.6, progress=False)


def test_calibration_is_cross_checked_and_recorded(tmp_path):
    """extrinsic_matrices.json must agree with calibration.json; source.calibration says what was
    used, the accuracies the file states and what was left (issue 27)."""
    src = _fake_sequence(tmp_path / "seq", frames=4)
    calib_dir = src / "sensor" / "calibration"
    calib = json.loads((calib_dir / "calibration.json").read_text())
    calib[CAMERA]["custom_vars"] = {"misalign_ref_angle_error": 0.5}
    calib[CAMERA]["reprojection_error"] = -1
    calib["Imu0"] = {"sensor_type": "imu_ins"}
    (calib_dir / "calibration.json").write_text(json.dumps(calib))
    matrices = {f"RT_body_from_{s}": calib[s]["RT_body_from_sensor"] for s in (CAMERA, RADAR)}
    (calib_dir / "extrinsic_matrices.json").write_text(json.dumps(matrices))
    scene = read_scene(convert_aimotive(src, tmp_path / "scene", progress=False))
    record = scene.source["calibration"]
    assert record["extrinsics_cross_checked"] == [CAMERA, RADAR]
    assert record["camera"]["misalign_ref_angle_error_deg"] == 0.5 and record["camera"]["reprojection_error_px"] is None
    assert record["camera"]["focal_length_px"] == [40.0, 40.0] and "Imu0" in record["not_used"]
    assert scene.source["poses_from_odometry"] is True
    matrices[f"RT_body_from_{RADAR}"][0][3] += 0.01
    (calib_dir / "extrinsic_matrices.json").write_text(json.dumps(matrices))
    with pytest.raises(SceneError, match="extrinsic_matrices.json"):
        convert_aimotive(src, tmp_path / "scene2", progress=False)
