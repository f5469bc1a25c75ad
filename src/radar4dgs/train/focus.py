"""Focus steps (``TrainConfig.focus_at``): late in a run, every other iteration goes to a training frame drawn by how
badly the model fits its moving pixels, and trains only the moving part.

A mover seen in few training frames (a pedestrian the masks find only once it is near) has copies that learn only
when those frames are drawn; in the shuffled order they get a small share of the run's steps and stay faint, while
the static scene has long converged. The errors are measured once, at the switch, so the draws stay a function of
``(seed, step)`` and the measured errors: a resumed run draws as the unbroken one did.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
import torch
from torch import Tensor


def moving_pixel_error(rgb: Tensor, image: Tensor, dynamic: Tensor) -> float:
    """Mean absolute error of ``rgb`` (H, W, 3) against ``image`` (H, W, 3) over the pixels where ``dynamic``
    (H, W, bool) is set; 0 for a frame without moving pixels."""
    if not bool(dynamic.any()):
        return 0.0
    return float((rgb.detach().clamp(0, 1) - image).abs().mean(dim=-1)[dynamic].mean())


def measure_focus_errors(render_row: Callable[[int], Tensor], targets: Sequence) -> np.ndarray:
    """(n,) ``moving_pixel_error`` of each training row, ``render_row(row)`` its (H, W, 3) render."""
    with torch.no_grad():
        return np.array([moving_pixel_error(render_row(row), targets[row].image, targets[row].dynamic)
                         for row in range(len(targets))])


def focus_weights(errors: np.ndarray) -> np.ndarray:
    """(n,) probabilities of drawing each training frame on a focus step: proportional to the square of its
    moving-pixel error, so a frame fitted at twice the typical error is drawn four times as often (uniform when no
    frame has moving pixels)."""
    squared = np.square(np.asarray(errors, dtype=np.float64))
    total = squared.sum()
    if not np.isfinite(total) or total <= 0:
        return np.full(len(squared), 1.0 / len(squared))
    return squared / total


def is_focus_step(focus_at: float, iterations: int, step: int) -> bool:
    """Whether iteration ``step`` is a focus step: from ``focus_at`` of the run on (0 = never), the even ones (the
    odd ones, after which densification runs, keep the shuffled order and train everything)."""
    return focus_at > 0 and step >= round(focus_at * iterations) and step % 2 == 0


def focus_row(seed: int, step: int, weights: np.ndarray) -> int:
    """The training row focus step ``step`` trains, drawn by ``weights`` (n,) from a generator of ``(seed,
    step)`` alone (its own stream: the step's other draws are unchanged)."""
    return int(np.random.default_rng([int(seed), int(step), 1]).choice(len(weights), p=weights))


def focus_note(errors: np.ndarray, weights: np.ndarray, names: Sequence[str], shown: int = 3) -> str:
    """One log line: the frames the focus steps favour, with their moving-pixel error and share of the draws."""
    top = np.argsort(-weights)[:shown]
    frames = ", ".join(f"{names[k]} ({errors[k]:.3f}, {100 * weights[k]:.0f} %)" for k in top)
    return f"focus steps from here: every other step on the frames whose moving pixels fit worst: {frames}"
