"""Radar-guided flow of dynamic objects: a textured object moving tens of pixels and growing in the
image (a car coming closer), its radar prediction, the matched warp, the failure drop and the
fallback to today's step without radar objects."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from _flow_helpers import texture
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.config import preset
from radar4dgs.motion.config import FlowConfig
from radar4dgs.motion.flow import pair_scene_flow, prepare_flow, radar_target_depth
from radar4dgs.motion.object_hints import (
    STATIC_TRACK,
    ObjectHint,
    component_claims,
    nearest_labels,
    predicted_targets,
    project_returns,
    split_by_returns,
    static_hint,
)
from radar4dgs.motion.objects_flow import (
    PairGeometry,
    choose_candidate,
    claimed_predictions,
    component_owners,
    object_flow,
)
from radar4dgs.motion.optical_flow import dis_flow
from radar4dgs.motion.rigid import rigid_object_flow

HEIGHT, WIDTH, FOCAL, DT, DEPTH = 120, 240, 200.0, 0.1, 12.0
K = np.array([[FOCAL, 0.0, WIDTH / 2], [0.0, FOCAL, HEIGHT / 2], [0.0, 0.0, 1.0]])
CENTRE = np.array([80.0, 60.0])  # the object's centre in frame a


def object_pair(shift: float, scale: float, swap_texture: bool = False) -> dict:
    """A static camera (world = camera axes) and a fronto-parallel textured object DEPTH m away that
    moves so that its image grows by ``scale`` about the principal point and moves ``shift`` px to
    the right, over a static textured background. ``swap_texture``: frame b shows another texture
    on the object (nothing can match it).

    Returns grey images a, b; masks a, b (H, W) bool; the true flow (H, W, 2) on mask a; the
    object's world velocity (3,) (m/s); depth maps a, b (H, W).
    """
    background, surface = texture(HEIGHT, WIDTH, seed=1), texture(HEIGHT, WIDTH, seed=7)
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    mask_a = ((u - CENTRE[0]) / 30) ** 2 + ((v - CENTRE[1]) / 18) ** 2 <= 1
    principal = K[:2, 2]
    # x' = scale (x - c) + c + (shift, 0): the image of the plane moved from z to z / scale.
    warp = np.column_stack([scale * np.eye(2), principal * (1 - scale) + [shift, 0.0]])
    mask_b = cv2.warpAffine(mask_a.astype(np.uint8) * 255, warp, (WIDTH, HEIGHT)) > 127
    moved = cv2.warpAffine(texture(HEIGHT, WIDTH, seed=9) if swap_texture else surface, warp, (WIDTH, HEIGHT))
    a, b = background.copy(), background.copy()
    a[mask_a], b[mask_b] = surface[mask_a], moved[mask_b]
    flow = np.stack([u * scale + warp[0, 2] - u, v * scale + warp[1, 2] - v], axis=-1)
    # X' = X + v dt with z' = z / scale: vx dt = shift z' / f, vz dt = z' - z.
    velocity = np.array([shift * DEPTH / (scale * FOCAL), 0.0, DEPTH / scale - DEPTH]) / DT
    depth_a = np.where(mask_a, DEPTH, 40.0)
    depth_b = np.where(mask_b, DEPTH / scale, 40.0)
    return {"a": a, "b": b, "mask_a": mask_a, "mask_b": mask_b, "flow": flow, "velocity": velocity,
            "depth_a": depth_a, "depth_b": depth_b}


def hint(pair: dict, velocity: np.ndarray | None = None) -> ObjectHint:
    """A radar object whose returns land on the object in frame a."""
    uv = CENTRE + np.array([[0.0, 0.0], [10.0, 3.0], [-12.0, -4.0], [5.0, -8.0]])
    return ObjectHint(uv, pair["velocity"] if velocity is None else velocity, track=0)


def geometry(depth: np.ndarray, dt: float = DT) -> PairGeometry:
    return PairGeometry(depth, K, np.eye(4), np.eye(4), dt)


def object_error(flow: np.ndarray, pair: dict) -> np.ndarray:
    """(N,) end-point error (px) on the object's pixels in frame a."""
    mask = pair["mask_a"]
    return np.linalg.norm(flow[mask] - pair["flow"][mask], axis=1)


def test_prediction_carries_the_zoom():
    pair = object_pair(shift=60.0, scale=1.2)
    rows, cols = np.nonzero(pair["mask_a"])
    pixels = np.stack([cols, rows], axis=1)
    targets = predicted_targets(pixels, pair["depth_a"][rows, cols], K, np.eye(4), np.eye(4),
                                pair["velocity"] * DT)
    assert targets - pixels == pytest.approx(pair["flow"][rows, cols], abs=1e-6)


def test_dense_flow_fails_and_the_radar_guided_match_recovers_shift_and_zoom():
    pair = object_pair(shift=60.0, scale=1.2)
    dense = dis_flow(pair["a"], pair["b"], "medium")
    assert np.median(object_error(dense, pair)) > 10.0  # the premise: DIS loses the object
    # The depth estimate is 10 % off, so the prediction misses by ~7 px and 2 % of scale: the
    # match has to fix it.
    flow, failed, counts, *_ = object_flow(pair["a"], pair["b"], dense, pair["mask_a"], [hint(pair)],
                                       geometry(pair["depth_a"] * 1.1), FlowConfig())
    assert counts["matched"] == 1 and not failed.any()
    assert object_error(flow, pair).max() < 1.0
    assert np.array_equal(flow[~pair["mask_a"]], dense[~pair["mask_a"]])


