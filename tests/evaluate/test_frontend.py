import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "radar"))
from _radar_helpers import write_tiny_scene  # noqa: E402

from radar4dgs.apps.prepare import run_prepare  # noqa: E402
from radar4dgs.cli import main  # noqa: E402
from radar4dgs.evaluate.frontend import (  # noqa: E402
    SECTIONS,
    evaluate_frontend,
    evaluate_radar,
    format_report,
    object_velocity_metrics,
)
from radar4dgs.io.scene import read_scene  # noqa: E402

OBJECTS_NOTE = "no per-object ground truth"


def test_metrics_on_a_scene_with_gt(tmp_path):
    root = write_tiny_scene(tmp_path / "scene", frames=4, yaw_rate=0.2)
    run_prepare(root, only=("radar",), progress=False)
    report = evaluate_radar(read_scene(root), root / "prepared")
    assert report["ego_velocity_rmse"] < 0.05
    assert report["ego_velocity_truth"] == "ego_velocity + pose yaw rate"
    assert report["dynamic_precision"] > 0.95 and report["dynamic_recall"] > 0.9
    assert report["static_residual_median"] < 0.1
    # The hand-made scene has radar labels but no per-object ground truth: only that is noted.
    assert len(report["notes"]) == 1 and OBJECTS_NOTE in report["notes"][0]
    assert report["object_count"] is None and report["object_velocity_error_median"] is None


def test_scene_without_gt_reports_nulls(tmp_path):
    root = write_tiny_scene(tmp_path / "scene", frames=3, labels=False, ego_velocity=False, poses=False)
    run_prepare(root, only=("radar",), progress=False)
    report = evaluate_radar(read_scene(root), root / "prepared")
    assert report["ego_velocity_rmse"] is None
    assert report["dynamic_precision"] is None and report["dynamic_recall"] is None
    assert report["static_residual_median"] is not None and report["static_points"] == "RANSAC inliers"
    assert len(report["notes"]) == 3 and OBJECTS_NOTE in report["notes"][2]


def test_command_writes_json_and_sections(tmp_path):
    root = write_tiny_scene(tmp_path / "scene", frames=3)
    out = tmp_path / "eval.json"
    assert main(["frontend-eval", str(root), "--json", str(out)]) == 1  # not prepared yet
    run_prepare(root, tmp_path / "prep", only=("radar",), progress=False)
    assert main(["frontend-eval", str(root), "--json", str(out), "--prepared", str(tmp_path / "prep")]) == 0
    report = json.loads(out.read_text())
    assert set(report["radar"]) >= {"ego_velocity_rmse", "dynamic_precision", "dynamic_recall",
                                     "static_residual_median"}
    assert "radar" in SECTIONS


def test_stale_outputs_are_refused(tmp_path):
    root = write_tiny_scene(tmp_path / "scene", frames=2)
    run_prepare(root, only=("radar",), progress=False)
    path = root / "radar" / "000000.npy"
    np.save(path, np.load(path)[:-3])
    with pytest.raises(Exception, match="stale"):
        evaluate_frontend(read_scene(root), root / "prepared")


def _object(centroid, velocity, scan, radial, returns):
    """One objects.json record (radar4dgs.radar.objects) with planar vectors given as (x, y)."""
    def planar(v):
        return [float(v[0]), float(v[1]), 0.0]
    return {"track": 0, "centroid": [*map(float, centroid), 0.5], "velocity": planar(velocity),
            "velocity_covariance": [[0.1, 0.0], [0.0, 0.1]], "frame_velocity": planar(scan),
            "frame_velocity_covariance": [[0.2, 0.0], [0.0, 0.2]], "radial_velocity": planar(radial),
            "observable": True, "azimuth_spread_deg": 3.0, "residual_std": 0.1, "num_returns": returns,
            "points": list(range(returns)), "outliers": []}


