"""The ``radar4dgs`` command line: a thin dispatcher over one dataclass per command.

Each command is a dataclass with a ``run()`` method; tyro generates its options from the fields.
A command whose class names ``PRESET_FIELDS`` (field name -> config dataclass) gets those fields'
defaults from ``--preset NAME`` first, so ``--preset small --scene.noise.range-std 0.1`` overrides
one value of the ``small`` preset. Modules are imported only for the command that runs, and a
command module imports its heavy dependencies (torch, OpenCV) inside ``run()``, so ``radar4dgs
--help`` and ``radar4dgs COMMAND --help`` answer without importing torch.

A user error (a missing or malformed file, an existing output, a bad value: ``ValueError`` and
``OSError`` subclasses such as :class:`radar4dgs.io.SceneError`, and the classes a command names
in its ``USER_ERRORS``) ends the command with one line ``radar4dgs COMMAND: <file>: <problem>`` on
stderr and exit status 1; a bad option ends it with one line ``radar4dgs COMMAND: <problem>`` and
exit status 2. ``--debug`` (anywhere on the line) shows the traceback, or tyro's full message,
instead. Warnings print as one line each, without the source line.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import importlib
import io
import re
import sys
import warnings
from typing import Iterator, Sequence

import tyro

from radar4dgs.config import PRESET_NAMES, preset

# name -> (module, class, summary), ordered as the pipeline runs. A name may be two words
# ("convert aimotive"): the dispatcher matches the longest name first. The summary is the first
# line of the class's docstring, written here too so that `radar4dgs --help` imports no command
# module (tests/test_cli.py checks that the two agree).
COMMANDS: dict[str, tuple[str, str, str]] = {
    "demo": ("radar4dgs.apps.demo", "DemoCommand",
        "Run the whole pipeline on a synthetic scene: synthesise, inspect, prepare, score the front end, "
        "train, evaluate."),
    "synth": ("radar4dgs.datasets.synth.command", "SynthCommand",
        "Synthesise a procedural driving scene with ground truth (radar4dgs synth OUT --preset small --seed 1)."),
    "convert aimotive": ("radar4dgs.datasets.convert.aimotive", "ConvertAimotiveCommand",
        "Convert an aiMotive sequence (front camera + front radar) into a scene folder."),
    "convert omnihd": ("radar4dgs.datasets.convert.omnihd", "ConvertOmnihdCommand",
        "Convert frames of an OmniHD-Scenes clip (front camera, front 4D radar, LiDAR) into a scene folder."),
    "convert vod": ("radar4dgs.datasets.convert.vod", "ConvertVodCommand",
        "Convert a frame range of View-of-Delft (camera, 3+1D radar, optional LiDAR) into a scene folder."),
    "convert nerfstudio": ("radar4dgs.datasets.convert.nerfstudio", "ConvertNerfstudioCommand",
        "Convert a nerfstudio dataset (transforms.json, images, optional ply) into a radar-less scene folder."),
    "convert colmap": ("radar4dgs.datasets.convert.colmap", "ConvertColmapCommand",
        "Convert a COLMAP model (cameras, images, points3D) and its images into a radar-less scene folder."),
    "inspect": ("radar4dgs.apps.inspect", "InspectCommand",
        "Summarise a scene folder and write a contact sheet of frames with radar points coloured by v_r."),
    "seg-train": ("radar4dgs.apps.seg_train", "SegTrainCommand",
        "Train the radar-camera dynamic segmentation network on scenes with gt/dynamic_mask."),
    "prepare": ("radar4dgs.apps.prepare", "PrepareCommand",
        "Run the front end on a scene: radar ego-motion, metric depth, sky and dynamic masks, movers' depth, flow."),
    "frontend-eval": ("radar4dgs.evaluate.frontend", "FrontendEvalCommand",
        "Score the prepared front-end outputs of a scene against its ground truth (gt/)."),
    "fit-motion": ("radar4dgs.apps.fit_motion", "FitMotionCommand",
        "Fit the invertible deformation field to a scene's prepared flow and radar; report the scene-flow error."),
    "train": ("radar4dgs.apps.train", "TrainCommand",
        "Train the Gaussian scene (static + dynamic Gaussians, VGPT field, sky) on a prepared scene."),
    "eval": ("radar4dgs.apps.eval", "EvalCommand",
        "Evaluate a trained run: metrics.json, renders, a video and an HTML report."),
    "bench": ("radar4dgs.apps.bench", "BenchCommand",
        "Train and evaluate every method (baselines and ablations) on every scene; one table."),
    "batch": ("radar4dgs.apps.batch", "BatchCommand",
        "Reconstruct many scenes at once on Ray (prepare, train, eval, report per scene); one table."),
    "actors": ("radar4dgs.apps.actors", "ActorsCommand",
        "List the moving objects (actors) of a trained run, found from its dynamic Gaussians' motion."),
    "render": ("radar4dgs.apps.render", "RenderCommand",
        "Re-render a trained run along a camera path: recorded, lane shift, height, bullet time, custom, nerfstudio."),
    "export": ("radar4dgs.apps.export", "ExportCommand",
        "Export a trained run: its Gaussians (.ply, a gsplat checkpoint, .splat) or its cameras (nerfstudio, COLMAP)."),
    "view": ("radar4dgs.apps.view", "ViewCommand",
        "Browse a trained run in a web browser (viser): Gaussian splats, a time slider, CPU renders."),
}


def _command_class(name: str) -> type:
    module, attribute = COMMANDS[name][:2]
    return getattr(importlib.import_module(module), attribute)


def class_summary(cls: type) -> str:
    """The first line of a command class's docstring."""
    doc = (cls.__doc__ or "").strip()
    return doc.splitlines()[0] if doc else ""