@settings(max_examples=8, deadline=None)
@given(shift=st.floats(40.0, 80.0), scale=st.floats(1.0, 1.25), depth_error=st.floats(0.9, 1.1))
def test_radar_guided_flow_recovers_large_shifts_and_zooms(shift, scale, depth_error):
    pair = object_pair(shift, scale)
    dense = dis_flow(pair["a"], pair["b"], "medium")
    flow, failed, _, *_ = object_flow(pair["a"], pair["b"], dense, pair["mask_a"], [hint(pair)],
                                  geometry(pair["depth_a"] * depth_error), FlowConfig())
    assert not failed.any()
    assert object_error(flow, pair).max() < 1.0


def test_a_wrong_radar_prediction_is_corrected_by_the_match():
    pair = object_pair(shift=60.0, scale=1.2)
    # 20 px more to the right at the object's new depth.
    wrong = pair["velocity"] + np.array([20.0 * DEPTH / (1.2 * FOCAL) / DT, 0.0, 0.0])
    rows, cols = np.nonzero(pair["mask_a"])
    pixels = np.stack([cols, rows], axis=1)
    predicted = predicted_targets(pixels, pair["depth_a"][rows, cols], K, np.eye(4), np.eye(4), wrong * DT)
    assert np.median(predicted[:, 0] - pixels[:, 0] - pair["flow"][rows, cols, 0]) == pytest.approx(20.0)
    dense = dis_flow(pair["a"], pair["b"], "medium")
    flow, _, counts, *_ = object_flow(pair["a"], pair["b"], dense, pair["mask_a"], [hint(pair, wrong)],
                                  geometry(pair["depth_a"]), FlowConfig())
    assert counts["matched"] == 1
    assert object_error(flow, pair).max() < 1.0


def pair_inputs(pair: dict) -> dict:
    """The keyword arguments of ``pair_scene_flow`` for an ``object_pair`` (DIS flows both ways)."""
    rgb_a, rgb_b = (np.repeat(pair[k][..., None], 3, axis=2) for k in ("a", "b"))
    return {"image_i": rgb_a, "image_j": rgb_b, "forward": dis_flow(rgb_a, rgb_b, "medium"),
            "backward": dis_flow(rgb_b, rgb_a, "medium"), "depth_i": pair["depth_a"],
            "depth_j": pair["depth_b"], "mask_i": pair["mask_a"], "mask_j": pair["mask_b"], "K": K,
            "world_to_cam_i": np.eye(4), "world_to_cam_j": np.eye(4)}


def test_a_car_passing_the_camera_leaves_the_view_on_its_side():
    pair = object_pair(shift=0.0, scale=1.0)
    rows, cols = np.nonzero(pair["mask_a"])
    pixels = np.stack([cols, rows], axis=1)
    # 13 m toward the camera from 12 m: every point ends 1 m behind it, left of the axis (u < cx).
    targets = predicted_targets(pixels, pair["depth_a"][rows, cols], K, np.eye(4), np.eye(4),
                                np.array([0.0, 0.0, -13.0]))
    assert np.isfinite(targets).all() and (targets[:, 0] < -WIDTH).all()
    # Frame b no longer shows it; the dense flow keeps it in place on the background.
    b = np.where(pair["mask_a"], texture(HEIGHT, WIDTH, seed=1), pair["b"])
    dense = np.zeros((HEIGHT, WIDTH, 2), dtype=np.float32)
    passing = ObjectHint(hint(pair).uv, np.array([0.0, 0.0, -13.0 / DT]), track=0)
    flow, failed, counts, *_ = object_flow(pair["a"], b, dense, pair["mask_a"], [passing], geometry(pair["depth_a"]),
                                       FlowConfig())
    assert counts["radar"] == 1 and not failed.any()
    assert ((cols + flow[rows, cols, 0]) < -WIDTH).all()  # out of view: never lifted onto what b shows there


def test_a_component_that_nothing_matches_is_dropped_not_lifted():
    pair = object_pair(shift=60.0, scale=1.2, swap_texture=True)
    inputs = pair_inputs(pair)
    back = ObjectHint(np.array([[136.0, 60.0], [140.0, 55.0]]), pair["velocity"])  # the object in b
    hints = {"hints_i": [hint(pair)], "hints_j": [back], "dt": DT}
    # The dense flow favoured (radar_dense_margin > 1): its failure here is consistent both ways.
    favoured = {"radar_dense_margin": 1.2}
    kept = pair_scene_flow(FlowConfig(max_component_error_ratio=0.0, max_pixel_error=0.0, **favoured),
                           **inputs, **hints)
    # The premise: without the drop, some of the failed match passes the consistency check and
    # would be lifted.
    assert sum(kept.models[m] for m in ("dense", "translation", "radar", "matched")) == 1
    assert len(kept.points_i) > 0
    dropped = pair_scene_flow(FlowConfig(**favoured), **inputs, **hints)
    assert not dropped.reliable[pair["mask_a"]].any()
    assert len(dropped.points_i) == 0


