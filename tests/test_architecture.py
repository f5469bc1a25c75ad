"""The architecture picture in docs/architecture.md is the package's real import graph."""

from __future__ import annotations

import re
from pathlib import Path

import grimp

ARCHITECTURE = Path(__file__).resolve().parents[1] / "docs" / "architecture.md"


def package_edges() -> set[tuple[str, str]]:
    """(importer, imported) pairs of top-level subpackages of radar4dgs, from every import
    statement (function-level ones included)."""
    graph = grimp.build_graph("radar4dgs")
    edges = set()
    for module in graph.modules:
        for imported in graph.find_modules_directly_imported_by(module):
            importer_parts, imported_parts = module.split("."), imported.split(".")
            if len(importer_parts) > 1 and len(imported_parts) > 1 and importer_parts[1] != imported_parts[1]:
                edges.add((importer_parts[1], imported_parts[1]))
    return edges


def documented_edges() -> set[tuple[str, str]]:
    block = re.search(r"```mermaid\n(.*?)```", ARCHITECTURE.read_text(encoding="utf-8"), re.S).group(1)
    return set(re.findall(r"^\s*(\w+) --> (\w+)\s*$", block, re.M))


def test_documented_dependencies_are_the_real_ones():
    real, documented = package_edges(), documented_edges()
    assert real - documented == set(), "imports missing from docs/architecture.md"
    assert documented - real == set(), "docs/architecture.md shows imports the code no longer has"
