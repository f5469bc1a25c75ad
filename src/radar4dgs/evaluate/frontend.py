"""The ``frontend-eval`` command: metrics of the prepared front-end outputs against a scene's gt.

The JSON report has one section per front-end stage (radar, depth, masks, object_depth, flow; registered in
``SECTIONS``) and scores whatever ground truth the scene has: a metric is ``null`` when the scene
lacks what it needs, with a ``notes`` entry saying why, and a section that could score nothing (a
stage not prepared, or no ground truth for it: real datasets have no ``gt/depth``) is left out and
listed under ``"skipped"`` as ``{section: reason}``.

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
    ``object_*``: radar objects (``objects.json``) with at least ``OBJECT_MIN_RETURNS`` returns, each
        matched to the nearest moving ground-truth object (scene.json ``extra.synthetic.objects``,
        planar distance from its centroid to the object's pose translation at that frame, within
        ``OBJECT_MATCH_GATE``). Errors are planar norms (m/s) against that object's velocity
        (``velocities[frame]`` where given, else ``velocity``): ``object_velocity_error_*`` for the
        tracked velocity, ``object_scan_error_*`` for the scan's own fit, ``object_radial_error_*``
        for the radial-only baseline (the velocity component along the mean line of sight only);
        median and p90 over ``object_count`` matched objects. ``object_velocity_at_returns_error_*``
        scores the tracked velocity against the ground-truth body's velocity at the returns'
        centroid, ``v + omega J (c - p)`` with the object's yaw rate ``omega`` (``yaw_rates``, 0
        where absent): a turning body's points move at different velocities, and the tracker
        estimates the one at its returns, which is what the velocity term uses; it equals the
        first for objects that do not turn. ``object_unmatched``: objects with no
        moving ground-truth object within the gate. ``object_observable_fraction``: of the matched
        objects, those whose returns spread enough in azimuth for a full per-scan fit.

Object-depth metrics (:func:`radar4dgs.evaluate.dynamic_depth.object_depth_metrics`): ``mover_absrel_before`` /
    ``_after`` and ``mover_bias_before`` / ``_after``, the prepared depth on the truly moving pixels
    before and after each moving object is rescaled by its radar returns.
"""

from __future__ import annotations

import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Callable, Optional

import numpy as np
import tyro

from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.io.scene import Scene, SceneError, SceneWarning, read_scene
from radar4dgs.radar.doppler import unit_directions
from radar4dgs.radar.objects import load_radar_objects
from radar4dgs.radar.poses import expected_radar_velocity
from radar4dgs.radar.process import load_radar_outputs

# Moving points slower than this along the line of sight cannot be seen by Doppler (m/s).
MEASURABLE_RADIAL_SPEED = 0.5
# A radar object matches a moving ground-truth object whose pose translation (footprint centre) lies
# within this planar distance (m) of the object's centroid: returns lie on the near side of a car, up
# to half its length (~2.3 m) from the centre.
OBJECT_MATCH_GATE = 4.0
# Radar objects with fewer returns are not scored: two returns determine a planar velocity exactly,
# with nothing left to check it.
OBJECT_MIN_RETURNS = 3


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
    objects, object_notes = object_velocity_metrics(scene, prepared_dir)
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
        **objects,
        "notes": notes + object_notes,
    }


def moving_ground_truth(scene: Scene) -> list[dict]:
    """The moving objects of the synthetic generator's ground truth (``extra.synthetic.objects``
    entries of kind "moving" with per-frame "poses"); empty when the scene has none."""
    synthetic = scene.extra.get("synthetic")
    objects = synthetic.get("objects") if isinstance(synthetic, dict) else None
    if not isinstance(objects, list):
        return []
    return [o for o in objects if isinstance(o, dict) and o.get("kind") == "moving"
            and len(o.get("poses") or ()) == len(scene) and ("velocity" in o or "velocities" in o)]


