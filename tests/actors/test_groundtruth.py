"""Which generator movers the actor benchmark counts: in view, and visible (own surface showing) when a
closer mover hides them. Closed-form depth maps of boxes in front of a camera at the world origin."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from radar4dgs.actors.groundtruth import Mover, own_pixel_counts, scene_movers, score_actors

WIDTH = HEIGHT = 64
FOCAL, CENTRE = 20.0, 32.0
# Camera axes (x right, y down, z forward) from a box's (x length, y width, z up): the box's length runs
# along the view, its width across, its up axis against the image's rows.
BOX_TO_CAMERA = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def box_pose(columns: tuple[int, int], rows: tuple[int, int], near: float, length: float) -> tuple[np.ndarray, list]:
    """Box-to-world pose (4, 4) and dims of a box whose near face, at depth ``near``, spans pixel
    ``columns`` and ``rows`` (inclusive) exactly."""
    x = [(c - CENTRE) / FOCAL * near for c in columns]
    y = [(r - CENTRE) / FOCAL * near for r in rows]
    pose = np.eye(4)
    pose[:3, :3] = BOX_TO_CAMERA
    pose[:3, 3] = [(x[0] + x[1]) / 2, y[1], near + length / 2]  # bottom centre: the lowest row
    return pose, [length, x[1] - x[0], y[1] - y[0]]


class FakeScene(SimpleNamespace):
    def __len__(self) -> int:
        return self.frames


def occluded_pair(frames: int = 6):
    """A car (columns 20-29, depth 10) partly hiding a car behind it (columns 25-44, depth 30), rows 20-39
    for both, over a wall at 50 m; and a pedestrian (columns 50-52, depth 30) wholly behind a van in front
    (columns 48-55, depth 8). Mask: every pixel of a box face."""
    depth = np.full((HEIGHT, WIDTH), 50.0, dtype=np.float32)
    mask = np.zeros((HEIGHT, WIDTH), dtype=np.uint8)
    # id: (columns, rows, near-face depth, length); drawn far to near, so the nearer face wins.
    faces = {1: ((25, 44), (20, 39), 30.0, 4.0), 3: ((50, 52), (10, 19), 30.0, 0.3),
             2: ((20, 29), (20, 39), 10.0, 2.0), 4: ((48, 55), (8, 22), 8.0, 2.0)}
    boxes = {k: box_pose(*faces[k]) for k in sorted(faces)}
    for (c0, c1), (r0, r1), near, _ in faces.values():
        depth[r0:r1 + 1, c0:c1 + 1] = near
        mask[r0:r1 + 1, c0:c1 + 1] = 255
    objects = [{"id": k, "kind": "moving", "class": "pedestrian" if k == 3 else "car", "dims": dims,
                "poses": [pose.tolist()] * frames, "velocity": [1.0, 0.0, 0.0]} for k, (pose, dims) in boxes.items()]
    scene = FakeScene(camera=SimpleNamespace(K=np.array([[FOCAL, 0, CENTRE], [0, FOCAL, CENTRE], [0, 0, 1.0]]),
                                             width=WIDTH, height=HEIGHT),
                      world_to_camera=lambda i: np.eye(4), frames=frames, root="fake",
                      load_optional=lambda kind, i: {"gt/depth": depth, "gt/dynamic_mask": mask}[kind],
                      extra={"synthetic": {"objects": objects}})
    return scene, boxes


def test_own_pixels_are_the_unhidden_part_of_each_box():
    scene, boxes = occluded_pair()
    poses = np.stack([boxes[k][0] for k in (1, 2, 3, 4)])
    dims = np.array([boxes[k][1] for k in (1, 2, 3, 4)])
    counts = own_pixel_counts(scene, 0, poses, dims)
    # Car 1 shows columns 30-44 (15 x 20 px), car 2 all its 10 x 20, the pedestrian nothing, the van 8 x 15.
    assert counts.tolist() == [300, 200, 0, 120]


def test_a_hidden_mover_is_in_view_not_visible_and_counts_only_for_the_in_view_recall():
    scene, _ = occluded_pair(frames=6)
    movers = {m.id: m for m in scene_movers(scene)}
    assert all(len(m.in_view) == 6 for m in movers.values())
    assert [len(movers[k].visible) for k in (1, 2, 3, 4)] == [6, 6, 0, 6]
    # One actor on each car and the van, on their centres; nothing on the pedestrian.
    actors = [SimpleNamespace(id=k, frames=np.arange(6), centroid=movers[k].centre.copy(),
                              velocity=movers[k].velocity.copy(), category=guess)
              for k, guess in ((1, "car"), (2, "car"), (4, "truck"))]
    score = score_actors(actors, list(movers.values()))
    assert score["movers"] == 3 and score["movers_in_view"] == 4
    assert score["recall"] == 1.0 and score["recall_in_view"] == 0.75
    assert score["missed"] == [{"mover": 3, "class": "pedestrian", "visible_frames": 0, "in_view_frames": 6}]
    assert score["centroid_error_median"] == 0.0 and score["spurious"] == 0
    assert score["class_accuracy"] == 2 / 3  # the van (class "car" in the generator) guessed a truck


def test_without_ground_truth_maps_visible_is_in_view():
    scene, _ = occluded_pair(frames=5)
    scene.load_optional = lambda kind, i: None
    movers = scene_movers(scene)
    assert all(np.array_equal(m.visible, m.in_view) and len(m.in_view) == 5 for m in movers)


def test_a_few_specks_of_a_mover_are_not_visible(monkeypatch):
    """A mover showing fewer own pixels than MIN_OWN_PIXELS (at 320 px wide, scaled with the image's area)
    is not visible: at 64 px wide, 250 of them are 10 px; the 3 px a speck shows are too few."""
    import radar4dgs.actors.groundtruth as groundtruth

    monkeypatch.setattr(groundtruth, "MIN_OWN_PIXELS", 250)
    scene, _ = occluded_pair(frames=5)
    pose, dims = box_pose((2, 4), (2, 2), 20.0, 1.0)
    depth = scene.load_optional("gt/depth", 0).copy()
    mask = scene.load_optional("gt/dynamic_mask", 0).copy()
    depth[2, 2:5], mask[2, 2:5] = 20.0, 255
    scene.load_optional = lambda kind, i: {"gt/depth": depth, "gt/dynamic_mask": mask}[kind]
    scene.extra["synthetic"]["objects"].append({"id": 9, "kind": "moving", "dims": dims, "poses": [pose.tolist()] * 5,
                                                "velocity": [0.0, 0.0, 0.0]})
    assert own_pixel_counts(scene, 0, pose[None], np.array([dims]))[0] == 3
    movers = {m.id: m for m in scene_movers(scene)}
    assert len(movers[9].in_view) == 5 and len(movers[9].visible) == 0
    assert len(movers[2].visible) == 5  # 200 own pixels


def test_a_spurious_actor_far_from_every_mover_does_not_take_a_good_pair():
    """Movers at x = 0, 18.4 and -24 m; actors 1 m from the first, 1.4 m from the second, and a stray one
    40 m from the second. Summed over all ungated distances, a0-M2, a1-M0, a2-M1 (25 + 17 + 40 m) is cheaper
    than the two good pairs plus the stray's 82 m, so the gate has to come before the assignment."""
    frames = np.arange(6)

    def along_x(x: float) -> np.ndarray:
        return np.tile([x, 0.0, 0.0], (len(frames), 1))

    movers = [Mover(id=k, category="car", centre=along_x(x), velocity=np.zeros((6, 3)), in_view=frames, visible=frames)
              for k, x in enumerate((0.0, 18.4, -24.0))]
    actors = [SimpleNamespace(id=10 + k, frames=frames, centroid=along_x(x), velocity=np.zeros((6, 3)), category="car")
              for k, x in enumerate((1.0, 17.0, 58.4))]
    score = score_actors(actors, movers)
    assert [(p["actor"], p["mover"]) for p in score["pairs"]] == [(10, 0), (11, 1)]
    assert score["spurious"] == 1 and score["recall"] == 2 / 3
    assert np.isclose(score["centroid_error_median"], 1.2)
    assert [m["mover"] for m in score["missed"]] == [2]
