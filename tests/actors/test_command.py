"""`radar4dgs actors RUN` and the actor flags of `radar4dgs render` on the oracle run
(tests/actors/conftest.py); the report's actors section."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from PIL import Image

from radar4dgs.actors.spec import parse_edits
from radar4dgs.apps.render import render_trajectory
from radar4dgs.cli import main

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_actors_command_prints_the_table_and_writes_json_and_picture(oracle, tmp_path, capsys):
    out = tmp_path / "actors.json"
    assert main(["actors", str(oracle.root), "--json", str(out), "--recompute"]) == 0
    printed = capsys.readouterr().out
    rows = [line for line in printed.splitlines() if line.strip()[:1].isdigit()]
    assert len(rows) == 3 and all(" car " in row for row in rows)
    document = json.loads(out.read_text())
    assert document == json.loads((oracle.root / "actors.json").read_text())
    assert sorted(a["n_gaussians"] for a in document["actors"]) == sorted(len(m) for m in oracle.members.values())
    frame = document["actors"][0]["frames"][0]
    assert frame["name"] == "000000" and len(frame["centroid_world"]) == 3 and len(frame["velocity_world"]) == 3
    assert Image.open(oracle.root / "actors.png").size[0] >= 600


def test_render_with_actors_removed_writes_never_observed_masks(oracle, tmp_path, capsys):
    assert main(["render", str(oracle.root), "--remove-actors", "all", "--out", str(tmp_path / "rm"),
                 "--no-video", "--quiet", "--no-fill-unobserved"]) == 0
    assert "rendered 8 views" in capsys.readouterr().out
    frames = sorted((tmp_path / "rm").glob("?????.png"))
    masks = sorted((tmp_path / "rm").glob("?????_never_observed.png"))
    assert len(frames) == len(masks) == len(oracle.run.scene)
    # Without filling, the frame is the static layer exactly (8-bit).
    from radar4dgs.evaluate.reconstruction import to_uint8
    from radar4dgs.io.scene import normalized_times
    from radar4dgs.model.view import frame_view

    view = frame_view(oracle.run.scene, 2, 1.0, normalized_times(oracle.run.scene))
    with torch.no_grad():
        static = oracle.run.model.render(view, oracle.run.config.raster, include_dynamic=False)
    assert np.array_equal(np.asarray(Image.open(frames[2]).convert("RGB")), to_uint8(static["rgb"]))


def test_repeated_flags_and_one_line_errors(oracle, tmp_path, capsys):
    from radar4dgs.cli import build_command

    command = build_command("render", ["RUN", "--remove-actors", "0", "--remove-actors", "1", "--move-actor", "2:1,0",
                                       "--retime-actor", "2:-0.5", "--retime-actor", "1:2"])
    assert command.remove_actors == ("0", "1") and command.move_actor == ("2:1,0",)
    assert command.retime_actor == ("2:-0.5", "1:2")
    edits = parse_edits(["0", "1"], ["2:1,0"], [])  # --remove-actors 0 --remove-actors 1 --move-actor 2:1,0
    result = render_trajectory(oracle.root, "stop-time:3", out=tmp_path / "edit", video=False, progress=False,
                               edits=edits)
    assert result.slug == "stop-time_3_rm0_rm1_mv2_1_0" and result.poses == len(oracle.run.scene)
    assert main(["render", str(oracle.root), "--move-actor", "7:1,0", "--quiet"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.endswith("actors.json: no actor 7 (actors: 0, 1, 2)")
    assert main(["render", str(oracle.root), "--retime-actor", "1:fast", "--quiet"]) == 1
    assert "--retime-actor '1:fast': SCALE 'fast' is not a finite number" in capsys.readouterr().err


def test_report_shows_the_actors_picture_beside_it(oracle, tmp_path):
    from radar4dgs.evaluate.report import write_report

    (tmp_path / "actors.png").write_bytes(b"\x89PNG not decoded, only embedded")
    path = write_report(tmp_path / "report.html", title="t", metrics={"recon": {}, "nvs": {}}, per_frame={},
                        history=[], panels=[])
    assert "<h2>Actors</h2>" in path.read_text()


def test_eval_finds_the_actors_and_its_report_shows_them(oracle):
    assert main(["eval", str(oracle.root), "--no-video", "--no-lpips"]) == 0
    assert len(json.loads((oracle.root / "actors.json").read_text())["actors"]) == 3
    assert "<h2>Actors</h2>" in (oracle.root / "report.html").read_text()


def test_edited_renders_use_the_repaired_sky_unless_told_not_to(oracle):
    from radar4dgs.actors.background import background_sky
    from radar4dgs.apps.render import edit_run

    edits = parse_edits(["all"])
    repaired, unedited = edit_run(oracle.run, edits)
    raw, _ = edit_run(oracle.run, edits, repair_sky=False)  # --no-fill-unobserved
    assert unedited is oracle.run.model and raw.model.sky is oracle.run.model.sky
    assert repaired.model.sky is not oracle.run.model.sky
    assert torch.equal(repaired.model.sky.logits, background_sky(oracle.run).logits)


def test_the_never_observed_mask_takes_the_unedited_render_when_given(oracle):
    from radar4dgs.actors.background import DYNAMIC_WEIGHT, never_observed_mask
    from radar4dgs.apps.render import Unobserved, edit_run
    from radar4dgs.evaluate.reconstruction import render_view
    from radar4dgs.io.scene import normalized_times
    from radar4dgs.model.view import frame_view

    edited, unedited = edit_run(oracle.run, parse_edits(["all"]))
    unobserved = Unobserved.of(edited, unedited, fill=True)
    view = frame_view(oracle.run.scene, oracle.run.scene.test_indices[0], 1.0, normalized_times(oracle.run.scene))
    with torch.no_grad():
        after, before = render_view(edited, view), unedited.render(view, edited.config.raster)
    assert np.array_equal(unobserved.mask(edited, view, after, unedited_render=before),
                          unobserved.mask(edited, view, after))
    # A given render is the one used: one that is dynamic everywhere leaves every pixel the edit left static.
    everywhere = {"dynamic": torch.ones_like(after["dynamic"])}
    left = after["dynamic"].cpu().numpy() <= DYNAMIC_WEIGHT
    expected = never_observed_mask(edited, view, left, unobserved.visibility)
    assert expected.any()
    assert np.array_equal(unobserved.mask(edited, view, after, unedited_render=everywhere), expected)
