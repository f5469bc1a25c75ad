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
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal, Sequence

import cv2
import numpy as np
import tyro
from tqdm import tqdm

from radar4dgs.datasets.convert.aimotive import scaled_intrinsics
from radar4dgs.io.scene import Camera, Frame, RadarSpec, Scene, SceneError, SceneWriter, _rigid
from radar4dgs.radar.config import RadarConfig
from radar4dgs.radar.poses import expected_radar_velocity
from radar4dgs.radar.process import fit_frames

CAMERA = "camera_front"
RADAR = "radar_front"
LIDAR = "lidar_top_compensation"
RAW_RADAR_COLUMNS = 8
RADAR_FIELDS = ("x", "y", "z", "v_r", "power", "snr", "motion_state")
# Raw column index of each stored field (raw: x y z v_r power motion_state SNR valid_flag).
_RAW_INDEX = (0, 1, 2, 3, 4, 6, 5)
_VALID_COLUMN = 7
DopplerSign = Literal["auto", "+1", "-1"]
# The sign check needs motion: below this speed (m/s) the Doppler of static points is noise.
SIGN_MIN_SPEED = 1.0
# The Doppler fit and the poses must point the same way (or exactly opposite) within ~60 deg.
SIGN_MIN_COSINE = 0.5


# --------------------------------------------------------------------------------------------
# Helpers shared with the View-of-Delft converter


@dataclass(frozen=True)
class ImageRectifier:
    """Undistorts (OpenCV) and resizes the images of one camera.

    ``K`` (3, 3) is the camera matrix of the output images. Undistortion maps to the matrix of
    ``getOptimalNewCameraMatrix`` with alpha = 0 (every output pixel valid, no black borders); it
    is skipped when every distortion coefficient is zero.
    """

    size_in: tuple[int, int]
    size_out: tuple[int, int]
    K: np.ndarray
    maps: tuple[np.ndarray, np.ndarray] | None

    @classmethod
    def build(cls, K: np.ndarray, distortion: Sequence[float] | None, size_in: tuple[int, int],
              size_out: tuple[int, int] | None = None) -> "ImageRectifier":
        """``K`` (3, 3) of the raw images, ``size_in``/``size_out`` (width, height); ``size_out``
        None keeps the size."""
        K = np.asarray(K, dtype=np.float64)
        dist = np.zeros(5) if distortion is None else np.asarray(distortion, dtype=np.float64).ravel()
        size_out = tuple(size_out or size_in)
        maps = None
        K_und = K
        if np.any(dist != 0):
            K_und, _ = cv2.getOptimalNewCameraMatrix(K, dist, size_in, alpha=0)
            maps = cv2.initUndistortRectifyMap(K, dist, None, K_und, size_in, cv2.CV_32FC1)
        K_out = scaled_intrinsics(K_und, size_out[0] / size_in[0], size_out[1] / size_in[1])
        return cls(tuple(size_in), size_out, K_out, maps)

    def __call__(self, bgr: np.ndarray | None, path: Path) -> np.ndarray:
        """(H, W, 3) uint8 RGB output image from a raw (H_in, W_in, 3) BGR image read from ``path``."""
        if bgr is None:
            raise SceneError(path, "unreadable image")
        if (bgr.shape[1], bgr.shape[0]) != self.size_in:
            raise SceneError(path, f"image is {bgr.shape[1]}x{bgr.shape[0]}, the first converted image is "
                                   f"{self.size_in[0]}x{self.size_in[1]}")
        if self.maps is not None:
            bgr = cv2.remap(bgr, self.maps[0], self.maps[1], cv2.INTER_LINEAR)
        if self.size_out != self.size_in:
            shrink = self.size_out[0] * self.size_out[1] < self.size_in[0] * self.size_in[1]
            bgr = cv2.resize(bgr, self.size_out, interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
        return np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))


