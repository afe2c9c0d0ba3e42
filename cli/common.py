"""Options and helpers shared by several commands."""

from __future__ import annotations

import click

threads_option = click.option(
    "--threads",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="CPU threads for torch (0: torch's default). Lower it when other work shares the machine.",
)

device_option = click.option(
    "--device",
    type=click.Choice(["auto", "cpu", "cuda"]),
    default="auto",
    show_default=True,
    help="Where torch runs: auto picks CUDA when present.",
)


def configure_torch(threads: int = 0, device: str = "auto"):
    """Apply --threads and resolve --device; returns a torch.device. Imports torch lazily."""
    import torch

    from tetweave_codec.errors import InputError

    if threads:
        torch.set_num_threads(threads)
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda was asked for but no CUDA device is available")
    return torch.device(device)
