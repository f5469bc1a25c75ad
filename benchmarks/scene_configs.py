"""What the benchmark scripts share (not a script): the synthetic scene of a seed under a traffic profile, frame rate
and image size, synthesized once into a folder they reuse and named alike, and a preset's PrepareConfig with dotted
overrides."""

from __future__ import annotations

from pathlib import Path

from radar4dgs.apps.bench_spec import parse_overrides
from radar4dgs.apps.prepare import PrepareConfig
from radar4dgs.config import from_dict, preset
from radar4dgs.datasets.synth import SynthConfig, synthesize, traffic_profile
from radar4dgs.train.variants import merge


def synth_config(preset_name: str, seed: int, traffic: str = "calm", fps: float | None = None,
                 supersample: int = 1, size: tuple[int, int] | None = None) -> SynthConfig:
    """The preset's SynthConfig for ``seed`` with traffic profile ``traffic``, frame rate ``fps`` (None: the
    preset's), ``supersample`` x ``supersample`` rays a pixel and image ``size`` (width, height; None: the
    preset's)."""
    overrides: dict = {} if traffic == "calm" else {"traffic": traffic_profile(traffic)}
    if fps is not None:
        overrides["fps"] = fps
    if size is not None:
        overrides["width"], overrides["height"] = size
    return preset(SynthConfig, preset_name, seed=seed, supersample=supersample, **overrides)


def synthesize_once(config: SynthConfig, folder: Path, preset_name: str | None = None) -> Path:
    """Synthesize ``config`` into ``folder`` unless a scene is there already (benchmarks reuse their scenes across
    runs); ``preset_name`` is recorded in scene.json's source."""
    if not (folder / "scene.json").is_file():
        synthesize(config, folder, overwrite=True, progress=False, preset=preset_name)
    return folder


def scene_label(traffic: str, seed: int, fps: float | None = None, supersample: int = 1,
                size: tuple[int, int] | None = None) -> str:
    """The folder name a benchmark gives the scene of these settings (``rush-s300-5hz-640x360``), so that
    scripts sharing a ``--work`` folder reuse each other's scenes."""
    return (f"{traffic}-s{seed}" + ("" if fps is None else f"-{fps:g}hz")
            + ("" if supersample == 1 else f"-ss{supersample}") + ("" if size is None else f"-{size[0]}x{size[1]}"))


def parse_size(text: str) -> tuple[int, int]:
    """``"640x360"`` -> (640, 360); argparse type of the scripts' ``--size``."""
    try:
        width, height = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"size {text!r} is not WIDTHxHEIGHT, e.g. 640x360") from None
    if width <= 0 or height <= 0:
        raise ValueError(f"size {text!r} must be positive")
    return width, height


def prepare_config(preset_name: str, items: list[str] = ()) -> PrepareConfig:
    """The preset's PrepareConfig with dotted ``KEY=VALUE`` overrides (``masks.completion.enabled=true``)
    merged into it field by field."""
    return from_dict(PrepareConfig, merge(PrepareConfig.PRESETS[preset_name], parse_overrides(list(items))))
