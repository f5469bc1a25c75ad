"""The learning-rate schedule of a run."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.config import preset
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.gaussians import GaussianSet
from radar4dgs.train.optimizers import dynamic_progress, exponential_lr, make_optimizer, set_learning_rates


def test_exponential_lr_is_log_linear():
    assert exponential_lr(1e-2, 1e-4, 0.5) == pytest.approx(1e-3)


def _means_rates(config: TrainConfig, extent: float, step: int) -> dict[str, float]:
    """The means' rate of a static and a dynamic set at ``step``."""
    gaussians = GaussianSet.from_points(np.eye(3), np.full((3, 3), 0.5))
    optimizers = {name: make_optimizer(gaussians, config, extent, f"{name}.") for name in ("static", "dynamic")}
    set_learning_rates(optimizers, config, extent, step)
    return {name: next(g["lr"] for g in opt.param_groups if g["name"] == f"{name}.means")
            for name, opt in optimizers.items()}


def test_dynamic_means_decay_from_their_birth_only_when_asked():
    config = preset(TrainConfig, "small")  # 1 800 iterations, stage 2 at 450
    o, extent = config.optim, 20.0
    birth, last = 450, 1799
    on_run = _means_rates(config, extent, birth)
    # On the run's schedule both sets share the rate: a quarter of the way down, 10^-0.5 of means_lr.
    assert on_run["dynamic"] == on_run["static"] == pytest.approx(o.means_lr * extent * 0.01 ** (birth / last))
    born = preset(TrainConfig, "small", optim={"dynamic_means_from_birth": True})
    at_birth, at_end = _means_rates(born, extent, birth), _means_rates(born, extent, last)
    assert at_birth["dynamic"] == pytest.approx(o.means_lr * extent)
    assert at_end["dynamic"] == pytest.approx(o.means_lr_final * extent)
    assert at_birth["static"] == pytest.approx(on_run["static"])
    # Baselines have no stage 2: their dynamic sets keep the run's schedule.
    pvg = preset(TrainConfig, "small", method="pvg", optim={"dynamic_means_from_birth": True})
    assert _means_rates(pvg, extent, birth)["dynamic"] == pytest.approx(on_run["static"])


@settings(max_examples=50, deadline=None)
@given(st.integers(100, 5000), st.floats(0.05, 0.95), st.floats(0.0, 1.0))
def test_dynamic_progress_runs_from_zero_at_stage_two_to_one_at_the_end(iterations, stage2, where):
    config = preset(TrainConfig, "tiny", optim={"iterations": iterations, "stage2_start": stage2,
                                                "stage3_start": max(stage2, 0.96), "dynamic_means_from_birth": True})
    birth = round(stage2 * iterations)
    assert dynamic_progress(config, birth) == pytest.approx(0.0)
    assert dynamic_progress(config, iterations - 1) == pytest.approx(1.0)
    step = birth + round(where * (iterations - 1 - birth))
    assert 0.0 <= dynamic_progress(config, step) <= 1.0
