"""The learning-rate schedule of a run and the selective Adam step."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.train.optimizers import adam, exponential_lr, gaussian_visibility, selective_step


def test_exponential_lr_is_log_linear():
    assert exponential_lr(1e-2, 1e-4, 0.5) == pytest.approx(1e-3)


def reference_selective_adam(start: np.ndarray, grads: list[np.ndarray], masks: list[np.ndarray], lr: float,
                             betas=(0.9, 0.999), eps=1e-15) -> np.ndarray:
    """Adam written out per row: a hidden row keeps its value and moments; the bias correction
    counts every step (gsplat's SelectiveAdam does the same)."""
    p, m, v = start.astype(np.float64).copy(), np.zeros_like(start, np.float64), np.zeros_like(start, np.float64)
    for t, (g, mask) in enumerate(zip(grads, masks, strict=True), start=1):
        m[mask] = betas[0] * m[mask] + (1 - betas[0]) * g[mask]
        v[mask] = betas[1] * v[mask] + (1 - betas[1]) * g[mask] ** 2
        m_hat, v_hat = m[mask] / (1 - betas[0] ** t), v[mask] / (1 - betas[1] ** t)
        p[mask] -= lr * m_hat / (np.sqrt(v_hat) + eps)
    return p


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 6))
def test_selective_step_is_adam_on_the_drawn_rows_only(seed, steps):
    rng = np.random.default_rng(seed)
    start = rng.normal(size=(7, 3))
    grads = [rng.normal(size=(7, 3)) for _ in range(steps)]
    masks = [rng.random(7) < 0.5 for _ in range(steps)]
    param = torch.nn.Parameter(torch.tensor(start))
    optimizer = adam([{"params": [param], "lr": 0.05, "name": "colors"}], eps=1e-15)
    for grad, mask in zip(grads, masks, strict=True):
        param.grad = torch.tensor(grad)
        selective_step(optimizer, torch.as_tensor(mask))
    np.testing.assert_allclose(param.detach().numpy(), reference_selective_adam(start, grads, masks, 0.05),
                               rtol=1e-9, atol=1e-12)


def test_plain_adam_moves_a_row_after_its_last_gradient():
    """The drift selective_step prevents: a zero gradient still moves a row with momentum."""
    param = torch.nn.Parameter(torch.zeros(2, 1, dtype=torch.float64))
    optimizer = adam([param], lr=0.1)
    param.grad = torch.tensor([[1.0], [1.0]], dtype=torch.float64)
    optimizer.step()
    param.grad = torch.tensor([[1.0], [0.0]], dtype=torch.float64)
    before = param.detach().clone()
    optimizer.step()
    assert float(param[1, 0] - before[1, 0]) < -0.05
    selective = torch.nn.Parameter(torch.zeros(2, 1, dtype=torch.float64))
    optimizer = adam([selective], lr=0.1)
    selective.grad = torch.tensor([[1.0], [1.0]], dtype=torch.float64)
    selective_step(optimizer, torch.tensor([True, True]))
    selective.grad = torch.tensor([[1.0], [0.0]], dtype=torch.float64)
    before = selective.detach().clone()
    selective_step(optimizer, torch.tensor([True, False]))
    assert float(selective[1, 0]) == float(before[1, 0])
    torch.testing.assert_close(optimizer.state[selective]["exp_avg"][1], torch.tensor([0.1], dtype=torch.float64))


def test_selective_step_refuses_a_mask_of_another_length():
    param = torch.nn.Parameter(torch.zeros(4, 3))
    optimizer = adam([{"params": [param], "lr": 0.1, "name": "dynamic.colors"}])
    param.grad = torch.ones(4, 3)
    with pytest.raises(ValueError, match="dynamic.colors has 4 rows, the visibility mask 3"):
        selective_step(optimizer, torch.tensor([True, False, True]))


def test_visibility_splits_the_render_order_and_drops_dropped_gaussians():
    radii = torch.tensor([[[2, 2], [0, 0], [3, 1], [1, 0], [4, 4]]])
    render = {"meta": {"radii": radii}, "n_static": 3, "n_dynamic": 2}
    visibility = gaussian_visibility(render, torch.tensor([True, True, False, True, True]))
    assert visibility["static"].tolist() == [True, False, False]
    assert visibility["dynamic"].tolist() == [False, True]
    assert "dynamic" not in gaussian_visibility({**render, "meta": {"radii": radii[:, :3]}, "n_dynamic": 0}, None)
