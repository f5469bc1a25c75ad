"""The standalone motion fit on a tiny synthetic scene: radar samples, radar-object velocity samples,
and fits that beat a field that does not move."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from radar4dgs.config import preset
from radar4dgs.io.scene import normalized_times
from radar4dgs.motion.association import load_radar_dynamics
from radar4dgs.motion.config import FlowConfig
from radar4dgs.motion.flow import frame_pairs
from radar4dgs.train.config import FitConfig, MotionConfig
from radar4dgs.train.fit_motion import (
    collect_radar_samples,
    collect_velocity_samples,
    dynamic_pixels,
    dynamic_points,
    load_field,
    run_fit,
    save_field,
)

# Tiny tensors: on the shared 2-core CI machine extra torch threads only spin.
pytestmark = pytest.mark.usefixtures("one_torch_thread")

ORACLE = {"depth_source": "oracle", "mask_source": "oracle"}  # gt depth and masks: the tests isolate one stage


def test_dynamic_pixels_are_masked_pixels_with_depth_and_lift_to_their_depth():
    depth = np.full((6, 8), 10.0)
    depth[0, :] = np.nan
    depth[1, :] = -1.0
    mask = np.zeros((6, 8), bool)
    mask[:3, 2:5] = True  # rows 0 and 1 have no usable depth: only row 2's three pixels count
    rows, cols = dynamic_pixels(depth, mask, 0, np.random.default_rng(0))
    assert sorted(zip(rows.tolist(), cols.tolist(), strict=True)) == [(2, 2), (2, 3), (2, 4)]
    rows, cols = dynamic_pixels(depth, mask, 2, np.random.default_rng(0))
    assert len(rows) == 2 and set(rows.tolist()) == {2}
    K = np.array([[4.0, 0, 4.0], [0, 4.0, 3.0], [0, 0, 1]])
    points = dynamic_points(depth, mask, K, np.eye(4), 0, np.random.default_rng(0))
    np.testing.assert_allclose(np.sort(points[:, 0]), 10.0 * (np.array([2, 3, 4]) - 4.0) / 4.0)
    np.testing.assert_allclose(points[:, 2], 10.0)


def test_radar_returns_become_samples_with_their_own_doppler(motion_scene):
    flow = FlowConfig(**ORACLE)
    times = normalized_times(motion_scene)
    base, base_stats = collect_radar_samples(motion_scene, None, flow,
                                             FitConfig(radar_source="oracle", radar_returns_as_points=False), times)
    more, stats = collect_radar_samples(motion_scene, None, flow,
                                        FitConfig(radar_source="oracle", radar_returns_as_points=True), times)
    pairs = frame_pairs(motion_scene, flow.skip_test_frames)
    returns = [load_radar_dynamics(motion_scene, i, "oracle") for i, _ in pairs]
    assert stats["radar_returns_supervised"] == sum(len(r) for r in returns) > 0
    assert base_stats["radar_returns_supervised"] == 0 and stats["radar_matched"] == base_stats["radar_matched"]
    assert len(more) == len(base) + stats["radar_returns_supervised"]
    # The returns of the first pair follow its lifted pixels, with their own Doppler and radar centre.
    first = int(np.sum(more.t_i == times[pairs[0][0]])) - len(returns[0])
    block = slice(first, first + len(returns[0]))
    assert np.array_equal(more.x[block], returns[0].points)
    assert np.array_equal(more.v_r[block], returns[0].v_r_comp)
    assert np.allclose(more.centre[block], returns[0].centre)


def test_fit_beats_a_field_that_does_not_move(motion_scene, motion_prepared):
    config = preset(MotionConfig, "tiny", flow=ORACLE, fit={"radar_source": "oracle", "iterations": 60})
    field, result = run_fit(motion_scene, motion_prepared, config, use_flow=True, use_radar=True)
    metrics = result["sceneflow"]
    assert metrics["points"] > 0 and metrics["epe"] < 0.8 * metrics["zero_motion_epe"]
    # The image-motion bins partition the evaluated points and average back to the pooled error.
    bins = [b for b in metrics["epe_by_image_motion"] if b["points"]]
    assert sum(b["points"] for b in bins) == metrics["points"]
    assert np.isclose(sum(b["epe"] * b["points"] for b in bins) / metrics["points"], metrics["epe"])
    assert metrics["epe_by_image_motion"][-1]["high"] is None
    assert result["history"][-1]["total"] < result["history"][0]["total"]
    path = save_field(field, motion_prepared / "field.pt")
    again = load_field(path)
    x = torch.rand(10, 3) * 20
    assert torch.equal(again.warp(x, 0.1, 0.4), field.warp(x, 0.1, 0.4))


@pytest.fixture(scope="module")
def radar_prepared(motion_scene, tmp_path_factory):
    """``motion_scene``'s radar stage alone (dynamic flags and objects.json), about a second."""
    from radar4dgs.apps.prepare import PrepareConfig, run_prepare

    folder = tmp_path_factory.mktemp("radar-prepared") / "prepared"
    run_prepare(motion_scene.root, folder, preset(PrepareConfig, "tiny"), only=("radar",), progress=False)
    return folder


