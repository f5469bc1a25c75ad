"""``RUN/actors.json``: the discovered actors of a run, written atomically, recomputed when missing or
when the run's model changed since.

Format (world frame of the scene; extra keys beyond the issue's shape)::

    {"format": "radar4dgs-actors", "version": 1,
     "model": {"size": 123, "mtime_ns": 456},     # model.pt it was computed from
     "config": {...},                              # the ActorConfig used
     "actors": [{"id": 3, "class": "car", "size": [l, w, h], "mean_speed": 12.1, "n_gaussians": 812,
                 "gaussians": [...],               # indices into the dynamic Gaussian set
                 "radar_tracks": [4, 9],           # radar track ids attached in any frame
                 "frames": [{"name": "000012", "index": 12, "time": 0.63, "timestamp": 1.2,
                             "centroid_world": [x, y, z], "velocity_world": [vx, vy, vz],
                             "heading": 0.02, "radar": [{"track": 4, "num_returns": 7, "points": [..]}]}],
                 "track": {"centroid_world": [[x, y, z], ...], "velocity_world": [...],
                           "heading": [...]}}]}    # every frame of the sequence, visible or not
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from radar4dgs.actors.config import ActorConfig
from radar4dgs.actors.discover import Actor, discover_actors
from radar4dgs.config import to_dict
from radar4dgs.io.atomic import atomic_write_json

ACTORS_FILE = "actors.json"
FORMAT = "radar4dgs-actors"


def _round(values: np.ndarray, digits: int = 4) -> list:
    return np.round(np.asarray(values, dtype=np.float64), digits).tolist()


def actor_record(actor: Actor, scene, times: np.ndarray) -> dict[str, Any]:
    """The JSON object of one actor (module docstring)."""
    frames = [{"name": scene.frames[f].name, "index": int(f), "time": round(float(times[f]), 6),
               "timestamp": float(scene.frames[f].timestamp), "centroid_world": _round(actor.centroid[f]),
               "velocity_world": _round(actor.velocity[f]), "heading": round(float(actor.heading[f]), 5),
               "radar": actor.radar.get(int(f), [])} for f in actor.frames]
    tracks = sorted({o["track"] for hits in actor.radar.values() for o in hits})
    return {"id": actor.id, "class": actor.category, "size": _round(actor.size, 3),
            "mean_speed": round(actor.mean_speed, 3), "n_gaussians": len(actor.gaussians),
            "gaussians": [int(i) for i in actor.gaussians], "radar_tracks": tracks, "frames": frames,
            "track": {"centroid_world": _round(actor.centroid), "velocity_world": _round(actor.velocity),
                      "heading": _round(actor.heading, 5)}}


def actor_from_record(record: dict[str, Any]) -> Actor:
    """The :class:`Actor` of a JSON object written by :func:`actor_record`."""
    track = record["track"]
    return Actor(id=int(record["id"]), gaussians=np.asarray(record["gaussians"], dtype=np.int64),
                 frames=np.asarray([f["index"] for f in record["frames"]], dtype=np.int64),
                 centroid=np.asarray(track["centroid_world"], dtype=np.float64).reshape(-1, 3),
                 velocity=np.asarray(track["velocity_world"], dtype=np.float64).reshape(-1, 3),
                 heading=np.asarray(track["heading"], dtype=np.float64),
                 size=tuple(float(v) for v in record["size"]), category=str(record["class"]),
                 radar={int(f["index"]): f["radar"] for f in record["frames"] if f["radar"]})


def model_stamp(run_root: Path) -> dict[str, int]:
    """Size and modification time of ``RUN/model.pt``: a changed model makes actors.json stale."""
    stat = (Path(run_root) / "model.pt").stat()
    return {"size": stat.st_size, "mtime_ns": stat.st_mtime_ns}


def write_actors(run, actors: list[Actor], config: ActorConfig, path: Path | None = None) -> Path:
    """Write ``actors`` of the loaded ``run`` to ``path`` (default RUN/actors.json), atomically."""
    from radar4dgs.io.scene import normalized_times

    times = normalized_times(run.scene)
    document = {"format": FORMAT, "version": 1, "model": model_stamp(run.root), "config": to_dict(config),
                "actors": [actor_record(a, run.scene, times) for a in actors]}
    return atomic_write_json(path or Path(run.root) / ACTORS_FILE, document)


def read_actors(path: Path) -> list[Actor]:
    """The actors of an actors.json file; ValueError naming the file when it is not one."""
    try:
        document = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read actors JSON: {exc}") from None
    if not isinstance(document, dict) or document.get("format") != FORMAT:
        raise ValueError(f"{path}: not a {FORMAT} file")
    try:
        return [actor_from_record(r) for r in document["actors"]]
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: malformed actor record ({exc!r})") from None


def is_current(run_root: Path) -> bool:
    """RUN/actors.json exists and was computed from the present model.pt with the present default
    :class:`ActorConfig` (a file from an older discovery is recomputed)."""
    path = Path(run_root) / ACTORS_FILE
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
        return document.get("model") == model_stamp(run_root) and document.get("config") == to_dict(ActorConfig())
    except (OSError, ValueError, AttributeError):
        return False


def run_actors(run, config: ActorConfig | None = None, recompute: bool = False) -> list[Actor]:
    """The actors of the loaded ``run``: read from RUN/actors.json when current, else discovered (with the
    prepared folder's radar objects when present) and written there."""
    from radar4dgs.radar.objects import optional_radar_objects

    root = Path(run.root)
    if not recompute and config is None and is_current(root):
        return read_actors(root / ACTORS_FILE)
    config = config or ActorConfig()
    # Without (current) radar objects the motion graph alone groups the Gaussians.
    radar_objects, _ = optional_radar_objects(run.prepared, len(run.scene))
    actors = discover_actors(run.model, run.scene, radar_objects, config)
    write_actors(run, actors, config)
    return actors