def doppler_sign(scans: Sequence[np.ndarray], frames: Sequence[Frame], camera: Camera, radar: RadarSpec,
                 where: Path, mode: DopplerSign = "auto", config: RadarConfig | None = None) -> tuple[int, dict]:
    """The factor (+1 or -1) that turns a dataset's raw Doppler into ``v_r`` (positive = receding),
    and a JSON-ready report of the evidence.

    ``scans`` are (N, >=4) arrays whose first four columns are x, y, z (radar frame) and the raw
    Doppler; ``frames`` carry the poses (``radar_ego_to_world`` at ``radar_timestamp``). ``auto``
    fits the radar's velocity to each scan (RANSAC, :func:`radar4dgs.radar.process.fit_frames`)
    and compares it with the velocity the poses imply
    (:func:`radar4dgs.radar.poses.expected_radar_velocity`): a static point seen from a radar
    moving at ``v_s`` has ``v_r = -d . v_s``, so with the wrong sign the fit points backwards.
    Frames slower than 1 m/s are not used; with none left the sign stays +1 and the report says
    it was not checked. A median cosine between -0.5 and 0.5 means the Doppler and the poses do
    not agree in either sign: a :class:`SceneError` naming ``where``.
    """
    if mode != "auto":
        return int(mode), {"mode": mode, "checked": False, "sign": int(mode)}
    # Only the poses are evidence: an IMU velocity of unknown convention would beg the question.
    pose_frames = tuple(replace(f, ego_velocity=None) for f in frames)
    expected, source = expected_radar_velocity(Scene(where, "doppler-check", camera, radar, pose_frames))
    if expected is None:
        return 1, {"mode": "auto", "checked": False, "sign": 1, "reason": source}
    config = config or RadarConfig()
    fits = fit_frames([(s[:, :3].astype(np.float64), s[:, 3].astype(np.float64)) for s in scans], config,
                      radar_to_ego=radar.radar_to_ego)
    cosines = []
    for fit, v_pose in zip(fits, expected):
        speed = float(np.linalg.norm(v_pose))
        if fit.ok and not fit.standstill and speed > SIGN_MIN_SPEED and fit.speed > SIGN_MIN_SPEED:
            cosines.append(float(fit.velocity @ v_pose) / (fit.speed * speed))
    if not cosines:
        return 1, {"mode": "auto", "checked": False, "sign": 1,
                   "reason": f"no frame where the poses and the Doppler fit both move faster than "
                             f"{SIGN_MIN_SPEED} m/s"}
    median = float(np.median(cosines))
    if abs(median) < SIGN_MIN_COSINE:
        raise SceneError(where, f"the radar's Doppler ego-motion and the poses disagree in either sign "
                                f"(median cosine {median:.2f} over {len(cosines)} frames); check the radar "
                                f"extrinsics and the poses, or force --doppler-sign +1/-1")
    sign = 1 if median > 0 else -1
    return sign, {"mode": "auto", "checked": True, "sign": sign, "frames_used": len(cosines),
                  "median_cosine_raw": round(median, 4), "pose_source": source,
                  "method": "RANSAC radar velocity vs pose finite differences; v_r = -d . v_s"}


def rebase(poses: Sequence[np.ndarray], origin: np.ndarray) -> list[np.ndarray]:
    """(4, 4) poses expressed relative to ``origin`` (4, 4): the world becomes ``origin``'s frame."""
    inverse = np.linalg.inv(origin)
    return [inverse @ p for p in poses]


def read_float32_bin(path: Path, columns: int, what: str) -> np.ndarray:
    """(N, columns) float32 rows of a raw little-endian float32 file."""
    if not path.is_file():
        raise SceneError(path, f"missing file ({what})")
    data = np.fromfile(path, dtype="<f4")
    if data.size % columns:
        raise SceneError(path, f"{data.size} float32 values is not a whole number of {columns}-float "
                               f"rows ({what})")
    return data.reshape(-1, columns)


