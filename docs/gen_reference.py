"""MkDocs hook: generates the CLI reference and the Python API pages on every build.

``mkdocs.yml`` names this file under ``hooks:``. On each build (and each reload of ``mkdocs serve``)
``on_files`` adds pages that exist only in the build, never in ``docs/``:

* ``reference/cli.md``: ``radar4dgs --help`` and then ``radar4dgs COMMAND --help`` for every command
  of ``radar4dgs.cli.COMMANDS``, in its order, each as a plain-text block. The text is what tyro
  prints from the command's dataclass, so a new option, a changed default or a new command shows
  up on the next build without anyone editing a page.
* ``reference/api/<package>.md``: one page per layer of the package, with a mkdocstrings block
  (``::: radar4dgs.<package>.<module>``) for every public module found in ``src/radar4dgs``.

The functions below import no MkDocs module, so ``tests/test_docs.py`` can call them without the
``docs`` extra installed.
"""

from __future__ import annotations

import ast
import contextlib
import io
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE_DIR = ROOT / "src" / "radar4dgs"
CLI_PAGE = "reference/cli.md"
# Width of the help text: wide enough for long option names, narrow enough for a page.
HELP_COLUMNS = 100

# The package's layers, bottom to top (docs/architecture.md), with one line each for the API pages.
# tests/test_docs.py fails when a package of src/radar4dgs is missing here.
API_LAYERS: dict[str, str] = {
    "io": "Scene folders: the types, reading with validation, writing (atomic), previews, time "
          "normalisation.",
    "config": "Presets, `to_dict` / `from_dict`, saving and reloading a run's resolved configuration.",
    "radar": "The radar front end: Doppler ego-motion (RANSAC), dynamic points, objects and their "
             "velocity, poses integrated from the radar.",
    "render": "The Gaussian rasterizer: one `rasterize` call, a pure-PyTorch backend (CPU and any "
              "device) and gsplat on CUDA.",
    "depth": "Monocular depth made metric by the radar (affine and the paper's plane voting), "
             "temporal smoothing, the flat-world fallback, sky masks.",
    "segment": "The radar-camera dynamic segmentation network, its training, inference and the "
               "non-learned baseline.",
    "motion": "Optical flow, whole-object and radar-guided matching, lifting to pseudo scene flow, "
              "radar association.",
    "datasets": "The synthetic scene generator and the converters (aiMotive, OmniHD-Scenes, "
                "View-of-Delft).",
    "model": "The scene model: Gaussian sets, sky map, the VGPT deformation field, the baselines' "
             "motion models, views, the run folder and its loader.",
    "metrics": "PSNR, SSIM, LPIPS, PSNR* on dynamic pixels; the flow, radar, depth and mask losses.",
    "train": "The three-stage trainer, initialisation, densification, the objective, optimisers, the "
             "standalone motion fit and the method variants.",
    "actors": "Actors without boxes: the moving objects of a trained run found from its dynamic "
              "Gaussians' motion, `RUN/actors.json`, edits at render time (remove, move, re-time), "
              "never-observed masks.",
    "evaluate": "Evaluation of a trained run (metrics, renders, video, HTML report) and scoring of the "
                "front end against ground truth.",
    "apps": "One module per command (prepare, demo, bench, render, export, viewer, ...).",
}


# --- CLI reference -------------------------------------------------------------------------------

def _plain_help(argv: list[str]) -> str:
    """What ``radar4dgs ARGV`` prints, as plain text (no colours, no box-drawing characters)."""
    import tyro

    from radar4dgs import cli

    options = getattr(tyro, "_experimental_options", None)
    saved_options = dict(options) if options is not None else None
    saved_columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(HELP_COLUMNS)
    if options is not None:
        options.update(utf8_boxes=False, ansi_codes=False)
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            try:
                cli.main(argv)
            except SystemExit as stop:  # tyro exits after printing --help
                if stop.code not in (0, None):
                    raise RuntimeError(f"`radar4dgs {' '.join(argv)}` exited with {stop.code}:\n"
                                       f"{out.getvalue()}") from None
    finally:
        if saved_columns is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = saved_columns
        if options is not None:
            options.clear()
            options.update(saved_options)
    lines = [line.rstrip() for line in out.getvalue().splitlines()]
    return "\n".join(lines).strip("\n")


