"""Camera paths for re-rendering a reconstructed scene (novel views, bullet time, custom paths).

A trajectory is a list of :class:`CameraPose`: a world-to-camera transform (OpenCV camera axes:
x right, y down, z forward, as in the scene format) and the normalised scene time ``t`` in [0, 1]
(``(timestamp - t_first) / (t_last - t_first)``, as :func:`radar4dgs.io.scene.normalized_times`)
at which the dynamic Gaussians are evaluated.

Specs (:func:`parse_trajectory`), built from the recorded cameras by :func:`build_trajectory`:

``recorded``
    The recorded cameras and times, unchanged.
``lane-shift:M``
    Every recorded camera moved sideways by M metres, orientation and time unchanged. Positive M
    moves to the LEFT (the ego frame's +y, which the scene format calls left), negative to the
    right. The direction is the camera's own left axis (-x of the OpenCV camera) made horizontal
    (its world-up component removed, then renormalised), so the path follows the road as the ego
    turns and the camera height stays the same even for a tilted or rolled camera.
``height:M``
    Every recorded camera moved up by M metres along world up (+z), orientation and time unchanged.
``stop-time:T``
    Bullet time: the camera follows the recorded path while the scene time is frozen. T written as
    an integer (``stop-time:12``) is a 0-based frame index and freezes the time at that frame's
    recorded time; T written with a decimal point or exponent (``stop-time:0.5``, ``stop-time:1.0``)
    is a normalised time in [0, 1]. So ``stop-time:1`` is frame 1, ``stop-time:1.0`` the last time.
``custom:FILE``
    Poses from a JSON file (path relative to the working directory): a list, one object per
    rendered view, each with exactly one of ``"world_to_camera"`` or ``"camera_to_world"`` (a 4x4
    nested list, row-major, OpenCV camera axes, in the scene's world frame; the last row must be
    0 0 0 1 and the rotation orthonormal) and ``"time"`` (a number in [0, 1], normalised scene time).
    Example::

        [{"world_to_camera": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]], "time": 0.0},
         {"camera_to_world": [[1,0,0,0.5],[0,1,0,0],[0,0,1,0],[0,0,0,1]], "time": 0.25}]

    The recorded cameras are ignored. :func:`write_custom_trajectory` writes such a file.

World up is taken as +z: the scene format makes the world frame the first frame's ego frame
(x forward, y left, z up). Pass ``up`` to :func:`build_trajectory` for a world frame that differs.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from radar4dgs.io.atomic import atomic_write_json

KINDS = ("recorded", "lane-shift", "height", "stop-time", "custom")

# Tolerances for validating user-supplied rigid transforms (JSON written by hand or other tools
# carries ~1e-6 rounding).
_ORTHONORMAL_TOL = 1e-4
_TIME_TOL = 1e-9

_SYNTAX = ("expected one of: 'recorded', 'lane-shift:M' (metres, + = left), 'height:M' (metres, "
           "+ = up), 'stop-time:T' (integer frame index, or normalised time in [0, 1] written with "
           "a decimal point), 'custom:FILE' (JSON list of {\"world_to_camera\"|\"camera_to_world\": "
           "4x4, \"time\": t})")


@dataclass
class CameraPose:
    """One rendered view: ``world_to_camera`` (4, 4) float64 (OpenCV axes), ``time`` in [0, 1]."""

    world_to_camera: np.ndarray
    time: float

    @property
    def camera_to_world(self) -> np.ndarray:
        """(4, 4) float64 inverse of ``world_to_camera``."""
        return _invert_rigid(self.world_to_camera)

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates."""
        R, t = self.world_to_camera[:3, :3], self.world_to_camera[:3, 3]
        return -R.T @ t


@dataclass(frozen=True)
class TrajectorySpec:
    """A parsed spec: ``kind`` in :data:`KINDS`, and the argument that kind takes.

    ``amount`` metres (lane-shift, height); ``frame`` or ``time`` (stop-time: exactly one set);
    ``path`` and its validated ``poses`` (custom). ``text`` is the spec as written.
    """

    kind: str
    text: str
    amount: float | None = None
    frame: int | None = None
    time: float | None = None
    path: Path | None = None
    poses: tuple[CameraPose, ...] = field(default=(), repr=False, compare=False)


