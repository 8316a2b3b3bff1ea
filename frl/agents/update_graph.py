"""The update captured once as a CUDA graph and replayed (``DDPGConfig.cuda_graph``).

On a GPU the default update is some 550 small kernels, and launching them one by one
from Python takes longer than running them: at batch 256 the networks leave the device
idle between launches. Once every shape is fixed (each grid's vehicles in slots,
:mod:`frl.agents.grid_vehicles`), the whole update (forward and backward passes, the
optimizer steps, the soft update) can be captured once per batch layout and replayed
with a single launch (``torch.cuda.graph``). A replay runs the kernels it captured on
the tensors it captured them with, so:

- each sampled batch is copied into *static* device tensors, through pinned host memory
  (two staging sets taking turns, so that filling one never races the copy out of the
  other);
- nothing inside the update is read from the host: the collision budget's multiplier is
  a device tensor (:meth:`frl.agents.constraint.CollisionConstraint.price`), losses
  are read by the training loop later, Adam is ``capturable``
  (:func:`frl.agents.networks.make_adam`), autocast keeps no weight-cast cache
  (:func:`frl.agents.precision.autocast`);
- anything that replaces a tensor the graph reads (a checkpoint's optimizer state, a
  FedProx anchor) changes the *fingerprint*, the addresses of those tensors, checked
  before every replay: the graphs are dropped and captured afresh.

The first ``warmup`` updates of a layout run eagerly (on a side stream, as
``torch.cuda.graph`` asks, so that lazily made state such as Adam's moments exists
before capture). Every update, eager or replayed, runs the same kernels on the same
numbers, so the graph changes the speed of a run and not its arithmetic.

Batches whose shapes change from one to the next (the flat encoder's sparse rows, whose
non-zeros vary in number) cannot be captured; they run eagerly.

What an update reads is a :class:`Packing`'s business: a sampled :class:`Batch` for one
agent (:data:`BATCH_PACKING`), or every vehicle's batch stacked for the update of many
(:mod:`frl.agents.stacked`).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from frl.agents.config import DDPGConfig
from frl.agents.grid_vehicles import GridVehicles
from frl.agents.replay_buffer import Batch
from frl.agents.sparse_linear import SparseRows

UpdateStep = Callable[[Any], dict[str, Tensor]]
"""One update on a batch on the device: its losses as tensors."""
Layout = tuple[Any, ...]
"""What a graph is captured for: the shapes and dtypes of a batch's tensors."""

WARMUP_UPDATES = 3
"""Eager updates of each layout before it is captured (torch.cuda.graph's warm-up)."""


def keeps_one_layout(config: DDPGConfig, sparse: bool) -> bool:
    """Whether an agent's update can be captured: its batches come in a few fixed layouts
    (the vehicles encoder reading sparse rows, whose vehicles the replay buffer lays in
    slots; a flat encoder reading dense rows). The vehicles encoder on dense rows finds
    each batch's vehicles on the device, a count the host must read; the flat encoder's
    sparse rows change their number of non-zeros from batch to batch."""
    return sparse == (config.encoder == "vehicles")


def batch_tensors(batch: Batch) -> list[Tensor | None] | None:
    """The tensors an update reads from ``batch``, in a fixed order; None where it cannot
    be captured (sparse rows without their vehicles: their non-zeros change in number)."""
    tensors: list[Tensor | None] = []
    for value in batch:
        if isinstance(value, SparseRows):
            if value.vehicles is None:
                return None
            found = value.vehicles
            tensors += [found.cell, found.channels, found.present, found.extra]
        else:
            tensors.append(value)
    return tensors


def layout_of(tensors: list[Tensor | None] | None) -> Layout | None:
    """The layout a graph for a batch of ``tensors`` is captured for, or None if it
    cannot be."""
    if tensors is None:
        return None
    return tuple(None if t is None else (tuple(t.shape), t.dtype) for t in tensors)