def command_anchor(name: str) -> str:
    """The heading id of a command's section, e.g. ``convert aimotive`` -> ``convert-aimotive``."""
    return name.replace(" ", "-")


def cli_reference_markdown() -> str:
    """The whole CLI reference page."""
    from radar4dgs.cli import COMMANDS

    parts = [
        "# CLI reference",
        "",
        "Generated on every build of these pages from the commands' own `--help`, which tyro "
        "writes from each command's configuration dataclass: every option, its type, its default "
        "and the comment on its field. `radar4dgs COMMAND --help` prints the same text in a terminal.",
        "",
        "Commands that take `--preset tiny|small|paper` fill every option from the preset first; any "
        "option given on the command line then overrides that one value "
        "(`radar4dgs synth out --preset small --scene.radar.range-std 0.1`). Nested options are "
        "written with dots, as shown in each command's help.",
        "",
        "| command | what it does |",
        "|---|---|",
    ]
    for name, (_, _, summary) in COMMANDS.items():
        parts.append(f"| [`{name}`](#{command_anchor(name)}) | {summary.replace('|', '&#124;')} |")
    parts += ["", "## `radar4dgs --help`", "", "```text", _plain_help(["--help"]), "```", ""]
    for name in COMMANDS:
        parts += [f"## `radar4dgs {name}` {{#{command_anchor(name)}}}", "",
                  "```text", _plain_help([*name.split(), "--help"]), "```", ""]
    return "\n".join(parts)


# --- API reference -------------------------------------------------------------------------------

def _docstring_first_paragraph(path: Path) -> str:
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    return doc.strip().split("\n\n")[0].replace("\n", " ")


def public_modules(package: str) -> list[str]:
    """Dotted names of the public modules of ``radar4dgs.<package>`` (subpackages included), read
    from the source tree without importing anything."""
    base = PACKAGE_DIR / package
    if not base.is_dir():
        return [f"radar4dgs.{package}"]
    names = []
    for path in sorted(base.rglob("*.py")):
        relative = path.relative_to(PACKAGE_DIR).with_suffix("")
        parts = list(relative.parts)
        if any(part.startswith("_") for part in parts[:-1]) or "weights" in parts:
            continue
        if parts[-1] == "__init__":
            parts = parts[:-1]
        elif parts[-1].startswith("_"):
            continue
        names.append(".".join(["radar4dgs", *parts]))
    return sorted(names, key=lambda name: (name.count("."), name))


def api_page_markdown(package: str) -> str:
    """The API page of one layer: its description, then every public module."""
    source = PACKAGE_DIR / package / "__init__.py"
    if not source.exists():
        source = PACKAGE_DIR / f"{package}.py"
    lines = [f"# `radar4dgs.{package}`", "", API_LAYERS[package], ""]
    summary = _docstring_first_paragraph(source) if source.exists() else ""
    if summary:
        lines += [summary, ""]
    lines += ["Generated from the docstrings of the source on every build.", ""]
    modules = public_modules(package)
    if package == "apps":  # the dispatcher sits beside the command modules, in the same layer
        modules.append("radar4dgs.cli")
    for module in modules:
        lines += [f"::: {module}", ""]
        if module == f"radar4dgs.{package}" and (PACKAGE_DIR / package).is_dir():
            # The package's own page section: its docstring only. What it re-exports is documented
            # once, in the module that defines it.
            lines[-1:] = ["    options:", "      members: false", ""]
    return "\n".join(lines)


def api_pages() -> dict[str, str]:
    """Path under docs/ -> content of every generated API page."""
    return {f"reference/api/{package}.md": api_page_markdown(package) for package in API_LAYERS}


def generated_pages() -> dict[str, str]:
    """Every page this hook adds to the build: path under docs/ -> Markdown."""
    return {CLI_PAGE: cli_reference_markdown(), **api_pages()}


# --- MkDocs hook ---------------------------------------------------------------------------------

def on_files(files, config):
    from mkdocs.structure.files import File

    for path, content in generated_pages().items():
        existing = files.get_file_from_path(path)
        if existing is not None:
            files.remove(existing)
        files.append(File.generated(config, path, content=content))
    return files
