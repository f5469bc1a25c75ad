"""Where every random draw of a training run comes from: generators seeded by ``(seed, epoch)`` and
``(seed, step)`` alone, with no state carried between iterations, so that a run resumed from a
checkpoint continues exactly as the unbroken run would."""

from __future__ import annotations

import numpy as np
import torch


def step_generator(seed: int, step: int) -> torch.Generator:
    """The generator of every random draw of iteration ``step`` (stateless: resumable)."""
    return torch.Generator().manual_seed(int(seed) * 1_000_003 + int(step) + 1)


def frame_order(seed: int, epoch: int, n: int) -> np.ndarray:
    """(n,) permutation of the training frames for ``epoch``."""
    return np.random.default_rng([int(seed), int(epoch)]).permutation(n)


def neighbour_row(seed: int, step: int, row: int, n: int, share: float) -> int | None:
    """With probability ``share``, the training row next to ``row`` (of ``n``, in time order) whose life spans
    iteration ``step`` renders (the previous or the next at random; the only one at either end), else None."""
    if share <= 0 or n < 2:
        return None
    draw = np.random.default_rng([int(seed), int(step), 1]).random(2)
    if draw[0] >= share:
        return None
    return row + 1 if row == 0 or (row < n - 1 and draw[1] < 0.5) else row - 1
