"""Preset configs: presets apply, overrides win, unknown names are refused, save/load round-trips."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pytest

from radar4dgs.config import from_dict, load_config, preset, save_config, to_dict


@dataclass
class Noise:
    range_std: float = 0.05  # m
    azimuth_std_deg: float = 0.3  # degrees


@dataclass
class StageConfig:
    width: int = 100  # pixels
    noise: Noise = field(default_factory=Noise)  # radar noise
    cache: Path | None = None  # optional folder
    size: tuple[int, int] = (1, 2)  # a tuple field

    PRESETS = {"tiny": {"width": 160, "noise": {"range_std": 0.0}}, "paper": {"width": 1920}}


def test_preset_values_and_overrides():
    tiny = preset(StageConfig, "tiny")
    assert tiny.width == 160 and tiny.noise.range_std == 0.0 and tiny.noise.azimuth_std_deg == 0.3
    assert preset(StageConfig, "small") == StageConfig()  # a preset absent from PRESETS is the defaults
    assert preset(StageConfig, "paper", width=7).width == 7
    # A nested override changes its own fields only: the preset's others in that group stay.
    merged = preset(StageConfig, "tiny", noise={"azimuth_std_deg": 1.5})
    assert merged.noise == Noise(0.0, 1.5) and merged.width == 160


def test_train_preset_keeps_its_stage_boundaries_under_an_iteration_override():
    from radar4dgs.model.config import TrainConfig

    short = preset(TrainConfig, "small", optim={"iterations": 600})
    full = preset(TrainConfig, "small")
    assert short.optim.iterations == 600
    assert (short.optim.stage2_start, short.optim.stage3_start) == (full.optim.stage2_start, full.optim.stage3_start)
    assert full.optim.stage2_start != TrainConfig().optim.stage2_start
    # small moves discovered actors rigidly from 30 % of the run; the bare defaults (and tiny) keep the field
    assert (full.rigid_actors_at, full.rigid_actors_smoothness, full.rigid_actors_attach) == (0.3, 1.0, 0.0125)
    assert (short.rigid_actors_at, preset(TrainConfig, "tiny").rigid_actors_at, TrainConfig().rigid_actors_at) == \
        (0.3, 0.0, 0.0)


def test_unknown_preset_and_field_are_refused():
    with pytest.raises(ValueError, match="unknown preset 'huge'"):
        preset(StageConfig, "huge")
    with pytest.raises(ValueError, match=r"StageConfig has no field\(s\) \['widht'\]"):
        preset(StageConfig, "tiny", widht=3)


def test_save_load_round_trip(tmp_path):
    config = StageConfig(width=3, noise=Noise(0.1, 1.0), cache=Path("/x"), size=(4, 5))
    save_config(config, tmp_path / "config.json")
    assert load_config(StageConfig, tmp_path / "config.json") == config
    assert to_dict(config)["cache"] == "/x"


def test_load_refuses_another_class(tmp_path):
    save_config(Noise(), tmp_path / "noise.json")
    with pytest.raises(ValueError, match="holds a .*Noise' config, expected .*StageConfig'"):
        load_config(StageConfig, tmp_path / "noise.json")


def test_from_dict_coerces_ints_to_floats():
    assert from_dict(Noise, {"range_std": 1}).range_std == 1.0
    assert isinstance(from_dict(Noise, {"range_std": 1}).range_std, float)


def test_a_tuple_of_the_wrong_length_names_the_field():
    from radar4dgs.datasets.synth import SynthConfig

    with pytest.raises(ValueError, match=r"SynthConfig\.ego_speed: expected 2 values, got 3"):
        from_dict(SynthConfig, {"ego_speed": [1.0, 2.0, 3.0]})
