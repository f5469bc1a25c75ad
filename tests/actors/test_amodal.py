"""Body centres completed from the faces the camera saw, against the box they were sampled on."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.actors.amodal import completed_centres, is_car_like

LENGTH, WIDTH = 4.4, 1.8


def face_points(faces: str, rng: np.random.Generator, count: int = 300) -> np.ndarray:
    """(count, 2) points uniform on the named vertical faces of a LENGTH x WIDTH box centred at the origin
    (body frame: x along the heading): "rear" (x = -L/2), "left" (y = +W/2), "all" (its four faces)."""
    names = ["rear", "front", "left", "right"] if faces == "all" else [faces]
    per_face = rng.integers(0, len(names), count)
    t = rng.uniform(-0.5, 0.5, count)
    out = np.empty((count, 2))
    for k, name in enumerate(names):
        sel = per_face == k
        if name in ("rear", "front"):
            out[sel] = np.stack([np.full(sel.sum(), (-1 if name == "rear" else 1) * LENGTH / 2), t[sel] * WIDTH], 1)
        else:
            out[sel] = np.stack([t[sel] * LENGTH, np.full(sel.sum(), (1 if name == "left" else -1) * WIDTH / 2)], 1)
    return out


def centre_seen(faces: str, heading: float, centre: np.ndarray, camera_body: np.ndarray, seed: int = 0):
    """(completed centre (2,), Gaussian centroid (2,)) of the box at ``centre`` (2,) world with ``heading``,
    sampled on ``faces``, seen from ``camera_body`` (2,) in its body frame."""
    c, s = np.cos(heading), np.sin(heading)
    to_world = np.array([[c, -s], [s, c]])
    local = face_points(faces, np.random.default_rng(seed))
    points = np.concatenate([local @ to_world.T + centre, np.full((len(local), 1), 0.8)], axis=1)[:, None]
    centroid = points.mean(axis=0)
    camera = np.concatenate([to_world @ camera_body + centre, [1.5]])[None]
    out = completed_centres(points, np.ones((len(local), 1)), centroid, np.array([heading]), camera,
                            (LENGTH, WIDTH), 0.05)
    assert out[0, 2] == centroid[0, 2]  # the height is left alone
    return out[0, :2], centroid[0, :2]


@settings(max_examples=40, deadline=None)
@given(heading=st.floats(-np.pi, np.pi), off_axis=st.floats(-0.25, 0.25), distance=st.floats(5.0, 60.0),
       x=st.floats(-100, 100), y=st.floats(-100, 100))
def test_a_car_seen_from_behind_is_completed_to_its_centre(heading, off_axis, distance, x, y):
    centre = np.array([x, y])
    camera = distance * np.array([-np.cos(off_axis), np.sin(off_axis)])
    completed, centroid = centre_seen("rear", heading, centre, camera)
    # The Gaussians of the rear face alone put the centroid half a car length behind the centre.
    assert np.linalg.norm(centroid - centre) > 0.45 * LENGTH
    # Completed, to within the sampling noise of 300 points across 1.8 m (at most 0.08 m in 300 draws).
    assert np.linalg.norm(completed - centre) < 0.15


@settings(max_examples=40, deadline=None)
@given(heading=st.floats(-np.pi, np.pi), off_axis=st.floats(-0.25, 0.25), distance=st.floats(5.0, 60.0))
def test_a_car_passing_beside_is_completed_across_its_width(heading, off_axis, distance):
    centre = np.array([3.0, -7.0])
    camera = distance * np.array([np.sin(off_axis), np.cos(off_axis)])  # on its left
    completed, centroid = centre_seen("left", heading, centre, camera)
    assert np.linalg.norm(centroid - centre) > 0.45 * WIDTH
    # To within the sampling noise of 300 points along 4.4 m (at most 0.20 m in 300 draws).
    assert np.linalg.norm(completed - centre) < 0.3


@settings(max_examples=40, deadline=None)
@given(angle=st.floats(-np.pi, np.pi), seed=st.integers(0, 1000))
def test_a_car_seen_all_round_keeps_its_centroid_from_any_side(angle, seed):
    centre = np.array([10.0, 2.0])
    completed, centroid = centre_seen("all", 0.3, centre, 20 * np.array([np.cos(angle), np.sin(angle)]), seed)
    assert np.array_equal(completed, centroid)


def test_a_body_longer_than_a_car_keeps_its_centroid():
    """Two cars one behind the other that discovery took for one actor: the middle of their 12 m extent
    lies between them, the centroid on the one with more Gaussians; neither end is completed."""
    rng = np.random.default_rng(0)
    near = face_points("rear", rng, 200) + [-4.0, 0.0]
    far = face_points("rear", rng, 100) + [8.0, 0.0]
    points = np.concatenate([near, far])
    points = np.concatenate([points, np.full((len(points), 1), 0.8)], axis=1)[:, None]
    centroid = points.mean(axis=0)
    out = completed_centres(points, np.ones((len(points), 1)), centroid, np.zeros(1), np.array([[-30.0, 0.0, 1.5]]),
                            (LENGTH, WIDTH), 0.05)
    assert np.array_equal(out, centroid)


def test_frames_without_enough_opaque_points_keep_the_centroid():
    points = np.zeros((3, 2, 3))
    centroid = np.array([[1.0, 2.0, 0.5], [3.0, 4.0, 0.5]])
    out = completed_centres(points, np.ones((3, 2)), centroid, np.zeros(2), np.zeros((2, 3)), (LENGTH, WIDTH), 0.05)
    assert np.array_equal(out, centroid)


def test_car_like_footprints():
    assert is_car_like((4.5, 0.3, 1.5)) and is_car_like((0.4, 1.7, 1.5))  # a car's side, its rear
    assert not is_car_like((1.8, 0.6, 1.7)) and not is_car_like((0.5, 0.6, 1.7))  # a cyclist, a pedestrian
