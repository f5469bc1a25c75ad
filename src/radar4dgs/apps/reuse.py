"""Whether a folder a command is asked to write into holds the outputs of another request.

Every command that reuses what a folder holds checks first that it was made by the same request;
when it was not, it refuses with one line saying what differs (``--force`` overwrites), so numbers
of one configuration are never reported under another's name. The scene checks read
``scene.json``; the run checks read ``RUN/config.json`` (:func:`radar4dgs.config.save_config`).
Imports of torch happen inside the functions that need them.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path
from typing import Any

from radar4dgs.config import config_difference, first_differences, read_config_dict, to_dict

# The force flag's hint, at the end of every refusal.
FORCE_HINT = "pass --force to overwrite it"


def read_json(path: Path) -> dict[str, Any] | None:
    """The JSON object in ``path``; None when it is missing, unreadable or not an object."""
    try:
        value = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return None
    return value if isinstance(value, dict) else None


def scene_fingerprint(scene_dir: Path) -> str | None:
    """sha256 of the scene's ``scene.json`` (None when it cannot be read): what prepared stages, runs and batch
    scenes record of the scene they were made from."""
    try:
        return hashlib.sha256((Path(scene_dir) / "scene.json").read_bytes()).hexdigest()
    except OSError:
        return None


def config_digest(config: Any) -> str:
    """The first 12 hex digits of the sha256 of a config (a dataclass or its dict), keys sorted:
    the same digest as :func:`radar4dgs.evaluate.reconstruction.config_hash` of a run's config."""
    values = config if isinstance(config, dict) else to_dict(config)
    return hashlib.sha256(json.dumps(values, sort_keys=True).encode("utf-8")).hexdigest()[:12]


def request_text(preset_name: Any, seed: Any) -> str:
    return f"preset '{preset_name}', seed {seed}"


def scene_conflict(scene_dir: Path, preset_name: str, seed: int, record: dict[str, Any]) -> str | None:
    """Why the synthetic scene in ``scene_dir`` is not the one asked for (None when it is, or when
    there is none): ``record`` is the generator config as scene.json records it
    (:func:`radar4dgs.datasets.synth.generate.config_record`)."""
    path = Path(scene_dir) / "scene.json"
    if not path.exists():
        return None
    scene = read_json(path)
    source = (scene or {}).get("source") or {}
    synthetic = (scene or {}).get("synthetic")  # SceneWriter.finish(extra=...) keys sit at the top level
    if scene is None or source.get("dataset") != "synthetic" or not isinstance(synthetic, dict):
        return f"{path}: not a synthetic scene made by radar4dgs"
    made = (source.get("preset"), source.get("seed"))
    if made != (preset_name, seed):
        return f"{scene_dir} was made with {request_text(*made)}, not {request_text(preset_name, seed)}"
    saved = synthetic.get("config")
    if isinstance(saved, dict) and saved != record:
        return (f"{path}: the scene was made with another generator config "
                f"({first_differences(config_difference(saved, record))})")
    return None


def run_differences(run_dir: Path, train_config: Any) -> list[str] | None:
    """Where the run in ``run_dir`` (its ``config.json``) and ``train_config`` describe different
    runs, as ``"optim.iterations: 20 != 1800"`` lines (saved first; runtime fields such as threads
    do not count); None when the folder has no ``config.json``. A ``config.json`` that is not a
    training config raises a ValueError naming it."""
    from radar4dgs.model.config import TrainConfig
    from radar4dgs.model.run import CONFIG_FILE
    from radar4dgs.train.run_config import run_config_difference

    path = Path(run_dir) / CONFIG_FILE
    if not path.is_file():
        return None
    return run_config_difference(read_config_dict(TrainConfig, path), train_config)


def run_conflict(run_dir: Path, train_config: Any) -> str | None:
    """Why the run in ``run_dir`` was not trained with ``train_config`` (None when it was, or when
    the folder holds no run)."""
    from radar4dgs.model.run import CONFIG_FILE

    lines = run_differences(run_dir, train_config)
    if not lines:
        return None
    return f"{Path(run_dir) / CONFIG_FILE}: the run was trained with another config ({first_differences(lines)})"


def holds_run(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds a run started by ``radar4dgs train`` (its ``run.json`` and
    ``config.json``): the only kind of folder :func:`remove_run` deletes."""
    from radar4dgs.model.run import CONFIG_FILE, RUN_FILE

    return (Path(run_dir) / RUN_FILE).is_file() and (Path(run_dir) / CONFIG_FILE).is_file()


def remove_run(run_dir: Path) -> None:
    """Delete the run folder ``run_dir`` and everything in it (its model, checkpoints, metrics,
    renders, report and videos: all made by the run being replaced); refuses a folder that does
    not hold a run, so that a mistyped ``--out`` never deletes anything else."""
    run_dir = Path(run_dir)
    if not run_dir.exists():
        return
    if not holds_run(run_dir):
        raise ValueError(f"{run_dir}: not a run folder (no run.json and config.json); not deleting it, "
                         f"choose another --out")
    shutil.rmtree(run_dir)
