"""Whether a saved configuration describes the same run: runtime fields and older configs."""

from __future__ import annotations

from radar4dgs.config import preset, to_dict
from radar4dgs.model.config import TrainConfig
from radar4dgs.train.run_config import run_config_difference, same_run_config
from radar4dgs.train.variants import apply_variant, variant_config


def test_a_run_is_the_same_run_whatever_its_threads_and_older_configs_resume():
    config = variant_config("tiny", "ours", threads=1)
    saved = to_dict(config)
    assert same_run_config(saved, apply_variant(preset(TrainConfig, "tiny", threads=2, device="cuda"), "ours"))
    # A checkpoint written before the baselines existed lacks their fields: they count as defaults.
    older = {k: v for k, v in saved.items() if k not in ("baselines", "mask_source")}
    older["init"] = {k: v for k, v in saved["init"].items() if k != "source"}
    assert same_run_config(older, config)
    # ... except where a run of that time did something else than the new default: a run saved
    # before life spans and the dynamic pixel grid had neither.
    before = {k: v for k, v in saved.items() if k != "dynamic_lifespan"}
    before["init"] = {k: v for k, v in saved["init"].items() if k != "dynamic_pixel_stride"}
    assert run_config_difference(before, config) == ["dynamic_lifespan: 0.0 != 0.05",
                                                     "init.dynamic_pixel_stride: 2 != 1"]
    assert same_run_config(before, variant_config("tiny", "ours", dynamic_lifespan=0.0,
                                                  init={"dynamic_pixel_stride": 2}))
    assert not same_run_config({**saved, "mask_source": "gt"}, config)
    assert not same_run_config({**saved, "optim": {**saved["optim"], "iterations": 7}}, config)


def test_a_config_from_before_the_dynamic_layer_was_drawn_ahead_resumes_as_it_ran():
    config = variant_config("tiny", "ours")
    saved = to_dict(config)
    before = {k: v for k, v in saved.items() if k not in ("dynamic_in_front", "render_in_front")}
    assert run_config_difference(before, config) == ["dynamic_in_front: 0.0 != 0.1", "render_in_front: 0.0 != 0.2"]
    # Runs of 2026-12-03 drew at 0.1 in training and kept it for the finished model.
    trained_ahead = {k: v for k, v in saved.items() if k != "render_in_front"}
    assert run_config_difference(trained_ahead, config) == ["render_in_front: 0.1 != 0.2"]
    assert same_run_config(trained_ahead, variant_config("tiny", "ours", render_in_front=0.1))
