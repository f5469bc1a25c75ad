"""``radar4dgs export RUN --format ply``: a trained run's Gaussians as a standard 3DGS ``.ply``.

``--part static`` writes the static Gaussians only; ``--part all`` (default) adds the dynamic ones
moved to normalised scene time ``--time T`` by the deformation field (``x_T = D_T(x_canonical)``).
The field moves positions only: a dynamic Gaussian keeps its canonical rotation and scale at every
time (it translates, it does not turn), so the exported rotations are the trained ones. A dynamic
Gaussian with a life span (``dynamic_lifespan``) is exported with its opacity at time T. Colours are
the view-independent ``sigmoid(colors)`` (degree-0 SH; the ``f_rest`` coefficients are zeros).

Default output: ``RUN/export/scene_<part>_t<T>.ply`` (``T`` as ``%g``: ``t0``, ``t0.5``, ``t1``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal, Optional

import numpy as np
import tyro

from radar4dgs.apps.options import default_is

if TYPE_CHECKING:
    pass

FORMATS = ("ply",)
PARTS = ("static", "all")
EXPORT_DIR = "export"


@dataclass
class ExportResult:
    """What :func:`export_run` wrote: the ``path``, ``n_static`` and ``n_dynamic`` Gaussian counts
    and the normalised ``time`` the dynamic ones were moved to."""

    path: Path
    n_static: int
    n_dynamic: int
    time: float


def default_export_path(run_root: Path, part: str, time: float) -> Path:
    """``RUN/export/scene_<part>_t<T>.ply``."""
    return Path(run_root) / EXPORT_DIR / f"scene_{part}_t{time:g}.ply"


def _check_options(fmt: str, part: str, time: float) -> float:
    if fmt not in FORMATS:
        raise ValueError(f"unknown export format {fmt!r}; supported: {', '.join(FORMATS)}")
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


def export_run(run_dir, fmt: str = "ply", part: str = "all", time: float = 0.0, out: Path | None = None,
               sh_degree: int = 3, device: str | None = None) -> ExportResult:
    """Export the run in ``run_dir`` (a path or a loaded ``Run``) to ``out`` (default
    :func:`default_export_path`); the model is loaded on ``device`` (default CPU). Raises
    ValueError on a bad format, part or time (before anything is loaded) and FileNotFoundError
    when the folder has no ``model.pt``."""
    from radar4dgs.apps.ply import write_gaussians_ply
    from radar4dgs.model.run import MODEL_FILE, Run
    from radar4dgs.model.scene_model import load_model

    time = _check_options(fmt, part, time)
    if isinstance(run_dir, Run):
        root, model = run_dir.root, run_dir.model
    else:
        # Only the model is needed: an export works even where the scene folder has moved.
        root = Path(run_dir)
        if not (root / MODEL_FILE).is_file():
            raise FileNotFoundError(f"{root / MODEL_FILE}: missing; is {root} a finished `radar4dgs train` run?")
        model = load_model(root / MODEL_FILE, device=device or "cpu")
    data = gaussians_for_export(model, part, time)
    path = Path(out) if out is not None else default_export_path(root, part, time)
    write_gaussians_ply(path, data["means"], data["quats"], data["log_scales"], data["opacity_logits"],
                        data["rgb"], sh_degree=sh_degree)
    return ExportResult(path, data["n_static"], data["n_dynamic"], time)


@dataclass
class ExportCommand:
    """Export a trained run's Gaussians (static, or static + dynamic at one time) as a 3DGS .ply."""

    # The run folder written by `radar4dgs train`.
    run_dir: tyro.conf.Positional[Path]
    # Output format (a standard 3DGS .ply: SuperSplat, SIBR and gsplat's tools open it).
    format: Literal["ply"] = "ply"
    # Normalised scene time in [0, 1] the dynamic Gaussians are moved to (0 = first frame, 1 = last).
    time: float = 0.0
    # static = static Gaussians only; all = static + dynamic at --time.
    part: Literal["static", "all"] = "all"
    # Output file.
    out: Annotated[Optional[Path], default_is("RUN/export/scene_<part>_t<T>.ply")] = None
    # Spherical-harmonics degree of the file (the extra coefficients are zeros; most viewers want 3).
    sh_degree: int = 3
    # Torch device the model is loaded on (the CPU is enough: only the field is evaluated).
    device: Optional[str] = None

    def run(self) -> int:
        # A missing run or a bad option raises a user error: one line (radar4dgs.cli).
        result = export_run(self.run_dir, self.format, self.part, self.time, self.out, self.sh_degree,
                            self.device)
        what = (f"{result.n_static} static" if self.part == "static"
                else f"{result.n_static} static + {result.n_dynamic} dynamic (moved to t={result.time:g}; "
                     "rotations are the canonical ones, the field moves positions only; opacities at that time)")
        print(f"wrote {result.n_static + result.n_dynamic} Gaussians: {what} -> {result.path}")
        return 0
