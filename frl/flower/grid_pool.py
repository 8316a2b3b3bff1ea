"""The vehicles as the roadside unit sees them under Flower: a :class:`ClientPool` over a Grid.

The frl :class:`~frl.federation.coordinator.Coordinator` drives the rounds exactly as
with worker processes (same FedAvg, logging, checkpoints); this pool carries its calls
as Flower messages. One round costs two message exchanges: ``train`` (uploads come
back), then ``query.sync`` (the global model goes down with the checkpoint order, since
:meth:`set_parameters` is held until the next call).

Failures follow Flower's FedAvg: with ``accept_failures``, a vehicle that errs, dies or
stays silent past ``timeout_s`` is logged and dropped from the rest of the run, and the
round goes on with the others while at least ``min_clients`` remain; otherwise the run
stops with :class:`ClientFailure`. Only aggregating schemes can drop a vehicle (under
the others a task would lose its model). The last committed round is never touched, so
a stopped run resumes from it (``resume=RUN_DIR``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from flwr.app import Message
from flwr.serverapp import Grid
from torch import Tensor

from frl.federation.client import ClientSpec, LocalUpdate
from frl.federation.client_pool import ProgressHook
from frl.federation.codec import (
    spec_to_json,
    tensors_to_arrays,
    update_from_parts,
)
from frl.federation.vehicle_host import MODEL_FILE_KEY
from frl.federation.workers import ClientFailure
from frl.fileio import write_bytes_atomic
from frl.flower.messages import (
    METRICS,
    PARAMETERS,
    PARTITION_KEY,
    SERIES,
    error_text,
    message_type,
    read_header,
    record_to_arrays,
    request_content,
)
from frl.run_directory import relative_path

log = logging.getLogger("frl.flower")

POLL_S = 0.2
REPLY_POLL_S = 0.02
"""Seconds between pulls for the replies of an exchange: each costs the SuperLink one
small request, and a vehicle's answer waits at most this long to be seen."""


