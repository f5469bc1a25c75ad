"""Training logs beyond the progress bar: ``RUN/history.json`` rewritten at every log step, and
TensorBoard event files in ``RUN/tb/`` (``tensorboard --logdir RUN/tb``).

The TensorBoard tags are gsplat's trainer's: ``train/loss`` (the total) and one per loss term
(``train/l1``, ``train/ssim``, ... as in ``history.json``), ``train/num_GS``, ``train/psnr`` (of the
training view of that step), ``train/mem`` (peak memory in GiB: CUDA's maximum allocated on a GPU,
the process's peak resident set on the CPU) and ``train/stage``; evaluation adds ``val/*`` (the
novel views' metrics), ``recon/*`` (the training frames') and a few rendered test frames.

Logging never stops training: the first failure of TensorBoard (not installed, disk full, ...)
is reported in one line and turns it off for the rest of the call; a failed ``history.json``
write is reported and retried at the next log step.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Callable, Mapping, Optional

import numpy as np
import torch

from radar4dgs.io.atomic import atomic_write_json

# The run folder's TensorBoard directory (one event file per training or evaluation call).
TB_DIR = "tb"


def peak_memory_gib(device: torch.device) -> Optional[float]:
    """Peak memory of this process so far, GiB: ``torch.cuda.max_memory_allocated`` on a CUDA
    device, else the peak resident set size (None where the platform does not say)."""
    if device.type == "cuda" and torch.cuda.is_available():
        return torch.cuda.max_memory_allocated(device) / 1024**3
    try:
        import resource
    except ImportError:  # Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    # KiB on Linux, bytes on macOS.
    return peak / 1024**3 if sys.platform == "darwin" else peak / 1024**2


class TensorBoard:
    """A ``torch.utils.tensorboard.SummaryWriter`` on ``log_dir`` that never raises.

    ``purge_step``: a resumed run's first step; TensorBoard then hides the events of an earlier
    call at or after it (logged after the checkpoint the run resumed from). ``enabled=False``
    writes nothing and creates no folder. Use as a context manager, or call ``close()``.
    """

    def __init__(self, log_dir: Path, log: Callable[[str], None] = print, purge_step: Optional[int] = None,
                 enabled: bool = True) -> None:
        self.log_dir = Path(log_dir)
        self.log = log
        self.writer = None
        if enabled:
            self._guard(lambda: self._open(purge_step))

    def _open(self, purge_step: Optional[int]) -> None:
        from torch.utils.tensorboard import SummaryWriter

        self.writer = SummaryWriter(log_dir=str(self.log_dir), purge_step=purge_step)

    def _guard(self, action: Callable[[], object]) -> None:
        try:
            action()
        except Exception as error:  # a logging failure must not end the run
            self.log(f"TensorBoard logging off ({self.log_dir}): {type(error).__name__}: {error}")
            writer, self.writer = self.writer, None
            if writer is not None:
                try:
                    writer.close()
                except Exception:
                    pass  # already off; the first error was reported

    @property
    def enabled(self) -> bool:
        return self.writer is not None

    def scalars(self, values: Mapping[str, Optional[float]], step: int) -> None:
        """``add_scalar`` for each tag whose value is not None, then a flush."""
        if self.writer is None:
            return

        def write() -> None:
            for tag, value in values.items():
                if value is not None:
                    self.writer.add_scalar(tag, float(value), int(step))
            self.writer.flush()

        self._guard(write)

    def images(self, images: Mapping[str, np.ndarray], step: int) -> None:
        """``add_image`` of ``(H, W, 3)`` uint8 images, then a flush."""
        if self.writer is None:
            return

        def write() -> None:
            for tag, image in images.items():
                self.writer.add_image(tag, np.asarray(image), int(step), dataformats="HWC")
            self.writer.flush()

        self._guard(write)

    def close(self) -> None:
        if self.writer is not None:
            self._guard(self.writer.close)
            self.writer = None

    def __enter__(self) -> "TensorBoard":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def history_payload(history: list[dict], num_static: int, num_dynamic: int,
                    seconds: Optional[float] = None) -> dict:
    """``history.json``'s content; ``train_seconds_last_call`` only when the training call ended."""
    payload: dict = {"history": history, "num_static": num_static, "num_dynamic": num_dynamic}
    if seconds is not None:
        payload["train_seconds_last_call"] = seconds
    return payload


def train_scalars(record: Mapping, loss_terms: tuple[str, ...], memory_gib: Optional[float]) -> dict:
    """The ``train/*`` TensorBoard scalars of one logged ``history.json`` record."""
    values = {"train/loss": record.get("total"), "train/psnr": record.get("psnr"),
              "train/num_GS": record.get("num_gaussians"), "train/stage": record.get("stage"),
              "train/mem": memory_gib}
    values.update({f"train/{term}": record[term] for term in loss_terms if term in record})
    return values


class TrainLog:
    """What the trainer writes at each log step: ``history.json`` (atomically) and TensorBoard."""

    def __init__(self, out: Path, device: torch.device, loss_terms: tuple[str, ...], history_file: str,
                 tensorboard: bool = True, start_step: int = 0, log: Callable[[str], None] = print) -> None:
        self.out, self.device, self.loss_terms = Path(out), device, loss_terms
        self.history_path = self.out / history_file
        self.log = log
        self.tb = TensorBoard(self.out / TB_DIR, log, purge_step=start_step or None, enabled=tensorboard)
        self._history_failed = False

    def write_history(self, payload: dict) -> None:
        try:
            atomic_write_json(self.history_path, payload)
            self._history_failed = False
        except (OSError, TypeError, ValueError) as error:
            if not self._history_failed:
                self.log(f"could not write {self.history_path} ({type(error).__name__}: {error}); "
                         "training goes on")
            self._history_failed = True

    def step(self, history: list[dict], num_static: int, num_dynamic: int) -> None:
        """A log step: ``history[-1]`` is the record just logged."""
        self.write_history(history_payload(history, num_static, num_dynamic))
        self.tb.scalars(train_scalars(history[-1], self.loss_terms, peak_memory_gib(self.device)),
                        history[-1]["step"])

    def close(self) -> None:
        self.tb.close()
