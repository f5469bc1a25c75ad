"""Converter for one OmniHD-Scenes clip (front camera + front 4D radar + top LiDAR) into a scene folder.

Expected layout (``ROOT``; the "NewScenes" devkit layout)::

    ROOT/
      <clip>/                                   clip folder, named by its start time in microseconds
        cameras/camera_front/<t_us>.jpg
        radars/radar_front/<t_us>.bin
        lidar/lidar_top_compensation/<t_us>.bin
      v1.0-trainval/                            the tables (``--version``), each a JSON list of objects
        sample_data.json  ego_pose.json  sensor_calibration.json  imu.json (or imu_data.json)

Table schema read here (only these keys; others are ignored). Where the public devkit left a key
unspecified, the nuScenes-like choice made here is marked "assumed".

* ``sample_data``: one record per synchronised 10 Hz frame (keyframes and sweeps alike):
  ``token`` (str, the frame's LiDAR time in microseconds, as in the devkit);
  ``scene_token`` (str, optional, assumed: the clip name; when absent the clip is the first path
  component of the camera file name); ``timestamp`` (int microseconds, optional, assumed;
  default ``int(token)``: used only to order the frames of a clip);
  ``cameras`` {channel: file path relative to ROOT}, ``radars`` {channel: path}, ``lidar``
  {channel: path}; ``ego_pose`` {channel: ego_pose token}, one token per sensor.
  ``prev``/``next`` are not read: frames are ordered by time.
* ``ego_pose``: ``scene_token`` (clip), ``token``, ``pose`` (16 floats, row-major 4x4, ego ->
  global). A record is found by the pair (scene_token, token), as in the devkit.
* ``sensor_calibration``: one record per clip, ``token`` = the clip name, ``calib`` {channel: ...}
  with ``calib.camera_front.intrinsic`` (3x3 nested or 9 floats row-major),
  ``calib.camera_front.distortion`` (OpenCV coefficients k1 k2 p1 p2 [k3 ...]),
  ``calib.camera_front.camera2ego`` and ``calib.radar_front.radar2ego`` (16 floats row-major;
  OpenCV camera axes, x forward / y left / z up radar axes). The LiDAR is already in the ego frame
  (``lidar_top_compensation``; the devkit's lidar2ego is the identity).
* ``imu`` (optional; ``imu.json``, or ``imu_data.json`` as the devkit names it): ``scene_token``,
  ``token`` (an ego_pose token), ``velocity_ego`` (3 floats, m/s, ego axes). Written as the frames'
  ``ego_velocity`` when every converted frame has one.

Sensor files: radar ``.bin`` is float32 x 8 per point ``[x, y, z, v_r, power, motion_state, SNR,
valid_flag]`` in the radar frame (``valid_flag`` 0 = invalid, assumed: any other value is valid);
LiDAR ``.bin`` is float32 x ``lidar_columns`` (5 in the devkit: x, y, z, intensity, ring) in the ego
frame at the LiDAR's own pose.

Times: each sensor's time is the microsecond stem of its file name (falls back to the record's
time when the stem is not a number); each sensor's ego pose comes from its own ``ego_pose`` token
(the camera falls back to the LiDAR's pose, as the devkit does, when ``ego_pose`` has no
``camera_front`` entry; ``source.camera_pose`` says which). The world frame is the camera-time ego
frame of the first converted frame.

What is converted: the undistorted, resized front image; the valid front-radar points with
``v_r`` in the scene convention (positive = receding; the raw Doppler's sign is checked against
the poses with the radar ego-motion fit, :func:`doppler_sign`); power, SNR and the radar's own
motion state as extra columns; the LiDAR in the camera-time ego frame; poses; IMU velocity.
Dropped: the other five cameras and radars, invalid radar rows (counted per frame as
``radar_invalid_dropped`` and in total in ``source.radar_rows``), the LiDAR ring index, the
annotations.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np
import tyro

from radar4dgs.datasets.convert.common import (
    DopplerSign,
    ImageRectifier,
    apply_doppler_sign,
    doppler_sign,
    keep_rows,
    radar_row_counts,
    read_first_image,
    read_lidar_scan,
    read_radar_scans,
    rebase,
    write_scene,
)
from radar4dgs.io.scene import Camera, Frame, RadarSpec, SceneError, read_json_file
from radar4dgs.io.scene_read import rigid_matrix

CAMERA = "camera_front"
RADAR = "radar_front"
LIDAR = "lidar_top_compensation"
RAW_RADAR_COLUMNS = 8
RADAR_FIELDS = ("x", "y", "z", "v_r", "power", "snr", "motion_state")
# Raw column index of each stored field (raw: x y z v_r power motion_state SNR valid_flag).
_RAW_INDEX = (0, 1, 2, 3, 4, 6, 5)
_VALID_COLUMN = 7


def _read_table(tables: Path, *names: str, required: bool = True) -> tuple[list[dict], Path] | None:
    for name in names:
        path = tables / f"{name}.json"
        if path.is_file():
            rows = read_json_file(path)
            if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
                raise SceneError(path, "expected a JSON list of objects (a NewScenes table)")
            return rows, path
    if required:
        raise SceneError(tables / f"{names[0]}.json", "missing table (OmniHD-Scenes / NewScenes layout)")
    return None


def _key(record: Any, keys: Sequence[str], path: Path, what: str) -> Any:
    """``record[k0][k1]...``; a SceneError naming the table, the record and the missing key."""
    value = record
    for depth, key in enumerate(keys):
        if not isinstance(value, dict) or key not in value:
            dotted = ".".join(keys[: depth + 1])
            raise SceneError(path, f"{what} has no key '{dotted}'")
        value = value[key]
    return value


def _matrix4(value: Any, path: Path, where: str) -> np.ndarray:
    try:
        matrix = np.asarray(value, dtype=np.float64).reshape(4, 4)
    except (TypeError, ValueError):
        raise SceneError(path, f"{where} is not 16 numbers (row-major 4x4)") from None
    return rigid_matrix(matrix, where, path)


def _intrinsics(value: Any, path: Path, where: str) -> np.ndarray:
    try:
        K = np.asarray(value, dtype=np.float64).reshape(3, 3)
    except (TypeError, ValueError):
        raise SceneError(path, f"{where} is not a 3x3 matrix (nested or 9 numbers)") from None
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0.0, 0.0, 1.0]):
        raise SceneError(path, f"{where} is not a camera matrix (positive focal lengths, last row 0 0 1)")
    return K


def _seconds(file_path: str, fallback_us: int) -> float:
    stem = Path(file_path).stem
    return (int(stem) if stem.isdigit() else fallback_us) * 1e-6


def _velocity(value: Any) -> np.ndarray | None:
    """(3,) float64 from an IMU ``velocity_ego`` entry, or None when absent or malformed (the
    frames then carry no ego_velocity; ``source.ego_velocity`` says so)."""
    try:
        velocity = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    return velocity if velocity.shape == (3,) and np.isfinite(velocity).all() else None


def clean_radar(raw: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Valid rows of a raw (N, 8) OmniHD radar array as (M, 7) float32 in ``RADAR_FIELDS`` order,
    with the raw Doppler still in column 3; returns (rows, invalid-flag count, non-finite count)."""
    valid = raw[:, _VALID_COLUMN] != 0
    finite = np.isfinite(raw[:, :4]).all(axis=1)
    return keep_rows(raw, valid, finite, _RAW_INDEX)


