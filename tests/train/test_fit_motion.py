"""The standalone motion fit on a tiny synthetic scene: radar samples, and a fit that beats a
field that does not move."""

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
from radar4dgs.train.fit_motion import collect_radar_samples, load_field, run_fit, save_field

# Tiny tensors: on the shared 2-core CI machine extra torch threads only spin.
pytestmark = pytest.mark.usefixtures("one_torch_thread")

ORACLE = {"depth_source": "oracle", "mask_source": "oracle"}  # gt depth and masks: the tests isolate one stage


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
    assert result["history"][-1]["total"] < result["history"][0]["total"]
    path = save_field(field, motion_prepared / "field.pt")
    again = load_field(path)
    x = torch.rand(10, 3) * 20
    assert torch.equal(again.warp(x, 0.1, 0.4), field.warp(x, 0.1, 0.4))
