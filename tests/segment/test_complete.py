"""Radar-object mask completion (segment/complete.py) on a closed-form scene: a flat road, a wall
at 40 m and a 2 m x 1.4 m car face 8 m ahead whose network mask covers only its left half."""

from types import SimpleNamespace

import numpy as np
import pytest

from radar4dgs.segment.complete import (
    complete_mask,
    lasting_tracks,
    pixel_heights,
    project_points,
)
from radar4dgs.segment.config import CompletionConfig

W, H, F = 160, 90, 114.0
K = np.array([[F, 0.0, 79.5], [0.0, F, 44.5], [0.0, 0.0, 1.0]])
# OpenCV camera 1.5 m above the road looking along ego x (x right = -y ego, y down = -z ego).
CAM_TO_EGO = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 1.5], [0.0, 0.0, 0.0, 1.0]])
CAR_Z, CAR_X, CAR_H = 8.0, (-0.5, 1.5), (0.1, 1.5)  # face depth, lateral extent (cam x), heights above road


def scene():
    """Depth (H, W) z-depth, the car's gt mask (H, W) and 40 radar returns (cam frame) on its face."""
    u, v = np.meshgrid(np.arange(W) + 0.0, np.arange(H) + 0.0)
    y_ray = (v - K[1, 2]) / F
    depth = np.where(y_ray > 0, 1.5 / np.where(y_ray > 0, y_ray, 1.0), 40.0).clip(max=40.0)
    x_car = (u - K[0, 2]) / F * CAR_Z
    h_car = 1.5 - y_ray * CAR_Z
    car = (x_car >= CAR_X[0]) & (x_car <= CAR_X[1]) & (h_car >= CAR_H[0]) & (h_car <= CAR_H[1])
    depth = np.where(car, CAR_Z, depth)
    rng = np.random.default_rng(0)
    x = rng.uniform(*CAR_X, 40)
    y = 1.5 - rng.uniform(*CAR_H, 40)
    returns = np.stack([x, y, CAR_Z + rng.normal(0.0, 0.1, 40)], axis=1)
    return depth, car, returns


def test_pixel_heights_of_the_road_are_zero():
    depth, car, _ = scene()
    heights = pixel_heights(depth, K, CAM_TO_EGO)
    road = ~car & (np.arange(H)[:, None] > K[1, 2] + 1)
    np.testing.assert_allclose(heights[road & (depth < 40.0)], 0.0, atol=1e-9)
    assert heights[car].min() >= CAR_H[0] - 0.05 and heights[car].max() <= CAR_H[1] + 0.05


