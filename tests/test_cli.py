"""The dispatcher: usage, unknown commands, presets filling nested config defaults."""

from __future__ import annotations

import importlib
import re
import subprocess
import sys
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import tyro

from radar4dgs import cli
from radar4dgs.config import PresetName


@dataclass
class Options:
    width: int = 1  # image width
    noise: float = 0.1  # noise

    PRESETS = {"tiny": {"width": 160}, "paper": {"width": 1920}}


@dataclass
class EchoCommand:
    """Echo the parsed options (test command)."""

    out: tyro.conf.Positional[Path]  # where
    preset: PresetName = "small"  # preset
    options: Options = field(default_factory=Options)  # options

    PRESET_FIELDS = {"options": Options}

    def run(self) -> int:
        print(f"{self.out} {self.preset} {self.options.width} {self.options.noise}")
        return 0


def register_command(monkeypatch, command_class: type, names: dict[str, str]) -> None:
    """Make ``command_class`` the command of each name (name -> summary), from a fake module."""
    module_name = f"{command_class.__name__.lower()}_module"
    module = types.ModuleType(module_name)
    setattr(module, command_class.__name__, command_class)
    monkeypatch.setitem(sys.modules, module_name, module)
    for name, summary in names.items():
        monkeypatch.setitem(cli.COMMANDS, name, (module_name, command_class.__name__, summary))


@pytest.fixture
def echo(monkeypatch):
    register_command(monkeypatch, EchoCommand, {"echo": "Echo.", "echo twice": "Echo twice."})


def test_preset_fills_nested_defaults_and_flags_override(echo, capsys):
    assert cli.main(["echo", "/o", "--preset", "tiny", "--options.noise", "0.5"]) == 0
    assert capsys.readouterr().out.strip() == "/o tiny 160 0.5"
    assert cli.main(["echo", "/o", "--preset=paper", "--options.width", "3"]) == 0
    assert capsys.readouterr().out.strip() == "/o paper 3 0.1"
    assert cli.main(["echo", "/o"]) == 0
    assert capsys.readouterr().out.strip() == "/o small 1 0.1"


def test_two_word_commands_match_the_longest_name(echo, capsys):
    assert cli.main(["echo", "twice", "/p", "--preset", "tiny"]) == 0
    assert capsys.readouterr().out.strip() == "/p tiny 160 0.1"
    assert cli.main(["echo", "/q"]) == 0
    assert capsys.readouterr().out.strip() == "/q small 1 0.1"


def test_required_positional_stays_required(echo, capsys):
    assert cli.main(["echo", "--preset", "tiny"]) == 2
    assert capsys.readouterr().err == "radar4dgs echo: Missing from radar4dgs echo: PATH where (required) " \
                                      "(radar4dgs echo --help)\n"
    with pytest.raises(SystemExit) as info:
        cli.build_command("echo", ["--preset", "tiny"])
    assert info.value.code == 2


def test_unknown_preset_is_refused(echo, capsys):
    assert cli.main(["echo", "/o", "--preset", "huge"]) == 2
    assert "radar4dgs echo: --preset: unknown preset 'huge'" in capsys.readouterr().err


def test_usage_and_unknown_command(capsys):
    assert cli.main([]) == 0
    assert "inspect" in capsys.readouterr().out
    assert cli.main(["fly"]) == 2
    assert "unknown command 'fly'" in capsys.readouterr().err


@pytest.mark.parametrize("name", list(cli.COMMANDS))
def test_listed_summary_is_the_command_docstring(name):
    module, attribute, summary = cli.COMMANDS[name]
    cls = getattr(importlib.import_module(module), attribute)
    assert summary == cli.class_summary(cls)


@pytest.mark.parametrize("args", [["--help"], ["train", "--help"], ["prepare", "--help"], ["render", "--help"],
                                  ["eval", "--help"], ["export", "--help"], ["view", "--help"],
                                  ["fit-motion", "--help"], ["seg-train", "--help"]])
def test_help_does_not_import_torch(args):
    # Importing torch alone takes 1.5-2 s; help must answer in well under a second (issue 20).
    code = ("import sys\nfrom radar4dgs.cli import main\ntry:\n    main(%r)\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in ('torch', 'torchvision', 'transformers') if m in sys.modules))" % (args,))
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "usage:" in result.stdout
    assert result.stdout.strip().splitlines()[-1] == "[]"