def _clip_records(sample_data: list[dict], path: Path, clip: str) -> list[dict]:
    """The sample_data records of ``clip`` in time order."""
    chosen = []
    for record in sample_data:
        owner = record.get("scene_token")
        if owner is None:
            cameras = record.get("cameras")
            camera_file = cameras.get(CAMERA) if isinstance(cameras, dict) else None
            owner = Path(str(camera_file)).parts[0] if camera_file else None
        if str(owner) == clip:
            chosen.append(record)
    for record in chosen:
        token = _key(record, ["token"], path, f"a sample_data record of clip {clip!r}")
        if "timestamp" not in record and not str(token).isdigit():
            raise SceneError(path, f"sample_data {token!r} has no 'timestamp' and its token is not a "
                                   f"microsecond time")
    return sorted(chosen, key=lambda r: int(r.get("timestamp", r["token"])))


def _check_arguments(root: Path, clip: str, start: int, frames: int, width: int, height: int, version: str,
                     lidar: bool, lidar_columns: int) -> Path:
    """The tables' folder, after checking the options and that the root, tables and clip exist."""
    if not root.is_dir():
        raise SceneError(root, "missing folder (the OmniHD-Scenes root)")
    if frames < 1 or start < 0:
        raise ValueError(f"--start must be >= 0 and --frames >= 1, got {start} and {frames}")
    if width < 1 or height < 1:
        raise ValueError(f"--width/--height must be positive, got {width}x{height}")
    if lidar and lidar_columns < 4:
        raise ValueError(f"--lidar-columns must be at least 4 (x, y, z, intensity), got {lidar_columns}")
    tables = root / version
    if not tables.is_dir():
        raise SceneError(tables, f"missing folder (the {version} tables); is {root} the OmniHD-Scenes root?")
    if not (root / clip).is_dir():
        clips = sorted(p.name for p in root.iterdir() if p.is_dir() and p.name.isdigit())
        raise SceneError(root / clip, f"missing clip folder; clips here: {clips[:10]}"
                                      + (" ..." if len(clips) > 10 else ""))
    return tables


