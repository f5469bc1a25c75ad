"""Torch device names as configs give them ("auto" or any torch device spec)."""

from __future__ import annotations

from typing import Any


def resolve_device(device: str | Any) -> Any:
    """A torch.device from "auto" (CUDA when torch sees a GPU, else the CPU) or any torch device
    spec ("cpu", "cuda", "cuda:1", a torch.device)."""
    import torch

    if isinstance(device, str) and device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)
