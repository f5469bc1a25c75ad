"""The field's error per moving object, against fields whose error is known in closed form."""

from __future__ import annotations

import math

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.evaluate.field_objects import ObjectErrors, box_owners, field_error_by_object
from radar4dgs.evaluate.frontend import moving_ground_truth
from radar4dgs.io.scene import normalized_times
from radar4dgs.model.field import DeformationField, randomize_
from radar4dgs.motion.truth import in_boxes, moving_surface_points
from radar4dgs.train.fit_motion import evaluate_sceneflow


class ConstantStep(torch.nn.Module):
    """A stand-in field that moves every point by the same (3,) step, whatever the times."""

    def __init__(self, step: np.ndarray):
        super().__init__()
        self.step = torch.nn.Parameter(torch.as_tensor(step, dtype=torch.float64))

    def displacement(self, x, t_from, t_to):
        return self.step.expand(len(x), 3)


def _frame_step(scene) -> float:
    return scene.frames[1].timestamp - scene.frames[0].timestamp


def test_a_field_that_moves_nothing_misses_each_object_by_its_own_motion(motion_scene):
    result = field_error_by_object(ConstantStep(np.zeros(3)), motion_scene, normalized_times(motion_scene))
    truth = moving_ground_truth(motion_scene)
    assert len(result["objects"]) == len(truth) == 2
    for entry in result["objects"]:
        assert math.isclose(entry["epe"], entry["motion"], rel_tol=1e-9)
        obj = next(o for o in truth if o["id"] == entry["id"])
        assert math.isclose(entry["motion"], np.linalg.norm(obj["velocity"]) * _frame_step(motion_scene), rel_tol=1e-3)
    # Every moving surface point lies in its object's (grown) box.
    moving = sum(len(s[0]) for i in range(len(motion_scene) - 1) if (s := moving_surface_points(motion_scene, i)))
    assert result["unassigned_points"] == 0
    assert sum(entry["points"] for entry in result["objects"]) == moving


def test_a_field_with_one_objects_velocity_is_exact_on_it_and_off_by_the_difference_on_the_other(motion_scene):
    truth = moving_ground_truth(motion_scene)
    dt = _frame_step(motion_scene)
    velocities = {o["id"]: np.asarray(o["velocity"], dtype=np.float64) for o in truth}
    chosen, other = truth[0]["id"], truth[1]["id"]
    result = field_error_by_object(ConstantStep(velocities[chosen] * dt), motion_scene, normalized_times(motion_scene))
    by_id = {entry["id"]: entry for entry in result["objects"]}
    assert by_id[chosen]["epe"] < 1e-3 and by_id[chosen]["epe_p90"] < 1e-3
    expected = np.linalg.norm(velocities[chosen] - velocities[other]) * dt
    assert math.isclose(by_id[other]["epe"], expected, rel_tol=1e-3)
    assert by_id[other]["worst_frames"][0]["epe"] >= by_id[other]["epe"] - 1e-9


def test_grouping_the_sceneflow_pass_gives_the_standalone_scores(motion_scene):
    # A random field, so every object has its own non-zero error to get right.
    field = randomize_(DeformationField().double(), generator=torch.Generator().manual_seed(3))
    field.fit_normalization(np.concatenate([s[0] for i in range(len(motion_scene) - 1)
                                            if (s := moving_surface_points(motion_scene, i))]))
    times = normalized_times(motion_scene)
    shared = ObjectErrors(motion_scene)
    overall = evaluate_sceneflow(field, motion_scene, times, on_pair=shared.add)
    grouped, alone = shared.summary(), field_error_by_object(field, motion_scene, times)
    assert [o["id"] for o in grouped["objects"]] == [o["id"] for o in alone["objects"]]
    for a, b in zip(grouped["objects"], alone["objects"], strict=True):
        assert a["points"] == b["points"] and a["epe"] > 0.01
        assert math.isclose(a["epe"], b["epe"], rel_tol=1e-6) and math.isclose(a["epe_p90"], b["epe_p90"], rel_tol=1e-6)
    weighted = sum(o["epe"] * o["points"] for o in grouped["objects"]) / overall["points"]
    assert math.isclose(weighted, overall["epe"], rel_tol=1e-6)


@settings(max_examples=50, deadline=None)
@given(yaw=st.floats(-math.pi, math.pi), local=st.tuples(st.floats(-4, 4), st.floats(-2, 2), st.floats(-1, 3)),
       margin=st.floats(0, 0.5))
def test_a_point_is_in_a_turned_box_exactly_when_its_local_coordinates_are(yaw, local, margin):
    dims = (4.2, 1.8, 1.5)
    pose = np.eye(4)
    pose[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    pose[:3, 3] = [10.0, -3.0, 0.2]
    world = (pose[:3, :3] @ np.asarray(local) + pose[:3, 3])[None]
    expected = (abs(local[0]) <= dims[0] / 2 + margin and abs(local[1]) <= dims[1] / 2 + margin
                and -margin <= local[2] <= dims[2] + margin)
    # Points within rounding of a face may land either side.
    faces = [abs(abs(local[0]) - dims[0] / 2 - margin), abs(abs(local[1]) - dims[1] / 2 - margin),
             abs(local[2] + margin), abs(local[2] - dims[2] - margin)]
    if min(faces) > 1e-9:
        assert bool(in_boxes(world, pose[None], np.array([dims]), margin)[0, 0]) == expected


def test_overlapping_boxes_give_a_point_to_the_nearer_centre():
    poses = [np.eye(4), np.eye(4)]
    poses[1][0, 3] = 3.0  # a second 4 m car starting 1 m behind the first one's rear
    objects = [{"poses": [poses[0]], "dims": (4.0, 2.0, 1.5)}, {"poses": [poses[1]], "dims": (4.0, 2.0, 1.5)}]
    points = np.array([[1.4, 0.0, 0.5], [1.6, 0.0, 0.5], [-1.9, 0.0, 0.5], [0.0, 5.0, 0.5]])
    np.testing.assert_array_equal(box_owners(points, objects, 0), [0, 1, 0, -1])
