"""``radar4dgs export RUN --format FORMAT``: a trained run's Gaussians or cameras for other tools.

Gaussian formats (one time slice each; :mod:`radar4dgs.apps.export_splats`): ``ply`` (the standard
3DGS ``.ply``), ``gsplat`` (a checkpoint ``{"step", "splats"}`` that gsplat's ``simple_viewer.py
--ckpt`` opens), ``splat`` and ``ply-compressed`` (through ``gsplat.exporter``, on a CUDA machine
with gsplat only). ``--up y`` writes them y-up; ``--times`` writes one file per recorded frame.
Camera formats (:mod:`radar4dgs.apps.export_cameras`): ``nerfstudio`` (``transforms.json``) and
``colmap`` (a text model, with its binary twin), with the images and the initial point cloud.

``--part static`` writes the static Gaussians only; ``--part all`` (default) adds the dynamic ones
moved to normalised scene time ``--time T`` by the deformation field (``x_T = D_T(x_canonical)``).
The field moves positions only: a dynamic Gaussian keeps its canonical rotation and scale at every
time (it translates, it does not turn), so the exported rotations are the trained ones, except for
rigid actors' Gaussians (``rigid_actors_at``), which turn with their actor and are exported turned
as at time T. A dynamic Gaussian with a life span (``dynamic_lifespan``) is exported with its
opacity at time T. Colours are
the view-independent ``sigmoid(colors)`` (degree-0 SH; the ``f_rest`` coefficients are zeros).

Default output: ``RUN/export/scene_<part>_t<T>.ply`` (``T`` as ``%g``: ``t0``, ``t0.5``, ``t1``;
``_yup`` added with ``--up y``; ``.pt``, ``.splat``, ``.compressed.ply`` for the other Gaussian
formats); ``RUN/export/scene_<part>_frames/<frame name>.<ext>`` with ``--times``;
``RUN/export/nerfstudio/`` and ``RUN/export/colmap/`` for the camera formats.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, Optional

import numpy as np
import tyro

from radar4dgs.apps.export_splats import SPLAT_SUFFIXES
from radar4dgs.apps.options import default_is

SPLAT_FORMATS = tuple(SPLAT_SUFFIXES)
CAMERA_FORMATS = ("nerfstudio", "colmap")
FORMATS = SPLAT_FORMATS + CAMERA_FORMATS
PARTS = ("static", "all")
EXPORT_DIR = "export"


@dataclass
class ExportResult:
    """What :func:`export_run` wrote: the ``path`` (a file, or the folder of ``--times`` and of the
    camera formats), ``n_static`` and ``n_dynamic`` Gaussian counts (of the last slice; 0 for the
    camera formats), the normalised ``time`` the dynamic ones were moved to, and ``files`` (every
    Gaussian file written)."""

    path: Path
    n_static: int
    n_dynamic: int
    time: float
    files: tuple[Path, ...] = ()


def default_export_path(run_root: Path, part: str, time: float, fmt: str = "ply", up: str = "z") -> Path:
    """``RUN/export/scene_<part>_t<T>[_yup].<ext>`` for a Gaussian format, ``RUN/export/<fmt>/`` for
    a camera format."""
    if fmt in CAMERA_FORMATS:
        return Path(run_root) / EXPORT_DIR / fmt
    return Path(run_root) / EXPORT_DIR / f"scene_{part}_t{time:g}{'_yup' if up == 'y' else ''}{SPLAT_SUFFIXES[fmt]}"


def _check_options(fmt: str, part: str, time: float, up: str = "z", times: bool = False) -> float:
    if fmt not in FORMATS:
        raise ValueError(f"unknown export format {fmt!r}; supported: {', '.join(FORMATS)}")
    if up not in ("y", "z"):
        raise ValueError(f"--up must be 'y' or 'z', got {up!r}")
    if fmt in CAMERA_FORMATS and (up != "z" or times):
        raise ValueError(f"--up and --times apply to the Gaussian formats ({', '.join(SPLAT_FORMATS)}), "
                         f"not to --format {fmt}")
    if part not in PARTS:
        raise ValueError(f"unknown part {part!r}; choose one of {', '.join(PARTS)}")
    if isinstance(time, bool) or not isinstance(time, (int, float)) or not math.isfinite(time) \
            or not 0.0 <= time <= 1.0:
        raise ValueError(f"--time must be a normalised scene time in [0, 1] (0 = first frame, 1 = last), "
                         f"got {time!r}")
    return float(time)


def gaussians_for_export(model, part: str = "all", time: float = 0.0) -> dict[str, np.ndarray]:
    """The model's Gaussians in the PLY writer's parametrisation, static first: ``means`` (N, 3),
    ``quats`` (N, 4) unit wxyz, ``log_scales`` (N, 3), ``opacity_logits`` (N,), ``rgb`` (N, 3) in
    [0, 1], plus ``n_static`` / ``n_dynamic`` (ints). Means are where the model puts them at
    ``time`` (the field, or a baseline's motion; static ones are the stored parameters) and a set's
    temporal visibility (PVG, bspline, ours' life spans) is folded into the opacity; the rest is the
    stored parameters."""
    import torch  # here, not at the top: `radar4dgs export --help` should not wait for torch

    sets = ["static"]
    if part == "all" and model.dynamic is not None and len(model.dynamic) > 0:
        sets.append("dynamic")
    columns: dict[str, list[np.ndarray]] = {k: [] for k in ("means", "quats", "log_scales", "opacity_logits", "rgb")}
    with torch.no_grad():
        for name in sets:
            gaussians = getattr(model, name)
            active = model.set_at(name, float(time))
            params = gaussians.params
            opacity_logits = params["opacity_logits"]
            if gaussians.has("log_lifespan"):
                opacity = active["opacities"].clamp(1e-6, 1 - 1e-6)
                opacity_logits = torch.log(opacity) - torch.log1p(-opacity)
            # float32 is what the file stores: converting here keeps the static means bit-identical.
            columns["means"].append(active["means"].float().cpu().numpy())
            columns["quats"].append(active["quats"].float().cpu().numpy())
            columns["log_scales"].append(params["log_scales"].float().cpu().numpy())
            columns["opacity_logits"].append(opacity_logits.float().cpu().numpy())
            columns["rgb"].append(active["colors"].float().cpu().numpy())
    out: dict = {k: np.concatenate(v, axis=0) for k, v in columns.items()}
    out["n_static"] = len(model.static)
    out["n_dynamic"] = len(out["means"]) - len(model.static)
    return out




def _load(run_dir, device: str | None, need_scene: bool):
    """(root, model, run or None): the whole run when the scene is needed, else ``model.pt`` alone
    (an export of the Gaussians works even where the scene folder has moved)."""
    from radar4dgs.model.run import MODEL_FILE, Run, load_run
    from radar4dgs.model.scene_model import load_model

    if isinstance(run_dir, Run):
        return run_dir.root, run_dir.model, run_dir
    root = Path(run_dir)
    if not (root / MODEL_FILE).is_file():
        raise FileNotFoundError(f"{root / MODEL_FILE}: missing; is {root} a finished `radar4dgs train` run?")
    if need_scene:
        run = load_run(root, device or "cpu")
        return root, run.model, run
    return root, load_model(root / MODEL_FILE, device=device or "cpu"), None


def _trained_steps(root: Path) -> int:
    """The run's iteration count (the ``step`` of a gsplat checkpoint); 0 when unknown."""
    import json

    from radar4dgs.model.run import CONFIG_FILE

    try:
        saved = json.loads((root / CONFIG_FILE).read_text())
        return int(saved.get("config", saved)["optim"]["iterations"])
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return 0


def _export_slice(model, root: Path, fmt: str, part: str, time: float, path: Path, sh_degree: int,
                  up: str) -> tuple[int, int]:
    from radar4dgs.apps.export_splats import apply_up, write_splats

    data = apply_up(gaussians_for_export(model, part, time), up)
    write_splats(path, data, fmt, sh_degree, _trained_steps(root) if fmt == "gsplat" else 0)
    return data["n_static"], data["n_dynamic"]


def export_run(run_dir, fmt: str = "ply", part: str = "all", time: float = 0.0, out: Path | None = None,
               sh_degree: int = 3, device: str | None = None, *, up: str = "z", times: bool = False,
               link_images: bool = False) -> ExportResult:
    """Export the run in ``run_dir`` (a path or a loaded ``Run``) as ``fmt`` to ``out`` (default
    :func:`default_export_path`); the model is loaded on ``device`` (default CPU). ``times``
    writes one Gaussian file per recorded frame, at that frame's normalised time, into the folder
    ``out`` (default ``RUN/export/scene_<part>_frames``). Raises ValueError on a bad format, part,
    time or up (before anything is loaded), FileNotFoundError when the folder has no ``model.pt``,
    and for a gsplat.exporter format where gsplat cannot be used."""
    time = _check_options(fmt, part, time, up, times)
    if fmt in ("splat", "ply-compressed"):
        from radar4dgs.apps.export_splats import require_gsplat

        require_gsplat(fmt)  # before the model loads
    root, model, run = _load(run_dir, device, need_scene=times or fmt in CAMERA_FORMATS)
    if fmt in CAMERA_FORMATS:
        from radar4dgs.apps.export_cameras import write_colmap, write_nerfstudio

        folder = Path(out) if out is not None else default_export_path(root, part, time, fmt)
        (write_nerfstudio if fmt == "nerfstudio" else write_colmap)(run, folder, link_images)
        return ExportResult(folder, 0, 0, time)
    if not times:
        path = Path(out) if out is not None else default_export_path(root, part, time, fmt, up)
        n_static, n_dynamic = _export_slice(model, root, fmt, part, time, path, sh_degree, up)
        return ExportResult(path, n_static, n_dynamic, time, (path,))
    from radar4dgs.io.scene import normalized_times

    folder = Path(out) if out is not None else Path(root) / EXPORT_DIR / f"scene_{part}_frames"
    files = []
    for frame, t in zip(run.scene.frames, normalized_times(run.scene), strict=True):
        path = folder / f"{frame.name}{'_yup' if up == 'y' else ''}{SPLAT_SUFFIXES[fmt]}"
        n_static, n_dynamic = _export_slice(model, root, fmt, part, float(t), path, sh_degree, up)
        files.append(path)
    return ExportResult(folder, n_static, n_dynamic, time, tuple(files))


@dataclass
class ExportCommand:
    """Export a trained run: its Gaussians (.ply, a gsplat checkpoint, .splat) or its cameras (nerfstudio, COLMAP)."""

    # The run folder written by `radar4dgs train`.
    run_dir: tyro.conf.Positional[Path]
    # ply: standard 3DGS .ply (SuperSplat, SIBR); gsplat: checkpoint for gsplat's simple_viewer.py --ckpt;
    # splat / ply-compressed: through gsplat.exporter (CUDA + gsplat only); nerfstudio: transforms.json +
    # images + initial points; colmap: sparse/0 text (and binary) model + images.
    format: Literal["ply", "gsplat", "splat", "ply-compressed", "nerfstudio", "colmap"] = "ply"
    # Normalised scene time in [0, 1] the dynamic Gaussians are moved to (0 = first frame, 1 = last).
    time: float = 0.0
    # One Gaussian file per recorded frame, at each frame's time (into a folder; needs the scene).
    times: bool = False
    # static = static Gaussians only; all = static + dynamic at --time.
    part: Literal["static", "all"] = "all"
    # World up axis of the Gaussian file: z (the scene's, as trained) or y ((x, y, z) -> (x, z, -y)).
    up: Literal["y", "z"] = "z"
    # Output file (folder with --times and for nerfstudio / colmap).
    out: Annotated[Optional[Path], default_is("RUN/export/scene_<part>_t<T>.ply (or .pt, .splat, ...; "
                                              "RUN/export/<format>/ for nerfstudio and colmap)")] = None
    # Spherical-harmonics degree of the file (the extra coefficients are zeros; most viewers want 3).
    sh_degree: int = 3
    # nerfstudio / colmap: symlink the scene's images instead of copying them.
    link_images: bool = False
    # Torch device the model is loaded on (the CPU is enough: only the field is evaluated).
    device: Optional[str] = None

    def run(self) -> int:
        # A missing run or a bad option raises a user error: one line (radar4dgs.cli).
        result = export_run(self.run_dir, self.format, self.part, self.time, self.out, self.sh_degree,
                            self.device, up=self.up, times=self.times, link_images=self.link_images)
        if self.format in CAMERA_FORMATS:
            print(f"wrote a {self.format} dataset (cameras, images, initial points) -> {result.path}")
            return 0
        when = "each frame's time" if self.times else f"t={result.time:g}"
        what = (f"{result.n_static} static" if self.part == "static"
                else f"{result.n_static} static + {result.n_dynamic} dynamic (moved to {when}; "
                     "rotations are the canonical ones, the field moves positions only; opacities at that time)")
        files = f"{len(result.files)} files in " if self.times else ""
        print(f"wrote {result.n_static + result.n_dynamic} Gaussians: {what} -> {files}{result.path}")
        return 0
