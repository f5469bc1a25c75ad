"""The ``frontend-eval`` command: metrics of the prepared front-end outputs against a scene's gt.

The JSON report has one section per front-end stage (``"radar"`` now; depth, segmentation and flow
sections are added by registering a function in ``SECTIONS``). Every metric is ``null`` when the
scene lacks the ground truth it needs, with a ``notes`` entry saying why.

Radar metrics:
    ``ego_velocity_rmse`` (m/s): RMS over frames of ``|v_est - v_true|`` (3-D, radar axes), with
        ``v_true = R^T (v_ego + w x t_mount)`` from the frames' ``ego_velocity`` (or pose finite
        differences) and the pose yaw rate. Null when the poses were integrated from this radar.
    ``dynamic_precision``: of the points flagged dynamic and labelled 0 or 1, the fraction labelled
        moving (1). Clutter and ghosts (label -1) have no true motion to get right; they are left
        out and the fraction of them flagged dynamic is reported as ``clutter_flagged_dynamic_rate``.
    ``dynamic_recall``: of the gt moving points whose true radial speed in the world is measurable
        (``|v_r_comp_true| >= 0.5`` m/s, ``v_r_comp_true = v_r + d . v_true``, i.e. the Doppler
        compensated with the TRUE ego velocity; or the fitted one when there is none), the
        fraction flagged dynamic.
    ``static_residual_median`` (m/s): median ``|v_r + d . v_est|`` over static points (gt label 0
        where labels exist, else the fit's inliers).
"""

from __future__ import annotations

import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np
import tyro

from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.io.scene import Scene, SceneError, SceneWarning, read_scene
from radar4dgs.radar.doppler import unit_directions
from radar4dgs.radar.poses import expected_radar_velocity
from radar4dgs.radar.process import load_radar_outputs

# Moving points slower than this along the line of sight cannot be seen by Doppler (m/s).
MEASURABLE_RADIAL_SPEED = 0.5


def _ratio(num: int, den: int) -> float | None:
    return float(num / den) if den > 0 else None


def evaluate_radar(scene: Scene, prepared_dir: str | Path) -> dict:
    """Radar front-end metrics (module doc) of ``<prepared_dir>/radar`` for ``scene``."""
    radar_dir = Path(prepared_dir) / "radar"
    notes: list[str] = []
    has_labels = scene.has("gt/radar_labels")
    truth, truth_source = expected_radar_velocity(scene)
    if scene.source.get("poses_from_radar"):
        truth, truth_source = None, "the scene's poses were integrated from the radar itself"
    if truth is None:
        notes.append(f"no independent ego velocity: {truth_source}")
    if not has_labels:
        notes.append("no gt/radar_labels: dynamic precision/recall unavailable")

    vel_err, static_res = [], []
    tp = fp = hit = clutter = clutter_flagged = 0
    flagged = moving_measurable = 0
    ok_frames = 0
    for i, frame in enumerate(scene.frames):
        out = load_radar_outputs(radar_dir, frame.name)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SceneWarning)  # NaN-row drops were reported by prepare
            scan = scene.load_radar(i)
        if len(out["dynamic"]) != len(scan):
            raise SceneError(radar_dir / f"{frame.name}.npz",
                             f"{len(out['dynamic'])} rows, the scan has {len(scan)}: stale outputs, "
                             f"rerun `radar4dgs prepare --force`")
        ok_frames += bool(out["ok"])
        v_est = out["ego_velocity"]
        if truth is not None and np.all(np.isfinite(v_est)):
            vel_err.append(float(np.linalg.norm(v_est - truth[i])))
        if len(scan) == 0:
            continue
        xyz, v_r = scan.xyz.astype(np.float64), scan.v_r.astype(np.float64)
        d, _ = unit_directions(xyz)
        dynamic = out["dynamic"].astype(bool)
        if has_labels:
            labels = scan.align(scene.load_optional("gt/radar_labels", i),
                                scene.root / "gt" / "radar_labels" / f"{scene.frames[i].name}.npy")
            static = labels == 0
            moving = labels == 1
            v_ref = truth[i] if truth is not None else v_est
            radial = np.abs(v_r + d @ v_ref)
            measurable = moving & (radial >= MEASURABLE_RADIAL_SPEED)
            tp += int((dynamic & moving).sum())
            fp += int((dynamic & static).sum())
            clutter += int((labels < 0).sum())
            clutter_flagged += int((dynamic & (labels < 0)).sum())
            hit += int((dynamic & measurable).sum())
            moving_measurable += int(measurable.sum())
        else:
            static = out["inliers"].astype(bool)
        flagged += int(dynamic.sum())
        if np.all(np.isfinite(v_est)) and static.any():
            static_res.append(np.abs(v_r[static] + d[static] @ v_est))

    residuals = np.concatenate(static_res) if static_res else np.zeros(0)
    return {
        "ego_velocity_rmse": float(np.sqrt(np.mean(np.square(vel_err)))) if vel_err else None,
        "ego_velocity_truth": truth_source if truth is not None else None,
        "dynamic_precision": _ratio(tp, tp + fp) if has_labels else None,
        "dynamic_recall": _ratio(hit, moving_measurable) if has_labels else None,
        "static_residual_median": float(np.median(residuals)) if len(residuals) else None,
        "static_points": "gt label 0" if has_labels else "RANSAC inliers",
        "frames": len(scene), "ok_frames": ok_frames, "dynamic_points": flagged,
        "measurable_moving_points": moving_measurable if has_labels else None,
        "clutter_points": clutter if has_labels else None,
        "clutter_flagged_dynamic_rate": _ratio(clutter_flagged, clutter) if has_labels else None,
        "notes": notes,
    }


