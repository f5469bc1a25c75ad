"""``radar4dgs synth``: write a procedural scene folder."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import tyro

from radar4dgs.config import PresetName
from radar4dgs.datasets.synth.config import SynthConfig, traffic_profile


@dataclass
class SynthCommand:
    """Synthesise a procedural driving scene with ground truth (radar4dgs synth OUT --preset small --seed 1)."""

    out: tyro.conf.Positional[Path]  # scene folder to write
    preset: PresetName = "small"  # size preset: tiny (tests), small (CPU default), paper (1920x1080)
    seed: int = 0  # layout, speeds, colours and textures
    # moving objects: calm (a few cars, a few pixels per frame) or realistic (lead car, cut-in, oncoming and
    # crossing cars passing close, pedestrians, cyclists: tens to hundreds of pixels per frame) or rush
    # (realistic with more and faster oncoming and crossing cars); explicit --scene.traffic.* options win
    traffic: Literal["calm", "realistic", "rush"] = "calm"
    # Overwrite OUT if it exists. Without it, OUT holding this very scene (same preset, seed and config) is
    # left as it is, and anything else there is refused with what differs.
    force: bool = False
    # Also write gt/background/<frame>.png: every frame without its moving objects (same world, camera and
    # noise; parked cars stay), the ground truth of the static scene under removed actors.
    background: bool = False
    scene: SynthConfig = field(default_factory=SynthConfig)  # every generator option; defaults from --preset

    PRESET_FIELDS = {"scene": SynthConfig}

    def run(self) -> int:
        from radar4dgs.datasets.synth.generate import synthesize

        config = replace(self.scene, seed=self.seed, traffic=traffic_profile(self.traffic, self.scene.traffic))
        if self.out.exists() and not self.force:
            difference = existing_scene_difference(self.out, config, self.preset)
            if difference:
                raise FileExistsError(f"{self.out}: already exists ({difference}); pass --force to overwrite it")
            print(f"{self.out}: holds this scene already (same preset, seed and config); left as it is "
                  f"(--force makes it again)")
            self._background()
            return 0
        start = time.perf_counter()
        out = synthesize(config, self.out, overwrite=self.force, preset=self.preset)
        print(f"wrote {out}: {config.num_frames} frames {config.width}x{config.height}, preset {self.preset}, "
              f"seed {config.seed}, traffic {self.traffic}, {time.perf_counter() - start:.1f} s")
        self._background()
        return 0

    def _background(self) -> None:
        if self.background:
            from radar4dgs.datasets.synth.background import write_backgrounds

            print(f"wrote {write_backgrounds(self.out)}: every frame without its moving objects")


def existing_scene_difference(out: Path, config: SynthConfig, preset: str) -> str | None:
    """How the folder ``out`` differs from the scene ``config`` and ``preset`` make (None when it
    holds that scene): not a synthetic scene, another preset or seed, or another generator config."""
    from radar4dgs.config import config_difference, first_differences
    from radar4dgs.datasets.synth.generate import config_record

    try:
        scene = json.loads((out / "scene.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        scene = None
    source = scene.get("source") if isinstance(scene, dict) else None
    synthetic = scene.get("synthetic") if isinstance(scene, dict) else None
    if not isinstance(source, dict) or source.get("dataset") != "synthetic" or not isinstance(synthetic, dict):
        return "not a synthetic scene"
    made, asked = (source.get("preset"), source.get("seed")), (preset, config.seed)
    if made != asked:
        return f"made with preset {made[0]!r}, seed {made[1]}, not preset {asked[0]!r}, seed {asked[1]}"
    changed = config_difference(synthetic.get("config") or {}, config_record(config))
    if changed:
        return f"made with another generator config: {first_differences(changed)}"
    return None
