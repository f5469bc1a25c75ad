"""``radar4dgs convert nerfstudio``: a nerfstudio dataset (``transforms.json``) into a radar-less
scene folder (docs/data/scene-format.md, docs/data/converters.md).

Read: the intrinsics (``fl_x fl_y cx cy w h``, shared at the top level or per frame, which must
then agree: the scene format has one camera), ``camera_model`` (PINHOLE, OPENCV with ``k1 k2
p1 p2 [k3]`` or OPENCV_FISHEYE with ``k1 k2 k3 k4``: images with non-zero distortion are
undistorted with OpenCV, to a pinhole camera), per frame ``file_path`` and the OpenGL camera-to-world
``transform_matrix``, an optional ``time``, the ``train_filenames`` / ``test_filenames`` split,
``ply_file_path`` (the initial point cloud, to ``priors/points3d.npy``) and ``applied_transform``
/ ``applied_scale`` (kept in ``source``; ``--world original`` undoes them).

Timestamps: frames are ordered by ``time`` when every frame has one (nerfstudio's normalised
time, spread over ``(N - 1) x --frame-interval`` seconds, so the scene's normalised times equal
``time``), else by file name (as nerfstudio's dataparser orders them), ``--frame-interval``
seconds apart.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, Mapping, Optional

import numpy as np
import tyro

from radar4dgs.datasets.convert.camera_import import (
    DEFAULT_FRAME_INTERVAL,
    OPENCV_TO_OPENGL,
    frame_names,
    frame_of,
    image_reader,
    order_timestamps,
    pinhole_K,
    read_ply_points,
    refuse_existing,
    test_every_of,
    write_radarless_scene,
)
from radar4dgs.io.scene import DEFAULT_TEST_EVERY, SceneError, read_json_file

INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
DISTORTION_KEYS = ("k1", "k2", "p1", "p2", "k3", "k4")
World = Literal["transforms", "original"]


def opencv_world_to_camera(transform_matrix: Any) -> np.ndarray:
    """(4, 4) OpenCV world-to-camera of nerfstudio's OpenGL camera-to-world ``transform_matrix``
    (4x4, or its top 3x4)."""
    c2w = np.eye(4)
    c2w[:np.asarray(transform_matrix).shape[0]] = np.asarray(transform_matrix, dtype=np.float64)
    return np.linalg.inv(c2w @ OPENCV_TO_OPENGL)


def read_transforms(src: Path) -> tuple[Path, Mapping[str, Any]]:
    """The path of ``transforms.json`` (``src`` itself or inside the folder ``src``) and its object."""
    path = src / "transforms.json" if src.is_dir() else src
    if not path.is_file():
        raise SceneError(path, "missing file (a nerfstudio dataset has a transforms.json)")
    meta = read_json_file(path)
    if not isinstance(meta, Mapping) or not isinstance(meta.get("frames"), list) or not meta["frames"]:
        raise SceneError(path, "needs a non-empty 'frames' list")
    return path, meta


def frame_camera(meta: Mapping[str, Any], frame: Mapping[str, Any], where: str, path: Path) -> tuple:
    """(model, (fx, fy, cx, cy), (w, h), distortion) of one frame: its own keys over the top level's."""
    def value(key: str, default: Any = None) -> Any:
        return frame.get(key, meta.get(key, default))

    missing = [k for k in INTRINSIC_KEYS if value(k) is None]
    if missing:
        raise SceneError(path, f"{where} has no intrinsics {missing} (at the top level or in the frame)")
    model = str(value("camera_model", "OPENCV"))
    distortion = tuple(float(value(k, 0.0)) for k in DISTORTION_KEYS)
    return (model, tuple(float(value(k)) for k in ("fl_x", "fl_y", "cx", "cy")),
            (int(value("w")), int(value("h"))), distortion)