def _truth_at(obj: dict, frame: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(2,) planar position (pose translation), (2,) planar world velocity and yaw rate (rad/s; 0
    where the scene records none) of ``obj`` at ``frame``."""
    velocities, yaw_rates = obj.get("velocities"), obj.get("yaw_rates")
    velocity = velocities[frame] if velocities is not None and len(velocities) > frame else None
    velocity = obj["velocity"] if velocity is None else velocity
    yaw_rate = float(yaw_rates[frame]) if yaw_rates is not None and len(yaw_rates) > frame else 0.0
    return (np.asarray(obj["poses"][frame], dtype=np.float64)[:2, 3], np.asarray(velocity, dtype=np.float64)[:2],
            yaw_rate)


def body_velocity_at(velocity: np.ndarray, yaw_rate: float, origin: np.ndarray, point: np.ndarray) -> np.ndarray:
    """(2,) planar velocity of the rigid body point ``point`` (2,) of a body whose ``origin`` (2,)
    moves at ``velocity`` (2,) while it turns at ``yaw_rate``: ``v + omega J (point - origin)``."""
    offset = np.asarray(point, dtype=np.float64) - origin
    return velocity + yaw_rate * np.array([-offset[1], offset[0]])


def _quantiles(prefix: str, errors: list[float]) -> dict[str, float | None]:
    if not errors:
        return {f"{prefix}_median": None, f"{prefix}_p90": None}
    return {f"{prefix}_median": float(np.median(errors)), f"{prefix}_p90": float(np.percentile(errors, 90))}


def object_velocity_metrics(scene: Scene, prepared_dir: str | Path) -> tuple[dict[str, Any], list[str]]:
    """The ``object_*`` radar metrics (module doc) and notes on what was unavailable."""
    errors: dict[str, list[float]] = {"velocity": [], "velocity_at_returns": [], "scan": [], "radial": []}
    counts = {"object_count": None, "object_unmatched": None, "object_observable_fraction": None}
    empty = {**counts, **{k: v for key in errors for k, v in _quantiles(f"object_{key}_error", []).items()}}
    truth = moving_ground_truth(scene)
    if not truth:
        return empty, ["no per-object ground truth (scene.json extra.synthetic.objects with moving "
                       "objects): object velocity errors unavailable"]
    try:
        per_frame = load_radar_objects(prepared_dir)
    except (FileNotFoundError, ValueError) as exc:
        return empty, [f"object velocity errors unavailable: {exc}"]
    if len(per_frame) != len(scene):
        return empty, [f"objects.json has {len(per_frame)} frames, the scene {len(scene)}: stale, rerun "
                       f"`radar4dgs prepare --only radar --force`"]
    unmatched = observable = 0
    for i, objects in enumerate(per_frame):
        places = [_truth_at(o, i) for o in truth]
        for obj in objects:
            if obj.num_returns < OBJECT_MIN_RETURNS:
                continue
            gaps = [float(np.linalg.norm(obj.centroid[:2] - p)) for p, _, _ in places]
            if min(gaps) > OBJECT_MATCH_GATE:
                unmatched += 1
                continue
            origin, v_true, yaw_rate = places[int(np.argmin(gaps))]
            observable += bool(obj.observable)
            for key, v in (("velocity", obj.velocity), ("scan", obj.frame_velocity),
                           ("radial", obj.radial_velocity)):
                errors[key].append(float(np.linalg.norm(v[:2] - v_true)))
            at_returns = body_velocity_at(v_true, yaw_rate, origin, obj.centroid[:2])
            errors["velocity_at_returns"].append(float(np.linalg.norm(obj.velocity[:2] - at_returns)))
    scored = len(errors["velocity"])
    out: dict[str, Any] = {"object_count": scored, "object_unmatched": unmatched,
                           "object_observable_fraction": _ratio(observable, scored)}
    for key, values in errors.items():
        out.update(_quantiles(f"object_{key}_error", values))
    return out, []


def evaluate_depth(scene: Scene, prepared_dir: Path) -> dict:
    # Imported here so that scoring the radar alone does not import the depth stage.
    from radar4dgs.depth.metrics import depth_frontend_metrics

    result = depth_frontend_metrics(scene, prepared_dir)
    notes = [f"no {folder}: {what} unavailable" for folder, what in
             (("gt/depth", "depth_absrel, depth_rmse, depth_delta1, depth_coverage"), ("gt/sky_mask", "sky_iou"))
             if not scene.has(folder)]
    return {**result, "notes": notes} if notes else result


def evaluate_object_depth(scene: Scene, prepared_dir: Path) -> dict:
    from radar4dgs.evaluate.dynamic_depth import object_depth_metrics

    return object_depth_metrics(scene, prepared_dir)


def evaluate_masks(scene: Scene, prepared_dir: Path) -> dict:
    from radar4dgs.segment.metrics import segmentation_frontend_metrics

    return segmentation_frontend_metrics(scene, prepared_dir)


def evaluate_flow(scene: Scene, prepared_dir: Path) -> dict:
    from radar4dgs.motion.metrics import motion_frontend_metrics

    return motion_frontend_metrics(scene, prepared_dir)


# Section name (= prepared stage folder) -> function(scene, prepared_dir) -> dict.
SECTIONS: dict[str, Callable[[Scene, Path], dict]] = {"radar": evaluate_radar, "depth": evaluate_depth,
                                                     "masks": evaluate_masks, "object_depth": evaluate_object_depth,
                                                     "flow": evaluate_flow}
# Section -> the ground-truth folders it cannot score without: every one of them ("all"), or at
# least one ("any"). The radar section always scores something (the static residual needs none).
GROUND_TRUTH: dict[str, tuple[str, tuple[str, ...]]] = {
    "depth": ("any", ("gt/depth", "gt/sky_mask")),
    "masks": ("all", ("gt/dynamic_mask",)),
    "object_depth": ("all", ("gt/depth", "gt/dynamic_mask")),
    "flow": ("all", ("gt/depth", "gt/flow", "gt/dynamic_mask")),
}


def missing_ground_truth(scene: Scene, section: str) -> str | None:
    """Why ``scene`` has no ground truth to score ``section`` with (None when it has)."""
    mode, folders = GROUND_TRUTH.get(section, ("all", ()))
    missing = [f for f in folders if not scene.has(f)]
    if mode == "any" and len(missing) == len(folders) and folders:
        return f"the scene has none of {', '.join(folders)}"
    if mode == "all" and missing:
        return f"the scene has no {', '.join(missing)}"
    return None


def format_report(report: dict[str, Any]) -> str:
    """The scalar metrics of every section as aligned ``section.metric  value`` lines."""
    lines = []
    for section in SECTIONS:
        for key, value in (report.get(section) or {}).items():
            if isinstance(value, bool) or not isinstance(value, (int, float, type(None))):
                continue
            shown = "null" if value is None else (f"{value:.4f}" if isinstance(value, float) else str(value))
            lines.append(f"{section + '.' + key:<40}{shown}")
    for section in SECTIONS:
        for note in (report.get(section) or {}).get("notes") or ():
            lines.append(f"{section + ' (note)':<40}{note}")
    for section, reason in (report.get("skipped") or {}).items():
        lines.append(f"{section + ' skipped':<40}{reason}")
    return "\n".join(lines)


def evaluate_frontend(scene: Scene, prepared_dir: str | Path) -> dict[str, Any]:
    """Every section that has its prepared stage folder and ground truth to score it with; the
    others are listed under ``"skipped"`` as ``{section: reason}``."""
    prepared_dir = Path(prepared_dir)
    report: dict[str, Any] = {"scene": str(scene.root), "prepared": str(prepared_dir), "skipped": {}}
    for name, function in SECTIONS.items():
        missing = missing_ground_truth(scene, name)
        if missing:  # first: preparing the stage would not help
            report["skipped"][name] = f"no ground truth: {missing}"
        elif not (prepared_dir / name).is_dir():
            report["skipped"][name] = f"not prepared (no {prepared_dir / name}; run `radar4dgs prepare`)"
        else:
            report[name] = function(scene, prepared_dir)
    return report


@dataclass
class FrontendEvalCommand:
    """Score the prepared front-end outputs of a scene against its ground truth (gt/)."""

    # The scene folder.
    scene: tyro.conf.Positional[Path]
    # Where to write the JSON report (printed to stdout when not given).
    json: Optional[Path] = None
    # The prepared folder.
    prepared: Annotated[Optional[Path], tyro.conf.arg(help_behavior_hint="(default: SCENE/prepared)")] = None

    def run(self) -> int:
        import json as _json

        # A missing or malformed scene or prepared folder is a user error: one line (radar4dgs.cli).
        scene = read_scene(self.scene)
        prepared = self.prepared if self.prepared is not None else self.scene / "prepared"
        if not prepared.is_dir():
            raise SceneError(prepared, "missing prepared folder (run `radar4dgs prepare` first)")
        report = evaluate_frontend(scene, prepared)
        if self.json is not None:
            atomic_write_json(self.json, report)
            print(format_report(report))
            print(f"wrote {self.json}")
        else:
            print(_json.dumps(report, indent=2))
            for section, reason in report["skipped"].items():
                print(f"radar4dgs frontend-eval: skipped {section}: {reason}", file=sys.stderr)
        return 0
