"""The torch device a training command runs on."""

from __future__ import annotations

__all__ = ["train_device"]


def train_device(args) -> str:
    """``--device`` of a training command: as given, else cuda when torch sees a GPU."""
    if args.device is not None:
        return args.device
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"