def test_half_missed_fast_car_is_completed_without_road():
    depth, car, returns = scene()
    cols = np.nonzero(car.any(axis=0))[0]
    base = car & (np.arange(W)[None, :] < (cols[0] + cols[-1]) // 2)  # the network found the left half
    assert 0.4 < base.sum() / car.sum() < 0.6
    objects = [project_points(returns, K, 0.5)]
    out = complete_mask(base, depth, objects, K, CAM_TO_EGO, CompletionConfig(enabled=True))
    assert (out & car).sum() / car.sum() >= 0.97  # recall of the car
    assert (out & ~car).sum() == 0  # road (height gate) and wall (depth gate) stay out
    assert (out & base).sum() == base.sum()  # the network's mask is kept


def body_scene(width_m: float, top_m: float, z: float = 12.0, x_m: float = 2.0):
    """The road-and-wall depth with a body ``width_m`` wide from the road to ``top_m`` high, ``z`` m ahead,
    its left edge ``x_m`` right of the optical axis: depth (H, W), its pixels (H, W) bool, and 2 radar
    returns on it (cam frame; a pedestrian's usual count)."""
    u, v = np.meshgrid(np.arange(W) + 0.0, np.arange(H) + 0.0)
    y_ray = (v - K[1, 2]) / F
    depth = np.where(y_ray > 0, 1.5 / np.where(y_ray > 0, y_ray, 1.0), 40.0).clip(max=40.0)
    x, h = (u - K[0, 2]) / F * z, 1.5 - y_ray * z
    body = (x >= x_m) & (x <= x_m + width_m) & (h >= 0.0) & (h <= top_m)
    returns = np.array([[x_m + 0.4 * width_m, 1.5 - 0.8, z], [x_m + 0.6 * width_m, 1.5 - 1.2, z + 0.1]])
    return np.where(body, z, depth), body, returns


def test_a_pedestrian_with_two_returns_is_completed_over_a_body_window():
    """0.6 m x 1.7 m at 12 m, nothing marked by the network: the window (1 m wide, up to 2 m) marks the
    body above min_height_m; the wall beside it (depth gate) and the road (height gate) stay out."""
    depth, body, returns = body_scene(0.6, 1.7)
    heights = pixel_heights(depth, K, CAM_TO_EGO)
    base = np.zeros_like(body)
    small = [project_points(returns, K, 0.5)]
    config = CompletionConfig(small_objects=True)
    out = complete_mask(base, depth, [], K, CAM_TO_EGO, config, small)
    assert (out & ~body).sum() == 0
    assert (out & body).sum() == (body & (heights >= config.min_height_m)).sum() > 40
    # The same returns as a hull object: fewer than min_returns, nothing.
    assert not complete_mask(base, depth, small, K, CAM_TO_EGO, config).any()


def test_the_body_window_stops_at_body_height_and_body_width():
    """A 3 m wide, 3.5 m tall mover (a van side) with two returns in its middle: only the 1 m wide strip
    around them is marked, up to 2 m above the road."""
    depth, body, returns = body_scene(3.0, 3.5, x_m=-1.5)
    heights = pixel_heights(depth, K, CAM_TO_EGO)
    config = CompletionConfig(small_objects=True)
    uv, z = project_points(returns, K, 0.5)
    out = complete_mask(np.zeros_like(body), depth, [], K, CAM_TO_EGO, config, [(uv, z)])
    assert out.any() and (out & ~body).sum() == 0
    assert heights[out].max() <= config.body_height_m + 1e-9 and heights[body].max() > 3.0
    columns = np.flatnonzero(out.any(axis=0))
    width_px = config.body_width_m * F / np.median(z)
    assert abs(len(columns) - width_px) <= 1 and abs(columns.mean() - uv[:, 0].mean()) <= 1.0


@pytest.mark.parametrize("bad", [{"body_width_m": 0.0}, {"body_height_m": 0.1}, {"small_track_frames": 0}])
def test_bad_body_window_settings_are_refused_with_their_values(bad):
    with pytest.raises(ValueError, match="masks.completion needs"):
        CompletionConfig(**bad)


def test_lasting_tracks_are_those_seen_in_enough_frames():
    frames = [[SimpleNamespace(track=t) for t in tracks] for tracks in ([1, 2], [1, 3], [1, 2, 2], [2, 4])]
    assert lasting_tracks(frames, 3) == {1, 2}  # track 2 twice in one frame counts once there
    assert lasting_tracks(frames, 4) == set() and lasting_tracks(frames, 1) == {1, 2, 3, 4}


def test_completion_needs_depth_and_enough_returns():
    depth, car, returns = scene()
    base = np.zeros_like(car)
    objects = [project_points(returns, K, 0.5)]
    assert not complete_mask(base, None, objects, K, CAM_TO_EGO, CompletionConfig()).any()
    few = [project_points(returns[:2], K, 0.5)]
    assert not complete_mask(base, depth, few, K, CAM_TO_EGO, CompletionConfig(min_returns=3)).any()



def masks_of_tiny_run(run, tmp_path, **completion):
    """prepare_masks (tiny preset, ``completion`` fields set) on a copy of the session's tiny run's radar
    and depth stages: (scene, prepared folder, summary)."""
    import shutil

    from radar4dgs.config import preset
    from radar4dgs.io.scene import read_scene
    from radar4dgs.segment.config import SegInferConfig
    from radar4dgs.segment.infer import prepare_masks
    from radar4dgs.train.fit_motion import torch_threads

    scene = read_scene(run / "scene")
    prepared = tmp_path / "prepared"
    for stage in ("radar", "depth"):
        shutil.copytree(run / "scene" / "prepared" / stage, prepared / stage)
    config = preset(SegInferConfig, "tiny")
    for key, value in completion.items():
        setattr(config.completion, key, value)
    with torch_threads(1):
        return scene, prepared, prepare_masks(scene, prepared, config)


def test_flow_stage_reads_masks_completed_for_it_and_training_keeps_the_networks(tiny_trained_run, tmp_path):
    """CompletionConfig.for_flow: the masks stage writes the completed masks to masks/flow/, the flow
    stage lifts those, the masks everything else reads stay the network's."""
    import json

    from radar4dgs.config import preset
    from radar4dgs.io.scene import read_mask_png
    from radar4dgs.io.scene_files import FLOW_MASKS
    from radar4dgs.motion.config import FlowConfig
    from radar4dgs.motion.flow import prepare_flow
    from radar4dgs.segment.config import SegInferConfig
    from radar4dgs.segment.infer import prepare_masks
    from radar4dgs.train.fit_motion import torch_threads

    # The network's masks alone (no body windows), so the gain is the hull completion's.
    scene, prepared, summary = masks_of_tiny_run(tiny_trained_run, tmp_path, for_flow=True, small_objects=False)
    with torch_threads(1):
        flow = prepare_flow(scene, prepared, preset(FlowConfig, "tiny"))
    masks = prepared / "masks"
    assert summary["completion"] == "flow masks"
    network_hits = flow_hits = added = added_true = truth_total = 0
    for i, frame in enumerate(scene.frames):
        network = read_mask_png(masks / f"{frame.name}.png")
        completed = read_mask_png(masks / FLOW_MASKS / f"{frame.name}.png")
        truth = scene.load_optional("gt/dynamic_mask", i)
        assert not (network & ~completed).any()  # completion only adds
        assert summary["frames"][i]["dynamic_pixels"] == network.sum()
        network_hits, flow_hits = network_hits + (network & truth).sum(), flow_hits + (completed & truth).sum()
        added, added_true = added + (completed & ~network).sum(), added_true + (completed & ~network & truth).sum()
        truth_total += truth.sum()
    # Tiny seed 4: the network finds 0.65 of the moving pixels, the completion 0.93, adding almost
    # only moving pixels.
    assert flow_hits / truth_total >= network_hits / truth_total + 0.2
    assert added_true / added >= 0.95
    for pair in flow["per_pair"]:
        assert pair["dynamic_pixels"] == read_mask_png(masks / FLOW_MASKS / f"{pair['frame']}.png").sum()
    # Written again without for_flow, the folder loses its flow masks (the flow stage would read them).
    config = preset(SegInferConfig, "tiny")
    config.completion.for_flow = False
    with torch_threads(1):
        assert prepare_masks(scene, prepared, config)["completion"] == "off"
    assert not (masks / FLOW_MASKS).exists()
    # By default (for_flow on) the training run's prepared folder has flow masks.
    assert (tiny_trained_run / "scene" / "prepared" / "masks" / FLOW_MASKS).is_dir()
    assert json.loads((tiny_trained_run / "scene" / "prepared" / "masks" / "summary.json").read_text())[
        "completion"] == "flow masks"


def test_small_object_windows_only_add_moving_pixels_to_the_networks_masks(tiny_trained_run, tmp_path):
    """CompletionConfig.small_objects through prepare_masks: the network's masks are kept, and the pixels
    the windows add are mostly moving ones (tiny calm seed 4, ground-truth masks)."""
    from radar4dgs.io.scene import read_mask_png

    scene, prepared, summary = masks_of_tiny_run(tiny_trained_run, tmp_path / "windows", small_objects=True,
                                                 for_flow=False)
    _, plain, plain_summary = masks_of_tiny_run(tiny_trained_run, tmp_path / "network", small_objects=False,
                                                 for_flow=False)
    assert summary["small_objects"] == "radar tracks" and summary["completion"] == "off"
    assert plain_summary["small_objects"] == "off"
    added = added_true = 0
    for i, frame in enumerate(scene.frames):
        network = read_mask_png(plain / "masks" / f"{frame.name}.png")
        windows = read_mask_png(prepared / "masks" / f"{frame.name}.png")
        truth = scene.load_optional("gt/dynamic_mask", i)
        assert not (network & ~windows).any()
        assert summary["frames"][i]["dynamic_pixels"] == windows.sum()
        added, added_true = added + (windows & ~network).sum(), added_true + (windows & ~network & truth).sum()
    print(f"added {added} px, {added_true} moving")
    assert added > 0 and added_true / added >= 0.8