def one_camera(meta: Mapping[str, Any], path: Path) -> tuple[np.ndarray, tuple[int, int], list[float] | None, str]:
    """The scene's single camera: ``K``, (w, h), OpenCV distortion (None without) and the model."""
    cameras = {frame_camera(meta, f, f"frames[{i}]", path) for i, f in enumerate(meta["frames"])}
    if len(cameras) > 1:
        raise SceneError(path, f"the frames have {len(cameras)} different cameras; the scene format has one "
                               f"(convert each camera's frames separately)")
    model, (fx, fy, cx, cy), size, (k1, k2, p1, p2, k3, k4) = cameras.pop()
    distorted = any((k1, k2, p1, p2, k3, k4))
    if model in ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE") and not k4:
        distortion = [k1, k2, p1, p2, k3] if distorted else None
    elif model == "OPENCV_FISHEYE" and not (p1 or p2):
        distortion = [k1, k2, k3, k4] if distorted else None
    else:
        raise SceneError(path, f"camera_model {model} with distortion {[k1, k2, p1, p2, k3, k4]} is not "
                               f"converted (PINHOLE, OPENCV and OPENCV_FISHEYE are); undistort the images first")
    return pinhole_K(fx, fy, cx, cy), size, distortion, model


def frame_order(frames: list, path: Path) -> tuple[list[int], np.ndarray | None, str]:
    """Frame indices in time order, the normalised times (None without ``time``), and how."""
    times = [f.get("time") for f in frames]
    if all(isinstance(t, (int, float)) for t in times):
        order = sorted(range(len(frames)), key=lambda i: times[i])
        ordered = np.array([times[i] for i in order], dtype=np.float64)
        same = np.flatnonzero(np.diff(ordered) <= 0)
        if len(same):
            a, b = order[same[0]], order[same[0] + 1]
            raise SceneError(path, f"frames[{a}] and frames[{b}] have the same time {times[a]}; a scene needs "
                                   f"increasing times (one camera)")
        return order, ordered, "the frames' nerfstudio 'time', spread over (N - 1) x --frame-interval seconds"
    order = sorted(range(len(frames)), key=lambda i: str(frames[i].get("file_path", "")))
    return order, None, "the frames' order (sorted by file_path), --frame-interval seconds apart"


def applied(meta: Mapping[str, Any]) -> np.ndarray:
    """(4, 4) the ``applied_transform`` (3x4 or 4x4) and ``applied_scale`` that nerfstudio applied to
    the original poses: ``x_transforms = scale * (A @ x_original)``."""
    A = np.eye(4)
    if meta.get("applied_transform") is not None:
        given = np.asarray(meta["applied_transform"], dtype=np.float64)
        A[:given.shape[0]] = given
    return np.diag([float(meta.get("applied_scale", 1.0))] * 3 + [1.0]) @ A


def split_of(meta: Mapping[str, Any], files: list[str], test_every: Optional[int], path: Path) -> tuple[int, str]:
    """``test_every`` and where it came from: the option, else the dataset's test (or val) file
    names when one value reproduces them, else the scene format's default."""
    if test_every is not None:
        return test_every, "--test-every"
    named = meta.get("test_filenames") or meta.get("val_filenames")
    if named:
        wanted = {str(Path(n)) for n in named}
        every = test_every_of(len(files), [i for i, f in enumerate(files) if str(Path(f)) in wanted])
        if every is not None:
            return every, "the dataset's test_filenames"
        print(f"radar4dgs convert nerfstudio: warning: {path}: test_filenames are not every k-th frame; the "
              f"scene uses every {DEFAULT_TEST_EVERY}th frame (--test-every to choose)", file=sys.stderr)
    return DEFAULT_TEST_EVERY, "default"


