"""The documentation site: the generated CLI reference covers every command, the navigation points
at pages that exist, every layer has an API page, every benchmark script is documented, every
picture exists, the README keeps its promises; and, when MkDocs is installed (the ``docs`` extra),
``mkdocs build --strict`` passes."""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from radar4dgs.cli import COMMANDS

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def _load_generator():
    spec = importlib.util.spec_from_file_location("docs_gen_reference", DOCS / "gen_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


gen = _load_generator()


def _nav_pages() -> list[str]:
    """Every page path named in mkdocs.yml's nav."""
    yaml = pytest.importorskip("yaml")

    class Loader(yaml.SafeLoader):
        pass

    # mkdocs.yml names Python objects (!!python/name:...) for Markdown extensions; keep them as text.
    Loader.add_multi_constructor("tag:yaml.org,2002:python/", lambda loader, suffix, node: suffix)
    config = yaml.load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"), Loader=Loader)

    def walk(entry):
        if isinstance(entry, str):
            yield entry
        elif isinstance(entry, list):
            for item in entry:
                yield from walk(item)
        elif isinstance(entry, dict):
            for value in entry.values():
                yield from walk(value)

    return [page for page in walk(config["nav"]) if page.endswith(".md")]


@pytest.fixture(scope="module")
def cli_page() -> str:
    return gen.cli_reference_markdown()


def test_cli_reference_has_every_command_with_its_help(cli_page):
    for name in COMMANDS:
        anchor = gen.command_anchor(name)
        heading = f"## `radar4dgs {name}` {{#{anchor}}}"
        assert heading in cli_page, f"no section for `radar4dgs {name}` in the CLI reference"
        section = cli_page.split(heading, 1)[1].split("\n## ", 1)[0]
        assert f"usage: radar4dgs {name}" in section, f"`radar4dgs {name} --help` text missing"
        assert f"](#{anchor})" in cli_page, f"`{name}` missing from the command table"


def test_cli_reference_is_plain_text(cli_page):
    # No ANSI colour codes and no box-drawing characters: the page shows the help as plain text.
    assert "\x1b[" not in cli_page
    assert not re.search("[\u2500-\u257f]", cli_page)


def test_cli_reference_shows_nested_config_options(cli_page):
    # The configuration fields of a stage appear as dotted options (--config.<group>.<field>).
    for name, group in (("train", "raster"), ("prepare", "radar"), ("synth", "scene")):
        section = cli_page.split(f"## `radar4dgs {name}`", 1)[1].split("\n## ", 1)[0]
        assert re.search(rf"--(config\.)?{group}\.[a-z]", section), f"no --...{group}.* option for {name}"


def test_every_nav_page_exists_or_is_generated():
    generated = set(gen.generated_pages())
    pages = _nav_pages()
    assert pages, "mkdocs.yml has no nav"
    missing = [page for page in pages if page not in generated and not (DOCS / page).is_file()]
    assert missing == [], f"pages named in mkdocs.yml's nav that do not exist: {missing}"
    assert len(pages) == len(set(pages)), "a page appears twice in the nav"


def test_every_package_has_an_api_page_in_the_nav():
    packages = sorted(p.name for p in (ROOT / "src" / "radar4dgs").iterdir()
                      if (p / "__init__.py").is_file())
    assert [p for p in packages if p not in gen.API_LAYERS] == [], "add the package to API_LAYERS"
    nav = set(_nav_pages())
    for path in gen.api_pages():
        assert path in nav, f"{path} is generated but not in mkdocs.yml's nav"
    for package in gen.API_LAYERS:
        for module in gen.public_modules(package):
            assert (ROOT / "src" / Path(*module.split("."))).with_suffix(".py").is_file() or \
                (ROOT / "src" / Path(*module.split(".")) / "__init__.py").is_file(), module


def test_every_benchmark_script_is_documented():
    page = (DOCS / "benchmarks.md").read_text(encoding="utf-8")
    for script in sorted((ROOT / "benchmarks").glob("*.py")):
        assert f"benchmarks/{script.name}" in page, f"benchmarks/{script.name} is not on docs/benchmarks.md"


def _image_links(path: Path) -> list[str]:
    text = path.read_text(encoding="utf-8")
    return [link for link in re.findall(r"!\[[^\]]*\]\(([^)\s]+)", text) if "://" not in link]


def test_every_referenced_picture_exists():
    files = [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]
    missing = [f"{path.relative_to(ROOT)}: {link}" for path in files for link in _image_links(path)
               if not (path.parent / link).is_file()]
    assert missing == []


def test_readme_starts_with_the_two_commands_and_stays_short():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 250
    block = lines[lines.index("```bash") + 1:]
    block = block[:block.index("```")]
    assert block == ['pip install -e . && radar4dgs demo', 'pip install -e ".[test]" && pytest -q']
    text = "\n".join(lines)
    assert "--index-url https://download.pytorch.org/whl/cpu" in text
    assert 'pip install -e ".[docs]"' in text and "mkdocs serve" in text


@pytest.mark.skipif(importlib.util.find_spec("mkdocs") is None or importlib.util.find_spec("material") is None
                    or importlib.util.find_spec("mkdocstrings") is None,
                    reason="mkdocs, mkdocs-material and mkdocstrings are in the docs extra")
def test_mkdocs_build_strict(tmp_path):
    result = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                            cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert (tmp_path / "site" / "reference" / "cli" / "index.html").is_file()
    shutil.rmtree(tmp_path / "site", ignore_errors=True)
