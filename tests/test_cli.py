"""The dispatcher: usage, unknown commands, presets filling nested config defaults."""

from __future__ import annotations

import importlib
import subprocess
import sys
import types
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


@pytest.fixture
def echo(monkeypatch):
    module = types.ModuleType("echo_module")
    module.EchoCommand = EchoCommand
    monkeypatch.setitem(sys.modules, "echo_module", module)
    monkeypatch.setitem(cli.COMMANDS, "echo", ("echo_module", "EchoCommand", "Echo."))
    monkeypatch.setitem(cli.COMMANDS, "echo twice", ("echo_module", "EchoCommand", "Echo twice."))


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


def test_required_positional_stays_required(echo):
    with pytest.raises(SystemExit) as info:
        cli.main(["echo", "--preset", "tiny"])
    assert info.value.code == 2


def test_unknown_preset_is_refused(echo):
    with pytest.raises(SystemExit, match="unknown preset 'huge'"):
        cli.main(["echo", "/o", "--preset", "huge"])


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
