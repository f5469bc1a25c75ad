"""Converter for a frame range of the View-of-Delft (VoD) dataset (camera + 3+1D radar) into a scene folder.

Expected layout (``ROOT``, the dataset as distributed, KITTI style)::

    ROOT/
      radar/training/
        image_2/<frame>.jpg       rectified left camera image
        velodyne/<frame>.bin      RADAR scan (VoD keeps the KITTI folder name): float32 x 7
                                  [x, y, z, RCS, v_r, v_r_compensated, time], radar frame
        calib/<frame>.txt         KITTI calib: P2 (3x4), Tr_velo_to_cam (3x4, radar -> camera),
                                  R0_rect (3x3, optional, identity in VoD)
        pose/<frame>.json         three JSON objects on three lines: odomToCamera, mapToCamera,
                                  UTMToCamera, each 16 floats row-major, camera -> that world
      lidar/training/             optional; used when every frame has velodyne/<frame>.bin
        velodyne/<frame>.bin      (float32 x 4: x y z reflectance, LiDAR frame) and calib/<frame>.txt
        calib/<frame>.txt         (Tr_velo_to_cam: LiDAR -> camera)

``<frame>`` is a global 5-digit number; a recording sequence is a run of consecutive numbers, and
the odometry restarts at each sequence's start. ``--frames A:B`` takes frames A .. B-1 (a Python
slice) and is refused when it crosses two sequences: a missing frame number inside the range, or
an odometry jump between consecutive frames (:func:`sequence_breaks`: a step beyond ``max_speed``,
a turn beyond ``MAX_TURN_PER_FRAME``, or a step unlike both neighbouring steps), named in the error.

Conventions chosen here:

* Ego frame = the radar frame (x forward, y left, z up, behind the front bumper): VoD has no
  vehicle frame, and the radar's axes are the car's closest to the scene convention's.
  ``radar_to_ego`` is the identity, ``cam_to_ego`` the inverse of radar -> camera 2.
* Poses: ``odomToCamera`` (camera -> odometry world) composed with the calibration; the world is
  re-based on the first converted frame's ego frame.
* Times: VoD frames follow the LiDAR at ~10 Hz and its KITTI files carry no time stamps, so frame
  ``n`` is at ``n * frame_period`` s. Radar and image are already synchronised and motion
  compensated to the camera, so ``radar_timestamp`` and ``radar_ego_to_world`` equal the camera's.
* ``v_r`` is the dataset's relative radial velocity with its sign checked against the poses
  (:func:`radar4dgs.datasets.convert.common.doppler_sign`); ``v_r_comp`` (the dataset's
  ego-motion-compensated radial velocity, same sign applied) and ``rcs`` are extra columns.

Dropped: radar rows from older scans (``time`` != 0, only in accumulated-scan folders) and rows
with NaN/inf in x, y, z or v_r (counted per frame and in ``source.radar_rows``), the ``time``
column, the labels, mapToCamera and UTMToCamera.
"""

from __future__ import annotations

import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, Optional

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
from radar4dgs.io.scene import Camera, Frame, RadarSpec, SceneError

RAW_RADAR_COLUMNS = 7
RADAR_FIELDS = ("x", "y", "z", "v_r", "rcs", "v_r_comp")
# Raw columns x y z RCS v_r v_r_compensated time -> RADAR_FIELDS order.
_RAW_INDEX = (0, 1, 2, 4, 3, 5)
_TIME_COLUMN = 6
POSE_KEY = "odomToCamera"
# Consecutive frames 0.1 s apart that turn more than this (rad, ~29 deg) are not one drive.
MAX_TURN_PER_FRAME = 0.5
# Metres added to max_speed * dt before a translation counts as a jump (odometry noise, dt jitter).
JUMP_SLACK = 0.5
# A step differing from both neighbouring steps by more than SLACK (m) + FRACTION x the longer
# step is a restart. The fraction absorbs pose-time jitter (poses are the nearest odometry message,
# up to ~1/60 s off: 0.25 m at 15 m/s); the slack absorbs odometry noise at standstill.
STEP_CHANGE_SLACK = 0.5
STEP_CHANGE_FRACTION = 0.5
# Calibration rotations are printed with ~8 digits; larger departures from a rotation are errors.
CALIB_ORTHONORMAL_TOLERANCE = 1e-3