# --- issue 22: rough edges of the command line --------------------------------------------------


def test_a_command_group_alone_lists_its_commands(capsys):
    assert cli.main(["convert"]) == 2
    err = capsys.readouterr().err
    assert "radar4dgs convert: choose one of aimotive, omnihd, vod" in err
    assert "convert vod" in err and "unknown command" not in err
    assert cli.main(["convert", "kitti"]) == 2
    assert "no command 'convert kitti'; choose one of aimotive, omnihd, vod" in capsys.readouterr().err
    assert cli.main(["convert", "--help"]) == 0
    assert "convert omnihd" in capsys.readouterr().out


@dataclass
class FailCommand:
    """Fail the way a user error does (test command)."""

    what: str = "missing"

    def run(self) -> int:
        import warnings

        if self.what == "missing":
            raise FileNotFoundError("/data/scene/scene.json: missing file")
        if self.what == "value":
            raise ValueError("--scale must be in (0, 1], got 2.0")
        warnings.warn("the radar frame 000003 is empty", UserWarning, stacklevel=1)
        return 0


@pytest.fixture
def fail(monkeypatch):
    register_command(monkeypatch, FailCommand, {"fail": "Fail."})


def test_user_errors_are_one_line_and_debug_shows_the_traceback(fail, capsys):
    assert cli.main(["fail"]) == 1
    captured = capsys.readouterr()
    assert captured.err == "radar4dgs fail: /data/scene/scene.json: missing file\n"
    assert cli.main(["fail", "--what", "value"]) == 1
    assert capsys.readouterr().err == "radar4dgs fail: --scale must be in (0, 1], got 2.0\n"
    with pytest.raises(FileNotFoundError):
        cli.main(["fail", "--debug"])


