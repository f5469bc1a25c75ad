"""Every class of user error ends the command with exactly one line on stderr naming the file (or
the option) and the problem, a non-zero exit status and no traceback; ``--debug`` shows the
traceback (or tyro's full message) instead. Each case fails before any real work."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from radar4dgs.cli import main


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory) -> Path:
    """A valid two-frame synthetic scene, never prepared."""
    from radar4dgs.config import preset
    from radar4dgs.datasets.synth import SynthConfig, synthesize

    return synthesize(preset(SynthConfig, "tiny", seed=1, num_frames=2),
                      tmp_path_factory.mktemp("user-errors") / "scene", progress=False, preset="tiny")


def one_line(capsys, command: str, *names: str) -> str:
    """The one stderr line of a failed command, checked: ``radar4dgs COMMAND: ...`` naming each of
    ``names``, no traceback."""
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.endswith("\n"), f"not one line:\n{err}"
    assert err.startswith(f"radar4dgs {command}: "), err
    assert "Traceback" not in err and "╭" not in err
    for name in names:
        assert name in err, f"{name!r} not named in {err!r}"
    return err


def command_args(command: str, scene: Path, tmp_path: Path) -> list[str]:
    """The arguments that make ``command`` read ``scene`` first."""
    if command == "train":
        return ["train", str(scene), "--out", str(tmp_path / "run"), "--preset", "tiny", "--quiet"]
    return [command, str(scene)] + (["--quiet"] if command == "prepare" else [])


COMMANDS = ("inspect", "prepare", "frontend-eval", "train")


@pytest.mark.parametrize("command", COMMANDS)
def test_missing_scene_folder(command, tmp_path, capsys):
    missing = tmp_path / "no-such-scene"
    assert main(command_args(command, missing, tmp_path)) == 1
    err = one_line(capsys, command, str(missing))
    assert "not a scene folder (no such directory)" in err


@pytest.mark.parametrize("command", COMMANDS)
def test_a_folder_that_is_not_a_scene(command, tmp_path, capsys):
    folder = tmp_path / "photos"
    folder.mkdir()
    (folder / "holiday.jpg").write_bytes(b"\xff\xd8")
    assert main(command_args(command, folder, tmp_path)) == 1
    err = one_line(capsys, command, str(folder / "scene.json"))
    assert "missing file" in err


@pytest.mark.parametrize(("text", "problem"), [("{\"frames\": [", "unreadable JSON"),
                                               ("[]", "top level must be a JSON object"),
                                               ("{\"version\": 1}", "expected 'radar4dgs-scene'")])
@pytest.mark.parametrize("command", COMMANDS)
def test_malformed_scene_json(command, text, problem, tmp_path, capsys):
    scene = tmp_path / "scene"
    scene.mkdir()
    (scene / "scene.json").write_text(text)
    assert main(command_args(command, scene, tmp_path)) == 1
    err = one_line(capsys, command, str(scene / "scene.json"))
    assert problem in err


def test_missing_prepared_stage(tiny_scene, tmp_path, capsys):
    # train without prepare: the prepared depth is named, with the command that makes it.
    assert main(["train", str(tiny_scene), "--out", str(tmp_path / "run"), "--preset", "tiny", "--quiet"]) == 1
    err = one_line(capsys, "train", str(tiny_scene / "prepared"))
    assert "no prepared depth" in err and f"radar4dgs prepare {tiny_scene}" in err
    assert not (tmp_path / "run" / "model.pt").exists()
    # frontend-eval without prepare.
    assert main(["frontend-eval", str(tiny_scene)]) == 1
    err = one_line(capsys, "frontend-eval", str(tiny_scene / "prepared"))
    assert "missing prepared folder" in err
    # One stage alone, before the stages it reads exist.
    assert main(["prepare", str(tiny_scene), "--out", str(tmp_path / "prepared"), "--only", "flow", "--quiet"]) == 1
    err = one_line(capsys, "prepare", str(tmp_path / "prepared" / "radar"))
    assert "not prepared" in err and "add radar to --only" in err
    assert not (tmp_path / "prepared" / "flow").exists()


@pytest.mark.parametrize(("args", "names"), [
    (["synth", "OUT", "--seed", "abc"], ["--seed", "'abc'"]),
    (["synth", "OUT", "--preset", "huge"], ["--preset", "'huge'"]),
    (["train", "SCENE", "--method", "fastest"], ["--method", "'fastest'"]),
    (["prepare", "SCENE", "--only", "sky"], ["--only", "'sky'"]),
    (["eval", "RUN", "--no-such-flag"], ["--no-such-flag"]),
    (["export", "RUN", "--format", "obj"], ["--format", "'obj'"]),
])
def test_bad_flag(args, names, tmp_path, capsys):
    args = [str(tmp_path / a) if a.isupper() else a for a in args]
    assert main(args) == 2
    one_line(capsys, args[0], *names)
    assert not (tmp_path / "OUT").exists()


def test_a_bad_value_found_while_running(tmp_path, capsys):
    # A value tyro accepts as text but the command cannot parse (a lane shift that is not a number).
    (tmp_path / "run").mkdir()
    assert main(["render", str(tmp_path / "run"), "--trajectory", "lane-shift:abc", "--quiet"]) == 1
    one_line(capsys, "render", "lane-shift:abc")


def test_debug_shows_the_traceback(tiny_scene, tmp_path, capsys):
    from radar4dgs.io.scene import SceneError

    with pytest.raises(SceneError, match="not a scene folder"):
        main(["inspect", str(tmp_path / "no-such-scene"), "--debug"])
    with pytest.raises(FileNotFoundError, match="no prepared depth"):
        main(["train", str(tiny_scene), "--out", str(tmp_path / "run"), "--preset", "tiny", "--quiet", "--debug"])
    capsys.readouterr()
    # A bad flag with --debug: tyro's whole message (several lines), still exit status 2.
    with pytest.raises(SystemExit) as info:
        main(["synth", str(tmp_path / "out"), "--seed", "abc", "--debug"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") > 2 and "Error parsing --seed" in err


def test_an_existing_run_of_another_config_is_refused_in_one_line(tiny_scene, tmp_path, capsys):
    # The reuse refusals are user errors as well: one line saying what differs, --force to overwrite.
    from radar4dgs.config import preset, save_config
    from radar4dgs.model.config import TrainConfig

    run = tmp_path / "run"
    run.mkdir()
    save_config(preset(TrainConfig, "tiny", optim={"iterations": 7}), run / "config.json")
    (run / "run.json").write_text(json.dumps({"scene": str(tiny_scene), "prepared": str(tiny_scene / "prepared")}))
    (run / "model.pt").write_bytes(b"a finished run")
    assert main(["train", str(tiny_scene), "--out", str(run), "--preset", "tiny", "--quiet"]) == 1
    err = one_line(capsys, "train", str(run / "config.json"), "optim.iterations: 7 != ")
    assert "pass --force to overwrite it" in err
    assert (run / "model.pt").read_bytes() == b"a finished run"
    # --force deletes that run; here the training then stops on the missing prepared depth.
    assert main(["train", str(tiny_scene), "--out", str(run), "--preset", "tiny", "--quiet", "--force"]) == 1
    captured = capsys.readouterr()
    assert f"--force: removed the earlier run in {run}" in captured.out
    assert "no prepared depth" in captured.err and not (run / "model.pt").exists()