def _select_records(sample_data: list[dict], sd_path: Path, clip: str, start: int, frames: int) -> list[dict]:
    """The ``frames`` sample_data records of ``clip`` from index ``start`` in time order."""
    records = _clip_records(sample_data, sd_path, clip)
    if not records:
        raise SceneError(sd_path, f"no sample_data record belongs to clip {clip!r} (by scene_token or "
                                  f"by the camera file's folder)")
    if start + frames > len(records):
        raise SceneError(sd_path, f"clip {clip!r} has {len(records)} frames; --start {start} --frames "
                                  f"{frames} needs frames {start}..{start + frames - 1}")
    return records[start:start + frames]


@dataclass(frozen=True)
class _PoseTable:
    """The ego_pose records of one clip, looked up by a sample_data record's per-sensor token."""

    records: dict[tuple[str, str], dict]
    clip: str
    sd_path: Path
    path: Path

    def __call__(self, record: dict, channel: str) -> tuple[np.ndarray, str]:
        """(4, 4) ego -> global of ``record``'s ``channel`` and its ego_pose token."""
        token = str(_key(record, ["ego_pose", channel], self.sd_path, f"sample_data {record['token']!r}"))
        if (self.clip, token) not in self.records:
            raise SceneError(self.path, f"no record with scene_token {self.clip!r} and token {token!r} "
                                        f"(sample_data {record['token']!r} ego_pose.{channel})")
        where = f"ego_pose {token!r} pose"
        return _matrix4(_key(self.records[(self.clip, token)], ["pose"], self.path, f"ego_pose {token!r}"),
                        self.path, where), token