def test_synth_into_an_existing_folder_is_one_line_without_a_progress_bar(tmp_path, capsys):
    (tmp_path / "scene").mkdir()
    assert cli.main(["synth", str(tmp_path / "scene"), "--preset", "tiny"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "already exists" in err and str(tmp_path / "scene") in err
    assert "Traceback" not in err and "%|" not in err


@pytest.mark.parametrize("args", [["convert", "aimotive", "SRC", "OUT"],
                                  ["convert", "omnihd", "SRC", "OUT", "--clip", "c1"],
                                  ["convert", "vod", "SRC", "OUT", "--frames", "0:5"]])
def test_converters_refuse_an_existing_output_before_reading_anything(args, tmp_path, capsys):
    # SRC is an empty folder: a converter that read it first would complain about it instead.
    (tmp_path / "SRC").mkdir()
    (tmp_path / "OUT").mkdir()
    args = [str(tmp_path / a) if a in ("SRC", "OUT") else a for a in args]
    assert cli.main(args) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{tmp_path / 'OUT'}: already exists" in err, err
    assert "pass --force to overwrite it" in err and "%|" not in err
    assert cli.build_command(args[0] + " " + args[1], args[2:] + ["--force"]).force


def test_synth_keeps_the_same_scene_refuses_another_and_force_overwrites(tmp_path, capsys):
    out = str(tmp_path / "scene")
    base = ["synth", out, "--preset", "tiny", "--scene.num-frames", "2"]
    assert cli.main([*base, "--seed", "1"]) == 0
    capsys.readouterr()
    assert cli.main([*base, "--seed", "1"]) == 0  # the very scene: left as it is
    assert "holds this scene already (same preset, seed and config)" in capsys.readouterr().out
    assert cli.main([*base, "--seed", "2"]) == 1
    assert capsys.readouterr().err == (f"radar4dgs synth: {out}: already exists (made with preset 'tiny', seed 1, "
                                       f"not preset 'tiny', seed 2); pass --force to overwrite it\n")
    assert cli.main([*base, "--seed", "1", "--scene.fps", "5"]) == 1
    assert "made with another generator config: fps: 10.0 != 5.0" in capsys.readouterr().err
    assert cli.main([*base, "--seed", "2", "--force"]) == 0
    assert "seed 2" in capsys.readouterr().out


def test_warnings_print_one_line_without_the_source_line():
    code = ("import sys, types\nfrom radar4dgs import cli\nfrom tests_fail import FailCommand\n"
            "module = types.ModuleType('fail_module'); module.FailCommand = FailCommand\n"
            "sys.modules['fail_module'] = module\n"
            "cli.COMMANDS['fail'] = ('fail_module', 'FailCommand', 'Fail.')\n"
            "sys.exit(cli.main(['fail', '--what', 'warn']))\n")
    helper = Path(__file__).resolve().parent
    result = subprocess.run([sys.executable, "-W", "default", "-c", code.replace("tests_fail", "test_cli")],
                            capture_output=True, text=True, cwd=helper, check=True)
    assert result.stderr == "radar4dgs: warning: the radar frame 000003 is empty\n"


_HINT = re.compile(r"\(default: ([^()]*)\)")


def _option_helps(text: str) -> list[str]:
    """Each option's invocation and help, as one line, of a `--help` page printed in one column
    (boxes drawn with "│" on a terminal, plain text otherwise): an option starts at a line indented
    by at most two spaces with a "-", its help goes on in lines indented more."""
    blocks: list[str] = []
    for raw in re.sub(r"\x1b\[[0-9;]*m", "", text).splitlines():
        line = raw.strip().strip("│").rstrip() if raw.lstrip().startswith("│") else raw.rstrip()
        indent = len(line) - len(line.lstrip())
        open_choices = bool(blocks) and blocks[-1].count("{") > blocks[-1].count("}")  # a wrapped metavar
        if indent <= 2 and not open_choices:
            blocks.append(line.strip())  # an option, or a header or a rule that ends the last one
        elif blocks:
            blocks[-1] += " " + line.strip()
    return [b for b in blocks if b.startswith("-") and not set(b) <= set("-─ ")]


@pytest.mark.parametrize("name", list(cli.COMMANDS))
def test_help_states_each_default_once(name, monkeypatch, capsys):
    monkeypatch.setenv("COLUMNS", "100")  # one column of boxes
    with pytest.raises(SystemExit) as info:
        cli.main([*name.split(), "--help"])
    assert info.value.code == 0
    helps = _option_helps(capsys.readouterr().out)
    assert helps, "no options parsed from the help page"
    for text in helps:
        hints = _HINT.findall(text)
        assert len(hints) <= 1, f"two defaults: {text}"
        if hints:
            before = text[:text.index("(default:")]
            assert hints[0].strip() not in ("", "''"), f"an empty default: {text}"
            assert not (hints[0] == "None" and re.search(r"\bdefault\b", before, re.I)), \
                f"the help says a default and then (default: None): {text}"


def test_prepare_only_lists_the_stages(capsys, monkeypatch):
    from radar4dgs.apps.prepare import STAGES, StageName

    assert typing.get_args(StageName) == tuple(s.name for s in STAGES)
    monkeypatch.setenv("COLUMNS", "100")
    with pytest.raises(SystemExit):
        cli.main(["prepare", "--help"])
    assert "--only [{radar,depth,masks,object_depth,flow}" in capsys.readouterr().out
    with pytest.raises(SystemExit) as info:
        cli.build_command("prepare", ["/scene", "--only", "sky"])
    assert info.value.code == 2
    assert cli.build_command("prepare", ["/scene", "--only", "flow", "radar"]).only == ("flow", "radar")


def test_train_has_one_method_option(capsys, monkeypatch):
    from radar4dgs.train.variants import METHOD_NAMES, apply_variant

    command = cli.build_command("train", ["/scene", "--preset", "tiny", "--method", "ours-no-radar"])
    config = apply_variant(command.config, command.method)
    assert config.losses.radar_weight == 0.0 and config.method == "ours"
    assert cli.build_command("train", ["/scene", "--method", "static"]).method == "static"
    with pytest.raises(SystemExit):
        cli.build_command("train", ["/scene", "--config.method", "static"])
    capsys.readouterr()
    monkeypatch.setenv("COLUMNS", "100")
    with pytest.raises(SystemExit):
        cli.main(["train", "--help"])
    out = capsys.readouterr().out
    assert "--config.method" not in out and "--method {" + ",".join(METHOD_NAMES[:3]) in out
