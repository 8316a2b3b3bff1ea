"""Checkpoint files: atomic writes, ``weights_only`` loads and a format check."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

from frl.fileio import atomic_write

CHECKPOINT_FORMAT = "frl.agents.ddpg"
CHECKPOINT_VERSION = 1


class CheckpointError(ValueError):
    """A file is not a readable checkpoint of this format and version."""


def write_checkpoint(payload: dict[str, Any], path: str | os.PathLike[str]) -> None:
    """Save ``payload`` tagged with format and version, atomically: a crash leaves the old
    file or the new one, never a torn one (:func:`frl.fileio.atomic_write`)."""
    data = {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, **payload}
    with atomic_write(path) as f:
        torch.save(data, f)


def read_checkpoint(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Load and validate a checkpoint with ``torch.load(weights_only=True)`` on the CPU.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        CheckpointError: truncated, corrupt or foreign file, or another format version.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(path)
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises RuntimeError, UnpicklingError, EOFError, ...
        raise CheckpointError(f"{path} is not a readable checkpoint: {error}") from error
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path} is not an {CHECKPOINT_FORMAT!r} checkpoint")
    if data.get("version") != CHECKPOINT_VERSION:
        raise CheckpointError(
            f"{path} has checkpoint version {data.get('version')!r}; "
            f"this frl reads version {CHECKPOINT_VERSION}"
        )
    return data
