"""`radar4dgs train RUN --resume` (issue 26): a run resumes with its own config, scene and prepared
folder and no flags; a changed option is refused naming the difference, except the iteration
count, which is accepted and recorded in provenance.json."""

from __future__ import annotations

import json
import re
import shutil

import pytest
import torch

from radar4dgs.apps.train import changed_values, resumed_config
from radar4dgs.cli import main
from radar4dgs.config import load_config, preset, save_config
from radar4dgs.model.config import TrainConfig

QUIET = ["--quiet", "--no-eval", "--no-tensorboard"]


@pytest.fixture
def run(tiny_trained_run, tmp_path):
    """A copy of the session's tiny run (20 iterations of a tiny config with threads=1; its
    run.json names the shared scene, which no test here changes)."""
    copy = tmp_path / "run"
    shutil.copytree(tiny_trained_run / "run", copy)
    return copy


def step_of(run) -> int:
    return int(torch.load(run / "checkpoints" / "last.pt", map_location="cpu", weights_only=True)["step"])


def test_changed_values_are_the_nested_entries_that_differ():
    assert changed_values({"a": 1, "b": {"c": 2, "d": 3}}, {"a": 1, "b": {"c": 2, "d": 4}}) == {"b": {"d": 4}}
    assert changed_values({"a": 1}, {"a": 1}) == {}


def test_the_resumed_config_is_the_runs_own_with_the_options_given(tmp_path):
    saved = preset(TrainConfig, "tiny", seed=3, threads=1, optim={"iterations": 30})
    save_config(saved, tmp_path / "config.json")
    small = preset(TrainConfig, "small")
    # No option given (the command's config is the preset's, here another preset): the run's own.
    config, changes = resumed_config(tmp_path, small, small)
    assert config == saved and changes == []
    # Options given are those differing from the preset; the runtime ones never count.
    asked = preset(TrainConfig, "small", threads=4, optim={"iterations": 50}, losses={"flow_weight": 2.0})
    config, changes = resumed_config(tmp_path, asked, small)
    assert config.threads == 4 and config.optim.iterations == 50 and config.seed == 3
    assert changes == ["losses.flow_weight: 1.0 != 2.0", "optim.iterations: 30 != 50"]
    # An explicit method sets its fields on the run's config.
    _, changes = resumed_config(tmp_path, small, small, method="static")
    assert changes == ["method: 'ours' != 'static'"]


def test_train_run_resume_needs_no_flags_and_accepts_more_iterations(run, capsys):
    assert step_of(run) == 20
    assert main(["train", str(run), "--resume", *QUIET]) == 0  # finished: nothing left to train
    out = capsys.readouterr().out
    assert f"resuming {run} with its config ({run / 'config.json'})" in out and "changed" not in out
    provenance = json.loads((run / "provenance.json").read_text())
    assert provenance["preset"] is None and provenance["method"] is None  # the run never recorded them
    assert "resumed" not in provenance
    # The iteration count may change: the run goes on from its checkpoint, and says so.
    assert main(["train", str(run), "--resume", "--config.optim.iterations", "23", *QUIET]) == 0
    assert "changed: optim.iterations: 20 != 23" in capsys.readouterr().out
    assert step_of(run) == 23 and load_config(TrainConfig, run / "config.json").optim.iterations == 23
    history = json.loads((run / "history.json").read_text())["history"]
    assert history[-1]["step"] == 22
    resumed = json.loads((run / "provenance.json").read_text())["resumed"]
    assert [r["changed"] for r in resumed] == [["optim.iterations: 20 != 23"]]
    # The explicit form with no config options (preset small by default) also takes the run's config.
    scene = json.loads((run / "run.json").read_text())["scene"]
    assert main(["train", scene, "--out", str(run), "--resume", *QUIET]) == 0
    assert load_config(TrainConfig, run / "config.json").optim.iterations == 23
    assert len(json.loads((run / "provenance.json").read_text())["resumed"]) == 1


@pytest.mark.parametrize("argv, message", [
    (["--config.losses.flow-weight", "2"],
     r"config\.json: --resume continues the run with its own config, and options given differ from it "
     r"\(losses\.flow_weight: 1\.0 != 2\.0\); only optim\.iterations may change on resume"),
    (["--method", "static"], r"\(method: 'ours' != 'static'\)"),
    (["--config.optim.iterations", "10"],
     r"last\.pt: the run is at iteration 20 already, past --config\.optim\.iterations 10"),
    (["--out", "elsewhere"], r"run: a run folder, resumed in place; drop --out elsewhere"),
])
def test_a_changed_option_is_refused_in_one_line(run, capsys, argv, message):
    before = {p.name: p.read_bytes() for p in (run / "config.json", run / "checkpoints" / "last.pt")}
    capsys.readouterr()
    assert main(["train", str(run), "--resume", *argv, *QUIET]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("radar4dgs train: ")
    assert re.search(message, err), err
    after = {p.name: p.read_bytes() for p in (run / "config.json", run / "checkpoints" / "last.pt")}
    assert after == before  # nothing changed in the run


def test_a_run_folder_whose_scene_is_gone_is_named(run, tmp_path, capsys):
    (run / "run.json").write_text(json.dumps({"scene": str(tmp_path / "moved"), "prepared": str(tmp_path / "p")}))
    assert main(["train", str(run), "--resume", *QUIET]) == 1
    err = capsys.readouterr().err
    assert f"run.json: the run's scene {tmp_path / 'moved'} is gone (moved?); resume with `radar4dgs train SCENE" in err