def test_rejected_pixels_no_neighbour_can_fill_store_their_radar_prediction():
    """Nothing matches the object (its texture swapped in b), so every pixel fails the checks, none is
    lifted and no lifted neighbour can fill the stored flow: it keeps the radar prediction, and the
    lifted pairs are those of the run without it (none)."""
    pair = object_pair(shift=60.0, scale=1.2, swap_texture=True)
    rows, cols = np.nonzero(pair["mask_a"])
    pixels = np.stack([cols, rows], axis=1)
    predicted = predicted_targets(pixels, pair["depth_a"][rows, cols], K, np.eye(4), np.eye(4),
                                  pair["velocity"] * DT) - pixels
    back = ObjectHint(np.array([[136.0, 60.0], [140.0, 55.0]]), pair["velocity"])
    hints = {"hints_i": [hint(pair)], "hints_j": [back], "dt": DT}
    inputs = pair_inputs(pair)
    runs = {on: pair_scene_flow(FlowConfig(radar_dense_margin=1.2, fill_radar_prediction=on), **inputs, **hints)
            for on in (False, True)}
    assert len(runs[True].points_i) == len(runs[False].points_i) == 0
    assert runs[True].filled[rows, cols].all() and not runs[False].filled[rows, cols].any()
    assert runs[True].forward[rows, cols] == pytest.approx(predicted, abs=1e-3)
    assert np.abs(runs[True].forward[rows, cols] - pair["flow"][rows, cols]).max() < 1.0  # the truth, here
    assert np.abs(runs[False].forward[rows, cols] - pair["flow"][rows, cols]).max() > 1.0
    outside = ~pair["mask_a"]
    assert np.array_equal(runs[True].forward[outside], runs[False].forward[outside])


def test_rejected_pixels_no_object_claims_take_the_split_objects_prediction():
    """The same failed match, its object missing from the frame's objects (its returns went to another
    mover's fit) but present among the split objects: the stored flow of its rejected pixels is that
    object's prediction, the lifted pairs are the same, and an object of frame i's own objects wins."""
    pair = object_pair(shift=60.0, scale=1.2, swap_texture=True)
    rows, cols = np.nonzero(pair["mask_a"])
    pixels = np.stack([cols, rows], axis=1)
    predicted = predicted_targets(pixels, pair["depth_a"][rows, cols], K, np.eye(4), np.eye(4),
                                  pair["velocity"] * DT) - pixels
    inputs = {**pair_inputs(pair), "hints_i": [], "hints_j": [], "dt": DT, "fill_hints_i": [hint(pair)]}
    runs = {on: pair_scene_flow(FlowConfig(radar_dense_margin=1.2, fill_split_objects=on), **inputs)
            for on in (False, True)}
    assert len(runs[True].points_i) == len(runs[False].points_i) == 0
    assert runs[True].filled[rows, cols].all() and not runs[False].filled[rows, cols].any()
    assert runs[True].forward[rows, cols] == pytest.approx(predicted, abs=1e-3)
    outside = ~pair["mask_a"]
    assert np.array_equal(runs[True].forward[outside], runs[False].forward[outside])
    # Where frame i's own objects predict, the split objects change nothing.
    slower = hint(pair, pair["velocity"] / 2)
    own = {**inputs, "hints_i": [slower]}
    with_split = pair_scene_flow(FlowConfig(radar_dense_margin=1.2), **own)
    without = pair_scene_flow(FlowConfig(radar_dense_margin=1.2), **{**own, "fill_hints_i": None})
    assert np.array_equal(with_split.forward, without.forward)


def test_claimed_predictions_split_a_component_between_its_objects_by_their_returns():
    """Two objects claim one component, each with returns on its own half at the object's depth: each
    half takes its own object's predicted motion (the closed form f v dt / z px at rest), the rest NaN."""
    mask = np.zeros((HEIGHT, WIDTH), dtype=bool)
    mask[40:60, 40:120] = True
    depth = np.full(mask.shape, DEPTH)
    halves = []
    for u0, vx in ((50.0, 2.0), (110.0, -3.0)):
        uv = np.array([[u0, 45.0], [u0 + 4, 50.0], [u0 - 4, 55.0]])
        camera = np.column_stack([(uv - K[:2, 2]) * DEPTH / FOCAL, np.full(3, DEPTH)])
        halves.append(ObjectHint(uv, np.array([vx, 0.0, 0.0]), track=len(halves), camera=camera))
    predicted = claimed_predictions(mask, halves, geometry(depth), FlowConfig())
    assert np.isnan(predicted[~mask]).all()
    assert predicted[50, 45] == pytest.approx([FOCAL * 2.0 * DT / DEPTH, 0.0], abs=1e-4)
    assert predicted[50, 115] == pytest.approx([FOCAL * -3.0 * DT / DEPTH, 0.0], abs=1e-4)
    assert claimed_predictions(mask, [], geometry(depth), FlowConfig()).shape == (HEIGHT, WIDTH, 2)


