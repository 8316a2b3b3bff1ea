"""The clients of a run as the coordinator sees them, and the worker-process backend."""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import shutil
import tempfile
import uuid
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

from torch import Tensor

from frl.agents import DDPGConfig
from frl.agents.stacked import config_refusal
from frl.envs import EnvConfig
from frl.federation.client import ClientSpec, LocalUpdate, drive_rounds
from frl.federation.codec import (
    arrays_to_tensors,
    spec_to_json,
    tensors_to_arrays,
    update_from_parts,
)
from frl.federation.frames import (
    Arrays,
    decode_frame,
    encode_frame,
    frame_header,
    prefixed,
    unprefixed,
)
from frl.federation.strategies import StrategySpec
from frl.federation.vehicle_host import (
    PARAMETERS_PREFIX,
    SERIES_PREFIX,
    VehicleHost,
    training_reply,
)
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
    """The vehicles one worker process hosts: a fleet larger than the cores shares
    processes instead of oversubscribing them.

    libsumo runs one simulation per process, so every vehicle after the first in a
    process drives its SUMO over TraCI (a SUMO child process each); both give the same
    simulation.

    By default the vehicles take turns, each training its whole round in turn. With
    ``stack_updates`` their rounds run in lockstep, a step of each at a time, and after
    each step they learn in one stacked update (:mod:`frl.agents.stacked`): what a GPU
    needs to be busy. A stacked run is its own run (batched products round differently
    from single ones), reproducible from its seed and resumed exactly.
    """

    def __init__(self, state_dir: str, count: int, stack_updates: bool = False) -> None:
        self.hosts = [VehicleHost(state_dir) for _ in range(count)]
        self.stack_updates = stack_updates
        self.stacked: Any = None
        """The stacked update of the agents that last trained together (None: none yet)."""
        self._stacked_agents: tuple[int, ...] = ()

    def serve(
        self, frames: Sequence[bytes | None], progress: Callable[..., None] | None = None
    ) -> list[bytes | None]:
        """Each vehicle's reply to its frame (None: skipped): one vehicle after the other,
        or a round of every vehicle in lockstep (``stack_updates``, all asked to train as
        many steps)."""
        if self.stack_updates:
            requests = self._lockstep_requests(frames)
            if requests is not None:
                return self._serve_in_lockstep(frames, requests, progress)
            if self.stacked is not None and any(frame is not None for frame in frames):
                # A vehicle trains on its own (a round that drew it alone): every agent
                # takes tensors of its own back first.
                self.stacked.release()
                self.stacked, self._stacked_agents = None, ()
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
                raise self._failure(slot, error) from error
        return replies

    def _lockstep_requests(self, frames: Sequence[bytes | None]) -> dict[int, Any] | None:
        """The train requests by slot where two or more vehicles are asked to train as
        many steps; None otherwise (they take turns)."""
        requests = {
            # Headers only: a sync request's arrays (the global model) are read where it is
            # served, not here too.
            slot: frame_header(frame)
            for slot, frame in enumerate(frames)
            if frame is not None
        }
        if len(requests) < 2 or any(h.get("op") != "train" for h in requests.values()):
            return None
        if len({int(h["num_steps"]) for h in requests.values()}) != 1:
            return None
        return requests

    def _serve_in_lockstep(
        self,
        frames: Sequence[bytes | None],
        requests: dict[int, Any],
        progress: Callable[..., None] | None,
    ) -> list[bytes | None]:
        slots = list(requests)
        rounds = []
        for slot in slots:
            report = None if progress is None else functools.partial(progress, slot=slot)
            try:
                rounds.append(self.hosts[slot].training_round(requests[slot], report))
            except Exception as error:
                raise self._failure(slot, error) from error
        stacked = self._stacked_update([self.hosts[slot].client.agent for slot in slots])
        agents = [self.hosts[slot].client.agent for slot in slots]
        update = (  # None: they cannot share an update, each learns alone, in lockstep
            (lambda: [agent.update_unread() for agent in agents])
            if stacked is None
            else stacked.update_unread
        )
        act = None if stacked is None else stacked.policy_actions  # one forward for all
        try:
            updates = drive_rounds(rounds, update, act)
        except Exception as error:
            names = ", ".join(self.hosts[slot].client.name for slot in slots)
            raise RuntimeError(
                f"vehicles {names} (in lockstep): {type(error).__name__}: {error}"
            ) from error
        replies: list[bytes | None] = [None] * len(frames)
        for slot, update in zip(slots, updates, strict=True):
            reply, out = training_reply(update)
            replies[slot] = encode_frame({"ok": True, **reply}, out)
        return replies

    def _stacked_update(self, agents: list[Any]) -> Any:
        """The stacked update of ``agents``, kept from round to round while the same
        agents train together; None if they cannot be stacked (they learn one by one)."""
        from frl.agents.stacked import StackedUpdate, stacking_refusal

        key = tuple(id(agent) for agent in agents)
        if self.stacked is not None and key == self._stacked_agents:
            return self.stacked
        if self.stacked is not None:
            self.stacked.release()
            self.stacked, self._stacked_agents = None, ()
        refusal = stacking_refusal(agents)
        if refusal is not None:
            warnings.warn(f"vehicles learn one by one: {refusal}", RuntimeWarning, stacklevel=2)
            return None
        self.stacked, self._stacked_agents = StackedUpdate(agents), key
        return self.stacked

    def _failure(self, slot: int, error: Exception) -> RuntimeError:
        host = self.hosts[slot]
        vehicle = host.client.name if host.client is not None else f"slot {slot}"
        return RuntimeError(f"vehicle {vehicle}: {type(error).__name__}: {error}")

    def close(self) -> None:
        for host in self.hosts:
            host.close()


def resolve_stacking(
    setting: Any, agent: DDPGConfig, env: EnvConfig, strategy: StrategySpec, backend: str,
    device: str,
) -> bool:  # fmt: skip
    """``federation.stack_updates`` (true, false or auto) resolved: whether a worker's
    vehicles learn in one stacked update. ``auto`` stacks on a GPU where the vehicles can
    be stacked; on a CPU one vehicle's products already fill the cores
    (docs/benchmarks.md), and the vehicles update one by one, as they always have.

    Raises:
        ValueError: a setting that is none of the three, or ``true`` for vehicles that
            cannot be stacked (saying why).
    """
    if setting not in (True, False, "auto"):
        raise ValueError(f"federation.stack_updates must be true, false or auto, got {setting!r}")
    if setting is False:
        return False
    refusal = None
    if strategy.proximal_mu > 0:
        refusal = f"FedProx's pull (federation.strategy={strategy.name}) is not stacked"
    elif backend != "processes":
        refusal = f"federation.backend={backend} runs each vehicle in a process of its own"
    device_type = device.split(":")[0]
    refusal = refusal or config_refusal(agent, math.prod(env.grid.shape), device_type)
    if setting is True and refusal is not None:
        raise ValueError(
            f"federation.stack_updates=true: the vehicles cannot be stacked: {refusal}"
        )
    return refusal is None and (setting is True or device_type == "cuda")


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
        stack_updates: the vehicles a worker hosts train in lockstep and learn in one
            stacked update (:class:`VehicleGroup`).
    """

    def __init__(
        self,
        specs: Sequence[ClientSpec],
        num_threads: int | None = None,
        timeout_s: float | None = None,
        on_message: MessageHook | None = None,
        state_dir: str | os.PathLike[str] | None = None,
        num_workers: int | None = None,
        stack_updates: bool = False,
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
                (name, functools.partial(VehicleGroup, state, len(members), stack_updates))
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