def test_object_velocity_metric_in_closed_form(tmp_path):
    root = write_tiny_scene(tmp_path / "scene", frames=3)
    run_prepare(root, only=("radar",), progress=False)
    scene = read_scene(root)
    poses = [np.eye(4) for _ in range(3)]
    for i, pose in enumerate(poses):
        pose[:2, 3] = [10.0 + i, 0.0]
    parked = [np.eye(4) for _ in range(3)]
    for pose in parked:
        pose[:2, 3] = [30.0, 5.0]
    truth = [{"id": "ego", "kind": "ego"},
             {"id": 7, "kind": "moving", "poses": [p.tolist() for p in poses], "velocity": [10.0, 0.0, 0.0],
              "velocities": [[10.0, 0.0, 0.0], [12.0, 0.0, 0.0], [14.0, 0.0, 0.0]], "yaw_rates": [0.5, 0.0, 0.0]},
             {"id": 8, "kind": "parked", "poses": [p.tolist() for p in parked], "velocity": [0.0, 0.0, 0.0]}]
    scene = dataclasses.replace(scene, extra={"synthetic": {"objects": truth}})
    frames = [[_object((11, 1), (10, 1), (10, 0), (9, 0), 5)],
              # Scored against velocities[1] = 12 m/s, not the constant "velocity".
              [_object((12, 0), (12, 0), (13, 0), (12, 0), 3),
               _object((30, 5), (0, 0), (0, 0), (0, 0), 4)],           # a parked car: unmatched
              [_object((12, 0), (0, 0), (0, 0), (0, 0), 2)]]           # too few returns: not scored
    document = {"format": "radar4dgs-radar-objects", "version": 1,
                "frames": [{"name": f.name, "timestamp": f.timestamp, "objects": o}
                           for f, o in zip(scene.frames, frames, strict=True)]}
    (root / "prepared" / "radar" / "objects.json").write_text(json.dumps(document))
    metrics, notes = object_velocity_metrics(scene, root / "prepared")
    assert notes == []
    assert metrics["object_count"] == 2 and metrics["object_unmatched"] == 1
    assert metrics["object_observable_fraction"] == 1.0
    for key in ("velocity", "scan", "radial"):
        assert metrics[f"object_{key}_error_median"] == pytest.approx(0.5)
        assert metrics[f"object_{key}_error_p90"] == pytest.approx(0.9)
    # Frame 0 turns at 0.5 rad/s: the body point at the returns' centroid, (1, 1) m from the pose,
    # moves at (10, 0) + 0.5 (-1, 1) = (9.5, 0.5) m/s, 0.71 m/s from the tracked (10, 1).
    assert metrics["object_velocity_at_returns_error_median"] == pytest.approx(0.5 ** 0.5 / 2)
    assert metrics["object_velocity_at_returns_error_p90"] == pytest.approx(0.9 * 0.5 ** 0.5)
    # Without objects.json (a folder prepared before it existed) the metric is skipped with a note.
    (root / "prepared" / "radar" / "objects.json").unlink()
    metrics, notes = object_velocity_metrics(scene, root / "prepared")
    assert metrics["object_count"] is None and "objects.json: missing file" in notes[0]


def test_object_velocity_on_a_tiny_synthetic_scene(tmp_path):
    from radar4dgs.config import preset
    from radar4dgs.datasets.synth import SynthConfig, synthesize

    root = synthesize(preset(SynthConfig, "tiny", seed=1), tmp_path / "scene", progress=False)
    run_prepare(root, only=("radar",), progress=False)
    report = evaluate_frontend(read_scene(root), root / "prepared")
    radar = report["radar"]
    # Measured (seed 1, 20 frames): 31 objects, tracked error median 0.13 / p90 0.41 m/s; one scan's
    # own fit 0.33 / 1.21; radial-only 0.07 / 1.62.
    assert radar["object_count"] >= 15
    assert radar["object_velocity_error_median"] < 0.4 and radar["object_velocity_error_p90"] < 1.2
    assert radar["object_radial_error_median"] is not None
    assert "radar.object_velocity_error_median" in format_report(report)


