"""``radar4dgs seg-train``: train the radar–camera dynamic segmentation network."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Optional

from radar4dgs.apps.options import default_is
from radar4dgs.config import PresetName
from radar4dgs.segment.config import SegTrainConfig


def parse_seeds(text: str) -> list[int]:
    """``"100-119,130"`` → [100, ..., 119, 130]."""
    seeds: list[int] = []
    for part in (p.strip() for p in text.split(",") if p.strip()):
        if "-" in part[1:]:
            a, b = part.split("-", 1) if not part.startswith("-") else (part, part)
            seeds.extend(range(int(a), int(b) + 1))
        else:
            seeds.append(int(part))
    return seeds


def synth_scenes(seeds: list[int], preset_name: str, cache: Path, progress: bool = True) -> list[Path]:
    """Synthetic scene folders ``cache/synth-<preset>-s<seed>`` (generated when missing)."""
    from radar4dgs.config import preset
    from radar4dgs.datasets.synth import SynthConfig, synthesize

    paths = []
    for seed in seeds:
        path = cache / f"synth-{preset_name}-s{seed}"
        if not (path / "scene.json").is_file():
            synthesize(preset(SynthConfig, preset_name, seed=seed), path, overwrite=False, progress=progress)
        paths.append(path)
    return paths


@dataclass
class SegTrainCommand:
    """Train the radar-camera dynamic segmentation network on scenes with gt/dynamic_mask."""

    out: Path  # run folder: config.json, last.pt, best.pt, history.json
    # training scene folders (need gt/dynamic_mask)
    scenes: Annotated[tuple[Path, ...], default_is("none")] = ()
    # also generate synthetic training scenes with these seeds, e.g. "100-119"
    synth_seeds: Annotated[str, default_is("none")] = ""
    synth_preset: PresetName = "small"  # preset of the generated synthetic scenes
    # where generated scenes are kept
    synth_cache: Annotated[Optional[Path], default_is("OUT/scenes")] = None
    # validation scenes
    val_scenes: Annotated[tuple[Path, ...], default_is("the last training scene is held out")] = ()
    # prepared folders (radar/<frame>.npz), one per --scenes entry, for dynamic_source=prepared/auto
    prepared: Annotated[tuple[Path, ...], default_is("none")] = ()
    resume: bool = False  # continue from OUT/last.pt
    preset: PresetName = "small"  # fills the training options below
    train: SegTrainConfig = field(default_factory=SegTrainConfig)  # training options

    PRESET_FIELDS = {"train": SegTrainConfig}

    def run(self) -> int:
        from radar4dgs.io.scene import SceneWarning, read_scene
        from radar4dgs.segment.dataset import load_train_frames

        scenes = list(self.scenes)
        seeds = parse_seeds(self.synth_seeds) if self.synth_seeds else []
        if seeds:
            cache = self.synth_cache or self.out / "scenes"
            scenes += synth_scenes(seeds, self.synth_preset, cache)
        val = list(self.val_scenes)
        val_seeds: list[int] = []
        if not val:
            if len(scenes) < 2:
                raise SystemExit("seg-train: give at least two scenes (one is held out for validation) or --val-scenes")
            val = [scenes.pop()]
            if seeds and not self.scenes:
                val_seeds = [seeds.pop()]
        if not scenes:
            raise SystemExit("seg-train: no training scenes (--scenes or --synth-seeds)")
        prepared = list(self.prepared) + [None] * (len(scenes) + len(val))
        train_frames, val_frames = [], []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SceneWarning)
            for k, path in enumerate(scenes):
                train_frames += load_train_frames(read_scene(path), self.train.dynamic_source, prepared[k])
                print(f"loaded {path} ({len(train_frames)} frames so far)", flush=True)
            for path in val:
                scene = read_scene(path)
                val_frames += load_train_frames(scene, self.train.dynamic_source, None,
                                                frames=list(range(0, len(scene), self.train.val_every)))
        from radar4dgs.segment.train import train_segmentation

        metadata = {"synth_seeds": seeds, "validation_seeds": val_seeds, "synth_preset": self.synth_preset,
                    "scenes": [str(p) for p in scenes], "validation_scenes": [str(p) for p in val]}
        state = train_segmentation(train_frames, val_frames, self.train, self.out, resume=self.resume,
                                   log=lambda s: print(s, flush=True), metadata=metadata)
        print(f"best validation IoU {state.best_iou:.4f}; checkpoint {self.out / 'best.pt'}")
        return 0
