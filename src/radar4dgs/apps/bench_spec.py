"""The bench grid's specification: its scenes (checked, labelled, or synthesized and prepared),
its methods, the ``--set`` TrainConfig overrides, and the :class:`CellSpec` of each cell."""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from radar4dgs.config import preset
from radar4dgs.train.variants import METHOD_NAMES, VARIANTS

SCENES_DIR = "scenes"


class BenchError(ValueError):
    """A bench that cannot start (bad scene, method or option); the message says what to fix."""


@dataclass(frozen=True)
class BenchScene:
    """One scene of the grid: its label (the runs/ subfolder and table name) and its folders."""

    label: str
    scene: Path
    prepared: Path


@dataclass(frozen=True)
class CellSpec:
    """Everything a cell's worker needs; plain values, since it is pickled to a worker process."""

    scene: str  # the scene's label
    method: str
    scene_path: Path
    prepared: Path
    run_dir: Path
    preset: str
    # TrainConfig overrides on top of the method's variant (nested dicts).
    overrides: Mapping[str, Any]
    lpips: bool
    progress: bool
    # Retrain a cell whose run folder was trained with another configuration (else it fails).
    force: bool = False


# --- scenes and methods ------------------------------------------------------------------------


def check_methods(methods: Sequence[str]) -> tuple[str, ...]:
    """``methods`` without repeats, in the given order; unknown names raise a BenchError listing the
    valid ones."""
    unknown = [m for m in methods if m not in VARIANTS]
    if unknown:
        raise BenchError(f"unknown method(s) {unknown}; methods are {list(METHOD_NAMES)}")
    if not methods:
        raise BenchError(f"no methods given; methods are {list(METHOD_NAMES)}")
    return tuple(dict.fromkeys(methods))


def check_scene(scene: Path) -> Path:
    """The prepared folder of scene folder ``scene``: ``<scene>/prepared`` (`radar4dgs prepare`'s
    default), else a ``prepared`` folder beside it (the demo's layout, ``DIR/{scene,prepared}``);
    a BenchError names what is missing."""
    if not (scene / "scene.json").is_file():
        raise BenchError(f"{scene}: not a scene folder (no scene.json)")
    for prepared in (scene / "prepared", scene.parent / "prepared"):
        if (prepared / "depth").is_dir():
            return prepared
    raise BenchError(f"{scene}: has no prepared folder ({scene / 'prepared'} or {scene.parent / 'prepared'}); "
                     f"run `radar4dgs prepare {scene}` first")