def _usage(names: Sequence[str] | None = None) -> str:
    lines = ["usage: radar4dgs COMMAND [OPTIONS]   (radar4dgs COMMAND --help for its options;"
             " --debug shows a traceback on errors)", "", "commands:"]
    for name, (_, _, summary) in COMMANDS.items():
        if names is None or name in names:
            lines.append(f"  {name:<18}{summary}")
    return "\n".join(lines)


def _group(word: str) -> list[str]:
    """The two-word commands that start with ``word`` ("convert" -> convert aimotive, ...)."""
    return [name for name in COMMANDS if " " in name and name.split(" ", 1)[0] == word]


def _format_warning(message, category, filename, lineno, line=None) -> str:
    """One line per warning, never the source line: the message, and the category of one that does
    not come from this package (a library's DeprecationWarning, say)."""
    ours = category is UserWarning or category.__module__.startswith("radar4dgs.")
    kind = "" if ours else f" ({category.__name__})"
    return f"radar4dgs: warning: {message}{kind}\n"


@contextlib.contextmanager
def _one_line_warnings() -> Iterator[None]:
    """Warnings shown while a command runs print as one line; the previous format comes back after
    (the library itself never touches the warnings machinery)."""
    previous = warnings.formatwarning
    warnings.formatwarning = _format_warning
    try:
        yield
    finally:
        warnings.formatwarning = previous


# What a user can cause (a missing or malformed file, an output that exists, a bad value): one
# line, no traceback. Anything else is a bug and keeps its traceback.
USER_ERRORS: tuple[type[BaseException], ...] = (ValueError, FileNotFoundError, FileExistsError, NotADirectoryError,
                                                IsADirectoryError, PermissionError)
# A full disk or a read-only output folder is the user's to fix too (radar4dgs.io.atomic names the
# folder and says which; any other writer's error names its file).
OUTPUT_ERRNOS = frozenset({errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC), errno.EROFS, errno.EACCES,
                           errno.EPERM})


def _preset_from_args(args: Sequence[str]) -> str | None:
    for i, arg in enumerate(args):
        if arg == "--preset" and i + 1 < len(args):
            return args[i + 1]
        if arg.startswith("--preset="):
            return arg.split("=", 1)[1]
    return None


def _default_instance(cls: type, preset_name: str):
    """A default instance for tyro: required fields stay required (tyro.MISSING), preset-driven
    config fields are filled from the preset."""
    values = {}
    for field in dataclasses.fields(cls):
        if field.name in getattr(cls, "PRESET_FIELDS", {}):
            values[field.name] = preset(cls.PRESET_FIELDS[field.name], preset_name)
        elif field.name == "preset":
            values[field.name] = preset_name
        elif field.default is not dataclasses.MISSING:
            values[field.name] = field.default
        elif field.default_factory is not dataclasses.MISSING:
            values[field.name] = field.default_factory()
        else:
            values[field.name] = tyro.MISSING
    return cls(**values)