def transform_points(transform: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """(N, 3) points mapped by a (4, 4) transform."""
    return np.asarray(xyz, dtype=np.float64) @ transform[:3, :3].T + transform[:3, 3]


# --------------------------------------------------------------------------------------------
# OmniHD-Scenes


def _read_table(tables: Path, *names: str, required: bool = True) -> tuple[list[dict], Path] | None:
    for name in names:
        path = tables / f"{name}.json"
        if path.is_file():
            try:
                rows = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
                raise SceneError(path, f"unreadable JSON ({exc})") from exc
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
    return _rigid(matrix, where, path)


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
    keep = valid & finite
    return (np.ascontiguousarray(raw[keep][:, _RAW_INDEX], dtype=np.float32), int((~valid).sum()),
            int((valid & ~finite).sum()))


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

    sample_data, sd_path = _read_table(tables, "sample_data")
    ego_pose, pose_path = _read_table(tables, "ego_pose")
    calibration, calib_path = _read_table(tables, "sensor_calibration")
    imu_table = _read_table(tables, "imu", "imu_data", required=False)

    records = _clip_records(sample_data, sd_path, clip)
    if not records:
        raise SceneError(sd_path, f"no sample_data record belongs to clip {clip!r} (by scene_token or "
                                  f"by the camera file's folder)")
    if start + frames > len(records):
        raise SceneError(sd_path, f"clip {clip!r} has {len(records)} frames; --start {start} --frames "
                                  f"{frames} needs frames {start}..{start + frames - 1}")
    records = records[start:start + frames]

    poses = {(str(r.get("scene_token")), str(r.get("token"))): r for r in ego_pose}
    imu = {} if imu_table is None else {(str(r.get("scene_token")), str(r.get("token"))): r for r in imu_table[0]}

    def pose_of(record: dict, channel: str) -> tuple[np.ndarray, str]:
        token = str(_key(record, ["ego_pose", channel], sd_path, f"sample_data {record['token']!r}"))
        if (clip, token) not in poses:
            raise SceneError(pose_path, f"no record with scene_token {clip!r} and token {token!r} "
                                        f"(sample_data {record['token']!r} ego_pose.{channel})")
        where = f"ego_pose {token!r} pose"
        return _matrix4(_key(poses[(clip, token)], ["pose"], pose_path, f"ego_pose {token!r}"), pose_path,
                        where), token

    # ---- calibration
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

    # ---- per-frame files, times and poses
    camera_pose_channel = CAMERA if all(CAMERA in (r.get("ego_pose") or {}) for r in records) else LIDAR
    image_paths, radar_paths, lidar_paths = [], [], []
    cam_times, radar_times, cam_poses, radar_poses, lidar_poses, velocities = [], [], [], [], [], []
    for record in records:
        what = f"sample_data {record['token']!r}"
        fallback = int(record.get("timestamp", record["token"]))
        image_file = str(_key(record, ["cameras", CAMERA], sd_path, what))
        radar_file = str(_key(record, ["radars", RADAR], sd_path, what))
        image_paths.append(root / image_file)
        radar_paths.append(root / radar_file)
        cam_times.append(_seconds(image_file, fallback))
        radar_times.append(_seconds(radar_file, fallback))
        cam_pose, cam_token = pose_of(record, camera_pose_channel)
        cam_poses.append(cam_pose)
        radar_poses.append(pose_of(record, RADAR)[0])
        velocities.append(_velocity(imu.get((clip, cam_token), {}).get("velocity_ego")))
        if lidar:
            lidar_paths.append(root / str(_key(record, ["lidar", LIDAR], sd_path,
                                               f"{what} (pass --no-lidar to convert without LiDAR)")))
            lidar_poses.append(pose_of(record, LIDAR)[0])
    for path in image_paths:
        if not path.is_file():
            raise SceneError(path, f"missing file (front camera image listed in {sd_path.name})")
    for path in lidar_paths:
        if not path.is_file():
            raise SceneError(path, f"missing file (LiDAR scan listed in {sd_path.name}; pass --no-lidar to "
                                   f"convert without LiDAR)")
    for name, stamps in (("camera", cam_times), ("radar", radar_times)):
        if np.any(np.diff(stamps) <= 0):
            raise SceneError(sd_path, f"{name} times of clip {clip!r} do not increase (file name stems, us)")
    has_velocity = all(v is not None for v in velocities)

    # ---- radar
    scans, invalid, nonfinite = [], [], []
    for path in radar_paths:
        rows, n_invalid, n_nonfinite = clean_radar(read_float32_bin(path, RAW_RADAR_COLUMNS,
                                                                   "front radar scan, float32 x 8"))
        scans.append(rows)
        invalid.append(n_invalid)
        nonfinite.append(n_nonfinite)

    # ---- scene geometry
    first = cv2.imread(str(image_paths[0]), cv2.IMREAD_COLOR)
    if first is None:
        raise SceneError(image_paths[0], "unreadable image")
    rectifier = ImageRectifier.build(K_raw, dist, (first.shape[1], first.shape[0]), (width, height))
    camera = Camera(width, height, rectifier.K, cam_to_ego)
    radar_spec = RadarSpec(radar_to_ego, RADAR_FIELDS)
    origin = cam_poses[0]
    cam_world, radar_world = rebase(cam_poses, origin), rebase(radar_poses, origin)
    scene_frames = [Frame(name=f"{start + i:06d}", timestamp=cam_times[i], ego_to_world=cam_world[i],
                          radar_timestamp=radar_times[i], radar_ego_to_world=radar_world[i],
                          ego_velocity=velocities[i] if has_velocity else None,
                          extra={"source_token": str(records[i]["token"]), "radar_invalid_dropped": invalid[i],
                                 "radar_nonfinite_dropped": nonfinite[i]})
                    for i in range(len(records))]
    sign, sign_report = doppler_sign(scans, scene_frames, camera, radar_spec, radar_paths[0].parent, doppler)
    for scan in scans:
        scan[:, 3] *= sign

    source = {
        "dataset": "omnihd-scenes", "clip": clip, "start": start, "frames": frames, "version": version,
        "path": str(root), "sensors": {"camera": CAMERA, "radar": RADAR, "lidar": LIDAR if lidar else None},
        "camera_pose": (f"own ego pose (ego_pose.{CAMERA})" if camera_pose_channel == CAMERA else
                        f"the LiDAR's ego pose (sample_data has no ego_pose.{CAMERA})"),
        "poses": "ego_pose tables (ego -> global), rebased to the camera-time ego frame of the first frame",
        "timestamps": "file name stems, microseconds",
        "images": f"undistorted (OpenCV, getOptimalNewCameraMatrix alpha=0) and resized "
                  f"{first.shape[1]}x{first.shape[0]} -> {width}x{height}",
        "doppler_sign": sign_report,
        "radar_rows": {"read": int(sum(len(s) for s in scans) + sum(invalid) + sum(nonfinite)),
                       "kept": int(sum(len(s) for s in scans)), "invalid_dropped": int(sum(invalid)),
                       "nonfinite_dropped": int(sum(nonfinite))},
        "ego_velocity": ("imu velocity_ego at the camera's pose token" if has_velocity else
                         "not written (no imu table, or a frame without a velocity_ego)"),
    }

    with SceneWriter(out, overwrite=overwrite) as writer:
        for i in tqdm(range(len(records)), desc="omnihd", unit="frame", disable=not progress):
            bgr = first if i == 0 else cv2.imread(str(image_paths[i]), cv2.IMREAD_COLOR)
            optional = {}
            if lidar:
                points = read_float32_bin(lidar_paths[i], lidar_columns, f"LiDAR scan, float32 x {lidar_columns}")
                # Into the ego frame at the camera's time: the scene stores LiDAR in the frame's ego frame.
                lidar_to_cam_ego = np.linalg.inv(cam_poses[i]) @ lidar_poses[i]
                xyz = transform_points(lidar_to_cam_ego, points[:, :3])
                optional["lidar"] = np.column_stack([xyz, points[:, 3]]).astype(np.float32)
            writer.add_frame(scene_frames[i], rectifier(bgr, image_paths[i]), scans[i], **optional)
        writer.finish(f"omnihd-{clip}-{start}", camera, radar_spec, source=source)
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
    # Replace an existing output folder.
    overwrite: bool = False
    # Hide the progress bar.
    quiet: bool = False

    def run(self) -> int:
        try:
            out = convert_omnihd(self.root, self.out, self.clip, self.start, self.frames, self.width, self.height,
                                 self.version, self.lidar, self.lidar_columns, self.doppler_sign, self.overwrite,
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