def test_a_scene_without_gt_depth_is_scored_on_what_it_has(tiny_trained_run, tmp_path, capsys):
    # Real datasets have no gt/depth: every section that can be scored is, the others are listed
    # as skipped with the reason, and the command succeeds.
    import shutil

    root = tmp_path / "scene"
    shutil.copytree(tiny_trained_run / "scene", root)
    shutil.rmtree(root / "gt" / "depth")
    assert (root / "prepared" / "flow").is_dir() and not (root / "gt" / "depth").exists()
    out = tmp_path / "frontend.json"
    assert main(["frontend-eval", str(root), "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    report = json.loads(out.read_text())
    assert report["radar"]["dynamic_recall"] is not None
    assert report["masks"]["mask_iou"] is not None
    assert report["depth"]["depth_absrel"] is None and report["depth"]["sky_iou"] is not None
    assert any("no gt/depth" in note for note in report["depth"]["notes"])
    assert "flow" not in report and "gt/depth" in report["skipped"]["flow"]
    assert "flow skipped" in printed and "no ground truth: the scene has no gt/depth" in printed
    # Without --json the report goes to stdout and each skipped section is said on stderr.
    assert main(["frontend-eval", str(root)]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["skipped"] == report["skipped"]
    assert "radar4dgs frontend-eval: skipped flow: no ground truth" in captured.err


AIMOTIVE = Path(__file__).resolve().parents[3] / "shared" / "fixtures" / "aimotive-night"


@pytest.mark.skipif(not AIMOTIVE.is_dir(), reason="shared aiMotive fixture not present")
def test_frontend_eval_on_the_converted_aimotive_clip(tmp_path, capsys):
    # A real recording: no gt/depth, gt/sky_mask, gt/dynamic_mask or gt/flow, poses from its own
    # radar. frontend-eval exits 0, scores the radar (labels from the dataset's boxes) and says why
    # the other sections are skipped: no ground truth, which preparing them would not change.
    scene = tmp_path / "aimotive"
    assert main(["convert", "aimotive", str(AIMOTIVE), str(scene), "--scale", "0.25", "--quiet"]) == 0
    assert main(["prepare", str(scene), "--preset", "tiny", "--only", "radar", "--quiet"]) == 0
    capsys.readouterr()
    assert main(["frontend-eval", str(scene), "--json", str(tmp_path / "frontend.json")]) == 0
    printed = capsys.readouterr().out
    report = json.loads((tmp_path / "frontend.json").read_text())
    radar = report["radar"]
    assert radar["frames"] == radar["ok_frames"] == 50
    assert radar["ego_velocity_rmse"] is None  # the poses came from this radar: no independent truth
    assert 0.0 <= radar["dynamic_precision"] <= 1.0 and 0.0 <= radar["dynamic_recall"] <= 1.0
    assert radar["static_residual_median"] < 0.5
    assert any("integrated from the radar itself" in note for note in radar["notes"])
    assert set(report["skipped"]) == {"depth", "masks", "object_depth", "flow"}
    assert all(reason.startswith("no ground truth: the scene has") for reason in report["skipped"].values())
    assert "radar.dynamic_precision" in printed and "depth skipped" in printed


@given(st.lists(st.floats(-30, 30), min_size=7, max_size=7))
def test_body_velocity_is_rigid(values):
    from radar4dgs.evaluate.frontend import body_velocity_at

    v, yaw_rate, origin, point = np.array(values[:2]), values[2] / 30, np.array(values[3:5]), np.array(values[5:7])
    at = body_velocity_at(v, yaw_rate, origin, point)
    # A rigid body's two points move at velocities whose difference is perpendicular to the segment
    # between them, |omega| times as long.
    offset = point - origin
    assert abs(float((at - v) @ offset)) <= 1e-9 * (1 + float(offset @ offset))
    assert np.linalg.norm(at - v) == pytest.approx(abs(yaw_rate) * np.linalg.norm(offset), abs=1e-9)
    np.testing.assert_allclose(body_velocity_at(v, yaw_rate, origin, origin), v)