class FlowerClientPool:
    """The clients of a run, reached through a Flower :class:`Grid`.

    Args:
        grid: the ServerApp's grid.
        specs: every client of the run; SuperNode ``partition-id`` i hosts ``specs[i]``.
        run_dir: the run directory; checkpoint paths go down relative to it.
        run_key: names the run to the vehicles (a vehicle rebuilds itself for a new one).
        accept_failures: drop failed vehicles and go on (aggregating schemes only).
        min_clients: fewest vehicles that must answer for the run to go on.
        aggregates: whether the scheme averages (only then can a vehicle be dropped).
        timeout_s: longest wait for the answers of one exchange (None: forever).
        connect_timeout_s: longest wait for every vehicle's SuperNode to connect.
        dropped: vehicles dropped in earlier sessions of this run (name -> reason).
    """

    def __init__(
        self,
        grid: Grid,
        specs: Sequence[ClientSpec],
        run_dir: Path,
        run_key: str,
        accept_failures: bool = True,
        min_clients: int = 1,
        aggregates: bool = True,
        timeout_s: float | None = None,
        connect_timeout_s: float = 120.0,
        dropped: Mapping[str, str] | None = None,
    ) -> None:
        self.grid = grid
        self.specs = list(specs)
        self.run_dir = Path(run_dir)
        self.run_key = run_key
        self.accept_failures = accept_failures
        self.min_clients = min_clients
        self.aggregates = aggregates
        self.timeout_s = timeout_s
        self.connect_timeout_s = connect_timeout_s
        self.dropped: dict[str, str] = dict(dropped or {})
        """Vehicles dropped after a failure, with the reason (kept in ``state.json``)."""
        self._nodes: dict[int, int] = {}
        self._pending: tuple[dict[str, Tensor], bool, list[int] | None] | None = None

    @property
    def names(self) -> list[str]:
        """The vehicles still in the run."""
        return [spec.name for spec in self._live()]

    def _live(self) -> list[ClientSpec]:
        return [spec for spec in self.specs if spec.name not in self.dropped]

    # ------------------------------------------------------------------ connect
    def connect(self) -> None:
        """Wait for the SuperNodes, then have each build its vehicle for this run."""
        wanted = len(self._live())
        deadline = time.monotonic() + self.connect_timeout_s
        while len(node_ids := list(self.grid.get_node_ids())) < wanted:
            if time.monotonic() > deadline:
                raise ClientFailure(
                    "(all)",
                    f"only {len(node_ids)} of {wanted} SuperNodes connected within "
                    f"{self.connect_timeout_s:g} s",
                )
            time.sleep(POLL_S)
        header = {"op": "setup", "run_key": self.run_key}
        header["specs"] = [spec_to_json(spec) for spec in self.specs]  # type: ignore[assignment]
        messages = [
            Message(request_content(header), dst_node_id=node, message_type="query.setup")
            for node in node_ids
        ]
        by_partition: dict[int, int] = {}
        for position, reply in self._send_and_receive(messages):
            node = node_ids[position]
            if reply.has_error():  # a node of another fleet: no round can be right
                raise ClientFailure(
                    "(all)",
                    f"SuperNode {node} refused the run: {error_text(reply.error.reason)}",
                )
            partition = int(read_header(reply.content)[PARTITION_KEY])
            if partition in by_partition:
                raise ClientFailure(
                    self.specs[partition].name,
                    f"SuperNodes {by_partition[partition]} and {node} were both started with "
                    f"--partition-id {partition}; give each vehicle's node its own",
                )
            by_partition[partition] = node
        missing = [spec for spec in self._live() if spec.index not in by_partition]
        if missing:
            raise ClientFailure(
                missing[0].name,
                f"no SuperNode with --partition-id {missing[0].index} set up its vehicle "
                f"(connected nodes: {len(node_ids)})",
            )
        self._nodes = {spec.index: by_partition[spec.index] for spec in self.specs}
        log.info("%d vehicles connected: %s", wanted, ", ".join(self.names))

    # ------------------------------------------------------------------ exchanges
    def _exchange(
        self,
        op: str,
        headers: Mapping[int, dict[str, Any]],
        parameters: dict[str, Tensor] | None = None,
    ) -> dict[int, Message]:
        """Send one request per client index; their replies, after applying the policy."""
        arrays = None if parameters is None else tensors_to_arrays(parameters)
        messages = [
            Message(
                request_content({"op": op, "run_key": self.run_key, **header}, arrays),
                dst_node_id=self._nodes[index],
                message_type=message_type(op),
            )
            for index, header in headers.items()
        ]
        indices = list(headers)
        began = time.perf_counter()
        replies: dict[int, Message] = {}
        failures: dict[int, str] = {}
        for position, reply in self._send_and_receive(messages):
            index = indices[position]
            if reply.has_error():
                failures[index] = error_text(reply.error.reason)
            else:
                replies[index] = reply
        log.debug("%s: %d replies in %.2f s", op, len(replies), time.perf_counter() - began)
        for index in headers:
            if index not in replies and index not in failures:
                failures[index] = f"no answer to {op!r} within timeout_s={self.timeout_s}"
        if failures:
            self._handle_failures(op, failures)
        return replies

    def _send_and_receive(self, messages: Sequence[Message]) -> list[tuple[int, Message]]:
        """Send ``messages`` and wait; each reply with the position of the request it
        answers, in the requests' order whatever the order of arrival. Matched by request,
        not by sender: for a SuperNode that stopped answering (its heartbeats missed), the
        SuperLink replies itself, an error from its own node id. Pushing gave each request
        its id."""
        # Pushed and pulled here rather than by Grid.send_and_receive, which over a
        # SuperLink waits 3 s between pulls: most of a short round's time.
        waiting = {message_id for message_id in self.grid.push_messages(messages) if message_id}
        position = {message.metadata.message_id: i for i, message in enumerate(messages)}
        deadline = None if self.timeout_s is None else time.monotonic() + self.timeout_s
        answered: list[tuple[int, Message]] = []
        while waiting:
            for reply in self.grid.pull_messages(waiting):
                waiting.discard(reply.metadata.reply_to_message_id)
                answered.append((position[reply.metadata.reply_to_message_id], reply))
            if waiting and deadline is not None and time.monotonic() > deadline:
                break
            if waiting:
                time.sleep(REPLY_POLL_S)
        return sorted(answered, key=lambda answer: answer[0])

    def _handle_failures(self, op: str, failures: Mapping[int, str]) -> None:
        names = {spec.index: spec.name for spec in self.specs}
        for index, reason in failures.items():
            log.warning("vehicle %s failed in %r: %s", names[index], op, reason.strip())
        remaining = len(self._live()) - len(failures)
        first = min(failures)
        if not self.accept_failures or not self.aggregates or remaining < self.min_clients:
            why = (
                "accept_failures is off" if not self.accept_failures
                else "the scheme does not aggregate, so its task would have no model"
                if not self.aggregates
                else f"only {remaining} vehicles remain, fewer than min_clients={self.min_clients}"
            )  # fmt: skip
            raise ClientFailure(
                names[first],
                f"{failures[first].strip()}\nThe run stops ({why}); the last committed round "
                f"is kept: resume=RUN_DIR continues from it.",
            )
        for index, reason in failures.items():
            self.dropped[names[index]] = f"{op}: {reason.strip().splitlines()[0]}"
        log.warning(
            "continuing with %d vehicles (%s) after dropping %s",
            remaining,
            ", ".join(self.names),
            ", ".join(names[i] for i in failures),
        )

    def _flush(self, checkpoint: str | None = None) -> None:
        """Send the held global model (and a checkpoint order) to every live vehicle, or
        the model to the vehicles it is held for."""
        if self._pending is None and checkpoint is None:
            return
        parameters, sync_targets, chosen = self._pending or (None, False, None)
        live = self._live()
        if parameters is not None and chosen is not None:
            header = {"parameters": True, "sync_targets": sync_targets, "checkpoint": None}
            self._exchange("sync", {live[i].index: header for i in chosen}, parameters)
            parameters = None
        self._pending = None
        if parameters is None and checkpoint is None:
            return
        header = {
            "parameters": parameters is not None,
            "sync_targets": sync_targets,
            "checkpoint": checkpoint,
        }
        self._exchange("sync", {spec.index: header for spec in live}, parameters)

    # ------------------------------------------------------------------ ClientPool
    def train(
        self,
        num_steps: int,
        upload: bool,
        include_targets: bool,
        on_progress: ProgressHook | None = None,
        vehicles: Sequence[int] | None = None,
    ) -> list[LocalUpdate]:
        """Local training on the live vehicles ``vehicles`` (indices into :attr:`names`;
        None: all); the updates of those that answered.

        ``on_progress`` is not called: Flower replies once per round.
        """
        self._flush()
        header = {"num_steps": num_steps, "upload": upload, "include_targets": include_targets}
        live = self._live()
        chosen = live if vehicles is None else [live[i] for i in vehicles]
        replies = self._exchange("train", {spec.index: header for spec in chosen})
        updates = []
        for index in sorted(replies):
            content = replies[index].content
            summary = read_header(content)["summary"]
            parameters = (
                record_to_arrays(content[PARAMETERS])
                if PARAMETERS in content.array_records
                else None
            )
            update = update_from_parts(parameters, record_to_arrays(content[SERIES]), summary)
            if int(content.metric_records[METRICS]["num-examples"]) != update.num_steps:
                raise ClientFailure(update.client, "inconsistent step count in its reply")
            updates.append(update)
        return updates

    def set_parameters(
        self,
        parameters: dict[str, Tensor],
        sync_targets: bool,
        vehicles: Sequence[int] | None = None,
    ) -> None:
        """Hold the global model for the live vehicles ``vehicles`` (None: all); it goes
        down with the next exchange."""
        self._pending = (parameters, sync_targets, None if vehicles is None else list(vehicles))

    def get_model(self, index: int) -> dict[str, Tensor]:
        """Live vehicle ``index``'s whole model (online and target networks)."""
        from frl.federation.codec import arrays_to_tensors

        self._flush()
        spec = self._live()[index]
        replies = self._exchange("model", {spec.index: {}})
        if spec.index not in replies:
            raise ClientFailure(spec.name, "no answer to 'model'")
        return arrays_to_tensors(record_to_arrays(replies[spec.index].content[PARAMETERS]))

    def save(self, directory: Path) -> None:
        self._flush(checkpoint=self._relative(directory))

    def load(self, directory: Path) -> list[str]:
        header = {"checkpoint": self._relative(directory)}
        replies = self._exchange("load", {spec.index: header for spec in self._live()})
        names = {spec.index: spec.name for spec in self.specs}
        return [
            names[index]
            for index, reply in sorted(replies.items())
            if not read_header(reply.content)["drive_restored"]
        ]

    def save_models(self, paths: Sequence[Path | None]) -> None:
        """Client ``i`` (of :attr:`names`) uploads its whole model; it is written here."""
        self._flush()
        for spec, path in zip(self._live(), paths, strict=True):
            if path is None:
                continue
            # If the vehicle fails now (and is dropped), under FedAvg any other holds
            # the same global model.
            for candidate in [spec, *[s for s in self._live() if s is not spec]]:
                replies = self._exchange("model_file", {candidate.index: {}})
                if candidate.index in replies:
                    arrays = record_to_arrays(replies[candidate.index].content[PARAMETERS])
                    write_model_file(candidate.name, arrays[MODEL_FILE_KEY].tobytes(), path)
                    break
            else:
                raise ClientFailure(spec.name, "no vehicle left to upload the final model")

    def _relative(self, directory: Path) -> str:
        return relative_path(directory, self.run_dir)


def write_model_file(client: str, data: bytes, path: Path) -> None:
    """Write the model file a vehicle sent, as the in-process backend's vehicle writes it
    (the same bytes), after checking that it loads as a checkpoint, tensors only."""
    import io

    import torch

    try:
        torch.load(io.BytesIO(data), weights_only=True, map_location="cpu")
    except Exception as error:  # a vehicle's file that would not load later
        raise ClientFailure(client, f"its model file does not load: {error}") from None
    write_bytes_atomic(path, data)