def test_without_radar_objects_the_flow_is_todays():
    pair = object_pair(shift=4.0, scale=1.0)
    inputs = pair_inputs(pair)
    today = pair_scene_flow(FlowConfig(radar_guided=False, max_pixel_error=0.0), **inputs)
    gray = (pair["a"], pair["b"])
    assert np.array_equal(today.forward, rigid_object_flow(*gray, inputs["forward"], pair["mask_a"]))
    for hints in ({}, {"hints_i": [], "hints_j": []}):
        guided = pair_scene_flow(FlowConfig(), **inputs, **hints)
        assert np.array_equal(guided.forward, today.forward)
        assert guided.models["no_radar"] == 1 and sum(guided.models.values()) == 1
        unchecked = pair_scene_flow(FlowConfig(max_component_error_ratio=0.0, max_pixel_error=0.0), **inputs, **hints)
        for a, b in zip(unchecked[:5], today[:5], strict=True):
            assert np.array_equal(a, b)


def test_an_object_the_radar_sees_well_takes_the_rigid_motion_and_its_rim_keeps_the_dense_flow():
    pair = object_pair(shift=20.0, scale=1.0)
    # The mask bleeds 4 px onto the static background; a dense flow 3 px off on the object and
    # right (zero) on that rim, favoured by the dense margin the way a per-pixel flow can win there.
    mask = cv2.dilate(pair["mask_a"].astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    dense = np.where(pair["mask_a"][..., None], pair["flow"] + [3.0, 0.0], 0.0).astype(np.float32)
    favoured = {"radar_dense_margin": 10.0}
    today, _, counts, *_ = object_flow(pair["a"], pair["b"], dense, mask, [hint(pair)], geometry(pair["depth_a"]),
                                   FlowConfig(**favoured))
    assert counts["dense"] == 1 and np.array_equal(today, dense)  # the premise
    trusted = FlowConfig(radar_rigid_min_returns=4, **favoured)  # hint() carries 4 returns
    flow, failed, counts, *_ = object_flow(pair["a"], pair["b"], dense, mask, [hint(pair)], geometry(pair["depth_a"]),
                                       trusted)
    assert counts["dense"] == 0 and not failed.any()
    assert np.median(object_error(flow, pair)) < 0.5
    far_rim = mask & (cv2.distanceTransform((~pair["mask_a"]).astype(np.uint8), cv2.DIST_L2, 5) >= 3)
    assert far_rim.sum() > 100
    # Most of the rim keeps its (right) dense flow; with the ratio at 0 the rigid motion takes all of it.
    assert (np.linalg.norm(flow[far_rim], axis=1) == 0).mean() > 0.6
    rigid_only = object_flow(pair["a"], pair["b"], dense, mask, [hint(pair)], geometry(pair["depth_a"]),
                             dataclasses.replace(trusted, radar_pixel_dense_ratio=0.0))[0]
    assert (np.linalg.norm(rigid_only[far_rim], axis=1) == 0).mean() == 0
    fewer = dataclasses.replace(trusted, radar_rigid_min_returns=5)
    assert np.array_equal(object_flow(pair["a"], pair["b"], dense, mask, [hint(pair)], geometry(pair["depth_a"]),
                                      fewer)[0], dense)

def test_returns_vote_for_the_component_they_land_on_or_near():
    labels = np.zeros((40, 60), dtype=np.int32)
    labels[5:15, 5:20], labels[20:35, 30:55] = 1, 2
    near = ObjectHint(np.array([[28.0, 25.0], [40.0, 30.0], [10.0, 10.0]]), np.zeros(3))  # 2 px left of 2
    far = ObjectHint(np.array([[2.0, 38.0], [58.0, 2.0]]), np.zeros(3))
    assert component_claims(nearest_labels(labels, 3.0), [near, far], min_returns=2) == {2: [near]}
    assert component_claims(nearest_labels(labels, 3.0), [near], min_returns=3) == {}
    # Two objects on one component: both claim it, most votes first.
    more = ObjectHint(np.array([[35.0, 22.0], [45.0, 33.0], [50.0, 30.0]]), np.ones(3))
    assert component_claims(nearest_labels(labels, 3.0), [near, more], min_returns=2) == {2: [more, near]}


def lifted(uv: np.ndarray, depth: float) -> np.ndarray:
    """(K, 3) camera coordinates of the (K, 2) pixels at z-depth ``depth``."""
    return np.column_stack([(uv - K[:2, 2]) / FOCAL * depth, np.full(len(uv), depth)])


def test_a_component_is_split_by_the_nearest_return_in_depth_not_in_the_image():
    # A near object's returns sit 6 px right of the pixels, a far one's on them: in the image the
    # far returns are nearer, in 3-D the near ones.
    pixels = np.array([[100, 60], [101, 61], [102, 59]])
    near = ObjectHint(pixels + [6.0, 0.0], np.zeros(3), camera=lifted(pixels + [6.0, 0.0], 10.0))
    far = ObjectHint(pixels.astype(float), np.zeros(3), camera=lifted(pixels.astype(float), 30.0))
    assert split_by_returns(pixels, np.full(3, 10.5), K, [far, near]).tolist() == [1, 1, 1]
    assert split_by_returns(pixels, np.full(3, 29.0), K, [far, near]).tolist() == [0, 0, 0]
    # Without depth, the image decides.
    assert split_by_returns(pixels, np.full(3, np.nan), K, [far, near]).tolist() == [0, 0, 0]


def two_movers(depths: tuple[float, float] = (12.0, 20.0), returns: tuple[np.ndarray, np.ndarray] | None = None,
               shifts: tuple[float, float] = (40.0, -30.0), flat_second: bool = False) -> dict:
    """Two textured discs that overlap in frame a (the first, ``depths[0]`` m away, in front) and
    part: the first moves ``shifts[0]`` px right (40), the second ``shifts[1]`` (30 px left). One mask
    component in a. ``returns``: each disc's radar returns in the image (default: three spread over it).
    ``flat_second``: the second disc one uniform grey (a car's plain paint)."""
    background = texture(HEIGHT, WIDTH, seed=1)
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    centres, surfaces = [np.array([100.0, 60.0]), np.array([135.0, 55.0])], [7, 5]
    spread = np.array([[-8.0, 2.0], [0.0, -6.0], [6.0, 5.0]])
    returns = returns or (centres[0] + spread - [8.0, 0.0], centres[1] + spread)
    a, b = background.copy(), background.copy()
    depth_a = np.full((HEIGHT, WIDTH), 40.0)
    flow = np.zeros((HEIGHT, WIDTH, 2))
    owner = np.full((HEIGHT, WIDTH), -1)
    hints = []
    for k in (1, 0):  # the far disc first, the near one over it
        surface, depth, shift = texture(HEIGHT, WIDTH, seed=surfaces[k]), depths[k], shifts[k]
        if flat_second and k == 1:
            surface = np.full_like(surface, 200)
        disc_a = (u - centres[k][0]) ** 2 + (v - centres[k][1]) ** 2 <= 20 ** 2
        disc_b = (u - centres[k][0] - shift) ** 2 + (v - centres[k][1]) ** 2 <= 20 ** 2
        a[disc_a] = surface[disc_a]
        b[disc_b] = np.roll(surface, int(shift), axis=1)[disc_b]
        depth_a[disc_a], flow[disc_a], owner[disc_a] = depth, [shift, 0.0], k
        hints.append(ObjectHint(returns[k], np.array([shift * depth / FOCAL / DT, 0.0, 0.0]), k,
                                lifted(returns[k], depth)))
    return {"a": a, "b": b, "mask": owner >= 0, "owner": owner, "flow": flow, "depth": depth_a,
            "hints": hints[::-1]}


def test_two_movers_in_one_component_each_get_their_own_motion():
    scene = two_movers()
    count, _ = cv2.connectedComponents(scene["mask"].astype(np.uint8), connectivity=8)
    assert count == 2  # the premise: one component
    dense = dis_flow(scene["a"], scene["b"], "medium")
    errors = {}
    for split in (0.0, 1.0):
        flow, _, counts, *_ = object_flow(scene["a"], scene["b"], dense, scene["mask"], scene["hints"],
                                      geometry(scene["depth"]), FlowConfig(radar_split_velocity=split))
        error = np.linalg.norm(flow - scene["flow"], axis=2)
        errors[split] = [float(np.median(error[scene["owner"] == k])) for k in (0, 1)]
    assert max(errors[0.0]) > 10.0  # one motion for both: one of them is lost
    assert max(errors[1.0]) < 1.0


def test_a_parked_car_in_a_movers_component_goes_to_the_static_returns():
    # A mover 12 m away pulls out 40 px to the left from in front of a plain parked car 20 m away: one
    # mask component that the mover's radar object claims; the parked car's static returns land on it.
    scene = two_movers(shifts=(-40.0, 0.0), flat_second=True)
    mover, parked = scene["hints"]
    static = ObjectHint(parked.uv, np.zeros(3), STATIC_TRACK, parked.camera)
    dense = dis_flow(scene["a"], scene["b"], "medium")
    trusted = {"radar_rigid_min_returns": 3}  # the mover's three returns suffice for its rigid motion
    runs = {n: object_flow(scene["a"], scene["b"], dense, scene["mask"], [mover, static], geometry(scene["depth"]),
                           FlowConfig(radar_static_min_returns=n, **trusted)) for n in (0, 3, 4)}
    on_parked, on_mover = scene["owner"] == 1, scene["owner"] == 0

    def mover_error(flow: np.ndarray) -> float:
        return float(np.median(np.linalg.norm(flow[on_mover] - scene["flow"][on_mover], axis=1)))

    # The premise: one motion for the component, and the plain car's stillness wins it (the mover's
    # motion is lost); neither images nor per-pixel checks can tell the plain paint's motion.
    assert mover_error(runs[0].flow) > 30.0 and not runs[0].static.any()
    split = runs[3]
    assert split.static[on_parked].mean() > 0.95 and split.static[on_mover].mean() < 0.03
    assert split.counts["static"] == 1
    assert np.array_equal(split.flow[split.static], dense[split.static])  # the dense flow stays
    assert mover_error(split.flow) < 1.0
    assert not runs[4].static.any()  # three static returns are fewer than asked for
    # In the pair's scene flow, the parked car's pixels are not lifted; the mover's are.
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH]
    mover_b, parked_b = (u - 60) ** 2 + (v - 60) ** 2 <= 400, (u - 135) ** 2 + (v - 55) ** 2 <= 400
    depth_b = np.where(mover_b, 12.0, np.where(parked_b, 20.0, 40.0))
    mover_in_b = ObjectHint(mover.uv - [40.0, 0.0], mover.velocity, mover.track, lifted(mover.uv - [40.0, 0.0], 12.0))
    rgb_a, rgb_b = (np.repeat(scene[k][..., None], 3, axis=2) for k in ("a", "b"))
    inputs = {"image_i": rgb_a, "image_j": rgb_b, "forward": dense, "backward": dis_flow(rgb_b, rgb_a, "medium"),
              "depth_i": scene["depth"], "depth_j": depth_b, "mask_i": scene["mask"], "mask_j": mover_b | parked_b,
              "K": K, "world_to_cam_i": np.eye(4), "world_to_cam_j": np.eye(4), "hints_i": [mover, static],
              "hints_j": [mover_in_b, static], "dt": DT}
    on = {n: scene["owner"][tuple(pair_scene_flow(FlowConfig(radar_static_min_returns=n, **trusted),
                                                  **inputs).pixels.astype(np.int64)[:, ::-1].T)] for n in (0, 3)}
    assert (on[0] == 1).sum() > 100 and (on[0] == 0).sum() == 0  # the premise: the parked car, not the mover
    assert (on[3] == 1).sum() == 0 and (on[3] == 0).sum() > 100
    # A slow radar object (under radar_split_velocity) is not split from the static world.
    slow = dataclasses.replace(mover, velocity=np.array([0.5, 0.0, 0.0]))
    assert not object_flow(scene["a"], scene["b"], dense, scene["mask"], [slow, static], geometry(scene["depth"]),
                           FlowConfig(radar_static_min_returns=3, **trusted)).static.any()


