"""The clients of a run as the coordinator sees them, and the worker-process backend."""

from __future__ import annotations

import functools
import os
import shutil
import tempfile
import uuid
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol

from torch import Tensor

from frl.federation.client import ClientSpec, LocalUpdate
from frl.federation.codec import (
    arrays_to_tensors,
    spec_to_json,
    tensors_to_arrays,
    update_from_parts,
)
from frl.federation.workers import MessageHook, WorkerPool
from frl.frames import Arrays, decode_frame, encode_frame, prefixed, unprefixed
from frl.run_directory import relative_path
from frl.vehicle_host import PARAMETERS_PREFIX, SERIES_PREFIX, VehicleHost

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
    """One vehicle per spawned worker process (one SUMO each), spoken to in frames.

    Each worker hosts a :class:`VehicleHost` and answers the same request frames as a
    Flower vehicle process (:mod:`frl.vehicle_host`): JSON headers and numpy
    arrays, no pickled objects. Use as a context manager, which builds every vehicle on
    the way in and stops every worker on the way out.

    Args:
        specs: the clients, in order.
        num_threads: torch threads per worker; default: the cores split evenly.
        timeout_s: longest one call may take in any worker (None: forever).
        on_message: sees every message a worker sends (tests audit the frames).
        state_dir: the directory every checkpoint and model path lies in (the run
            directory); default: a private temporary directory.
    """

    def __init__(
        self,
        specs: Sequence[ClientSpec],
        num_threads: int | None = None,
        timeout_s: float | None = None,
        on_message: MessageHook | None = None,
        state_dir: str | os.PathLike[str] | None = None,
    ) -> None:
        self.specs = list(specs)
        self.names = [spec.name for spec in self.specs]
        self.dropped: dict[str, str] = {}  # a failed worker stops the run instead
        self._own_dir = state_dir is None
        self.state_dir = Path(
            tempfile.mkdtemp(prefix="frl-pool-") if state_dir is None else state_dir
        )
        self.run_key = f"{self.state_dir.resolve()}#{uuid.uuid4().hex[:8]}"
        host = functools.partial(VehicleHost, os.fspath(self.state_dir))
        self.workers = WorkerPool(
            [(spec.name, host) for spec in self.specs],
            num_threads=num_threads,
            timeout_s=timeout_s,
            on_message=on_message,
        )

    def __enter__(self) -> ProcessClientPool:
        self.workers.start()
        try:
            self._exchange([{"op": "setup", "spec": spec_to_json(spec)} for spec in self.specs])
        except BaseException:
            self.close(graceful=False)
            raise
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        self.close(graceful=exc_type is None)

    def close(self, graceful: bool = True) -> None:
        self.workers.close(graceful=graceful)
        if self._own_dir:
            shutil.rmtree(self.state_dir, ignore_errors=True)

    @property
    def busy_s(self) -> float:
        return self.workers.busy_s

    def _exchange(
        self,
        headers: Sequence[dict[str, Any]],
        arrays: Arrays | None = None,
        workers: Sequence[int] | None = None,
        on_progress: ProgressHook | None = None,
    ) -> list[tuple[dict[str, Any], Arrays]]:
        """One request frame per selected worker (the same ``arrays`` to each); the replies."""
        frames = [encode_frame({**header, "run_key": self.run_key}, arrays) for header in headers]
        replies = self.workers.call(
            "serve", args=[(frame,) for frame in frames], workers=workers, on_progress=on_progress
        )
        return [decode_frame(reply) for reply in replies]

    def train(
        self,
        num_steps: int,
        upload: bool,
        include_targets: bool,
        on_progress: ProgressHook | None = None,
    ) -> list[LocalUpdate]:
        header = {
            "op": "train",
            "num_steps": num_steps,
            "upload": upload,
            "include_targets": include_targets,
        }
        replies = self._exchange([header] * len(self.names), on_progress=on_progress)
        return [
            update_from_parts(
                unprefixed(out, PARAMETERS_PREFIX) if reply["upload"] else None,
                unprefixed(out, SERIES_PREFIX),
                reply["summary"],
            )
            for reply, out in replies
        ]

    def set_parameters(self, parameters: dict[str, Tensor], sync_targets: bool) -> None:
        header = {"op": "sync", "parameters": True, "sync_targets": sync_targets}
        arrays = prefixed(tensors_to_arrays(parameters), PARAMETERS_PREFIX)
        self._exchange([header] * len(self.names), arrays)

    def get_parameters(self) -> list[dict[str, Tensor]]:
        """Every client's full model (online and target networks)."""
        replies = self._exchange([{"op": "model"}] * len(self.names))
        return [arrays_to_tensors(unprefixed(out, PARAMETERS_PREFIX)) for _, out in replies]

    def save(self, directory: Path) -> None:
        header = {"op": "sync", "parameters": False, "checkpoint": self._relative(directory)}
        self._exchange([header] * len(self.names))

    def load(self, directory: Path) -> None:
        self._exchange([{"op": "load", "checkpoint": self._relative(directory)}] * len(self.names))

    def save_models(self, paths: Sequence[Path | None]) -> None:
        chosen = [i for i, path in enumerate(paths) if path is not None]
        headers = [{"op": "save_model", "path": self._relative(paths[i])} for i in chosen]  # type: ignore[arg-type]
        self._exchange(headers, workers=chosen)

    def _relative(self, path: Path) -> str:
        return relative_path(path, self.state_dir)