def parse_range(text: str) -> tuple[int, int]:
    """``"A:B"`` -> (A, B), frames A .. B-1; A and B as plain or zero-padded integers."""
    match = re.fullmatch(r"\s*(\d+)\s*:\s*(\d+)\s*", text)
    if not match:
        raise ValueError(f"--frames must be A:B (frames A .. B-1, e.g. 00100:00150), got {text!r}")
    a, b = int(match.group(1)), int(match.group(2))
    if b <= a:
        raise ValueError(f"--frames {text}: the end must be after the start (frames A .. B-1)")
    return a, b


def read_calib(path: Path) -> dict[str, np.ndarray]:
    """KITTI calib file -> {key: (k,) float64 values}; keys with no values are left out."""
    if not path.is_file():
        raise SceneError(path, "missing file (KITTI calibration)")
    values: dict[str, np.ndarray] = {}
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip():
            continue
        key, sep, rest = line.partition(":")
        if not sep:
            raise SceneError(path, f"line {number} is not 'KEY: values'")
        try:
            numbers = np.array([float(v) for v in rest.split()])
        except ValueError:
            raise SceneError(path, f"line {number} ({key.strip()}) holds a value that is not a number") from None
        if numbers.size:
            values[key.strip()] = numbers
    return values


def _calib_matrix(calib: dict[str, np.ndarray], key: str, shape: tuple[int, int], path: Path,
                  required: bool = True) -> np.ndarray | None:
    if key not in calib:
        if required:
            raise SceneError(path, f"no '{key}' line")
        return None
    if calib[key].size != shape[0] * shape[1]:
        raise SceneError(path, f"'{key}' has {calib[key].size} values, expected {shape[0] * shape[1]}")
    return calib[key].reshape(shape)


def _rotation(R: np.ndarray, path: Path, key: str) -> np.ndarray:
    """The nearest rotation to ``R`` (3, 3); refuses a matrix that is not nearly one."""
    error = np.abs(R.T @ R - np.eye(3)).max()
    if error > CALIB_ORTHONORMAL_TOLERANCE or np.linalg.det(R) <= 0:
        raise SceneError(path, f"'{key}' rotation is not orthonormal (max |R^T R - I| = {error:.1e})")
    u, _, vt = np.linalg.svd(R)
    return u @ vt