def batch_layout(batch: Batch) -> Layout | None:
    """The layout a graph for ``batch`` is captured for, or None if it cannot be."""
    return layout_of(batch_tensors(batch))


def rebuild_batch(template: Batch, tensors: Iterator[Tensor | None]) -> Batch:
    """A batch shaped as ``template`` whose tensors are ``tensors`` (in
    :func:`batch_tensors`' order). Sparse rows keep only their vehicles: the vehicles
    encoder reads nothing else, and empty non-zeros make any other reader fail loudly
    instead of reading a stale batch."""
    fields: list[Any] = []
    for value in template:
        if not isinstance(value, SparseRows):
            fields.append(next(tensors))
            continue
        assert value.vehicles is not None
        cell, channels, present, extra = (next(tensors) for _ in range(4))
        assert cell is not None and channels is not None and present is not None
        device = cell.device
        fields.append(
            SparseRows(
                torch.empty(0, dtype=torch.int64, device=device),
                torch.empty(0, dtype=torch.float32, device=device),
                torch.zeros(value.batch_size, dtype=torch.int64, device=device),
                value.num_features,
                vehicles=GridVehicles(value.vehicles.geometry, cell, channels, present, extra),
            )
        )
    return Batch(*fields)


@dataclass(frozen=True)
class Packing:
    """How an update's input is taken apart into the tensors a graph copies, and put back.

    Attributes:
        tensors: the input's tensors in a fixed order (None in a place an input leaves
            empty), or None where the input cannot be captured.
        rebuild: an input shaped as the first argument, holding the given tensors.
        to: the input moved to a device (the eager update's way in).
    """

    tensors: Callable[[Any], list[Tensor | None] | None]
    rebuild: Callable[[Any, Iterator[Tensor | None]], Any]
    to: Callable[[Any, torch.device], Any]


BATCH_PACKING = Packing(batch_tensors, rebuild_batch, lambda batch, device: batch.to(device))
"""One agent's sampled :class:`Batch`."""


class CapturedStep:
    """One update captured for one batch layout: its static batch, and a replay.

    Args:
        step: the update on a device batch.
        batch: a host batch of the layout (captured on, and updated with, at once).
        device: the CUDA device the update runs on.
        replay_as_graph: capture with ``torch.cuda.graph`` (False: run ``step`` on the
            static batch at each replay; the same data path without the graph, for tests
            on a machine without CUDA).
        packing: what a batch is made of (:data:`BATCH_PACKING`: one agent's).
    """

    def __init__(
        self, step: UpdateStep, batch: Any, device: torch.device, replay_as_graph: bool = True,
        packing: Packing = BATCH_PACKING,
    ) -> None:  # fmt: skip
        tensors = packing.tensors(batch)
        assert tensors is not None, "a batch without a fixed layout cannot be captured"
        self.step, self.packing = step, packing
        self.static = [None if t is None else torch.empty_like(t, device=device) for t in tensors]
        self.static_batch = packing.rebuild(batch, iter(self.static))
        pinned = device.type == "cuda"
        self.staging = [
            [None if t is None else torch.empty_like(t, pin_memory=pinned) for t in tensors]
            for _ in range(2)
        ]
        self.copied = [torch.cuda.Event() if pinned else None for _ in range(2)]
        """Recorded after each staging set's copy to the device: refilling it waits."""
        self.turn = 0
        self.names: list[str] = []
        self.losses: Tensor | None = None
        """The captured update's losses, stacked (overwritten by each replay)."""
        self.graph: torch.cuda.CUDAGraph | None = None
        if replay_as_graph:
            self.load(batch)
            self.graph = torch.cuda.CUDAGraph()
            with torch.cuda.graph(self.graph):
                self.losses = self.stacked(step(self.static_batch))

    def stacked(self, losses: dict[str, Tensor]) -> Tensor:
        self.names = list(losses)
        return torch.stack([loss.float() for loss in losses.values()])

    def load(self, batch: Any) -> None:
        """Copy ``batch`` into the static tensors (through pinned memory on a GPU)."""
        tensors = self.packing.tensors(batch)
        assert tensors is not None
        staging, copied = self.staging[self.turn], self.copied[self.turn]
        if copied is not None:
            copied.synchronize()
        for new, pinned, static in zip(tensors, staging, self.static, strict=True):
            if new is None or pinned is None or static is None:
                continue
            pinned.copy_(new)
            static.copy_(pinned, non_blocking=True)
        if copied is not None:
            copied.record()
        self.turn ^= 1

    def replay(self, batch: Any) -> dict[str, Tensor]:
        """The update on ``batch``: its losses, each a view of one fresh tensor."""
        self.load(batch)
        if self.graph is None:
            losses = self.stacked(self.step(self.static_batch))
        else:
            self.graph.replay()
            assert self.losses is not None
            losses = self.losses.clone()  # the next replay overwrites the static losses
        return {name: losses[i] for i, name in enumerate(self.names)}


