"""``radar4dgs synth``: write a procedural scene folder."""

from __future__ import annotations

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
    overwrite: bool = False  # replace OUT if it exists
    scene: SynthConfig = field(default_factory=SynthConfig)  # every generator option; defaults from --preset

    PRESET_FIELDS = {"scene": SynthConfig}

    def run(self) -> int:
        from radar4dgs.datasets.synth.generate import synthesize

        config = replace(self.scene, seed=self.seed, traffic=traffic_profile(self.traffic, self.scene.traffic))
        start = time.perf_counter()
        out = synthesize(config, self.out, overwrite=self.overwrite, preset=self.preset)
        print(f"wrote {out}: {config.num_frames} frames {config.width}x{config.height}, preset {self.preset}, "
              f"seed {config.seed}, traffic {self.traffic}, {time.perf_counter() - start:.1f} s")
        return 0