def sensor_to_camera(calib: dict[str, np.ndarray], path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(3, 3) K of image_2, (4, 4) rectified reference camera -> image_2 camera, and (4, 4) sensor
    (the calib's "velo") -> image_2 camera; OpenCV axes.

    KITTI projects ``x = P2 R0_rect Tr_velo_to_cam X``; ``P2 = K [I | t]`` with ``t = K^-1 P2[:, 3]``
    the offset of camera 2 from the rectified reference camera (zero in VoD, where the pose files'
    camera is the image's camera).
    """
    P2 = _calib_matrix(calib, "P2", (3, 4), path)
    K = P2[:, :3].copy()
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0.0, 0.0, 1.0]):
        raise SceneError(path, "'P2' does not start with a camera matrix (positive focal lengths, last row 0 0 1)")
    reference_to_cam = np.eye(4)
    reference_to_cam[:3, 3] = np.linalg.solve(K, P2[:, 3])
    rect = np.eye(4)
    R0 = _calib_matrix(calib, "R0_rect", (3, 3), path, required=False)
    if R0 is not None:
        rect[:3, :3] = _rotation(R0, path, "R0_rect")
    tr = np.eye(4)
    tr[:3, :] = _calib_matrix(calib, "Tr_velo_to_cam", (3, 4), path)
    tr[:3, :3] = _rotation(tr[:3, :3], path, "Tr_velo_to_cam")
    return K, reference_to_cam, reference_to_cam @ rect @ tr


def read_pose(path: Path, key: str = POSE_KEY) -> np.ndarray:
    """(4, 4) camera -> world of ``key`` from a VoD pose file (one JSON object per line)."""
    if not path.is_file():
        raise SceneError(path, "missing file (odometry pose)")
    merged: dict = {}
    try:
        text = path.read_text(encoding="utf-8")
        for line in text.splitlines():
            if line.strip():
                obj = json.loads(line)
                if not isinstance(obj, dict):
                    raise SceneError(path, "a line is not a JSON object")
                merged.update(obj)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SceneError(path, f"unreadable pose file, expected one JSON object per line ({exc})") from exc
    if key not in merged:
        raise SceneError(path, f"no '{key}' (found {sorted(merged)})")
    try:
        matrix = np.asarray(merged[key], dtype=np.float64).reshape(4, 4)
    except (TypeError, ValueError):
        raise SceneError(path, f"'{key}' is not 16 numbers (row-major 4x4)") from None
    if not np.isfinite(matrix).all():
        raise SceneError(path, f"'{key}' holds NaN or inf")
    matrix[:3, :3] = _rotation(matrix[:3, :3], path, key)
    return matrix


def sequence_breaks(names: list[str], camera_to_world: list[np.ndarray], frame_period: float,
                    max_speed: float) -> list[tuple[str, str, str]]:
    """(frame, next frame, why) for each consecutive pair whose odometry jumps. ``camera_to_world``
    (4, 4) per frame.

    A pair breaks when its step is longer than ``max_speed * dt + JUMP_SLACK``, when it turns more
    than ``MAX_TURN_PER_FRAME``, or when its step vector differs from every other step within two
    steps of it by more than ``STEP_CHANGE_SLACK + STEP_CHANGE_FRACTION * the longer step``: the
    odometry restarts at each sequence's origin, so a short sequence can end near it and jump back
    by less than the speed limit, but not by a step its neighbours share. Comparing with several
    neighbours pins the break on the one odd step (with only two steps in the range, both look
    odd and the first is named); steps of a turning or braking car change smoothly.
    """
    positions = np.array([T[:3, 3] for T in camera_to_world])
    steps = np.diff(positions, axis=0)
    limit = max_speed * frame_period + JUMP_SLACK

    def odd_against(i: int, j: int) -> bool:
        longer = max(np.linalg.norm(steps[i]), np.linalg.norm(steps[j]))
        return bool(np.linalg.norm(steps[i] - steps[j]) > STEP_CHANGE_SLACK + STEP_CHANGE_FRACTION * longer)

    breaks = []
    for i in range(len(steps)):
        a, b = camera_to_world[i], camera_to_world[i + 1]
        step = float(np.linalg.norm(steps[i]))
        turn = float(np.arccos(np.clip((np.trace(a[:3, :3].T @ b[:3, :3]) - 1) / 2, -1.0, 1.0)))
        neighbours = [j for j in range(i - 2, i + 3) if j != i and 0 <= j < len(steps)]
        if step > limit:
            why = f"the odometry jumps {step:.1f} m in one frame (at most {limit:.1f} m at {max_speed:g} m/s)"
        elif turn > MAX_TURN_PER_FRAME:
            why = (f"the odometry turns {np.degrees(turn):.0f} deg in one frame (at most "
                   f"{np.degrees(MAX_TURN_PER_FRAME):.0f})")
        elif neighbours and all(odd_against(i, j) for j in neighbours):
            change = min(float(np.linalg.norm(steps[i] - steps[j])) for j in neighbours)
            why = f"the odometry step differs by {change:.1f} m or more from the neighbouring frames' steps"
        else:
            continue
        breaks.append((names[i], names[i + 1], why))
    return breaks


def _available(folder: Path, suffix: str) -> set[int]:
    return {int(p.stem) for p in folder.iterdir() if p.suffix == suffix and p.stem.isdigit()}


def _spans(numbers: list[int]) -> str:
    """"00000-00543, 00600-00700" for sorted numbers (runs of consecutive numbers)."""
    if not numbers:
        return "none"
    runs, first = [], numbers[0]
    for prev, cur in zip(numbers, numbers[1:] + [None], strict=True):
        if cur is None or cur != prev + 1:
            runs.append(f"{first:05d}-{prev:05d}" if prev != first else f"{first:05d}")
            first = cur
    return ", ".join(runs[:8]) + (" ..." if len(runs) > 8 else "")


def clean_radar(raw: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Current-scan, finite rows of a raw (N, 7) VoD radar array as (M, 6) float32 in
    ``RADAR_FIELDS`` order (Doppler columns still in the dataset's sign); returns (rows, rows of
    older scans, non-finite rows)."""
    current = raw[:, _TIME_COLUMN] == 0
    finite = np.isfinite(raw[:, [0, 1, 2, 4]]).all(axis=1)
    return keep_rows(raw, current, finite, _RAW_INDEX)


def _check_arguments(root: Path, frames: str, width: int | None, height: int | None, frame_period: float,
                     max_speed: float) -> tuple[int, int, dict[str, Path]]:
    """The frame range (A, B) and the radar/training folders, after checking the options and the layout."""
    first_number, end_number = parse_range(frames)
    if (width is None) != (height is None):
        raise ValueError("give both --width and --height, or neither (keep the image size)")
    if width is not None and (width < 1 or height < 1):
        raise ValueError(f"--width/--height must be positive, got {width}x{height}")
    if frame_period <= 0 or max_speed <= 0:
        raise ValueError("--frame-period and --max-speed must be positive")
    if not root.is_dir():
        raise SceneError(root, "missing folder (the View-of-Delft root holding radar/)")
    base = root / "radar" / "training"
    folders = {name: base / name for name in ("image_2", "velodyne", "calib", "pose")}
    for name, folder in folders.items():
        if not folder.is_dir():
            raise SceneError(folder, f"missing folder (VoD radar/training/{name}); is {root} the View-of-Delft root?")
    return first_number, end_number, folders


def _frame_numbers(velodyne: Path, first_number: int, end_number: int, frames: str) -> list[int]:
    """Frame numbers A .. B-1; each must have a radar scan (a gap separates two sequences)."""
    numbers = list(range(first_number, end_number))
    available = _available(velodyne, ".bin")
    missing = [n for n in numbers if n not in available]
    if len(missing) == len(numbers):
        raise SceneError(velodyne, f"no radar scans for frames {first_number:05d}..{end_number - 1:05d}; "
                                   f"frames here: {_spans(sorted(available))}")
    if missing:
        raise SceneError(velodyne, f"frames {', '.join(f'{n:05d}' for n in missing[:10])} are missing "
                                   f"inside --frames {frames}: a gap in the numbering separates two "
                                   f"sequences (frames here: {_spans(sorted(available))}); choose a "
                                   f"range inside one sequence")
    return numbers


def _image_paths(image_dir: Path, names: list[str]) -> list[Path]:
    """Each frame's camera image, .jpg or .png."""
    image_paths = []
    for name in names:
        candidates = [image_dir / f"{name}{s}" for s in (".jpg", ".png")]
        found = next((p for p in candidates if p.is_file()), None)
        if found is None:
            raise SceneError(candidates[0], "missing file (camera image, .jpg or .png)")
        image_paths.append(found)
    return image_paths


def _camera_poses(pose_dir: Path, names: list[str], frames: str, frame_period: float,
                  max_speed: float) -> list[np.ndarray]:
    """(4, 4) camera -> odometry world per frame; refuses a range whose odometry restarts."""
    camera_to_world = [read_pose(pose_dir / f"{name}.json") for name in names]
    breaks = sequence_breaks(names, camera_to_world, frame_period, max_speed)
    if breaks:
        a, b, why = breaks[0]
        raise SceneError(pose_dir, f"--frames {frames} crosses two sequences between frames {a} and {b}: "
                                   f"{why}; choose a range inside one sequence")
    return camera_to_world


def _read_rig(calib_dir: Path, names: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """K (3, 3), reference camera -> camera 2 and radar -> camera 2 (4, 4) of the first frame's
    calibration; every other frame's must agree."""
    # Per frame in VoD; one rig, so every frame must agree.
    calib_paths = [calib_dir / f"{name}.txt" for name in names]
    K, reference_to_cam, radar_to_cam = sensor_to_camera(read_calib(calib_paths[0]), calib_paths[0])
    for path in calib_paths[1:]:
        K_i, _, radar_to_cam_i = sensor_to_camera(read_calib(path), path)
        if not (np.allclose(K_i, K, atol=1e-6) and np.allclose(radar_to_cam_i, radar_to_cam, atol=1e-6)):
            raise SceneError(path, f"calibration differs from {calib_paths[0].name}'s; one scene needs one rig")
    return K, reference_to_cam, radar_to_cam


def convert_vod(root: str | Path, out: str | Path, frames: str, width: int | None = None, height: int | None = None,
                lidar: Literal["auto", "on", "off"] = "auto", doppler: DopplerSign = "auto",
                frame_period: float = 0.1, max_speed: float = 40.0, overwrite: bool = False,
                progress: bool = True) -> Path:
    """Convert VoD frames ``frames`` ("A:B", frames A .. B-1, one sequence) into a scene folder at
    ``out`` and return ``out``. Images keep their size unless ``width`` and ``height`` are given."""
    root, out = Path(root), Path(out)
    if out.exists() and not overwrite:  # refused before any reading (and any progress bar)
        raise FileExistsError(f"{out}: already exists (pass --force to overwrite it)")
    first_number, end_number, folders = _check_arguments(root, frames, width, height, frame_period, max_speed)
    numbers = _frame_numbers(folders["velodyne"], first_number, end_number, frames)
    names = [f"{n:05d}" for n in numbers]
    image_paths = _image_paths(folders["image_2"], names)
    camera_to_world = _camera_poses(folders["pose"], names, frames, frame_period, max_speed)
    K, reference_to_cam, radar_to_cam = _read_rig(folders["calib"], names)
    lidar_paths, lidar_note, lidar_to_cam = _lidar_setup(root, names, lidar)

    # ---- radar
    scans, older, nonfinite = read_radar_scans([folders["velodyne"] / f"{name}.bin" for name in names],
                                               RAW_RADAR_COLUMNS, "radar scan, float32 x 7", clean_radar)

    # ---- geometry: ego = radar frame
    cam_to_ego = np.linalg.inv(radar_to_cam)
    # The pose files give the (rectified reference) camera's pose; image_2's camera sits at its offset.
    ego_poses = [c @ np.linalg.inv(reference_to_cam) @ radar_to_cam for c in camera_to_world]
    world = rebase(ego_poses, ego_poses[0])
    first = read_first_image(image_paths[0])
    size_in = (first.shape[1], first.shape[0])
    rectifier = ImageRectifier.build(K, None, size_in, None if width is None else (width, height))
    camera = Camera(rectifier.size_out[0], rectifier.size_out[1], rectifier.K, cam_to_ego)
    radar_spec = RadarSpec(np.eye(4), RADAR_FIELDS)
    scene_frames = [Frame(name=name, timestamp=n * frame_period, ego_to_world=world[i],
                          radar_timestamp=n * frame_period, radar_ego_to_world=world[i],
                          extra={"radar_older_scan_dropped": older[i], "radar_nonfinite_dropped": nonfinite[i]})
                    for i, (name, n) in enumerate(zip(names, numbers, strict=True))]
    sign, sign_report = doppler_sign(scans, scene_frames, camera, radar_spec, folders["velodyne"], doppler)
    apply_doppler_sign(scans, sign, [3, 5])

    source = {
        "dataset": "view-of-delft", "frames": f"{names[0]}..{names[-1]}", "path": str(root),
        "ego_frame": "the radar frame (radar_to_ego = identity)",
        "poses": f"pose/<frame>.json {POSE_KEY} (camera -> odometry world) composed with the calibration, "
                 f"rebased to the first frame",
        "timestamps": f"frame number x {frame_period} s (VoD's KITTI files carry no times)",
        "images": f"rectified by VoD; {size_in[0]}x{size_in[1]} -> {camera.width}x{camera.height}",
        "doppler_sign": sign_report,
        "radar_rows": radar_row_counts(scans, older, nonfinite, "older_scan_dropped"),
        "lidar": lidar_note,
    }

    def frame_files(i: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        bgr = first if i == 0 else cv2.imread(str(image_paths[i]), cv2.IMREAD_COLOR)
        optional = {}
        if lidar_paths:
            optional["lidar"] = read_lidar_scan(lidar_paths[i], 4, cam_to_ego @ lidar_to_cam)
        return rectifier(bgr, image_paths[i]), optional

    write_scene(out, f"vod-{names[0]}-{names[-1]}", camera, radar_spec, source, scene_frames, scans, frame_files,
                overwrite, progress, "vod")
    return out


def _lidar_setup(root: Path, names: list[str], mode: str) -> tuple[list[Path], str, np.ndarray | None]:
    """The LiDAR scans to convert (empty for none), a note for ``source``, and LiDAR -> camera 2
    (4, 4; None without LiDAR)."""
    lidar_paths, lidar_note = _lidar_files(root, names, mode)
    lidar_to_cam = None
    if lidar_paths:
        lidar_calib = root / "lidar" / "training" / "calib" / f"{names[0]}.txt"
        lidar_to_cam = sensor_to_camera(read_calib(lidar_calib), lidar_calib)[2]
    return lidar_paths, lidar_note, lidar_to_cam


def _lidar_files(root: Path, names: list[str], mode: str) -> tuple[list[Path], str]:
    """The LiDAR scans to convert (empty for none) and a note for ``source``."""
    if mode == "off":
        return [], "not converted (--lidar off)"
    base = root / "lidar" / "training"
    paths = [base / "velodyne" / f"{name}.bin" for name in names]
    missing = [p for p in paths + [base / "calib" / f"{names[0]}.txt"] if not p.is_file()]
    if missing:
        if mode == "on":
            raise SceneError(missing[0], "missing file (LiDAR requested with --lidar on)")
        return [], f"not converted: {missing[0]} is missing"
    return paths, "lidar/training/velodyne, into the ego (radar) frame through lidar/training/calib"


@dataclass
class ConvertVodCommand:
    """Convert a frame range of View-of-Delft (camera, 3+1D radar, optional LiDAR) into a scene folder."""

    # The View-of-Delft root (holding radar/training/ and optionally lidar/training/).
    root: tyro.conf.Positional[Path]
    # The scene folder to write.
    out: tyro.conf.Positional[Path]
    # Frames A:B, i.e. A .. B-1 (5-digit frame numbers, inside one sequence).
    frames: str
    # Output image width (pixels).
    width: Annotated[Optional[int], tyro.conf.arg(help_behavior_hint="(default: the image size)")] = None
    # Output image height (pixels).
    height: Annotated[Optional[int], tyro.conf.arg(help_behavior_hint="(default: the image size)")] = None
    # Convert lidar/ from lidar/training/velodyne: when present (auto), required (on), or never (off).
    lidar: Literal["auto", "on", "off"] = "auto"
    # Sign applied to v_r and v_r_comp: auto checks it against the poses with the ego-motion fit.
    doppler_sign: DopplerSign = "auto"
    # Seconds between consecutive frame numbers (VoD frames follow the 10 Hz LiDAR).
    frame_period: float = 0.1
    # Fastest plausible ego speed (m/s): a larger odometry step between frames is a sequence break.
    max_speed: float = 40.0
    # Overwrite an existing output folder.
    force: bool = False
    # Hide the progress bar.
    quiet: bool = False

    def run(self) -> int:
        try:
            out = convert_vod(self.root, self.out, self.frames, self.width, self.height, self.lidar,
                              self.doppler_sign, self.frame_period, self.max_speed, self.force,
                              progress=not self.quiet)
        except (SceneError, ValueError, FileExistsError) as exc:
            print(f"radar4dgs convert vod: {exc}", file=sys.stderr)
            return 1
        source = json.loads((out / "scene.json").read_text(encoding="utf-8"))["source"]
        rows, sign = source["radar_rows"], source["doppler_sign"]
        print(f"radar: kept {rows['kept']} of {rows['read']} rows; dropped {rows['older_scan_dropped']} from "
              f"older scans and {rows['nonfinite_dropped']} non-finite; Doppler sign {sign['sign']:+d} "
              f"({'checked against the poses' if sign['checked'] else 'not checked'})")
        print(f"wrote {out}")
        return 0
