"""The README's test command also checks the layers contract and the lint rules (as CI does)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("command", [["lint-imports"], ["ruff", "check", "--quiet"]])
def test_linter_passes(command):
    executable = shutil.which(command[0])
    assert executable, f"{command[0]} is missing: pip install -e '.[test]'"
    result = subprocess.run([executable, *command[1:]], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
