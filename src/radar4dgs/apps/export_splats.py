"""The Gaussian formats of ``radar4dgs export``: the 3DGS ``.ply``, gsplat's checkpoint, and (where
gsplat is installed on a CUDA machine) the ``.splat`` and compressed ``.ply`` of ``gsplat.exporter``.

Every format takes one time slice of the scene (:func:`radar4dgs.apps.export.gaussians_for_export`):
the static Gaussians and the dynamic ones where the model puts them at normalised time T. The sky
map is not a Gaussian and is never exported.

``--up y`` turns the scene's z-up world (the ego frame: x forward, y left, z up) into a y-up one
for viewers that assume it: a point ``(x, y, z)`` becomes ``(x, z, -y)`` (a rotation of -90 degrees
about x; the Gaussians' rotations are turned with it).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from radar4dgs.apps.ply import SH_C0, write_gaussians_ply
from radar4dgs.io.atomic import atomic_write_bytes

# Formats handled here, and their file suffixes.
SPLAT_SUFFIXES = {"ply": ".ply", "gsplat": ".pt", "splat": ".splat", "ply-compressed": ".compressed.ply"}
# The formats that go through gsplat.exporter (CUDA machines with gsplat only).
GSPLAT_EXPORTER = {"splat": "splat", "ply-compressed": "ply_compressed"}

# World rotation of --up y: z-up (x, y, z) -> y-up (x, z, -y).
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
# The same rotation as a unit quaternion w x y z (-90 degrees about x).
_Z_UP_TO_Y_UP_QUAT = np.array([np.sqrt(0.5), -np.sqrt(0.5), 0.0, 0.0])


def _quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of wxyz quaternions, ``a`` (4,) times each row of ``b`` (N, 4)."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], axis=1)


def apply_up(data: dict, up: str) -> dict:
    """``data`` (:func:`~radar4dgs.apps.export.gaussians_for_export`) in a world with ``up`` "z" (as
    trained, returned unchanged) or "y" (:data:`Z_UP_TO_Y_UP` applied to means and rotations)."""
    if up == "z":
        return data
    if up != "y":
        raise ValueError(f"--up must be 'y' or 'z', got {up!r}")
    out = dict(data)
    out["means"] = (data["means"].astype(np.float64) @ Z_UP_TO_Y_UP.T).astype(np.float32)
    quats = data["quats"].astype(np.float64)
    quats = quats / np.linalg.norm(quats, axis=1, keepdims=True)
    out["quats"] = _quat_multiply(_Z_UP_TO_Y_UP_QUAT, quats).astype(np.float32)
    return out


def gsplat_splats(data: dict, sh_degree: int = 3) -> dict:
    """The ``splats`` dict of a gsplat checkpoint (float32 CPU tensors): ``means`` (N, 3), ``quats``
    (N, 4) wxyz, ``scales`` (N, 3) log, ``opacities`` (N,) logit, ``sh0`` (N, 1, 3) ``(rgb - 0.5) /
    C0``, ``shN`` (N, (deg + 1)^2 - 1, 3) zeros (the colours are view-independent)."""
    import torch

    n = len(data["means"])
    sh0 = (np.asarray(data["rgb"], dtype=np.float64) - 0.5) / SH_C0
    return {
        "means": torch.as_tensor(np.asarray(data["means"], dtype=np.float32)),
        "quats": torch.as_tensor(np.asarray(data["quats"], dtype=np.float32)),
        "scales": torch.as_tensor(np.asarray(data["log_scales"], dtype=np.float32)),
        "opacities": torch.as_tensor(np.asarray(data["opacity_logits"], dtype=np.float32)),
        "sh0": torch.as_tensor(sh0.astype(np.float32)).reshape(n, 1, 3),
        "shN": torch.zeros(n, (sh_degree + 1) ** 2 - 1, 3, dtype=torch.float32),
    }


def write_gsplat_checkpoint(path: Path, data: dict, step: int = 0, sh_degree: int = 3) -> Path:
    """Write ``{"step": step, "splats": gsplat_splats(data)}`` with ``torch.save``, the checkpoint
    that gsplat's ``examples/simple_viewer.py --ckpt`` and ``simple_trainer.py --ckpt`` load
    (plain tensors and an int: ``torch.load(weights_only=True)`` reads it)."""
    from radar4dgs.io.atomic import atomic_save_torch

    atomic_save_torch(path, {"step": int(step), "splats": gsplat_splats(data, sh_degree)})
    return Path(path)


def gsplat_available() -> bool:
    """True where ``gsplat.exporter`` may be imported: gsplat installed and CUDA present (gsplat
    is never imported on a CPU-only machine)."""
    import torch

    return torch.cuda.is_available() and importlib.util.find_spec("gsplat") is not None


def require_gsplat(fmt: str) -> None:
    """Raise ValueError (one line on the command line) where ``fmt`` cannot go through gsplat.exporter."""
    if not gsplat_available():
        raise ValueError(f"--format {fmt} goes through gsplat.exporter, which needs gsplat on a CUDA "
                           "machine (pip install 'radar4dgs[cuda]'); use --format ply or gsplat here")


def write_gsplat_exporter(path: Path, data: dict, fmt: str, sh_degree: int = 3) -> Path:
    """Write ``fmt`` ("splat" or "ply-compressed") with ``gsplat.exporter.export_gaussian_splats``."""
    require_gsplat(fmt)
    from gsplat.exporter import export_gaussian_splats

    splats = gsplat_splats(data, sh_degree)
    payload = export_gaussian_splats(splats["means"], splats["scales"], splats["quats"], splats["opacities"],
                                     splats["sh0"], splats["shN"], format=GSPLAT_EXPORTER[fmt])
    return atomic_write_bytes(path, payload)


def write_splats(path: Path, data: dict, fmt: str, sh_degree: int = 3, step: int = 0) -> Path:
    """Write one time slice ``data`` in Gaussian format ``fmt`` (a key of :data:`SPLAT_SUFFIXES`)."""
    if fmt == "ply":
        return write_gaussians_ply(path, data["means"], data["quats"], data["log_scales"],
                                   data["opacity_logits"], data["rgb"], sh_degree=sh_degree)
    if fmt == "gsplat":
        return write_gsplat_checkpoint(path, data, step, sh_degree)
    if fmt in GSPLAT_EXPORTER:
        return write_gsplat_exporter(path, data, fmt, sh_degree)
    raise ValueError(f"{fmt!r} is not a Gaussian format ({', '.join(SPLAT_SUFFIXES)})")
