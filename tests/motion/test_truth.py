"""The generator's true motion between frames that are not consecutive, against the moving objects'
own poses, and the oracle flow method built on it."""

from __future__ import annotations

import numpy as np
import pytest

from radar4dgs.config import preset
from radar4dgs.motion.config import FlowConfig
from radar4dgs.motion.flow import load_flow_pairs, prepare_flow
from radar4dgs.motion.metrics import gt_flow_2d, motion_frontend_metrics
from radar4dgs.motion.truth import gt_scene_flow, in_boxes


def _object_of(world: np.ndarray, obj: dict, frame: int) -> np.ndarray:
    """(N,) bool: which (N, 3) world points lie in ``obj``'s box at ``frame`` (grown by 0.2 m)."""
    return in_boxes(world, np.asarray(obj["poses"][frame])[None], np.array([obj["dims"]]), 0.2)[0]


def test_two_frame_motion_is_each_movers_own_rigid_motion(motion_scene):
    """Composed over the frame in between, a moving pixel's point lands where its object's poses
    put it (X_j = P_j P_i^-1 X_i), and a static pixel's point stays where it was."""
    movers = [o for o in motion_scene.extra["synthetic"]["objects"] if o.get("kind") == "moving" and "poses" in o]
    checked = 0
    for i in range(len(motion_scene) - 2):
        world_i, world_j, valid = gt_scene_flow(motion_scene, i, i + 2)
        dynamic = motion_scene.load_optional("gt/dynamic_mask", i)
        static = valid & ~dynamic
        np.testing.assert_allclose(world_j[static], world_i[static], atol=1e-6)
        points_i, points_j = world_i[valid & dynamic], world_j[valid & dynamic]
        for obj in movers:
            inside = _object_of(points_i, obj, i)
            if not inside.any():
                continue
            relative = np.asarray(obj["poses"][i + 2]) @ np.linalg.inv(np.asarray(obj["poses"][i]))
            expected = points_i[inside] @ relative[:3, :3].T + relative[:3, 3]
            error = np.linalg.norm(points_j[inside] - expected, axis=1)
            assert np.median(error) < 0.01 and np.quantile(error, 0.95) < 0.05, (i, obj["id"])
            checked += int(inside.sum())
    assert checked > 100


def test_consecutive_frames_need_no_composition(motion_scene):
    world_i, world_j, valid = gt_scene_flow(motion_scene, 3, 4)
    motion = motion_scene.load_optional("gt/flow", 3).astype(np.float64)
    np.testing.assert_allclose((world_j - world_i)[valid], motion[valid], atol=1e-9)
    with pytest.raises(ValueError, match="forward in time"):
        gt_scene_flow(motion_scene, 4, 4)


def test_oracle_flow_method_writes_the_truth(motion_scene, tmp_path):
    # depth_source stays "prepared" and tmp_path has no depth: the oracle takes the generator's own.
    prepare_flow(motion_scene, tmp_path, preset(FlowConfig, "tiny", method="oracle", mask_source="oracle"))
    metrics = motion_frontend_metrics(motion_scene, tmp_path)
    assert metrics["flow2d_epe_dynamic"] < 1e-3 and metrics["sceneflow_epe_dynamic"] < 1e-4
    assert metrics["sceneflow_two_frame_pairs"] > 0 and metrics["sceneflow_epe_dynamic_two_frame"] < 1e-4
    assert metrics["flow2d_epe_dynamic_two_frame"] < 1e-3
    skipping = [p for p in load_flow_pairs(tmp_path) if int(p["index_j"]) > int(p["index_i"]) + 1]
    assert skipping, "the tiny scene's training pairs skip its test frames"
    pair = skipping[0]
    i, j = int(pair["index_i"]), int(pair["index_j"])
    gt2d, valid = gt_flow_2d(motion_scene, i, j)
    assert np.abs(pair["flow"][pair["consistent"]] - gt2d[pair["consistent"]]).max() < 1e-3
    dynamic = motion_scene.load_optional("gt/dynamic_mask", i)
    assert len(pair["points_i"]) == int((pair["consistent"] & dynamic).sum()) > 0
    assert (valid | ~pair["consistent"]).all()


def test_the_pairs_that_skip_a_test_frame_are_scored_against_the_composed_motion(motion_scene, tmp_path):
    prepare_flow(motion_scene, tmp_path, preset(FlowConfig, "tiny", method="oracle", mask_source="oracle"))
    offset = np.array([0.3, 0.0, 0.4], dtype=np.float32)  # 0.5 m
    for path in sorted((tmp_path / "flow").glob("*.npz")):
        with np.load(path) as data:
            arrays = {key: data[key] for key in data.files}
        if int(arrays["index_j"]) > int(arrays["index_i"]) + 1:
            arrays["points_j"] = arrays["points_j"] + offset
            arrays["flow"] = arrays["flow"] + np.array([3.0, -4.0], dtype=arrays["flow"].dtype)  # 5 px
            np.savez(path, **arrays)
    metrics = motion_frontend_metrics(motion_scene, tmp_path)
    assert metrics["sceneflow_epe_dynamic"] < 1e-4 and metrics["flow2d_epe_dynamic"] < 1e-3  # adjacent pairs untouched
    assert metrics["sceneflow_epe_dynamic_two_frame"] == pytest.approx(0.5, abs=1e-4)
    assert metrics["flow2d_epe_dynamic_two_frame"] == pytest.approx(5.0, abs=1e-3)
