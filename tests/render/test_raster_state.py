"""The torch backend leaves no global state behind (flush-denormal mode, thread count)."""

from __future__ import annotations

import pytest
import torch

from conftest import grads_of, make_scene
from radar4dgs.render import rasterize


def _flush_on() -> bool:
    return bool(torch.tensor([1e-40], dtype=torch.float32).item() == 0.0)


@pytest.mark.parametrize("initial", [False, True])
def test_flush_denormal_and_threads_restored(initial):
    threads = torch.get_num_threads()
    if not torch.set_flush_denormal(initial) and initial:
        pytest.skip("this CPU has no flush-to-zero mode")
    try:
        grads_of(rasterize, make_scene(3, dtype=torch.float32), backend="torch", checkpoint=True)
        grads_of(rasterize, make_scene(4, dtype=torch.float32), backend="torch")
        assert _flush_on() == initial
        assert torch.get_num_threads() == threads
    finally:
        torch.set_flush_denormal(False)
