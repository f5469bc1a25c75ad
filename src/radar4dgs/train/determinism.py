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