def _invert_rigid(matrix: np.ndarray) -> np.ndarray:
    R, t = matrix[:3, :3], matrix[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def _parse_number(spec: str, text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"trajectory spec {spec!r}: {what} {text!r} is not a number; {_SYNTAX}") from None
    if not math.isfinite(value):
        raise ValueError(f"trajectory spec {spec!r}: {what} must be finite, got {text!r}")
    return value


def _check_rigid(matrix: Any, where: str) -> np.ndarray:
    try:
        m = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: not a 4x4 matrix of numbers") from None
    if m.shape != (4, 4):
        raise ValueError(f"{where}: expected a 4x4 matrix, got shape {m.shape}")
    if not np.isfinite(m).all():
        raise ValueError(f"{where}: contains NaN or inf")
    if np.abs(m[3] - (0, 0, 0, 1)).max() > _ORTHONORMAL_TOL:
        raise ValueError(f"{where}: last row must be [0, 0, 0, 1], got {m[3].tolist()}")
    R = m[:3, :3]
    if np.abs(R @ R.T - np.eye(3)).max() > _ORTHONORMAL_TOL or np.linalg.det(R) <= 0:
        raise ValueError(f"{where}: the 3x3 block is not a rotation (orthonormal, det +1)")
    m[3] = (0, 0, 0, 1)
    return m


def _check_time(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: 'time' must be a number in [0, 1], got {value!r}")
    t = float(value)
    if not (math.isfinite(t) and -_TIME_TOL <= t <= 1 + _TIME_TOL):
        raise ValueError(f"{where}: 'time' must lie in [0, 1] (normalised scene time), got {value!r}")
    return min(max(t, 0.0), 1.0)


def load_custom_trajectory(path: str | os.PathLike) -> list[CameraPose]:
    """Read and validate a custom trajectory JSON file (format in the module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: custom trajectory file not found")
    try:
        entries = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read the custom trajectory as JSON: {exc}") from None
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{path}: a custom trajectory must be a non-empty JSON list of poses")
    poses = []
    for i, entry in enumerate(entries):
        where = f"{path}: pose {i}"
        if not isinstance(entry, dict):
            raise ValueError(f"{where}: expected an object, got {type(entry).__name__}")
        keys = [k for k in ("world_to_camera", "camera_to_world") if k in entry]
        if len(keys) != 1:
            raise ValueError(f"{where}: needs exactly one of 'world_to_camera' or 'camera_to_world'")
        unknown = set(entry) - {"world_to_camera", "camera_to_world", "time"}
        if unknown:
            raise ValueError(f"{where}: unknown keys {sorted(unknown)}")
        if "time" not in entry:
            raise ValueError(f"{where}: missing 'time' (normalised scene time in [0, 1])")
        matrix = _check_rigid(entry[keys[0]], f"{where} '{keys[0]}'")
        w2c = matrix if keys[0] == "world_to_camera" else _invert_rigid(matrix)
        poses.append(CameraPose(world_to_camera=w2c, time=_check_time(entry["time"], where)))
    return poses


def write_custom_trajectory(path: str | os.PathLike, poses: Sequence[CameraPose]) -> Path:
    """Write ``poses`` as a custom trajectory JSON file (``world_to_camera`` form), atomically."""
    return atomic_write_json(path, [{"world_to_camera": np.asarray(p.world_to_camera, float).tolist(),
                                     "time": float(p.time)} for p in poses])


def parse_trajectory(spec: str) -> TrajectorySpec:
    """Parse a trajectory spec string (see the module docstring); a custom file is read here too,
    so a bad file fails before any rendering. Raises ValueError naming the spec."""
    if not isinstance(spec, str):
        raise ValueError(f"trajectory spec must be a string, got {type(spec).__name__}; {_SYNTAX}")
    text = spec.strip()
    kind, sep, arg = text.partition(":")
    kind = kind.strip().lower()
    arg = arg.strip()
    if kind == "recorded":
        if sep:
            raise ValueError(f"trajectory spec {spec!r}: 'recorded' takes no argument")
        return TrajectorySpec(kind="recorded", text=text)
    if kind not in KINDS:
        raise ValueError(f"unknown trajectory spec {spec!r}; {_SYNTAX}")
    if not arg:
        raise ValueError(f"trajectory spec {spec!r}: '{kind}' needs an argument after ':'; {_SYNTAX}")
    if kind in ("lane-shift", "height"):
        return TrajectorySpec(kind=kind, text=text, amount=_parse_number(spec, arg, "metres"))
    if kind == "stop-time":
        if re.fullmatch(r"[+-]?\d+", arg):
            frame = int(arg)
            if frame < 0:
                raise ValueError(f"trajectory spec {spec!r}: frame index must be >= 0")
            return TrajectorySpec(kind=kind, text=text, frame=frame)
        t = _parse_number(spec, arg, "time")
        if not 0.0 <= t <= 1.0:
            raise ValueError(f"trajectory spec {spec!r}: a normalised time must lie in [0, 1] "
                             "(write an integer for a frame index)")
        return TrajectorySpec(kind=kind, text=text, time=t)
    path = Path(os.path.expanduser(arg))
    try:
        poses = load_custom_trajectory(path)
    except ValueError as exc:
        raise ValueError(f"trajectory spec {spec!r}: {exc}") from None
    return TrajectorySpec(kind=kind, text=text, path=path, poses=tuple(poses))


def _validate_recorded(world_to_cameras: Any, times: Any) -> tuple[np.ndarray, np.ndarray]:
    w2c = np.asarray(world_to_cameras, dtype=np.float64)
    if w2c.ndim != 3 or w2c.shape[1:] != (4, 4) or len(w2c) == 0:
        raise ValueError(f"world_to_cameras must have shape (N, 4, 4) with N >= 1, got {w2c.shape}")
    t = np.asarray(times, dtype=np.float64)
    if t.shape != (len(w2c),):
        raise ValueError(f"times must have shape ({len(w2c)},), got {t.shape}")
    if not (np.isfinite(w2c).all() and np.isfinite(t).all()):
        raise ValueError("world_to_cameras and times must be finite")
    R = w2c[:, :3, :3]
    bad = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max(axis=(1, 2)) > _ORTHONORMAL_TOL
    bad |= np.linalg.det(R) <= 0
    if bad.any():
        raise ValueError(f"world_to_cameras[{int(np.nonzero(bad)[0][0])}]: the 3x3 block is not a "
                         "rotation (orthonormal, det +1)")
    if t.min() < -_TIME_TOL or t.max() > 1 + _TIME_TOL:
        raise ValueError(f"times must be normalised to [0, 1], got range [{t.min()}, {t.max()}]")
    return w2c, np.clip(t, 0.0, 1.0)


def _horizontal(direction: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(N, 3) unit vectors: ``direction`` (N, 3) minus its ``up`` component, renormalised; rows
    that are (nearly) parallel to up keep their own unit direction."""
    flat = direction - (direction @ up)[:, None] * up
    norm = np.linalg.norm(flat, axis=1, keepdims=True)
    own = direction / np.linalg.norm(direction, axis=1, keepdims=True)
    return np.where(norm > 1e-6, flat / np.maximum(norm, 1e-12), own)


def _translated(w2c: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Move each camera centre by ``offsets`` (N, 3) world metres; rotations untouched."""
    out = w2c.copy()
    # centre' = centre + d  <=>  t' = -R (centre + d) = t - R d
    out[:, :3, 3] -= np.einsum("nij,nj->ni", w2c[:, :3, :3], offsets)
    return out


def build_trajectory(spec: str | TrajectorySpec, world_to_cameras: np.ndarray, times: np.ndarray,
                     *, interpolate: int = 1, up: Sequence[float] = (0.0, 0.0, 1.0)) -> list[CameraPose]:
    """Camera path for ``spec`` from the recorded cameras.

    ``world_to_cameras`` (N, 4, 4) recorded world-to-camera transforms (OpenCV axes), ``times``
    (N,) their normalised times in [0, 1]; ``interpolate`` > 1 upsamples the result by that factor
    (:func:`interpolate_trajectory`); ``up`` (3,) the world up direction. Returns a list of
    :class:`CameraPose` (N of them, or ``(N - 1) * interpolate + 1``; the custom file's count for
    ``custom``). Raises ValueError on a bad spec or inputs.
    """
    parsed = parse_trajectory(spec) if isinstance(spec, str) else spec
    if not isinstance(parsed, TrajectorySpec):
        raise ValueError(f"spec must be a string or a TrajectorySpec, got {type(spec).__name__}")
    up_vec = np.asarray(up, dtype=np.float64)
    if up_vec.shape != (3,) or not np.isfinite(up_vec).all() or np.linalg.norm(up_vec) == 0:
        raise ValueError(f"up must be a finite non-zero 3-vector, got {up!r}")
    up_vec = up_vec / np.linalg.norm(up_vec)

    if parsed.kind == "custom":
        poses = [CameraPose(p.world_to_camera.copy(), p.time) for p in parsed.poses]
        return interpolate_trajectory(poses, interpolate)
    w2c, t = _validate_recorded(world_to_cameras, times)
    if parsed.kind == "lane-shift":
        # Camera x is right, so its left axis in world coordinates is -(first row of R).
        left = _horizontal(-w2c[:, 0, :3], up_vec)
        w2c = _translated(w2c, parsed.amount * left)
    elif parsed.kind == "height":
        w2c = _translated(w2c, np.broadcast_to(parsed.amount * up_vec, (len(w2c), 3)))
    elif parsed.kind == "stop-time":
        if parsed.frame is not None:
            if parsed.frame >= len(t):
                raise ValueError(f"trajectory spec {parsed.text!r}: frame index {parsed.frame} out of "
                                 f"range for {len(t)} frames (0..{len(t) - 1})")
            frozen = float(t[parsed.frame])
        else:
            frozen = float(parsed.time)
        t = np.full_like(t, frozen)
    elif parsed.kind != "recorded":
        raise ValueError(f"unknown trajectory kind {parsed.kind!r}")
    poses = [CameraPose(world_to_camera=w2c[i].copy(), time=float(t[i])) for i in range(len(w2c))]
    return interpolate_trajectory(poses, interpolate)


def interpolate_trajectory(poses: Sequence[CameraPose], factor: int) -> list[CameraPose]:
    """Upsample a path by an integer ``factor``: ``factor - 1`` views between consecutive poses.

    Rotations are slerped, camera centres and times interpolated linearly (centres rather than
    world-to-camera translations, so the camera moves on straight segments). Returns
    ``(len(poses) - 1) * factor + 1`` poses; the originals are kept exactly at every
    ``factor``-th position. ``factor`` 1 (or a single pose) returns copies.
    """
    if isinstance(factor, bool) or not isinstance(factor, (int, np.integer)) or factor < 1:
        raise ValueError(f"interpolation factor must be an integer >= 1, got {factor!r}")
    poses = list(poses)
    if not poses:
        raise ValueError("cannot interpolate an empty trajectory")
    if factor == 1 or len(poses) == 1:
        return [CameraPose(np.array(p.world_to_camera, dtype=np.float64), float(p.time)) for p in poses]
    c2w = np.stack([_invert_rigid(np.asarray(p.world_to_camera, dtype=np.float64)) for p in poses])
    key_times = np.arange(len(poses), dtype=np.float64)
    query = np.linspace(0.0, len(poses) - 1, (len(poses) - 1) * factor + 1)
    rotations = Slerp(key_times, Rotation.from_matrix(c2w[:, :3, :3]))(query).as_matrix()
    centres = np.stack([np.interp(query, key_times, c2w[:, k, 3]) for k in range(3)], axis=1)
    times = np.interp(query, key_times, np.array([p.time for p in poses], dtype=np.float64))
    out = []
    for j in range(len(query)):
        if j % factor == 0:  # keep the keyframes bit-exact rather than round-tripped via slerp
            key = poses[j // factor]
            out.append(CameraPose(np.array(key.world_to_camera, dtype=np.float64), float(key.time)))
            continue
        m = np.eye(4)
        m[:3, :3] = rotations[j]
        m[:3, 3] = centres[j]
        out.append(CameraPose(world_to_camera=_invert_rigid(m), time=float(times[j])))
    return out
