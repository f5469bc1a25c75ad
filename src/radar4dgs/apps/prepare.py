"""The ``prepare`` command: the front-end stages that turn a scene folder into a prepared folder.

Stages run in order, each writing ``<prepared>/<stage>/``. A stage is skipped when its folder holds
a ``stage.json`` written for the same stage config and the same ``scene.json`` from the outputs its
predecessors hold now (their ``stage.json`` stamps, recorded as ``inputs``); ``--force`` redoes it.
Each stage folder is written in a temporary folder and renamed into place, so an interrupted run
leaves either the old outputs or none. The resolved config is saved as
``<prepared>/config.json``. ``--only`` runs some stages alone; the stages before them must then
hold this scene's outputs for this config, else the command refuses with what differs.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Callable, ClassVar, Literal, Mapping, Optional

import tyro
from tqdm import tqdm

from radar4dgs.apps.options import default_is
from radar4dgs.apps.reuse import scene_fingerprint
from radar4dgs.config import PresetName, save_config, to_dict
from radar4dgs.depth.config import DepthConfig, ObjectDepthConfig
from radar4dgs.io.atomic import atomic_directory, atomic_write_json, remove_dead_temporaries
from radar4dgs.io.locks import folder_lock
from radar4dgs.io.scene import Scene, read_scene
from radar4dgs.motion.config import FlowConfig
from radar4dgs.motion.flow import run_flow_stage
from radar4dgs.radar.config import RadarConfig
from radar4dgs.segment.config import SegInferConfig

STAGE_MARKER = "stage.json"


@dataclass
class PrepareConfig:
    """Configuration of every prepare stage (one field per stage)."""

    # Stage "radar": ego-motion RANSAC, dynamic points, compensated Doppler.
    radar: RadarConfig = field(default_factory=RadarConfig)
    # Stage "depth": monocular depth made metric by the static radar points; sky masks.
    depth: DepthConfig = field(default_factory=DepthConfig)
    # Stage "masks": radar-camera dynamic segmentation (the shipped network by default).
    masks: SegInferConfig = field(default_factory=SegInferConfig)
    # Stage "object_depth": each moving object's depth rescaled by its own radar returns.
    object_depth: ObjectDepthConfig = field(default_factory=ObjectDepthConfig)
    # Stage "flow": optical flow between training frames lifted to 3D scene flow on dynamic pixels.
    flow: FlowConfig = field(default_factory=FlowConfig)

    PRESETS: ClassVar[Mapping[str, Mapping[str, Any]]] = {
        name: {"radar": dict(RadarConfig.PRESETS.get(name, {})), "depth": dict(DepthConfig.PRESETS.get(name, {})),
               "masks": dict(SegInferConfig.PRESETS.get(name, {})),
               "object_depth": dict(ObjectDepthConfig.PRESETS.get(name, {})),
               "flow": dict(FlowConfig.PRESETS.get(name, {}))}
        for name in ("tiny", "small", "paper")}


@dataclass(frozen=True)
class Stage:
    """One prepare stage: its folder name (also its field of :class:`PrepareConfig`) and its
    runner ``run(scene, out_dir, stage_config, progress) -> summary dict``."""

    name: str
    run: Callable[..., dict]


# Each runner imports its stage when it runs: the stages pull in torch and OpenCV, which
# `radar4dgs prepare --help` should not wait for.
def _run_radar(scene: Scene, out_dir: Path, config: RadarConfig, progress: Callable) -> dict:
    from radar4dgs.radar.process import prepare_radar

    summary = prepare_radar(scene, out_dir, config, progress)
    return {"frames": summary["num_frames"], "ok": summary["num_ok"], "time_sync": summary["time_sync"]["action"]}


def _run_depth(scene: Scene, out_dir: Path, config: DepthConfig, progress: Callable) -> dict:
    from radar4dgs.depth.pipeline import write_depth

    # The radar stage has already been renamed into place beside this stage's temporary folder.
    summary = write_depth(scene, out_dir, out_dir / "sky", config, progress,
                          radar_dir=out_dir.parent / "radar")
    result = {"frames": len(summary["frames"]), "fallback_frames": len(summary.get("fallbacks", []))}
    if not scene.has_radar:
        result["no_radar"] = "the sparse depth of the scene's point cloud"
    return result


def _run_masks(scene: Scene, out_dir: Path, config: SegInferConfig, progress: Callable) -> dict:
    from radar4dgs.segment.infer import prepare_masks

    summary = prepare_masks(scene, out_dir.parent, config, out_dir=out_dir, progress=progress)
    return {"frames": len(summary["frames"]),
            "frames_with_dynamic_pixels": sum(f["dynamic_pixels"] > 0 for f in summary["frames"]),
            "completion": summary["completion"]}


def _run_object_depth(scene: Scene, out_dir: Path, config: ObjectDepthConfig, progress: Callable) -> dict:
    from radar4dgs.depth.objects import write_object_depth

    summary = write_object_depth(scene, out_dir, config, progress)
    return {"objects": summary["objects"], "rescaled": summary["rescaled"],
            "median_abs_correction": round(summary["median_abs_correction"], 4)}


def _no_radar(scene: Scene, out_dir: Path, config: Any, progress: Callable) -> dict:
    """Radar (ego-motion), object-depth and flow stages of a radar-less scene: nothing to compute (they
    work on dynamic pixels or returns only, and a radar-less scene's masks are empty); the folder says why."""
    atomic_write_json(out_dir / "summary.json", {"skipped": f"{scene.root} has no radar", "pairs": 0,
                                                 "per_pair": []})
    return {"no_radar": "nothing to do"}


def _masks_no_radar(scene: Scene, out_dir: Path, config: SegInferConfig, progress: Callable) -> dict:
    """Masks of a radar-less scene: empty (every pixel static), since the segmentation needs radar."""
    import numpy as np
    from PIL import Image

    empty = np.zeros((scene.camera.height, scene.camera.width), np.uint8)
    for frame in progress(scene.frames):
        Image.fromarray(empty).save(out_dir / f"{frame.name}.png")
    frames = [{"name": f.name, "anchors": 0, "dynamic_pixels": 0} for f in scene.frames]
    atomic_write_json(out_dir / "summary.json", {"method": "none: the scene has no radar", "frames": frames})
    return {"frames": len(frames), "frames_with_dynamic_pixels": 0, "no_radar": "empty dynamic masks"}


# A radar-less scene (docs/data/scene-format.md) runs these instead; its depth stage is the sparse
# depth of its point cloud (radar4dgs.depth.points, chosen inside the depth stage).
RADARLESS_RUNNERS: dict[str, Callable[..., dict]] = {"radar": _no_radar, "masks": _masks_no_radar,
                                                     "object_depth": _no_radar, "flow": _no_radar}

STAGES: tuple[Stage, ...] = (
    Stage("radar", _run_radar),
    Stage("depth", _run_depth),
    Stage("masks", _run_masks),
    Stage("object_depth", _run_object_depth),
    Stage("flow", run_flow_stage),
)
# The stage names, for `--only` (tests/apps/test_prepare.py keeps them equal to STAGES').
StageName = Literal["radar", "depth", "masks", "object_depth", "flow"]


def stage_stamps(prepared: Path, before: str | None = None) -> dict[str, str]:
    """sha256 of each prepared stage's ``stage.json`` (its config, its scene and its result), by stage
    name, for the stages before ``before`` (all when None); stages not prepared are left out."""
    names = [s.name for s in STAGES]
    wanted = names if before is None else names[:names.index(before)]
    return {name: hashlib.sha256((prepared / name / STAGE_MARKER).read_bytes()).hexdigest()
            for name in wanted if (prepared / name / STAGE_MARKER).is_file()}


def inputs_difference(stage_dir: Path, saved: Mapping[str, Any]) -> str | None:
    """Why the stage in ``stage_dir`` (its ``stage.json`` contents ``saved``) was not made from the outputs its
    predecessors now hold (None when it was): a predecessor was redone (``--only ... --force``, another config)
    after it. Folders from before the stamps were recorded (no ``inputs``) cannot tell and pass."""
    recorded = saved.get("inputs")
    if not isinstance(recorded, dict):
        return None
    now = stage_stamps(stage_dir.parent, stage_dir.name)
    redone = [name for name in recorded if now.get(name) != recorded[name]]
    redone += [name for name in now if name not in recorded]
    if redone:
        return f"{stage_dir}: made from {redone[0]} outputs that were redone since"
    return None


def stage_difference(stage_dir: Path, stage_config: Any, fingerprint: str) -> str | None:
    """Why the outputs in ``stage_dir`` are not those of ``stage_config`` on the scene with
    ``fingerprint`` from its predecessors' current outputs (None when they are): missing, unreadable,
    another scene, another config, or a predecessor redone since (:func:`inputs_difference`)."""
    from radar4dgs.config import config_difference, first_differences

    marker = stage_dir / STAGE_MARKER
    if not marker.is_file():
        return f"{stage_dir}: not prepared (no {STAGE_MARKER})"
    try:
        saved = json.loads(marker.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return f"{marker}: unreadable"
    if saved.get("scene") != fingerprint:
        return f"{stage_dir}: prepared for another scene.json"
    changed = config_difference(saved.get("config") or {}, to_dict(stage_config))
    if changed:
        return f"{stage_dir}: prepared with another config ({first_differences(changed)})"
    return inputs_difference(stage_dir, saved)


def stage_is_current(stage_dir: Path, stage_config: Any, fingerprint: str) -> bool:
    return stage_difference(stage_dir, stage_config, fingerprint) is None


def run_prepare(scene_path: Path, prepared: Path | None = None, config: PrepareConfig | None = None,
                force: bool = False, only: tuple[str, ...] = (), progress: bool = True,
                wait: float = 0.0) -> dict[str, str]:
    """Run the stages (all, or those named in ``only``) and return ``{stage: "ran" | "skipped"}``.
    ``wait``: seconds to wait for the prepared folder when another process holds it (0: fail at
    once, ``math.inf``: until it is free; :func:`radar4dgs.io.locks.folder_lock`)."""
    config = config or PrepareConfig()
    scene = read_scene(scene_path)
    prepared = Path(prepared) if prepared is not None else Path(scene_path) / "prepared"
    known = [s.name for s in STAGES]
    unknown = [name for name in only if name not in known]
    if unknown:
        raise ValueError(f"unknown stage(s) {unknown}; stages are {known}")
    # One process per prepared folder (another one's is refused in one line); what dead runs left
    # half-written there is removed first.
    with folder_lock(prepared, wait=wait):
        remove_dead_temporaries(prepared, recursive=True)
        return _run_stages(scene, prepared, config, force, only, progress)


def _run_stages(scene: Scene, prepared: Path, config: PrepareConfig, force: bool, only: tuple[str, ...],
                progress: bool) -> dict[str, str]:
    prepared.mkdir(parents=True, exist_ok=True)
    save_config(config, prepared / "config.json")
    # A stage's outputs are reused only for the same scene metadata.
    fingerprint = scene_fingerprint(scene.root)
    status: dict[str, str] = {}
    # Stages read their predecessors' outputs, so once one stage reruns, every later one does too.
    upstream_changed = False
    checked: set[str] = set()
    for position, stage in enumerate(STAGES):
        if only and stage.name not in only:
            continue
        # A stage run alone reads its predecessors' outputs: they must be this scene's and config's, and made
        # from what the stages before them hold now (`--only radar flow` with a new radar config leaves the
        # masks between them stale). For the first stage asked for, this is checked before anything runs; a
        # stage left out does not change during the run, so once is enough.
        for earlier in STAGES[:position] if only else ():
            if earlier.name in only or earlier.name in checked:
                continue
            checked.add(earlier.name)
            stale = stage_difference(prepared / earlier.name, getattr(config, earlier.name), fingerprint)
            if stale:
                raise ValueError(f"{stale}; the later stages read it: add {earlier.name} to --only, or run "
                                 f"without --only")
        stage_dir = prepared / stage.name
        stage_config = getattr(config, stage.name)
        if not force and not upstream_changed and stage_is_current(stage_dir, stage_config, fingerprint):
            status[stage.name] = "skipped"
            continue
        upstream_changed = True

        def bar(items, _name=stage.name):
            # Stages iterate over frames, or over frame pairs (flow); generators are per frame.
            total = len(items) if hasattr(items, "__len__") else len(scene)
            return tqdm(items, total=total, desc=_name, unit="item", disable=not progress)

        run = stage.run if scene.has_radar else RADARLESS_RUNNERS.get(stage.name, stage.run)
        # The stages after the radar's see its scans re-stamped by the clock offset it applied.
        from radar4dgs.radar.sync import prepared_synced_scene

        stage_scene = scene if stage.name == "radar" or not scene.has_radar else prepared_synced_scene(
            scene, prepared / "radar")
        with atomic_directory(stage_dir, overwrite=True) as tmp:
            result = run(stage_scene, tmp, stage_config, bar)
            # The stamps of the outputs it read: a later `--only <earlier stage> --force` makes it stale.
            atomic_write_json(tmp / STAGE_MARKER, {"stage": stage.name, "config": to_dict(stage_config),
                                                   "scene": fingerprint, "result": result,
                                                   "inputs": stage_stamps(prepared, stage.name)})
        status[stage.name] = "ran"
    return status


def _stage_note(stage_dir: Path) -> str:
    """", the scene has no radar: <what the stage did instead>" for a radar-less scene's stage, the
    radar stage's clock-offset action ("time sync: applied ...") and a stage's own ``note``."""
    try:
        result = json.loads((stage_dir / STAGE_MARKER).read_text(encoding="utf-8"))["result"]
        no_radar, sync, note = result.get("no_radar"), result.get("time_sync"), result.get("note")
    except (OSError, ValueError, KeyError, AttributeError):
        return ""
    return ((f" (the scene has no radar: {no_radar})" if no_radar else "") + (f" (time sync: {sync})" if sync else "")
            + (f" ({note})" if note else ""))


@dataclass
class PrepareCommand:
    """Run the front end on a scene: radar ego-motion, metric depth, sky and dynamic masks, movers' depth, flow."""

    # The scene folder.
    scene: tyro.conf.Positional[Path]
    # The prepared folder.
    out: Annotated[Optional[Path], default_is("SCENE/prepared")] = None
    # Preset the stage configs start from.
    preset: PresetName = "small"
    # Stage configs (filled from --preset, then overridden by the options below).
    config: PrepareConfig = field(default_factory=PrepareConfig)
    # Redo stages even when their outputs exist for the same config (a stage made with another config or
    # for another scene is always redone, and so are the stages after it).
    force: bool = False
    # Run only these stages (in pipeline order, whatever the order given).
    only: Annotated[tuple[StageName, ...], default_is("every stage")] = ()
    # Hide the progress bars.
    quiet: bool = False

    PRESET_FIELDS: ClassVar[dict[str, type]] = {"config": PrepareConfig}

    # A depth model that cannot load is a one-line error too (radar4dgs.cli).
    USER_ERRORS: ClassVar[tuple[str, ...]] = ("radar4dgs.depth.sources.DepthModelError",
                                               "radar4dgs.io.locks.FolderInUseError")

    def run(self) -> int:
        # A missing or malformed scene or a bad option raises a user error: one line (radar4dgs.cli).
        status = run_prepare(self.scene, self.out, self.config, self.force, tuple(self.only),
                             progress=not self.quiet)
        prepared = self.out if self.out is not None else self.scene / "prepared"
        for name, what in status.items():
            print(f"{name}: {what}{_stage_note(prepared / name)} -> {prepared / name}")
        return 0
