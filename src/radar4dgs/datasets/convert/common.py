"""Steps the dataset converters share: undistorting and resizing images, reading raw float32 sensor
files, keeping the usable radar rows, checking the Doppler sign against the poses, re-basing poses,
and writing the scene folder frame by frame.

Only computations that are the same in every converter that uses them live here; each converter
keeps its own layout reading, calibration and conventions.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Literal, Sequence

import cv2
import numpy as np
from tqdm import tqdm

from radar4dgs.io.scene import Camera, Frame, RadarSpec, Scene, SceneError, SceneWriter
from radar4dgs.radar.config import RadarConfig
from radar4dgs.radar.poses import expected_radar_velocity
from radar4dgs.radar.process import fit_frames

DopplerSign = Literal["auto", "+1", "-1"]
# The sign check needs motion: below this speed (m/s) the Doppler of static points is noise.
SIGN_MIN_SPEED = 1.0
# The Doppler fit and the poses must point the same way (or exactly opposite) within ~60 deg.
SIGN_MIN_COSINE = 0.5


# --------------------------------------------------------------------------------------------
# Images


def scaled_intrinsics(K: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """K for an image resized by ``sx`` x ``sy`` (pixel centres at integer coordinates)."""
    out = K.copy()
    out[0, 0] *= sx
    out[1, 1] *= sy
    out[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    out[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return out


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


def read_first_image(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 BGR image at ``path``: the first frame's, which fixes the input size."""
    first = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if first is None:
        raise SceneError(path, "unreadable image")
    return first


# --------------------------------------------------------------------------------------------
# Raw sensor files and radar rows


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


def read_lidar_scan(path: Path, columns: int, to_ego: np.ndarray) -> np.ndarray:
    """(N, 4) float32 [x, y, z, intensity] in the ego frame from a raw float32 x ``columns`` LiDAR
    file whose first four columns are x, y, z (sensor frame) and intensity; ``to_ego`` (4, 4)."""
    points = read_float32_bin(path, columns, f"LiDAR scan, float32 x {columns}")
    xyz = transform_points(to_ego, points[:, :3])
    return np.column_stack([xyz, points[:, 3]]).astype(np.float32)


def keep_rows(raw: np.ndarray, usable: np.ndarray, finite: np.ndarray,
              order: Sequence[int]) -> tuple[np.ndarray, int, int]:
    """Rows of ``raw`` (N, C) that are ``usable`` and ``finite`` (both (N,) bool), as (M, len(order))
    float32 with the raw columns in ``order``; returns (rows, unusable count, usable but
    non-finite count)."""
    keep = usable & finite
    return (np.ascontiguousarray(raw[keep][:, order], dtype=np.float32), int((~usable).sum()),
            int((usable & ~finite).sum()))


def read_radar_scans(paths: Sequence[Path], columns: int, what: str,
                     clean: Callable[[np.ndarray], tuple[np.ndarray, int, int]]
                     ) -> tuple[list[np.ndarray], list[int], list[int]]:
    """Each raw float32 x ``columns`` radar file passed through ``clean`` (raw rows -> (kept rows,
    dropped count, non-finite count)); returns the three per-file lists."""
    scans, dropped, nonfinite = [], [], []
    for path in paths:
        rows, n_dropped, n_nonfinite = clean(read_float32_bin(path, columns, what))
        scans.append(rows)
        dropped.append(n_dropped)
        nonfinite.append(n_nonfinite)
    return scans, dropped, nonfinite


def radar_row_counts(scans: Sequence[np.ndarray], dropped: Sequence[int], nonfinite: Sequence[int],
                     dropped_key: str) -> dict[str, int]:
    """``source.radar_rows``: rows read, kept, dropped (under ``dropped_key``) and non-finite."""
    kept = int(sum(len(s) for s in scans))
    return {"read": kept + int(sum(dropped) + sum(nonfinite)), "kept": kept, dropped_key: int(sum(dropped)),
            "nonfinite_dropped": int(sum(nonfinite))}


# --------------------------------------------------------------------------------------------
# Doppler and poses


def fit_scans(scans: Sequence[np.ndarray], config: RadarConfig, radar_to_ego: np.ndarray) -> list:
    """The radar ego-motion fit (:func:`radar4dgs.radar.process.fit_frames`) of each (N, >=4) scan
    whose first four columns are x, y, z (radar frame) and the Doppler."""
    return fit_frames([(s[:, :3].astype(np.float64), s[:, 3].astype(np.float64)) for s in scans], config,
                      radar_to_ego=radar_to_ego)


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
    fits = fit_scans(scans, config, radar.radar_to_ego)
    cosines = []
    for fit, v_pose in zip(fits, expected, strict=True):
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


def apply_doppler_sign(scans: Sequence[np.ndarray], sign: int, columns: Any) -> None:
    """Multiplies the Doppler ``columns`` (an index or a list of them) of every scan by ``sign``, in place."""
    for scan in scans:
        scan[:, columns] *= sign


def rebase(poses: Sequence[np.ndarray], origin: np.ndarray) -> list[np.ndarray]:
    """(4, 4) poses expressed relative to ``origin`` (4, 4): the world becomes ``origin``'s frame."""
    inverse = np.linalg.inv(origin)
    return [inverse @ p for p in poses]


# --------------------------------------------------------------------------------------------
# Writing


def write_scene(out: Path, name: str, camera: Camera, radar: RadarSpec, source: dict, frames: Sequence[Frame],
                scans: Sequence[np.ndarray], frame_files: Callable[[int], tuple[np.ndarray, dict[str, np.ndarray]]],
                overwrite: bool, progress: bool, desc: str) -> None:
    """Writes the scene folder ``out`` (atomically, :class:`radar4dgs.io.scene.SceneWriter`).

    Frame ``i`` is ``frames[i]`` with radar ``scans[i]``; ``frame_files(i)`` returns its (H, W, 3)
    uint8 RGB image and its optional per-frame arrays (``SceneWriter.add_frame`` keywords), and is
    called once per frame, in order, so a converter can read each frame's files only then.
    """
    with SceneWriter(out, overwrite=overwrite) as writer:
        for i in tqdm(range(len(frames)), desc=desc, unit="frame", disable=not progress):
            image, optional = frame_files(i)
            writer.add_frame(frames[i], image, scans[i], **optional)
        writer.finish(name, camera, radar, source=source)