def test_the_images_split_a_component_where_the_returns_cannot():
    # Both discs 15 m away, the first one's returns on its far left, the second's near the overlap:
    # much of the first disc lies nearer the second's returns.
    scene = two_movers(depths=(15.0, 15.0), returns=(np.array([[84.0, 60.0], [86.0, 52.0], [85.0, 68.0]]),
                                                     np.array([[122.0, 55.0], [125.0, 48.0], [124.0, 62.0]])))
    mask = scene["mask"]
    rows, cols = np.nonzero(mask)
    pixels = np.stack([cols, rows], axis=1)
    truth = scene["owner"][rows, cols]
    nearest = split_by_returns(pixels, scene["depth"][rows, cols], K, scene["hints"])
    owner, _ = component_owners(scene["a"], scene["b"], mask, pixels, scene["hints"], geometry(scene["depth"]),
                                FlowConfig(radar_split_velocity=1.0))
    assert (nearest == truth).mean() < 0.85  # the premise
    assert (owner == truth).mean() > 0.97


def test_the_flow_stage_uses_the_prepared_radar_objects(motion_scene, tmp_path):
    from radar4dgs.radar.process import prepare_radar

    prepare_radar(motion_scene, tmp_path / "radar")
    summary = prepare_flow(motion_scene, tmp_path, preset(FlowConfig, "tiny", depth_source="oracle",
                                                          mask_source="oracle"))
    assert summary["radar_objects"] == summary["split_objects"] == "used"
    assert sum(summary["models"][m] for m in ("dense", "translation", "radar", "matched")) > 0
    off = prepare_flow(motion_scene, tmp_path, preset(FlowConfig, "tiny", depth_source="oracle", mask_source="oracle",
                                                      fill_split_objects=False))
    assert off["split_objects"] == "off"
    # A folder whose radar stage predates objects_split.json: the flow runs without it, and prepare says so.
    from radar4dgs.motion.flow import run_flow_stage

    (tmp_path / "radar" / "objects_split.json").unlink()
    result = run_flow_stage(motion_scene, tmp_path / "flow", preset(FlowConfig, "tiny", depth_source="oracle",
                                                                       mask_source="oracle"), lambda items: items)
    assert result["note"].startswith(f"no second movers' predictions, unavailable: {tmp_path / 'radar'}")
    assert result["note"].endswith("`--only radar flow --force` adds them")
    assert sum(p["models"]["no_radar"] for p in summary["per_pair"]) == summary["models"]["no_radar"]


