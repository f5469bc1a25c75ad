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


def frame_probabilities(mask_fractions: np.ndarray, weight: float) -> np.ndarray:
    """(n,) probability of drawing each training frame, proportional to ``1 + weight * m_i / mean(m)``
    for the (n,) fractions ``m`` of each frame's pixels inside its dynamic mask; uniform when no frame
    has any."""
    fractions = np.asarray(mask_fractions, dtype=np.float64)
    mean = fractions.mean() if len(fractions) else 0.0
    raw = 1.0 + (weight * fractions / mean if mean > 0 else 0.0 * fractions)
    return raw / raw.sum()


def training_frame(seed: int, step: int, n: int, probabilities: np.ndarray | None = None) -> int:
    """The training frame (of ``n``) of iteration ``step``: drawn with ``probabilities`` (n,) when given,
    else the next of its epoch's :func:`frame_order` (stateless either way: resumable)."""
    if probabilities is not None:
        return int(np.random.default_rng([int(seed), int(step), 1]).choice(n, p=probabilities))
    return int(frame_order(seed, step // n, n)[step % n])
