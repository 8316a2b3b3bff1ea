"""The clients of a run as the coordinator sees them, and their worker-process transport."""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol

from torch import Tensor

from frl.federation.client import ClientSpec, LocalUpdate, VehicleClient
from frl.federation.workers import MessageHook, WorkerPool

ProgressHook = Callable[[int, dict[str, Any]], None]


class ClientPool(Protocol):
    """What the roadside unit needs from its clients, whatever carries the messages."""

    names: list[str]
    """The clients in the run, in order."""
    dropped: dict[str, str]
    """Clients dropped after a failure (name -> reason); they are no longer in ``names``."""

    def train(
        self,
        num_steps: int,
        upload: bool,
        include_targets: bool,
        on_progress: ProgressHook | None = None,
    ) -> list[LocalUpdate]:
        """Every client trains ``num_steps`` steps in parallel; their updates in order."""

    def set_parameters(self, parameters: dict[str, Tensor], sync_targets: bool) -> None:
        """Send the global model to every client."""

    def save(self, directory: Path) -> None:
        """Every client writes its full resumable state under ``directory``."""

    def load(self, directory: Path) -> None:
        """Every client restores :meth:`save`."""

    def save_models(self, paths: Sequence[Path | None]) -> None:
        """Client ``i`` writes its model to ``paths[i]`` (None: nothing)."""


class ProcessClientPool:
    """One :class:`VehicleClient` per spawned worker process (one SUMO each).

    Only :class:`LocalUpdate` objects and ``None`` come back from the workers; parameter
    dicts go down. Use as a context manager, which stops every worker on the way out.
    """

    def __init__(
        self,
        specs: Sequence[ClientSpec],
        num_threads: int | None = None,
        timeout_s: float | None = None,
        on_message: MessageHook | None = None,
    ) -> None:
        self.specs = list(specs)
        self.names = [spec.name for spec in self.specs]
        self.dropped: dict[str, str] = {}  # a failed worker stops the run instead
        self.workers = WorkerPool(
            [(spec.name, functools.partial(VehicleClient, spec)) for spec in self.specs],
            num_threads=num_threads,
            timeout_s=timeout_s,
            on_message=on_message,
        )

    def __enter__(self) -> ProcessClientPool:
        self.workers.start()
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        self.workers.close(graceful=exc_type is None)

    @property
    def busy_s(self) -> float:
        return self.workers.busy_s

    def train(
        self,
        num_steps: int,
        upload: bool,
        include_targets: bool,
        on_progress: ProgressHook | None = None,
    ) -> list[LocalUpdate]:
        return self.workers.call(
            "train",
            kwargs={"num_steps": num_steps, "upload": upload, "include_targets": include_targets},
            on_progress=on_progress,
        )

    def set_parameters(self, parameters: dict[str, Tensor], sync_targets: bool) -> None:
        self.workers.call("set_parameters", args=[(parameters, sync_targets)] * len(self.names))

    def save(self, directory: Path) -> None:
        self.workers.call("save", args=[(os.fspath(directory),)] * len(self.names))

    def load(self, directory: Path) -> None:
        self.workers.call("load", args=[(os.fspath(directory),)] * len(self.names))

    def save_models(self, paths: Sequence[Path | None]) -> None:
        chosen = [i for i, path in enumerate(paths) if path is not None]
        self.workers.call(
            "save_model", args=[(os.fspath(paths[i]),) for i in chosen], workers=chosen
        )