def parse_overrides(items: Sequence[str]) -> dict[str, Any]:
    """``["densify.max_gaussians=40000", "optim.dropout=0.2"]`` as the nested dict of TrainConfig
    fields they set; values are JSON (numbers, true/false, quoted strings) or else plain strings."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise BenchError(f"--set {item!r}: expected KEY=VALUE with a dotted TrainConfig field, "
                             f"e.g. densify.max_gaussians=40000")
        try:
            value = json.loads(text)
        except ValueError:
            value = text
        node = out
        *parents, leaf = key.strip().split(".")
        for part in parents:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise BenchError(f"--set {item!r}: {part} is set as a value and as a group")
        node[leaf] = value
    return out


def dotted(values: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """A nested dict as ``[("densify.max_gaussians", 40000), ...]`` (the inverse of
    :func:`parse_overrides`)."""
    out: list[tuple[str, Any]] = []
    for key, value in values.items():
        if isinstance(value, Mapping):
            out += dotted(value, f"{prefix}{key}.")
        else:
            out.append((f"{prefix}{key}", value))
    return out


def scene_labels(paths: Sequence[Path], reserved: Sequence[str] = ()) -> list[str]:
    """A distinct label per scene folder: its name, or where names clash (with each other or with
    ``reserved``) its name preceded by parent folders until they do not ("seed1-scene").

    The same folder given twice raises a BenchError: its cells would share one run folder.
    """
    resolved = [Path(p).resolve() for p in paths]
    repeated = [str(p) for p, count in Counter(resolved).items() if count > 1]
    if repeated:
        raise BenchError(f"scene(s) given more than once: {repeated}")
    # parts[0] is the root ("/"); a label never includes it.
    parts = [p.parts[1:] for p in resolved]
    depth = [1] * len(paths)
    while True:
        labels = ["-".join(part[-d:]) for part, d in zip(parts, depth, strict=True)]
        counts = Counter(labels + list(reserved))
        clashing = [i for i, label in enumerate(labels) if counts[label] > 1]
        if not clashing:
            return labels
        deeper = [i for i in clashing if depth[i] < len(parts[i])]
        if not deeper:  # whole paths that still clash ("a-b/c" and "a/b-c"): number them
            return [f"{label}-{i}" if i in clashing else label for i, label in enumerate(labels)]
        for i in deeper:
            depth[i] += 1


def synth_scene(seed: int, preset_name: str, root: Path, log: Callable[[str], None], force: bool = False,
                runs: Path | None = None) -> BenchScene:
    """Synthesize and prepare seed ``seed`` into ``root/seed<N>/{scene,prepared}``; a scene that
    exists is reused and only its stale prepare stages rerun. A scene made with another preset or
    generator config raises a BenchError saying what differs; with ``force`` it is made again and
    the cells trained on it (``runs``, the scene's folder of run folders) are deleted."""
    import shutil

    from radar4dgs.apps.prepare import PrepareConfig, run_prepare
    from radar4dgs.apps.reuse import scene_conflict
    from radar4dgs.datasets.synth import SynthConfig, synthesize
    from radar4dgs.datasets.synth.generate import config_record

    scene = root / f"seed{seed}" / "scene"
    prepared = root / f"seed{seed}" / "prepared"
    config = preset(SynthConfig, preset_name, seed=seed)
    conflict = scene_conflict(scene, preset_name, seed, config_record(config))
    if conflict and not force:
        raise BenchError(f"{conflict}; pass --force to make it again (and retrain its cells), "
                         f"or bench into another --out")
    if conflict or not (scene / "scene.json").is_file():
        if conflict and runs is not None and runs.is_dir():
            log(f"--force: deleting the cells trained on the earlier seed {seed} scene ({runs})")
            shutil.rmtree(runs)
        log(f"synthesizing seed {seed} ({preset_name}) -> {scene}")
        synthesize(config, scene, overwrite=True, progress=False, preset=preset_name)
    status = run_prepare(scene, prepared, preset(PrepareConfig, preset_name), progress=False)
    ran = [stage for stage, state in status.items() if state == "ran"]
    if ran:
        log(f"prepared seed {seed}: {', '.join(ran)}")
    return BenchScene(f"seed{seed}", scene, prepared)


def resolve_scenes(scene_dirs: Sequence[Path], synth_seeds: Sequence[int], synth_preset: str, out: Path,
                   log: Callable[[str], None] = print, force: bool = False) -> list[BenchScene]:
    """The grid's scenes: ``scene_dirs`` (checked first, so that a typo fails before any
    synthesis) then the synthetic seeds, made and prepared under ``out/scenes`` (``force``: see
    :func:`synth_scene`)."""
    if not scene_dirs and not synth_seeds:
        raise BenchError("no scenes: give --scenes DIR ... or --synth-seeds N ...")
    if len(set(synth_seeds)) != len(synth_seeds):
        raise BenchError(f"synthetic seed(s) given more than once: {sorted(synth_seeds)}")
    prepared = [check_scene(Path(s)) for s in scene_dirs]
    synth_labels = [f"seed{seed}" for seed in synth_seeds]
    labels = scene_labels(scene_dirs, reserved=synth_labels)
    scenes = [BenchScene(label, Path(s), p) for label, s, p in zip(labels, scene_dirs, prepared, strict=True)]
    scenes += [synth_scene(seed, synth_preset, out / SCENES_DIR, log, force, out / "runs" / f"seed{seed}")
               for seed in synth_seeds]
    return scenes
