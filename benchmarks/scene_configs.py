"""Configs the benchmark scripts share (not a script): the synthetic scene of a seed under a traffic
profile and frame rate, and a preset's PrepareConfig with dotted overrides."""

from __future__ import annotations

from radar4dgs.apps.bench_spec import parse_overrides
from radar4dgs.apps.prepare import PrepareConfig
from radar4dgs.config import from_dict, preset
from radar4dgs.datasets.synth import SynthConfig, traffic_profile
from radar4dgs.train.variants import merge


def synth_config(preset_name: str, seed: int, traffic: str = "calm", fps: float | None = None,
                 supersample: int = 1) -> SynthConfig:
    """The preset's SynthConfig for ``seed`` with traffic profile ``traffic``, frame rate ``fps`` (None: the
    preset's) and ``supersample`` x ``supersample`` rays a pixel."""
    overrides: dict = {} if traffic == "calm" else {"traffic": traffic_profile(traffic)}
    if fps is not None:
        overrides["fps"] = fps
    return preset(SynthConfig, preset_name, seed=seed, supersample=supersample, **overrides)


def prepare_config(preset_name: str, items: list[str] = ()) -> PrepareConfig:
    """The preset's PrepareConfig with dotted ``KEY=VALUE`` overrides (``masks.completion.enabled=true``)
    merged into it field by field."""
    return from_dict(PrepareConfig, merge(PrepareConfig.PRESETS[preset_name], parse_overrides(list(items))))
