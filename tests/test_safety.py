"""No unsafe deserialisation in the package (issue 26): every ``torch.load`` passes
``weights_only=True``, no ``np.load`` allows pickles, and no ``pickle`` / ``torch.jit`` /
``yaml.load`` reads a file: a crafted checkpoint or array must not run code."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "radar4dgs"
SOURCES = sorted(SRC.rglob("*.py"))


def _dotted(node: ast.AST) -> str:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return f"{_dotted(node.value)}.{node.attr}"
    return ""


def _keyword(call: ast.Call, name: str) -> ast.AST | None:
    return next((k.value for k in call.keywords if k.arg == name), None)


def unsafe_calls(source: str) -> list[str]:
    """What in ``source`` could unpickle: one ``line: problem`` per finding."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Call):
            continue
        name, line = _dotted(node.func), node.lineno
        if any(k.arg is None for k in node.keywords) and name.endswith(".load"):
            found.append(f"{line}: {name}(**kwargs) hides its pickle setting")
        if name == "torch.load":
            value = _keyword(node, "weights_only")
            if not (isinstance(value, ast.Constant) and value.value is True):
                found.append(f"{line}: torch.load without weights_only=True")
        elif name in ("np.load", "numpy.load"):
            value = _keyword(node, "allow_pickle")
            if value is not None and not (isinstance(value, ast.Constant) and value.value is False):
                found.append(f"{line}: np.load with allow_pickle other than False")
        elif name in ("pickle.load", "pickle.loads", "torch.jit.load", "yaml.load", "marshal.loads",
                      "dill.load", "joblib.load"):
            found.append(f"{line}: {name}")
    return found


@pytest.mark.parametrize("text", ["weights_only=False", "allow_pickle=True"])
def test_no_unsafe_flag_in_the_package(text):
    hits = [f"{path.relative_to(SRC.parent)}:{n}" for path in SOURCES
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1) if text in line]
    assert not hits, f"{text} in {hits}"


def test_every_load_is_safe():
    findings = [f"{path.relative_to(SRC.parent)}:{finding}" for path in SOURCES
                for finding in unsafe_calls(path.read_text(encoding="utf-8"))]
    assert not findings, findings


def test_the_scanner_finds_unsafe_loads():
    source = ("import torch, numpy as np, pickle\n"
              "torch.load('a')\ntorch.load('b', weights_only=False)\n"
              "np.load('c', allow_pickle=True)\npickle.load(open('d', 'rb'))\n"
              "torch.load('e', weights_only=True)\nnp.load('f', allow_pickle=False)\nnp.load('g')\n")
    assert [f.split(":")[0] for f in unsafe_calls(source)] == ["2", "3", "4", "5"]
