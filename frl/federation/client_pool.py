"""The clients of a run as the coordinator sees them, and the worker-process backend."""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import shutil
import tempfile
import uuid
from collections.abc import Callable, Mapping, Sequence
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
from frl.federation.frames import Arrays, decode_frame, encode_frame, prefixed, unprefixed
from frl.federation.vehicle_host import PARAMETERS_PREFIX, SERIES_PREFIX, VehicleHost
from frl.federation.workers import MessageHook, WorkerPool
from frl.run_directory import relative_path

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
        vehicles: Sequence[int] | None = None,
    ) -> list[LocalUpdate]:
        """The clients ``vehicles`` (indices into :attr:`names`; None: all) train
        ``num_steps`` steps in parallel; their updates in order."""

    def set_parameters(
        self,
        parameters: dict[str, Tensor],
        sync_targets: bool,
        vehicles: Sequence[int] | None = None,
    ) -> None:
        """Send the global model to the clients ``vehicles`` (None: every client)."""

    def get_model(self, index: int) -> dict[str, Tensor]:
        """Client ``index``'s whole model (online and target networks)."""

    def save(self, directory: Path) -> None:
        """Every client writes its full resumable state under ``directory``."""

    def load(self, directory: Path) -> list[str]:
        """Every client restores :meth:`save`; the names of those whose checkpoint predates
        their drive (the episode each was running is dropped)."""

    def save_models(self, paths: Sequence[Path | None]) -> None:
        """Client ``i`` writes its model to ``paths[i]`` (None: nothing)."""


class VehicleGroup:
    """The vehicles one worker process hosts, taking turns: a fleet larger than the cores
    shares processes instead of oversubscribing them.

    libsumo runs one simulation per process, so every vehicle after the first in a
    process drives its SUMO over TraCI (a SUMO child process each); both give the same
    simulation.
    """

    def __init__(self, state_dir: str, count: int) -> None:
        self.hosts = [VehicleHost(state_dir) for _ in range(count)]

    def serve(
        self, frames: Sequence[bytes | None], progress: Callable[..., None] | None = None
    ) -> list[bytes | None]:
        """Each vehicle's reply to its frame, one vehicle after the other (None: skipped)."""
        replies: list[bytes | None] = []
        for slot, frame in enumerate(frames):
            if frame is None:
                replies.append(None)
                continue
            report = None if progress is None else functools.partial(progress, slot=slot)
            host = self.hosts[slot]
            try:
                replies.append(host.serve(frame, report))
            except Exception as error:
                if len(self.hosts) == 1:
                    raise
                vehicle = host.client.name if host.client is not None else f"slot {slot}"
                raise RuntimeError(f"vehicle {vehicle}: {type(error).__name__}: {error}") from error
        return replies

    def close(self) -> None:
        for host in self.hosts:
            host.close()


