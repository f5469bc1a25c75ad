"""Whether two training configurations describe the same run: what resuming a run folder, and the
bench reusing one, check. Runtime fields (threads, device) do not count, and a config saved
before a field existed counts as what a run of its time did."""

from __future__ import annotations

from radar4dgs.config import config_difference, from_dict, to_dict
from radar4dgs.model.config import GaussianInitConfig, TrainConfig

# Where a run computes, not what it computes: a run may resume with other values.
RUNTIME_FIELDS = ("threads", "device", "frame_cache")


def with_legacy_values(saved: dict) -> dict:
    """A saved TrainConfig dict with the fields it predates set to what a run of its time did,
    where that is not the field's default: no life span (``dynamic_lifespan`` 0), dynamic
    pixels on the background's grid (``init.dynamic_pixel_stride`` = ``init.pixel_stride``), no
    pose or appearance refinement (``poses.refine`` / ``poses.appearance`` "off"), static
    Gaussians trained on every pixel in stage 3 (``static_outside_masks`` False), the dynamic layer in
    depth order (``dynamic_in_front`` 0) and rendered after training as in it (``render_in_front``)."""
    out = dict(saved)
    out.setdefault("dynamic_lifespan", 0.0)
    # Runs from before the static layer was kept off the dynamic masks in stage 3 (issue 24).
    out.setdefault("static_outside_masks", False)
    # Runs from before pose refinement and exposure compensation (issue 27) had neither.
    out.setdefault("poses", {"refine": "off", "appearance": "off"})
    # Runs from before the dynamic layer was drawn ahead drew it in depth order, and until render_in_front
    # existed the finished model kept the training value.
    out.setdefault("dynamic_in_front", 0.0)
    out.setdefault("render_in_front", out["dynamic_in_front"])
    init = out.get("init")
    if isinstance(init, dict) and "dynamic_pixel_stride" not in init:
        out["init"] = {**init, "dynamic_pixel_stride": init.get("pixel_stride", GaussianInitConfig.pixel_stride)}
    return out


def run_config_difference(saved: TrainConfig | dict, config: TrainConfig) -> list[str]:
    """Where ``saved`` (a config, or its dict as saved) and ``config`` describe different runs, as
    :func:`radar4dgs.config.config_difference` lines, ignoring :data:`RUNTIME_FIELDS`. A field that
    a saved dict lacks (a run from before the field existed) counts as what such a run did
    (:func:`with_legacy_values`), else as its default."""
    if isinstance(saved, dict):
        saved = from_dict(TrainConfig, with_legacy_values(saved), partial=False)
    return config_difference(to_dict(saved), to_dict(config), ignore=RUNTIME_FIELDS)


def same_run_config(saved: TrainConfig | dict, config: TrainConfig) -> bool:
    """True when ``saved`` and ``config`` describe the same run (:func:`run_config_difference`)."""
    return not run_config_difference(saved, config)