def test_static_hint_holds_the_returns_neither_flagged_dynamic_nor_owned_by_an_object(motion_scene):
    from types import SimpleNamespace

    scan = motion_scene.load_radar(0)
    n = len(scan.xyz)
    seen = (scan.xyz, motion_scene.radar_to_camera(0), motion_scene.camera.K)
    in_front = len(project_returns(*seen)[0])
    assert static_hint(*seen, [], np.ones(n, dtype=bool)) is None
    everything = static_hint(*seen, [], np.zeros(n, dtype=bool))
    assert everything.track == STATIC_TRACK and not everything.velocity.any() and len(everything.uv) == in_front
    dynamic = np.zeros(n, dtype=bool)
    dynamic[::2] = True
    owned = SimpleNamespace(points=np.array([1, 3, n + 5]))  # a stale row beyond the scan is ignored
    hint = static_hint(*seen, [owned], dynamic)
    rows = np.setdiff1d(np.arange(1, n, 2), [1, 3])
    expected = project_returns(scan.xyz[rows], motion_scene.radar_to_camera(0), motion_scene.camera.K)[1]
    assert np.allclose(hint.camera, expected)


def test_the_flow_stage_splits_off_static_returns_only_when_asked(motion_scene, tmp_path):
    from radar4dgs.radar.process import prepare_radar

    prepare_radar(motion_scene, tmp_path / "radar")
    oracle = {"depth_source": "oracle", "mask_source": "oracle"}
    off = prepare_flow(motion_scene, tmp_path, preset(FlowConfig, "tiny", **oracle))
    on = prepare_flow(motion_scene, tmp_path, preset(FlowConfig, "tiny", radar_static_min_returns=1, **oracle))
    assert off["models"]["static"] == 0
    # The oracle masks hold only movers: the static returns find at most a few rims to take.
    assert sum(p["points"] for p in on["per_pair"]) >= 0.9 * sum(p["points"] for p in off["per_pair"])