def _true_velocities(scene) -> list[np.ndarray]:
    """(2,) planar velocity of each moving generator object (its first frame's)."""
    objects = scene.extra["synthetic"]["objects"]
    return [np.asarray((o.get("velocities") or [o["velocity"]])[0], dtype=float)[:2]
            for o in objects if o.get("kind") == "moving"]


def test_velocity_samples_match_the_true_object_velocities(motion_scene, radar_prepared):
    times = normalized_times(motion_scene)
    returns_only = FitConfig(velocity_pixels="off")
    samples, stats = collect_velocity_samples(motion_scene, radar_prepared, FlowConfig(), returns_only, times)
    assert stats["velocity_note"] is None and stats["velocity_objects"] > 0 and len(samples) > 0
    assert samples.x.shape == (len(samples), 3) and samples.covariance.shape == (len(samples), 2, 2)
    pairs = frame_pairs(motion_scene)
    assert set(np.round(samples.t_i, 9)) <= {round(float(times[i]), 9) for i, _ in pairs}
    assert np.allclose(samples.dt, (samples.t_j - samples.t_i) * motion_scene.duration)
    # Every sample's velocity is near one of the movers' (tracked, from Doppler only).
    truth = np.stack(_true_velocities(motion_scene))
    error = np.linalg.norm(samples.velocity[:, None] - truth[None], axis=2).min(axis=1)
    assert np.median(error) < 0.5 and np.percentile(error, 90) < 1.5
    # Trusted only: the covariance threshold holds, and a stricter one keeps fewer objects.
    assert np.sqrt(np.trace(samples.covariance, axis1=1, axis2=2)).max() <= returns_only.velocity_max_std
    strict, _ = collect_velocity_samples(motion_scene, radar_prepared, FlowConfig(), FitConfig(
        velocity_pixels="off", velocity_min_returns=8, velocity_max_std=0.3), times)
    assert len(strict) < len(samples)
    # With the objects' dynamic pixels: more samples, the same velocities; without a flow folder
    # every object counts as lacking flow, so "no_flow" adds them all.
    pixels, pixel_stats = collect_velocity_samples(motion_scene, radar_prepared, FlowConfig(**ORACLE),
                                                   FitConfig(velocity_pixels="no_flow"), times)
    assert pixel_stats["velocity_pixels"] > 0 and len(pixels) == len(samples) + pixel_stats["velocity_pixels"]
    assert set(map(tuple, pixels.velocity)) == set(map(tuple, samples.velocity))
    # The oracle source gives the generator's velocities exactly, on returns inside the movers.
    oracle, oracle_stats = collect_velocity_samples(motion_scene, None, FlowConfig(),
                                                    FitConfig(radar_source="oracle", velocity_pixels="off"), times)
    assert oracle_stats["velocity_objects"] > 0
    assert np.linalg.norm(oracle.velocity[:, None] - truth[None], axis=2).min(axis=1).max() < 1e-9


def test_velocity_term_off_without_objects_json(motion_scene, motion_prepared):
    times = normalized_times(motion_scene)
    with pytest.warns(UserWarning, match="velocity term off"):
        samples, stats = collect_velocity_samples(motion_scene, motion_prepared, FlowConfig(), FitConfig(), times)
    assert len(samples) == 0 and "objects.json" in stats["velocity_note"]
    config = preset(MotionConfig, "tiny", flow=ORACLE, fit={"iterations": 5, "velocity": True})
    with pytest.warns(UserWarning, match="velocity term off"):
        _, result = run_fit(motion_scene, motion_prepared, config, use_flow=True, use_radar=False, evaluate=False)
    assert result["use_velocity"] and result["velocity_samples"] == 0
    assert "velocity" not in result["history"][-1]


def test_velocity_term_alone_moves_the_movers_the_right_way(motion_scene, radar_prepared):
    # Without flow every object lacks it: its dynamic pixels (gt depth and masks here) join its returns.
    config = preset(MotionConfig, "tiny", flow=ORACLE, fit={"iterations": 100})
    _, result = run_fit(motion_scene, radar_prepared, config, use_flow=False, use_radar=False, use_velocity=True)
    assert result["velocity_pixels"] > 0
    metrics = result["sceneflow"]
    assert result["velocity_samples"] > 0 and result["history"][-1]["velocity"] < result["history"][0]["velocity"]
    assert metrics["epe"] < 0.4 * metrics["zero_motion_epe"]