def _read_calibration(calibration: list[dict], calib_path: Path,
                      clip: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The clip's raw camera matrix (3, 3), OpenCV distortion coefficients (k,), camera -> ego and
    radar -> ego (4, 4)."""
    calib = next((r for r in calibration if str(r.get("token")) == clip), None)
    if calib is None:
        raise SceneError(calib_path, f"no record with token {clip!r} (the clip's calibration)")
    what = f"sensor_calibration {clip!r}"
    K_raw = _intrinsics(_key(calib, ["calib", CAMERA, "intrinsic"], calib_path, what), calib_path,
                        f"calib.{CAMERA}.intrinsic")
    dist = _key(calib, ["calib", CAMERA, "distortion"], calib_path, what)
    try:
        dist = np.asarray(dist, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise SceneError(calib_path, f"calib.{CAMERA}.distortion is not a list of numbers") from None
    if dist.size not in (4, 5, 8, 12, 14):
        raise SceneError(calib_path, f"calib.{CAMERA}.distortion has {dist.size} coefficients; OpenCV takes "
                                     f"4, 5, 8, 12 or 14")
    cam_to_ego = _matrix4(_key(calib, ["calib", CAMERA, "camera2ego"], calib_path, what), calib_path,
                          f"calib.{CAMERA}.camera2ego")
    radar_to_ego = _matrix4(_key(calib, ["calib", RADAR, "radar2ego"], calib_path, what), calib_path,
                            f"calib.{RADAR}.radar2ego")
    return K_raw, dist, cam_to_ego, radar_to_ego


@dataclass
class _ClipFrames:
    """Per converted frame: sensor files, times (s), ego -> global poses (4, 4) and IMU velocity."""

    camera_pose_channel: str
    image_paths: list[Path] = field(default_factory=list)
    radar_paths: list[Path] = field(default_factory=list)
    lidar_paths: list[Path] = field(default_factory=list)
    cam_times: list[float] = field(default_factory=list)
    radar_times: list[float] = field(default_factory=list)
    cam_poses: list[np.ndarray] = field(default_factory=list)
    radar_poses: list[np.ndarray] = field(default_factory=list)
    lidar_poses: list[np.ndarray] = field(default_factory=list)
    velocities: list[np.ndarray | None] = field(default_factory=list)


def _frame_sources(records: list[dict], root: Path, clip: str, sd_path: Path, pose_of: _PoseTable,
                   imu: dict[tuple[str, str], dict], lidar: bool) -> _ClipFrames:
    """Each record's files, times and poses; the files must exist and each sensor's times increase."""
    camera_pose_channel = CAMERA if all(CAMERA in (r.get("ego_pose") or {}) for r in records) else LIDAR
    out = _ClipFrames(camera_pose_channel)
    for record in records:
        what = f"sample_data {record['token']!r}"
        fallback = int(record.get("timestamp", record["token"]))
        image_file = str(_key(record, ["cameras", CAMERA], sd_path, what))
        radar_file = str(_key(record, ["radars", RADAR], sd_path, what))
        out.image_paths.append(root / image_file)
        out.radar_paths.append(root / radar_file)
        out.cam_times.append(_seconds(image_file, fallback))
        out.radar_times.append(_seconds(radar_file, fallback))
        cam_pose, cam_token = pose_of(record, camera_pose_channel)
        out.cam_poses.append(cam_pose)
        out.radar_poses.append(pose_of(record, RADAR)[0])
        out.velocities.append(_velocity(imu.get((clip, cam_token), {}).get("velocity_ego")))
        if lidar:
            out.lidar_paths.append(root / str(_key(record, ["lidar", LIDAR], sd_path,
                                                   f"{what} (pass --no-lidar to convert without LiDAR)")))
            out.lidar_poses.append(pose_of(record, LIDAR)[0])
    for path in out.image_paths:
        if not path.is_file():
            raise SceneError(path, f"missing file (front camera image listed in {sd_path.name})")
    for path in out.lidar_paths:
        if not path.is_file():
            raise SceneError(path, f"missing file (LiDAR scan listed in {sd_path.name}; pass --no-lidar to "
                                   f"convert without LiDAR)")
    for name, stamps in (("camera", out.cam_times), ("radar", out.radar_times)):
        if np.any(np.diff(stamps) <= 0):
            raise SceneError(sd_path, f"{name} times of clip {clip!r} do not increase (file name stems, us)")
    return out


def _scene_frames(clip_frames: _ClipFrames, records: list[dict], start: int, has_velocity: bool,
                  invalid: list[int], nonfinite: list[int]) -> list[Frame]:
    """The scene's frames, in the camera-time ego frame of the first one."""
    origin = clip_frames.cam_poses[0]
    cam_world, radar_world = rebase(clip_frames.cam_poses, origin), rebase(clip_frames.radar_poses, origin)
    return [Frame(name=f"{start + i:06d}", timestamp=clip_frames.cam_times[i], ego_to_world=cam_world[i],
                  radar_timestamp=clip_frames.radar_times[i], radar_ego_to_world=radar_world[i],
                  ego_velocity=clip_frames.velocities[i] if has_velocity else None,
                  extra={"source_token": str(records[i]["token"]), "radar_invalid_dropped": invalid[i],
                         "radar_nonfinite_dropped": nonfinite[i]})
            for i in range(len(records))]


def convert_omnihd(root: str | Path, out: str | Path, clip: str, start: int = 0, frames: int = 50,
                   width: int = 1920, height: int = 1080, version: str = "v1.0-trainval",
                   lidar: bool = True, lidar_columns: int = 5, doppler: DopplerSign = "auto",
                   overwrite: bool = False, progress: bool = True) -> Path:
    """Convert ``frames`` consecutive frames of one OmniHD-Scenes clip, from index ``start`` in the
    clip's time-ordered sample_data, into a scene folder at ``out``; returns ``out``.

    Images are undistorted (OpenCV, alpha = 0) and resized to ``width`` x ``height``; the module
    doc lists the tables and keys read and what is kept and dropped.
    """
    root, out = Path(root), Path(out)
    if out.exists() and not overwrite:  # refused before any reading (and any progress bar)
        raise FileExistsError(f"{out}: already exists (pass --force to overwrite it)")
    tables = _check_arguments(root, clip, start, frames, width, height, version, lidar, lidar_columns)

    sample_data, sd_path = _read_table(tables, "sample_data")
    ego_pose, pose_path = _read_table(tables, "ego_pose")
    calibration, calib_path = _read_table(tables, "sensor_calibration")
    imu_table = _read_table(tables, "imu", "imu_data", required=False)

    records = _select_records(sample_data, sd_path, clip, start, frames)
    pose_of = _PoseTable({(str(r.get("scene_token")), str(r.get("token"))): r for r in ego_pose}, clip, sd_path,
                         pose_path)
    imu = {} if imu_table is None else {(str(r.get("scene_token")), str(r.get("token"))): r for r in imu_table[0]}
    K_raw, dist, cam_to_ego, radar_to_ego = _read_calibration(calibration, calib_path, clip)
    clip_frames = _frame_sources(records, root, clip, sd_path, pose_of, imu, lidar)
    has_velocity = all(v is not None for v in clip_frames.velocities)

    # ---- radar
    scans, invalid, nonfinite = read_radar_scans(clip_frames.radar_paths, RAW_RADAR_COLUMNS,
                                                 "front radar scan, float32 x 8", clean_radar)

    # ---- scene geometry
    image_paths = clip_frames.image_paths
    first = read_first_image(image_paths[0])
    rectifier = ImageRectifier.build(K_raw, dist, (first.shape[1], first.shape[0]), (width, height))
    camera = Camera(width, height, rectifier.K, cam_to_ego)
    radar_spec = RadarSpec(radar_to_ego, RADAR_FIELDS)
    scene_frames = _scene_frames(clip_frames, records, start, has_velocity, invalid, nonfinite)
    sign, sign_report = doppler_sign(scans, scene_frames, camera, radar_spec, clip_frames.radar_paths[0].parent,
                                     doppler)
    apply_doppler_sign(scans, sign, 3)

    source = {
        "dataset": "omnihd-scenes", "clip": clip, "start": start, "frames": frames, "version": version,
        "path": str(root), "sensors": {"camera": CAMERA, "radar": RADAR, "lidar": LIDAR if lidar else None},
        "camera_pose": (f"own ego pose (ego_pose.{CAMERA})" if clip_frames.camera_pose_channel == CAMERA else
                        f"the LiDAR's ego pose (sample_data has no ego_pose.{CAMERA})"),
        "poses": "ego_pose tables (ego -> global), rebased to the camera-time ego frame of the first frame",
        "timestamps": "file name stems, microseconds",
        "images": f"undistorted (OpenCV, getOptimalNewCameraMatrix alpha=0) and resized "
                  f"{first.shape[1]}x{first.shape[0]} -> {width}x{height}",
        "doppler_sign": sign_report,
        "radar_rows": radar_row_counts(scans, invalid, nonfinite, "invalid_dropped"),
        "ego_velocity": ("imu velocity_ego at the camera's pose token" if has_velocity else
                         "not written (no imu table, or a frame without a velocity_ego)"),
    }

    def frame_files(i: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        bgr = first if i == 0 else cv2.imread(str(image_paths[i]), cv2.IMREAD_COLOR)
        optional = {}
        if lidar:
            # Into the ego frame at the camera's time: the scene stores LiDAR in the frame's ego frame.
            lidar_to_cam_ego = np.linalg.inv(clip_frames.cam_poses[i]) @ clip_frames.lidar_poses[i]
            optional["lidar"] = read_lidar_scan(clip_frames.lidar_paths[i], lidar_columns, lidar_to_cam_ego)
        return rectifier(bgr, image_paths[i]), optional

    write_scene(out, f"omnihd-{clip}-{start}", camera, radar_spec, source, scene_frames, scans, frame_files,
                overwrite, progress, "omnihd")
    return out


@dataclass
class ConvertOmnihdCommand:
    """Convert frames of an OmniHD-Scenes clip (front camera, front 4D radar, LiDAR) into a scene folder."""

    # The OmniHD-Scenes root (holding the <clip>/ folders and v1.0-trainval/).
    root: tyro.conf.Positional[Path]
    # The scene folder to write.
    out: tyro.conf.Positional[Path]
    # The clip: its folder name (start time in microseconds).
    clip: str
    # Index of the first frame in the clip's time-ordered sample_data (10 Hz).
    start: int = 0
    # Number of frames to convert.
    frames: int = 50
    # Output image width (pixels), after undistortion.
    width: int = 1920
    # Output image height (pixels), after undistortion.
    height: int = 1080
    # The tables' folder name under ROOT.
    version: str = "v1.0-trainval"
    # Also write lidar/ (the LiDAR in the ego frame).
    lidar: bool = True
    # float32 values per LiDAR point in the .bin files (x, y, z, intensity, ring).
    lidar_columns: int = 5
    # Sign applied to the raw Doppler: auto checks it against the poses with the ego-motion fit.
    doppler_sign: DopplerSign = "auto"
    # Overwrite an existing output folder.
    force: bool = False
    # Hide the progress bar.
    quiet: bool = False

    def run(self) -> int:
        try:
            out = convert_omnihd(self.root, self.out, self.clip, self.start, self.frames, self.width, self.height,
                                 self.version, self.lidar, self.lidar_columns, self.doppler_sign, self.force,
                                 progress=not self.quiet)
        except (SceneError, ValueError, FileExistsError) as exc:
            print(f"radar4dgs convert omnihd: {exc}", file=sys.stderr)
            return 1
        source = json.loads((out / "scene.json").read_text(encoding="utf-8"))["source"]
        rows, sign = source["radar_rows"], source["doppler_sign"]
        print(f"radar: kept {rows['kept']} of {rows['read']} rows; dropped {rows['invalid_dropped']} invalid "
              f"(valid_flag 0) and {rows['nonfinite_dropped']} non-finite; Doppler sign {sign['sign']:+d} "
              f"({'checked against the poses' if sign['checked'] else 'not checked'})")
        print(f"wrote {out}")
        return 0