def _graded_candidates(greys: dict[str, int | tuple[int, int]]):
    """Frame a flat grey 100 on a 10 x 10 object; candidate k lands on a patch of b of grey
    ``greys[k]`` (or a (left, right) pair of greys, one per half), so its mean absolute error is
    exactly ``greys[k] - 100`` (the halves' mean)."""
    gray_a = np.full((30, 40 + 30 * len(greys)), 100, np.uint8)
    gray_b = gray_a.copy()
    v, u = np.mgrid[0:10, 0:10]
    pixels = np.stack([u.ravel() + 5, v.ravel() + 5], axis=1)
    candidates = {}
    for k, (name, grey) in enumerate(greys.items()):
        offset = 20 + 30 * k
        left, right = grey if isinstance(grey, tuple) else (grey, grey)
        gray_b[5:15, 5 + offset:10 + offset], gray_b[5:15, 10 + offset:15 + offset] = left, right
        candidates[name] = (pixels + [offset, 0]).astype(np.float64)
    return gray_a, gray_b, pixels, candidates


@pytest.mark.parametrize(("matched_greys", "expected", "error"), [((109, 110), "radar", 10.0),
                                                                  ((108, 108), "matched", 8.0)])
def test_a_match_must_clearly_beat_the_radar_prediction(matched_greys, expected, error):
    # Errors: dense 30, radar 10, the match 9.5 (half 109, half 110: within accept = 0.9 of the
    # radar prediction's, the prediction stays) or 8 (clearly better: the match wins).
    gray_a, gray_b, pixels, candidates = _graded_candidates({"dense": 130, "radar": 110, "matched": matched_greys})
    model, found = choose_candidate(gray_a, gray_b, pixels, candidates, 0.9, 0.25)
    assert model == expected and found == pytest.approx(error)


@pytest.mark.parametrize(("dense_greys", "expected"), [(109, "radar"), ((107, 108), "radar"), (106, "dense")])
def test_the_dense_flow_must_clearly_beat_the_radar_prediction(dense_greys, expected):
    # Radar prediction 10 grey levels, the dense flow 9, 7.5 or 6: it wins only below 0.7 x 10.
    gray_a, gray_b, pixels, candidates = _graded_candidates({"dense": dense_greys, "radar": 110})
    model, _ = choose_candidate(gray_a, gray_b, pixels, candidates, 0.9, 0.25, dense_margin=0.7)
    assert model == expected


@pytest.mark.parametrize(("translation_grey", "expected"), [(110, "dense"), (108, "translation")])
def test_without_a_radar_prediction_the_dense_flow_stays_unless_clearly_beaten(translation_grey, expected):
    gray_a, gray_b, pixels, candidates = _graded_candidates({"dense": 110, "translation": translation_grey})
    model, error = choose_candidate(gray_a, gray_b, pixels, candidates, 0.9, 0.25, dense_margin=0.7)
    assert model == expected and error == pytest.approx(10.0 if expected == "dense" else 8.0)


@pytest.mark.parametrize(("radar_grey", "expected"), [(119, "dense"), (117, "radar")])
def test_by_default_the_radar_prediction_must_beat_the_dense_flow_by_a_tenth(radar_grey, expected):
    # Dense flow 20 grey levels: the prediction takes over only below 0.9 x 20 = 18 (the default
    # margin 1/0.9 keeps the rule the reconstructions were measured with).
    gray_a, gray_b, pixels, candidates = _graded_candidates({"dense": 120, "radar": radar_grey})
    model, _ = choose_candidate(gray_a, gray_b, pixels, candidates, 0.9, 0.25)
    assert model == expected


