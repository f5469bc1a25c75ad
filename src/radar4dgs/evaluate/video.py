"""H.264 mp4 videos of rendered frames, written whole or not at all."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Iterable

import numpy as np

from radar4dgs.io.atomic import atomic_path


def _check_frame(frame: np.ndarray, index: int, shape: tuple[int, ...] | None) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
        raise ValueError(f"write_video: frame {index} is {frame.dtype} {frame.shape}, "
                         f"expected uint8 (H, W, 3)")
    if shape is not None and frame.shape != shape:
        raise ValueError(f"write_video: frame {index} is {frame.shape[1]}x{frame.shape[0]}, "
                         f"the first frame {shape[1]}x{shape[0]}; all frames must have one size")  # fmt: skip
    return frame


def _pad_to_even(frame: np.ndarray) -> np.ndarray:
    # H.264 in yuv420p (the pixel format every player decodes) halves the chroma resolution, so
    # both sides must be even: one row/column of black is added rather than resampling the image.
    h, w = frame.shape[:2]
    if h % 2 == 0 and w % 2 == 0:
        return frame
    return np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)))


def write_video(frames: Iterable[np.ndarray], path: str | os.PathLike, fps: float = 10) -> Path:
    """Write RGB uint8 ``(H, W, 3)`` frames to an H.264 (yuv420p) mp4 at ``path``; returns the path.

    Frames of odd width or height get one black column/row at the right/bottom (the video is
    ``(H + H % 2, W + W % 2)``). ``frames`` may be a generator: frames are encoded one at a time.
    The file is written under a temporary name in the same folder and renamed when complete: on
    any error (bad frame, encoder failure, interrupt) nothing is left at ``path`` (an existing
    file stays as it was) and no temporary file remains. Raises ``ValueError`` for zero frames or
    frames of different sizes.
    """
    import imageio.v2 as imageio

    path = Path(path)
    if fps <= 0:
        raise ValueError(f"write_video: fps must be positive, got {fps}")
    iterator = iter(frames)
    try:
        first = next(iterator)
    except StopIteration:
        raise ValueError(f"write_video: no frames for {path}") from None
    first = _check_frame(first, 0, None)

    # The ".mp4" suffix is for ffmpeg, which picks the container from the name.
    with atomic_path(path, suffix=".tmp.mp4") as tmp:
        # macro_block_size=1: imageio would otherwise resize to multiples of 16; the even sizes
        # that H.264 needs are made by _pad_to_even.
        writer = imageio.get_writer(
            tmp, format="FFMPEG", mode="I", fps=fps, codec="libx264", pixelformat="yuv420p",
            macro_block_size=1, ffmpeg_log_level="error",
        )  # fmt: skip
        try:
            writer.append_data(_pad_to_even(first))
            for index, frame in enumerate(iterator, start=1):
                writer.append_data(_pad_to_even(_check_frame(frame, index, first.shape)))
        except BaseException:
            # The first error is the one to report, not the encoder's complaint at closing.
            with contextlib.suppress(Exception):
                writer.close()
            raise
        writer.close()
    return path
