"""What a run ran with: package versions, the platform and the git state of the checkout."""

from __future__ import annotations

import contextlib
import importlib.metadata
import os
import platform
import subprocess
from pathlib import Path
from typing import Any

import numpy as np

import frl

RUN_AFFECTING_PATHS = ("frl", "pyproject.toml", "constraints.txt")
"""What decides a run's behaviour, relative to the checkout's root (the Hydra configs
live in ``frl/conf``); see :func:`git_state`."""


def git_state(package_dir: Path) -> tuple[str | None, bool | None]:
    """The commit of the checkout that holds ``package_dir``, and whether its code differs.

    Dirty means frl/ (its configs included) or the install files differ from the commit,
    untracked files there included (a new module changes a run as much as an edit).
    Exported results and reports written into docs/ during a sweep do not count.
    ``(None, None)`` when the package is not the ``frl/`` of a git checkout (an installed
    wheel, or a venv that merely sits inside some other repository).
    """

    def git(*args: str) -> str | None:
        with contextlib.suppress(OSError, subprocess.SubprocessError):
            return subprocess.run(
                ["git", *args],
                cwd=package_dir,
                capture_output=True,
                text=True,
                timeout=5,
                check=True,
            ).stdout.strip()
        return None

    root = git("rev-parse", "--show-toplevel")
    if root is None or Path(root).resolve() / "frl" != package_dir.resolve():
        return None, None
    commit = git("rev-parse", "HEAD")
    changes = git("-C", root, "status", "--porcelain", "--", *RUN_AFFECTING_PATHS)
    return commit, None if commit is None or changes is None else bool(changes)


def versions() -> dict[str, Any]:
    """Package, SUMO, torch and Python versions, and the git state (see :func:`git_state`)."""
    import torch

    def dist(name: str) -> str | None:
        try:
            return importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            return None

    commit, dirty = git_state(Path(frl.__file__).parent)
    return {
        "frl": frl.__version__,
        "git_commit": commit,
        "git_dirty": dirty,
        "torch": torch.__version__,
        "numpy": np.__version__,
        "sumo": dist("eclipse-sumo"),
        "libsumo": dist("libsumo"),
        "gymnasium": dist("gymnasium"),
        "hydra": dist("hydra-core"),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
    }