def evaluate_depth(scene: Scene, prepared_dir: Path) -> dict:
    # Imported here so that scoring the radar alone does not import the depth stage.
    from radar4dgs.depth.metrics import depth_frontend_metrics

    return depth_frontend_metrics(scene, prepared_dir)


def evaluate_masks(scene: Scene, prepared_dir: Path) -> dict:
    from radar4dgs.segment.metrics import segmentation_frontend_metrics

    return segmentation_frontend_metrics(scene, prepared_dir)


def evaluate_flow(scene: Scene, prepared_dir: Path) -> dict:
    from radar4dgs.motion.metrics import motion_frontend_metrics

    return motion_frontend_metrics(scene, prepared_dir)


# Section name (= prepared stage folder) -> function(scene, prepared_dir) -> dict.
SECTIONS: dict[str, Callable[[Scene, Path], dict]] = {"radar": evaluate_radar, "depth": evaluate_depth,
                                                     "masks": evaluate_masks, "flow": evaluate_flow}


def format_report(report: dict[str, Any]) -> str:
    """The scalar metrics of every section as aligned ``section.metric  value`` lines."""
    lines = []
    for section in SECTIONS:
        for key, value in (report.get(section) or {}).items():
            if isinstance(value, bool) or not isinstance(value, (int, float, type(None))):
                continue
            shown = "null" if value is None else (f"{value:.4f}" if isinstance(value, float) else str(value))
            lines.append(f"{section + '.' + key:<40}{shown}")
    if report.get("skipped"):
        lines.append(f"{'skipped (not prepared)':<40}{', '.join(report['skipped'])}")
    return "\n".join(lines)


def evaluate_frontend(scene: Scene, prepared_dir: str | Path) -> dict[str, Any]:
    """Every section whose prepared stage folder exists; absent stages are listed as skipped."""
    prepared_dir = Path(prepared_dir)
    report: dict[str, Any] = {"scene": str(scene.root), "prepared": str(prepared_dir), "skipped": []}
    for name, function in SECTIONS.items():
        if (prepared_dir / name).is_dir():
            report[name] = function(scene, prepared_dir)
        else:
            report["skipped"].append(name)
    return report


@dataclass
class FrontendEvalCommand:
    """Score the prepared front-end outputs of a scene against its ground truth (gt/)."""

    # The scene folder.
    scene: tyro.conf.Positional[Path]
    # Where to write the JSON report (printed to stdout when not given).
    json: Optional[Path] = None
    # The prepared folder; default <scene>/prepared.
    prepared: Optional[Path] = None

    def run(self) -> int:
        import json as _json

        try:
            scene = read_scene(self.scene)
            prepared = self.prepared if self.prepared is not None else self.scene / "prepared"
            if not prepared.is_dir():
                raise SceneError(prepared, "missing prepared folder (run `radar4dgs prepare` first)")
            report = evaluate_frontend(scene, prepared)
        except (SceneError, FileNotFoundError) as exc:
            print(f"radar4dgs frontend-eval: {exc}", file=sys.stderr)
            return 1
        if self.json is not None:
            atomic_write_json(self.json, report)
            print(format_report(report))
            print(f"wrote {self.json}")
        else:
            print(_json.dumps(report, indent=2))
        return 0
