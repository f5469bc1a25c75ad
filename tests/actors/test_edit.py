"""Actor edits applied to the Gaussians (oracle run: tests/actors/conftest.py): remove, move, re-time,
against closed forms and the unedited model's own renders."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from radar4dgs.actors.edit import edited_model
from radar4dgs.actors.spec import ActorEdits, check_ids, parse_edits
from radar4dgs.actors.store import run_actors
from radar4dgs.io.scene import normalized_times
from radar4dgs.model.view import frame_view


@pytest.fixture(scope="module")
def setup(oracle):
    run = oracle.run
    actors = run_actors(run, recompute=True)
    times = normalized_times(run.scene)

    def edit(**kwargs):
        return edited_model(run.model, actors, ActorEdits(**kwargs), times, run.scene.duration)

    def render(model, index, time=None):
        view = frame_view(run.scene, index, 1.0, times)
        if time is not None:
            view.time = time
        with torch.no_grad():
            return model.render(view, run.config.raster)

    return run, actors, times, edit, render


def test_parse_edits_forms_and_one_line_errors():
    edits = parse_edits(["1,2", "5"], ["3:1.5,-2"], ["4:0.5", "6:+1.2", "7:-0.3"])
    assert edits.remove == (1, 2, 5) and not edits.remove_all
    assert edits.move == {3: (1.5, -2.0)}
    assert edits.retime == {4: ("scale", 0.5), 6: ("shift", 1.2), 7: ("shift", -0.3)}
    assert parse_edits(["all"]).remove_all
    for bad, needle in ((dict(remove=["x"]), "actor id 'x'"), (dict(move=["3:1"]), "ID:DX,DY"),
                        (dict(move=["3:a,1"]), "DX 'a'"), (dict(retime=["3:0"]), "positive"),
                        (dict(retime=["3:"]), "ID:SCALE")):
        with pytest.raises(ValueError, match=needle) as info:
            parse_edits(**bad)
        assert "\n" not in str(info.value)


def test_unknown_actor_id_names_the_actors_file(setup):
    _, actors, *_ = setup
    with pytest.raises(ValueError, match=r"RUN/actors.json: no actor 9 \(actors: 0, 1, 2\)"):
        check_ids(parse_edits(move=["9:1,0"]), actors, "RUN/actors.json")


def test_remove_all_leaves_exactly_the_static_layer(setup, one_torch_thread):
    run, _, times, edit, render = setup
    removed = edit(remove_all=True)
    view = frame_view(run.scene, 3, 1.0, times)
    with torch.no_grad():
        edited = removed.render(view, run.config.raster)
        static = run.model.render(view, run.config.raster, include_dynamic=False)
    # There was something to remove: a car over its pixels (not 1: the tiny run's static layer, trained
    # for 20 iterations, partly covers it).
    assert float(render(run.model, 3)["dynamic"].max()) > 0.5
    assert torch.allclose(edited["rgb"], static["rgb"], atol=1e-6)
    assert float(edited["dynamic"].abs().max()) == 0.0


def test_removing_one_actor_leaves_the_others_pixels_unchanged(setup, one_torch_thread):
    run, actors, _, edit, render = setup
    others = [a.id for a in actors[1:]]
    before, after = render(run.model, 3), render(edit(remove=(actors[0].id,)), 3)
    # The removed actor's footprint: where it alone has weight (every other actor and nothing else removed).
    alone = render(edit(remove=tuple(others)), 3)["dynamic"]
    untouched = alone < 1e-6
    assert float(alone.max()) > 0.5 and bool((~untouched).any())
    assert torch.allclose(before["rgb"][untouched], after["rgb"][untouched], atol=1e-6)
    assert float((before["rgb"] - after["rgb"]).abs().max()) > 0.1


def test_move_offsets_the_gaussians_in_the_actors_frame(setup):
    run, actors, times, edit, _ = setup
    actor = actors[0]
    moved = edit(move={actor.id: (1.5, -2.0)})
    t = float(times[5])
    with torch.no_grad():
        delta = (moved.gaussians_at(t, include_static=False)["means"]
                 - run.model.gaussians_at(t, include_static=False)["means"]).numpy()
    h = float(actor.heading[5])
    expected = 1.5 * np.array([-np.sin(h), np.cos(h), 0]) - 2.0 * np.array([np.cos(h), np.sin(h), 0])
    assert np.allclose(delta[actor.gaussians], expected, atol=1e-5)
    assert np.abs(np.delete(delta, actor.gaussians, axis=0)).max() == 0.0
    # The heading is the generator car's own direction of travel (constant velocity).
    velocity = actor.velocity[5, :2]
    assert abs(np.arctan2(velocity[1], velocity[0]) - h) < 1e-6


def test_a_moved_actor_looks_like_the_camera_moved_the_other_way(setup, one_torch_thread):
    """Moving an actor by d renders it (alone, static layer left out) exactly as the unmoved actor seen
    from the camera moved by -d; its image centroid moves by the projected offset (several pixels)."""
    run, actors, times, edit, _ = setup
    actor = actors[0]
    others = tuple(a.id for a in actors if a.id != actor.id)
    index = 3
    h = float(actor.heading[index])
    offset = np.array([-np.sin(h), np.cos(h), 0.0])  # 1 m to the actor's left
    view = frame_view(run.scene, index, 1.0, times)
    back = frame_view(run.scene, index, 1.0, times)
    back.world_to_camera = view.world_to_camera.copy()
    back.world_to_camera[:3, 3] += view.world_to_camera[:3, :3] @ offset
    with torch.no_grad():
        moved = edit(remove=others, move={actor.id: (1.0, 0.0)}).render(view, run.config.raster, include_static=False)
        still = edit(remove=others).render(view, run.config.raster, include_static=False)
        reference = edit(remove=others).render(back, run.config.raster, include_static=False)
    assert torch.allclose(moved["alpha"], reference["alpha"], atol=1e-5)
    assert torch.allclose(moved["rgb"], reference["rgb"], atol=1e-5)

    def centroid(weight):
        rows, cols = np.indices(weight.shape)
        return np.array([(weight * cols).sum(), (weight * rows).sum()]) / weight.sum()

    def project(point):
        cam = view.world_to_camera[:3, :3] @ point + view.world_to_camera[:3, 3]
        return (view.K @ cam)[:2] / cam[2]

    shift = centroid(moved["alpha"].numpy()) - centroid(still["alpha"].numpy())
    expected = project(actor.centroid[index] + offset) - project(actor.centroid[index])
    # The image centroid is that of the visible surface, not of the body, and the moved car shows more of
    # its side: within 15 % (measured 10.3 %, 0.81 px of 7.85 px).
    assert np.linalg.norm(expected) > 3
    assert np.linalg.norm(shift - expected) < 0.15 * np.linalg.norm(expected)


@pytest.mark.parametrize("seconds", [0.2, -0.1])
def test_retime_shift_shows_the_actor_where_it_was_seconds_earlier(setup, seconds, one_torch_thread):
    run, actors, times, edit, render = setup
    actor = actors[0]
    others = tuple(a.id for a in actors if a.id != actor.id)
    index = 4
    shifted = render(edit(remove=others, retime={actor.id: ("shift", seconds)}), index)
    earlier = float(times[index]) - seconds / run.scene.duration
    reference = render(edit(remove=others), index, time=earlier)
    assert torch.allclose(shifted["rgb"], reference["rgb"], atol=1e-5)
    assert float((shifted["rgb"] - render(edit(remove=others), index)["rgb"]).abs().max()) > 0.1


def test_retime_scale_and_clamp(setup):
    run, actors, times, edit, _ = setup
    actor = actors[1]
    model = edit(retime={actor.id: ("scale", 2.0)})
    with torch.no_grad():
        fast = model.gaussians_at(0.3, include_static=False)["means"][actor.gaussians]
        twice = run.model.gaussians_at(0.6, include_static=False)["means"][actor.gaussians]
        late = model.gaussians_at(0.9, include_static=False)["means"][actor.gaussians]
        end = run.model.gaussians_at(1.0, include_static=False)["means"][actor.gaussians]
    assert torch.allclose(fast, twice, atol=1e-6) and torch.allclose(late, end, atol=1e-6)


def test_edits_apply_to_a_model_whose_actors_move_rigidly(setup):
    """Training with rigid actors (train.rigid_actors) gives the model an actor motion; a retimed
    actor of such a model stands where the unedited oracle has it at the remapped time."""
    import copy

    from radar4dgs.train.optimizers import adam
    from radar4dgs.train.rigid_actors import rigid_actor_motion, rigid_members

    run, actors, times, _, _ = setup
    model = copy.deepcopy(run.model)
    optimizer = adam(model.dynamic.param_groups({"means": 0.01}), eps=1e-15)
    motion, actor_index, start = rigid_actor_motion(model, [a.gaussians for a in actors], times)
    rigid_members(model, motion, actor_index, start, optimizer)
    actor = actors[1]
    edited = edited_model(model, actors, ActorEdits(retime={actor.id: ("scale", 2.0)}), times, run.scene.duration)
    with torch.no_grad():
        fast = edited.gaussians_at(0.3, include_static=False)["means"][actor.gaussians]
        twice = run.model.gaussians_at(0.6, include_static=False)["means"][actor.gaussians]
    assert edited.actor_motion is motion
    assert torch.allclose(fast, twice, atol=1e-4)


def test_an_edited_model_draws_its_dynamic_layer_in_front_as_its_model_does(setup, one_torch_thread):
    run, actors, _, edit, render = setup
    run.model.dynamic_in_front = 0.1
    try:
        # A shift by 0 s edits nothing but still wraps the model.
        unchanged = edit(retime={actors[0].id: ("shift", 0.0)})
        assert unchanged is not run.model and unchanged.dynamic_in_front == 0.1
        edited, plain = render(unchanged, 3), render(run.model, 3)
    finally:
        run.model.dynamic_in_front = 0.0
    torch.testing.assert_close(edited["rgb"], plain["rgb"])
    torch.testing.assert_close(edited["depth"], plain["depth"])