def nearest_lifted_flow(flow: np.ndarray, sources: np.ndarray, row: int, col: int) -> set[tuple[float, float]]:
    """Naive reference: the flows of every source pixel at the least distance from (row, col)."""
    rows, cols = np.nonzero(sources)
    distance = (rows - row) ** 2 + (cols - col) ** 2
    nearest = distance == distance.min()
    return {tuple(v) for v in flow[rows[nearest], cols[nearest]].tolist()}


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), lifted_share=st.floats(0.02, 0.9), max_distance=st.sampled_from([2.0, 5.0, np.inf]))
def test_rejected_pixels_take_their_nearest_lifted_neighbours_flow_within_their_object(seed, lifted_share,
                                                                                       max_distance):
    from radar4dgs.motion.objects_flow import fill_rejected_flow

    rng = np.random.default_rng(seed)
    mask = np.zeros((30, 60), dtype=bool)
    mask[5:25, 4:24] = True  # object A
    mask[5:25, 30:56] = True  # object B, a gap of 6 px from A
    flow = rng.normal(0.0, 20.0, (30, 60, 2)).astype(np.float32)
    lifted = mask & (rng.random(mask.shape) < lifted_share)
    lifted[:, :24] &= rng.random() < 0.5  # sometimes A has no lifted pixel at all: left as it was
    rejected = mask & ~lifted & (rng.random(mask.shape) < 0.7)
    filled_flow, filled = fill_rejected_flow(flow, mask, lifted, rejected, 20, max_distance)
    for component in (np.s_[:, :27], np.s_[:, 27:]):
        part = np.zeros_like(mask)
        part[component] = True
        sources = lifted & part
        enough = sources.sum() >= max(20, 0.1 * (mask & part).sum())
        assert not (filled & part).any() or enough
        for row, col in zip(*np.nonzero(rejected & part), strict=True):
            if not enough:
                break
            rows, cols = np.nonzero(sources)
            near = np.sqrt(((rows - row) ** 2 + (cols - col) ** 2).min()) <= max_distance
            assert filled[row, col] == near
            if near:
                assert tuple(filled_flow[row, col].tolist()) in nearest_lifted_flow(flow, sources, row, col)
    assert np.array_equal(filled_flow[~filled], flow[~filled])  # lifted, unrejected and off-mask pixels keep theirs
    off, nothing = fill_rejected_flow(flow, mask, lifted, rejected, min_lifted=0)
    assert np.array_equal(off, flow) and not nothing.any()


def test_the_fill_changes_the_stored_flow_of_rejected_pixels_not_the_lifted_pairs():
    pair = object_pair(shift=8.0, scale=1.0)
    inputs = pair_inputs(pair)
    # No radar or translation step: the checks reject a tenth of the dense flow on the object.
    config = {"radar_guided": False, "rigid_objects": False}
    unfilled = pair_scene_flow(FlowConfig(fill_min_lifted=0, **config), **inputs)
    filled = pair_scene_flow(FlowConfig(**config), **inputs)
    for a, b in zip(unfilled[1:6], filled[1:6], strict=True):  # checks, pairs and pixels
        assert np.array_equal(a, b)
    changed = filled.filled
    assert not (changed & ~(pair["mask_a"] & ~(filled.consistent & filled.reliable))).any()
    assert changed.sum() > 50 and not unfilled.filled.any()
    assert np.array_equal(filled.forward[~changed], unfilled.forward[~changed])
    truth = pair["flow"][changed]
    before = np.linalg.norm(unfilled.forward[changed] - truth, axis=1).mean()
    after = np.linalg.norm(filled.forward[changed] - truth, axis=1).mean()
    assert after < 0.6 * before  # 3.3 -> 1.6 px


@pytest.mark.parametrize(("depth_error", "replaced"), [(1.05, True), (1.3, False)])
def test_radar_target_depth_takes_the_line_of_sight_from_the_radar_where_the_depth_map_roughly_agrees(
        depth_error, replaced):
    """Frame b's depth map puts the object ``depth_error`` too far: sampled at the match, it adds (error - 1) x
    12 m of false motion along the line of sight. With ``radar_target_depth`` the far end takes the depth its
    radar prediction gives (exact here) where the two agree within 20 %, and the motion is the truth."""
    pair = object_pair(shift=40.0, scale=1.0)
    inputs = {**pair_inputs(pair), "depth_j": np.where(pair["mask_b"], DEPTH * depth_error, 40.0)}
    hints = {"hints_i": [hint(pair)], "hints_j": [ObjectHint(hint(pair).uv + [40.0, 0.0], pair["velocity"])],
             "dt": DT}
    truth = pair["velocity"] * DT
    runs = {on: pair_scene_flow(FlowConfig(radar_target_depth=on), **inputs, **hints) for on in (False, True)}
    for run in runs.values():
        assert len(run.points_i) > 0.5 * pair["mask_a"].sum()
    today = runs[False].points_j - runs[False].points_i - truth
    assert np.median(today[:, 2]) == pytest.approx((depth_error - 1) * DEPTH, rel=0.05)
    moved = runs[True].points_j - runs[True].points_i - truth
    if replaced:
        assert np.abs(moved).max() < 0.05
    else:
        assert np.array_equal(moved, today)


def test_radar_target_depth_is_the_moved_points_depth_in_camera_b():
    depth = np.full((HEIGHT, WIDTH), 10.0)
    displacement = np.full((HEIGHT, WIDTH, 3), np.nan)
    displacement[50:60, 70:90] = [1.0, 0.0, 2.5]
    world_to_cam_b = np.eye(4)
    world_to_cam_b[2, 3] = -1.0  # camera b one metre further forward
    out = radar_target_depth(displacement, PairGeometry(depth, K, np.eye(4), world_to_cam_b, DT))
    assert np.isnan(out[:50]).all() and np.isnan(out[:, :70]).all()
    assert out[50:60, 70:90] == pytest.approx(10.0 + 2.5 - 1.0)