class GraphedUpdate:
    """An agent's update, replayed from a graph captured for each batch layout.

    Args:
        step: the update on a batch on ``device``: its losses as tensors.
        device: the CUDA device.
        tensors_read: every tensor the update reads or writes in place besides the batch
            (parameters, optimizer state, anchors, the multiplier); their addresses are the
            fingerprint that a replay must match.
        warmup: eager updates of a layout before it is captured.
        replay_as_graph: False runs the same data path without capturing (tests on CPU).
        packing: what a batch is made of (:data:`BATCH_PACKING`: one agent's).
    """

    def __init__(
        self, step: UpdateStep, device: torch.device, tensors_read: Callable[[], list[Tensor]],
        warmup: int = WARMUP_UPDATES, replay_as_graph: bool = True,
        packing: Packing = BATCH_PACKING,
    ) -> None:  # fmt: skip
        self.step, self.device, self.tensors_read = step, torch.device(device), tensors_read
        self.warmup, self.replay_as_graph = int(warmup), replay_as_graph
        self.packing = packing
        self.captured: dict[Layout, CapturedStep] = {}
        self.eager_updates: Counter[Layout] = Counter()
        """Per layout: eager updates since the graphs were last dropped."""
        self.fingerprint: tuple[int, ...] = ()
        self.captures = 0
        """Graphs captured so far (a fingerprint change or a new layout adds one)."""
        self._side_stream: torch.cuda.Stream | None = None

    def __call__(self, batch: Any) -> dict[str, Tensor]:
        """One update on ``batch`` (on the host): replayed, captured or eager."""
        layout = layout_of(self.packing.tensors(batch))
        if layout is None:
            return self.step(self.packing.to(batch, self.device))
        fingerprint = tuple(t.data_ptr() for t in self.tensors_read())
        if fingerprint != self.fingerprint:
            self.drop()
            self.fingerprint = fingerprint
        captured = self.captured.get(layout)
        if captured is None:
            if self.eager_updates[layout] < self.warmup:
                self.eager_updates[layout] += 1
                return self.eager(batch)
            captured = CapturedStep(
                self.step, batch, self.device, self.replay_as_graph, self.packing
            )
            self.captured[layout] = captured
            self.captures += 1
        return captured.replay(batch)

    def drop(self) -> None:
        """Forget every graph: the next updates warm up and capture again."""
        self.captured.clear()
        self.eager_updates.clear()

    def eager(self, batch: Any) -> dict[str, Tensor]:
        """An eager update, on a side stream on a GPU (capture's warm-up)."""
        to_device = self.packing.to
        if self.device.type != "cuda" or not self.replay_as_graph:
            return self.step(to_device(batch, self.device))
        current = torch.cuda.current_stream(self.device)
        if self._side_stream is None:
            self._side_stream = torch.cuda.Stream(self.device)
        side = self._side_stream
        side.wait_stream(current)
        with torch.cuda.stream(side):
            losses = self.step(to_device(batch, self.device))
        current.wait_stream(side)
        return losses