def convert_nerfstudio(src: str | Path, out: str | Path, frame_interval: float = DEFAULT_FRAME_INTERVAL,
                       test_every: int | None = None, world: World = "transforms", overwrite: bool = False,
                       progress: bool = True) -> Path:
    """Convert the nerfstudio dataset ``src`` (its folder or its ``transforms.json``) into the
    radar-less scene folder ``out`` and return ``out`` (module doc)."""
    src, out = Path(src), Path(out)
    refuse_existing(out, overwrite)
    path, meta = read_transforms(src)
    root = path.parent
    K, size, distortion, model = one_camera(meta, path)
    frames = meta["frames"]
    order, times, timing = frame_order(frames, path)
    files = [str(frames[i].get("file_path", "")) for i in order]
    if not all(files):
        raise SceneError(path, "every frame needs a file_path")
    # x_transforms = M x_original; a camera's frame is not scaled with the world (1 / applied_scale).
    to_world = np.linalg.inv(applied(meta)) if world == "original" else np.eye(4)
    unscale = np.diag([1.0 / float(meta.get("applied_scale", 1.0))] * 3 + [1.0]) if world == "original" else np.eye(4)
    stamps = order_timestamps(len(order), frame_interval)
    if times is not None and times[-1] > times[0]:
        stamps = (times - times[0]) / (times[-1] - times[0]) * stamps[-1]
    names = frame_names(files)
    scene_frames = []
    for k, i in enumerate(order):
        if "transform_matrix" not in frames[i]:
            raise SceneError(path, f"frames[{i}] has no transform_matrix")
        w2c = unscale @ opencv_world_to_camera(frames[i]["transform_matrix"]) @ np.linalg.inv(to_world)
        scene_frames.append(frame_of(names[k], stamps[k], w2c, f"frames[{i}].transform_matrix", path,
                                     {"source_file": files[k]}))
    points = None
    if meta.get("ply_file_path"):
        xyz, rgb = read_ply_points(root / str(meta["ply_file_path"]))
        points = (xyz @ to_world[:3, :3].T + to_world[:3, 3], rgb)
    camera, read_image = image_reader([root / f for f in files], K, distortion, size, model == "OPENCV_FISHEYE")
    every, split = split_of(meta, files, test_every, path)
    source = {"dataset": "nerfstudio", "path": str(path.resolve()), "radar": "absent", "camera_model": model,
              "images": ("undistorted (OpenCV fisheye, balance 0)" if model == "OPENCV_FISHEYE" else
                         "undistorted (OpenCV, getOptimalNewCameraMatrix alpha=0)") if distortion else "copied",
              "timestamps": timing, "split": split, "points": 0 if points is None else int(len(points[0])),
              "world": "transforms.json's" if world == "transforms" else "original (applied_transform undone)",
              "applied_transform": applied(meta).tolist()}
    return write_radarless_scene(out, f"nerfstudio-{root.name}", camera, scene_frames, read_image, points, source,
                                 every, overwrite, progress, "nerfstudio")


@dataclass
class ConvertNerfstudioCommand:
    """Convert a nerfstudio dataset (transforms.json, images, optional ply) into a radar-less scene folder."""

    # The nerfstudio dataset folder (or its transforms.json).
    src: tyro.conf.Positional[Path]
    # The scene folder to write.
    out: tyro.conf.Positional[Path]
    # Seconds between consecutive frames (nerfstudio has no timestamps; 'time' is normalised).
    frame_interval: float = DEFAULT_FRAME_INTERVAL
    # Every k-th frame is a test frame; 0 = no test frames.
    test_every: Annotated[Optional[int], tyro.conf.arg(
        help_behavior_hint="(default: the dataset's test_filenames when they are every k-th frame, else 4)")] = None
    # "transforms": the poses and points as transforms.json holds them; "original": undo its
    # applied_transform / applied_scale (the world before nerfstudio re-oriented it).
    world: World = "transforms"
    # Overwrite an existing output folder.
    force: bool = False
    # Hide the progress bar.
    quiet: bool = False

    def run(self) -> int:
        # A missing or malformed dataset raises a user error: one line (radar4dgs.cli).
        out = convert_nerfstudio(self.src, self.out, self.frame_interval, self.test_every, self.world, self.force,
                                 progress=not self.quiet)
        print(f"wrote {out} (no radar: train it with --method static)")
        return 0
