"""The scene level of the flow stage on a tiny synthetic scene: the prepared flow/ folder, its
front-end metrics, and the errors for missing prepared inputs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radar4dgs.motion.association import load_radar_dynamics
from radar4dgs.motion.config import FlowConfig, flow_settings_at_width
from radar4dgs.motion.flow import frame_inputs, frame_pairs, load_flow_pairs, object_scale, prepare_flow
from radar4dgs.motion.metrics import motion_frontend_metrics


def test_prepare_flow_writes_pairs_of_training_frames(motion_scene, motion_prepared):
    pairs = load_flow_pairs(motion_prepared)
    expected = frame_pairs(motion_scene, skip_test_frames=True)
    assert [(int(p["index_i"]), int(p["index_j"])) for p in pairs] == expected
    assert not set(motion_scene.test_indices) & {i for pair in expected for i in pair}
    h, w = motion_scene.camera.height, motion_scene.camera.width
    total = 0
    for pair in pairs:
        assert pair["flow"].shape == (h, w, 2) and pair["consistent"].shape == (h, w)
        assert pair["points_i"].shape == pair["points_j"].shape == (len(pair["pixels"]), 3)
        total += len(pair["pixels"])
    assert total > 0
    assert json.loads((motion_prepared / "flow" / "config.json").read_text())["depth_source"] == "oracle"
    summary = json.loads((motion_prepared / "flow" / "summary.json").read_text())
    assert [p["filled_pixels"] for p in summary["per_pair"]] == [int(p["filled"].sum()) for p in pairs]
    metrics = motion_frontend_metrics(motion_scene, motion_prepared)
    assert metrics["flow2d_pairs"] > 0
    assert 0 <= metrics["flow2d_epe_dynamic"] < 5.0  # pixels, on 160x90
    assert 0 <= metrics["sceneflow_epe_dynamic"] < 1.0  # metres


def test_missing_prepared_inputs_name_the_folder_and_the_option(motion_scene, tmp_path):
    with pytest.raises(FileNotFoundError, match=r"depth.*depth_source='oracle'"):
        prepare_flow(motion_scene, tmp_path, FlowConfig())
    with pytest.raises(FileNotFoundError, match=r"masks.*mask_source='oracle'"):
        prepare_flow(motion_scene, tmp_path, FlowConfig(depth_source="oracle"))
    with pytest.raises(FileNotFoundError, match=r"radar.*radar_source='oracle'"):
        load_radar_dynamics(motion_scene, 0, "prepared", tmp_path)
    assert not (tmp_path / "flow").exists()


def test_a_rescaled_frame_keeps_the_depth_stage_map_for_its_pairs_other_end(motion_scene, tmp_path):
    # Frame 0's movers were rescaled by the object-depth stage, frame 1's were not: frame 0 reads the
    # rescaled map and knows its scale (1 / 1.02 on the car, 1 elsewhere); frame 1 has one map only.
    truth = [motion_scene.load_optional("gt/depth", k).astype(np.float64) for k in (0, 1)]
    mask = motion_scene.load_optional("gt/dynamic_mask", 0)
    for folder in ("depth", "object_depth"):
        (tmp_path / folder).mkdir()
    for k, depth in enumerate(truth):
        np.save(tmp_path / "depth" / f"{motion_scene.frames[k].name}.npy", 1.02 * depth)
    np.save(tmp_path / "object_depth" / f"{motion_scene.frames[0].name}.npy", np.where(mask, truth[0], 1.02 * truth[0]))
    config = FlowConfig(depth_source="prepared", mask_source="oracle")
    first, second = (frame_inputs(motion_scene, k, config, tmp_path, None, None) for k in (0, 1))
    np.testing.assert_allclose(first.base, 1.02 * truth[0])
    scale = object_scale(first.depth, first.base)
    finite = np.isfinite(truth[0]) & (truth[0] > 0)
    np.testing.assert_allclose(scale[mask & finite], 1 / 1.02)
    assert np.all(scale[~mask] == 1.0) and second.base is second.depth


@pytest.mark.parametrize(("flow_y", "out_of_view"), [(-0.2, 0.0), (-20.0, 1.0)])
def test_2d_flow_error_counts_only_pixels_that_stay_in_view(tmp_path, monkeypatch, flow_y, out_of_view):
    """A block moving 0.2 m sideways stays in view: a stored flow 3 px off scores 3 px. Moving
    20 m it leaves the 80 px image (a gt 'flow' of ~200 px): it is counted as out of view, not scored."""
    import radar4dgs.motion.metrics as metrics_module
    from _motion_scene import write_scene
    from radar4dgs.motion.metrics import gt_flow_2d

    scene = write_scene(tmp_path / "scene", frames=2, flow_y=flow_y)
    gt2d, _ = gt_flow_2d(scene, 0)
    stored = gt2d + np.array([3.0, 0.0])
    pair = {"index_i": 0, "index_j": 1, "flow": stored, "pixels": np.zeros((0, 2)),
            "points_i": np.zeros((0, 3)), "points_j": np.zeros((0, 3))}
    monkeypatch.setattr(metrics_module, "load_flow_pairs", lambda _: [pair])
    metrics = motion_frontend_metrics(scene, tmp_path)
    assert metrics["flow2d_out_of_view"] == out_of_view
    if out_of_view:
        assert metrics["flow2d_epe_dynamic"] is None
    else:
        assert np.isclose(metrics["flow2d_epe_dynamic"], 3.0) and np.isclose(metrics["flow2d_epe_dynamic_p90"], 3.0)


def test_2d_flow_error_is_split_by_what_the_checks_kept(tmp_path, monkeypatch):
    """Stored flow exact on the pixels that passed both checks and 3 px off on the others: the kept
    pixels score 0 px, the rejected 3 px, and the kept share is theirs among the scored pixels."""
    import radar4dgs.motion.metrics as metrics_module
    from _motion_scene import write_scene
    from radar4dgs.motion.metrics import gt_flow_2d

    scene = write_scene(tmp_path / "scene", frames=2, flow_y=-0.2)
    gt2d, valid = gt_flow_2d(scene, 0)
    scored = scene.load_optional("gt/dynamic_mask", 0) & valid
    consistent = np.zeros(scored.shape, bool)
    consistent[:, ::2] = True  # every other column passes forward-backward ...
    reliable = np.ones(scored.shape, bool)
    reliable[::3] = False  # ... and two rows in three pass the photometric check
    kept = consistent & reliable
    stored = np.where(kept[..., None], gt2d, gt2d + np.array([3.0, 0.0]))
    pair = {"index_i": 0, "index_j": 1, "flow": stored, "consistent": consistent, "reliable": reliable,
            "pixels": np.zeros((0, 2)), "points_i": np.zeros((0, 3)), "points_j": np.zeros((0, 3))}
    monkeypatch.setattr(metrics_module, "load_flow_pairs", lambda _: [pair])
    metrics = motion_frontend_metrics(scene, tmp_path)
    assert metrics["flow2d_out_of_view"] == 0.0 and 0 < kept[scored].sum() < scored.sum()
    assert metrics["flow2d_kept_share"] == pytest.approx(kept[scored].mean())
    assert metrics["flow2d_epe_dynamic_kept"] == pytest.approx(0.0, abs=1e-9)
    assert metrics["flow2d_epe_dynamic_rejected"] == pytest.approx(3.0)
    assert metrics["flow2d_epe_dynamic"] == pytest.approx(3.0 * (1 - kept[scored].mean()))
    # Pairs without the flags (older prepared folders) leave the split out.
    del pair["consistent"]
    assert motion_frontend_metrics(scene, tmp_path)["flow2d_kept_share"] is None


def test_pixel_lengths_scale_with_the_scene_width_when_asked():
    config = FlowConfig(reference_width=320)
    wide = flow_settings_at_width(config, 640)
    assert (wide.rigid_search, wide.radar_search, wide.radar_association_radius) == (24, 48, 8.0)
    assert (wide.fill_max_distance, wide.pixel_error_window, wide.rigid_wide_search) == (20.0, 11, 0)
    assert (wide.rigid_min_pixels, wide.consistency_beta) == (config.rigid_min_pixels, config.consistency_beta)
    assert flow_settings_at_width(config, 160).pixel_error_window == 3  # 2.5 rounds to an odd 3
    assert flow_settings_at_width(config, 320) is config
    default = FlowConfig()
    assert flow_settings_at_width(default, 640) is default  # off by default