_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def parse_error_line(text: str) -> str:
    """tyro's boxed parse error (a title, the problem, a rule, the option's help; drawn with UTF-8
    box characters, or with dashes where stdout is not UTF-8) as one line: the problem above the
    first rule, or the title where the box has nothing there."""
    lines = [line.strip().strip("│╰╯").strip() for line in _ANSI.sub("", text).splitlines()]
    lines = [line for line in lines if line]
    if not lines:
        return "bad options"

    def is_rule(line: str) -> bool:
        return set(line) <= set("─-")

    title, rest = lines[0].strip("╭╮─ "), lines[1:]
    if rest and is_rule(rest[0]):  # the dashes under the title of a box drawn without UTF-8
        rest = rest[1:]
    problem = []
    for line in rest:
        if is_rule(line):
            break
        problem.append(line)
    return " ".join(problem) or title


def build_command(name: str, args: Sequence[str], debug: bool = True):
    """Parse ``args`` into an instance of command ``name`` (exposed for tests). A bad option ends
    with ``SystemExit(2)``; unless ``debug``, after one line on stderr instead of tyro's box."""
    cls = _command_class(name)
    default = None
    if hasattr(cls, "PRESET_FIELDS"):
        chosen = _preset_from_args(args) or next(
            f.default for f in dataclasses.fields(cls) if f.name == "preset")
        if chosen not in PRESET_NAMES:
            raise SystemExit(f"radar4dgs {name}: --preset: unknown preset {chosen!r}; "
                             f"choose one of {list(PRESET_NAMES)}")
        default = _default_instance(cls, chosen)

    def parse():
        return tyro.cli(cls, args=list(args), prog=f"radar4dgs {name}", default=default,
                        description=(cls.__doc__ or "").strip())

    if debug:
        return parse()
    box = io.StringIO()
    try:
        with contextlib.redirect_stderr(box):
            command = parse()
        sys.stderr.write(box.getvalue())  # anything tyro said on a successful parse (a warning)
        return command
    except SystemExit as exc:
        if exc.code in (0, None):
            sys.stderr.write(box.getvalue())
            raise
        raise SystemExit(f"radar4dgs {name}: {parse_error_line(box.getvalue())} "
                         f"(radar4dgs {name} --help)") from None


def _is_user_error(exc: BaseException, cls: type | None) -> bool:
    """Whether ``exc`` is a user error: one of :data:`USER_ERRORS`, or of the classes the command
    names in ``USER_ERRORS`` (dotted names, so that naming them imports nothing)."""
    if isinstance(exc, USER_ERRORS) or (isinstance(exc, OSError) and exc.errno in OUTPUT_ERRNOS):
        return True
    names = set(getattr(cls, "USER_ERRORS", ()))
    return any(f"{c.__module__}.{c.__qualname__}" in names for c in type(exc).__mro__)


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    args = [a for a in args if a != "--debug"]
    if not args or args[0] in ("-h", "--help", "help"):
        print(_usage())
        return 0
    two_words = " ".join(args[:2])
    name, rest = (two_words, args[2:]) if two_words in COMMANDS else (args[0], args[1:])
    if name not in COMMANDS:
        group = _group(args[0])
        if group:  # "radar4dgs convert" alone, or with an unknown dataset
            asked = " ".join(args[:2]) if len(args) > 1 and not args[1].startswith("-") else None
            choices = ", ".join(n.split(" ", 1)[1] for n in group)
            head = (f"radar4dgs {args[0]}: no command {asked!r}; " if asked
                    else f"radar4dgs {args[0]}: ") + f"choose one of {choices}"
            help_asked = not asked and any(a in ("-h", "--help") for a in args[1:])
            print(f"{head}\n\n{_usage(group)}", file=sys.stdout if help_asked else sys.stderr)
            return 0 if help_asked else 2
        print(f"radar4dgs: unknown command {name!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    with _one_line_warnings():
        try:
            command = build_command(name, rest, debug)
        except SystemExit as exc:  # a bad option: one line (build_command), exit status 2
            if exc.code in (0, None) or not isinstance(exc.code, str):
                raise
            print(exc.code, file=sys.stderr)
            return 2
        try:
            result = command.run()
        except Exception as exc:
            if debug or not _is_user_error(exc, type(command)):
                raise
            print(f"radar4dgs {name}: {exc}", file=sys.stderr)
            return 1
        except KeyboardInterrupt:
            if debug:
                raise
            print(f"radar4dgs {name}: interrupted", file=sys.stderr)
            return 130
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())