def assign_workers(num_vehicles: int, num_workers: int) -> list[tuple[int, int]]:
    """``(worker, slot)`` of each vehicle: vehicle i goes to worker i mod W, so each
    worker's vehicles mix the tasks as the fleet does."""
    if not 1 <= num_workers <= num_vehicles:
        raise ValueError(f"need 1 to {num_vehicles} workers, got {num_workers}")
    return [(i % num_workers, i // num_workers) for i in range(num_vehicles)]


class ProcessClientPool:
    """The vehicles in spawned worker processes (one per vehicle by default), spoken to
    in frames.

    Each vehicle is a :class:`VehicleHost`, which answers the same request frames as a
    Flower vehicle process (:mod:`frl.federation.vehicle_host`): JSON headers and numpy arrays, no
    pickled objects. With fewer ``num_workers`` than vehicles, each worker hosts a
    :class:`VehicleGroup` whose vehicles train one after the other. Use as a context
    manager, which builds every vehicle on the way in and stops every worker on the way
    out.

    Args:
        specs: the clients, in order.
        num_threads: torch threads per worker; default: the cores split evenly.
        timeout_s: longest one call may take in any worker (None: forever).
        on_message: sees every message a worker sends (tests audit the frames).
        state_dir: the directory every checkpoint and model path lies in (the run
            directory); default: a private temporary directory.
        num_workers: worker processes (default: one per vehicle).
    """

    def __init__(
        self,
        specs: Sequence[ClientSpec],
        num_threads: int | None = None,
        timeout_s: float | None = None,
        on_message: MessageHook | None = None,
        state_dir: str | os.PathLike[str] | None = None,
        num_workers: int | None = None,
    ) -> None:
        self.names = [spec.name for spec in specs]
        self.dropped: dict[str, str] = {}  # a failed worker stops the run instead
        self.placement = assign_workers(len(specs), num_workers or len(specs))
        # A vehicle sharing its process with an earlier one drives SUMO over TraCI.
        self.specs = [
            spec if slot == 0 else dataclasses.replace(
                spec, env=dataclasses.replace(spec.env, backend="traci"))
            for spec, (_, slot) in zip(specs, self.placement, strict=True)
        ]  # fmt: skip
        self._own_dir = state_dir is None
        self.state_dir = Path(
            tempfile.mkdtemp(prefix="frl-pool-") if state_dir is None else state_dir
        )
        self.run_key = f"{self.state_dir.resolve()}#{uuid.uuid4().hex[:8]}"
        workers = max(worker for worker, _ in self.placement) + 1
        self._members = [
            [i for i, (w, _) in enumerate(self.placement) if w == worker]
            for worker in range(workers)
        ]
        names = [
            self.names[members[0]] if len(members) == 1 else f"worker{worker}"
            for worker, members in enumerate(self._members)
        ]
        state = os.fspath(self.state_dir)
        self.workers = WorkerPool(
            [
                (name, functools.partial(VehicleGroup, state, len(members)))
                for name, members in zip(names, self._members, strict=True)
            ],
            num_threads=num_threads,
            timeout_s=timeout_s,
            on_message=on_message,
        )

    def __enter__(self) -> ProcessClientPool:
        self.workers.start()
        try:
            self._exchange({i: {"op": "setup", "spec": spec_to_json(spec)}
                            for i, spec in enumerate(self.specs)})  # fmt: skip
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

    @property
    def num_workers(self) -> int:
        return len(self._members)

    def _exchange(
        self,
        headers: Mapping[int, dict[str, Any]],
        arrays: Arrays | None = None,
        on_progress: ProgressHook | None = None,
    ) -> dict[int, tuple[dict[str, Any], Arrays]]:
        """One request frame per vehicle in ``headers`` (the same ``arrays`` to each); the
        replies by vehicle. Workers run in parallel, a worker's vehicles in turn."""
        frames: list[list[bytes | None]] = [[None] * len(m) for m in self._members]
        # Vehicles sent the same header (a round's global model, a train request) share
        # one frame: encoded once here, pickled once per worker.
        encoded: dict[str, bytes] = {}
        for vehicle, header in headers.items():
            worker, slot = self.placement[vehicle]
            full = {**header, "run_key": self.run_key}
            key = json.dumps(full, sort_keys=True)
            if key not in encoded:
                encoded[key] = encode_frame(full, arrays)
            frames[worker][slot] = encoded[key]
        del encoded
        busy = [w for w, row in enumerate(frames) if any(f is not None for f in row)]

        def report(worker_index: int, info: dict[str, Any]) -> None:
            slot = info.pop("slot")
            on_progress(self._members[worker_index][slot], info)  # type: ignore[misc]

        replies = self.workers.call(
            "serve",
            args=[(frames[w],) for w in busy],
            workers=busy,
            on_progress=report if on_progress is not None else None,
        )
        del frames
        decoded: dict[int, tuple[dict[str, Any], Arrays]] = {}
        for position, worker in enumerate(busy):
            for slot, reply in enumerate(replies[position]):
                if reply is not None:
                    decoded[self._members[worker][slot]] = decode_frame(reply)
            replies[position] = None  # a worker's reply frames go once they are read
        return decoded

    def _all(self, vehicles: Sequence[int] | None) -> list[int]:
        return list(range(len(self.names))) if vehicles is None else list(vehicles)

    def train(
        self,
        num_steps: int,
        upload: bool,
        include_targets: bool,
        on_progress: ProgressHook | None = None,
        vehicles: Sequence[int] | None = None,
    ) -> list[LocalUpdate]:
        header = {
            "op": "train",
            "num_steps": num_steps,
            "upload": upload,
            "include_targets": include_targets,
        }
        chosen = self._all(vehicles)
        replies = self._exchange(dict.fromkeys(chosen, header), on_progress=on_progress)
        return [
            update_from_parts(
                unprefixed(out, PARAMETERS_PREFIX) if reply["upload"] else None,
                unprefixed(out, SERIES_PREFIX),
                reply["summary"],
                copy=False,
            )
            for reply, out in (replies[i] for i in chosen)
        ]

    def set_parameters(
        self,
        parameters: dict[str, Tensor],
        sync_targets: bool,
        vehicles: Sequence[int] | None = None,
    ) -> None:
        header = {"op": "sync", "parameters": True, "sync_targets": sync_targets}
        arrays = prefixed(tensors_to_arrays(parameters), PARAMETERS_PREFIX)
        self._exchange(dict.fromkeys(self._all(vehicles), header), arrays)

    def get_parameters(self) -> list[dict[str, Tensor]]:
        """Every client's full model (online and target networks)."""
        return [self.get_model(i) for i in range(len(self.names))]

    def get_model(self, index: int) -> dict[str, Tensor]:
        _, out = self._exchange({index: {"op": "model"}})[index]
        return arrays_to_tensors(unprefixed(out, PARAMETERS_PREFIX), copy=False)

    def save(self, directory: Path) -> None:
        header = {"op": "sync", "parameters": False, "checkpoint": self._relative(directory)}
        self._exchange(dict.fromkeys(self._all(None), header))

    def load(self, directory: Path) -> list[str]:
        header = {"op": "load", "checkpoint": self._relative(directory)}
        replies = self._exchange(dict.fromkeys(self._all(None), header))
        return [
            self.names[i]
            for i, (reply, _) in sorted(replies.items())
            if not reply["drive_restored"]
        ]

    def save_models(self, paths: Sequence[Path | None]) -> None:
        headers = {
            i: {"op": "save_model", "path": self._relative(path)}
            for i, path in enumerate(paths)
            if path is not None
        }
        self._exchange(headers)

    def _relative(self, path: Path) -> str:
        return relative_path(path, self.state_dir)
