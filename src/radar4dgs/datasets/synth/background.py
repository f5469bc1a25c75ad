"""The scene without its moving objects: the same world, camera path, lighting and image noise, with
every mover that moves in any frame left out (parked cars stay). Ground truth for the static layer
under removed actors (issue 24): ``write_backgrounds(SCENE)`` writes ``SCENE/gt/background/<name>.png``.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from radar4dgs.datasets.synth import camera as C
from radar4dgs.datasets.synth import world as W
from radar4dgs.datasets.synth.config import SynthConfig
from radar4dgs.datasets.synth.street import build_world

BACKGROUND_DIR = "gt/background"


def background_world(world: W.World, times: np.ndarray) -> W.World:
    """``world`` with every mover that moves at any of ``times`` (s) emptied of its boxes (indices are
    kept: a mover's index is its position, which the shading tables rely on)."""
    movers = tuple(replace(m, local_center=np.zeros((0, 3)), local_half=np.zeros((0, 3)),
                           local_material=np.zeros(0, dtype=np.int64), local_color=np.zeros((0, 3)))
                   if any(m.moving_at(float(t)) for t in times) else m for m in world.movers)
    return replace(world, movers=movers)


def scene_config(scene_dir: str | Path) -> SynthConfig:
    """The generator config a synthetic scene folder was made with (``scene.json`` synthetic.config).
    Raises ValueError for a scene the generator did not write."""
    import json

    from radar4dgs.config import from_dict

    path = Path(scene_dir) / "scene.json"
    meta = json.loads(path.read_text(encoding="utf-8"))
    record = (meta.get("synthetic") or {}).get("config")
    if not isinstance(record, dict):
        raise ValueError(f"{path}: not a synthetic scene (no synthetic.config); only `radar4dgs synth` "
                         "scenes have a background render")
    return from_dict(SynthConfig, record, partial=True)


def background_frame(config: SynthConfig, index: int) -> C.CameraFrame:
    """Frame ``index`` of the scene ``config`` makes, without its moving objects: image (H, W, 3) uint8
    and z-depth (H, W) (+inf for sky), with the frame's own camera-noise stream, so pixels that no mover
    covers equal the recorded image."""
    from radar4dgs.datasets.synth.generate import _CAMERA

    dt = 1.0 / config.fps
    times = np.arange(config.num_frames) * dt
    world = background_world(build_world(config), times)
    K = C.intrinsics(config)
    return C.render(world, config, K, C.cam_to_ego(config), C.pixel_rays(K, config.width, config.height),
                    float(times[index]), dt, np.random.default_rng([config.seed, _CAMERA, index]))


def render_background(config: SynthConfig, index: int) -> np.ndarray:
    """(H, W, 3) uint8 image of :func:`background_frame`."""
    return background_frame(config, index).image


def write_backgrounds(scene_dir: str | Path, indices=None) -> Path:
    """Write ``SCENE/gt/background/<frame name>.png`` for ``indices`` (all frames when None); returns
    the folder. Each image is written atomically; existing ones are rewritten (they are deterministic)."""
    from radar4dgs.io.preview import save_png

    scene_dir = Path(scene_dir)
    config = scene_config(scene_dir)
    folder = scene_dir / BACKGROUND_DIR
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(config.num_frames) if indices is None else indices:
        save_png(folder / f"{int(i):06d}.png", render_background(config, int(i)))
    return folder
