"""The vehicle process: one long-lived :class:`VehicleClient` that Flower messages reach.

Flower runs a ClientApp afresh for every message: in a new ``flwr-clientapp`` process
under the deployment runtime, in whichever Ray actor is free under the simulation
runtime. A vehicle's replay buffer, exploration noise, optimizer moments and running
SUMO simulation cannot live there (and libsumo allows one simulation per process). So
each vehicle keeps them in its own long-lived process, this module's *vehicle service*,
and the ClientApp only relays: it opens the service's Unix socket, forwards the request
and returns the answer as the Flower reply.

The local channel carries :func:`frl.flower.codec.encode_frame` frames (JSON
and ``.npz``, no pickle) after ``multiprocessing``'s HMAC handshake with a random key.
Requests are served one at a time, in order: a vehicle does one thing at a time.

Checkpoints are written under the service's ``state_dir`` (the run directory when
vehicles run beside the roadside unit, the vehicle's own disk otherwise): replay
buffers never leave the vehicle.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import secrets
import shutil
import tempfile
import time
import traceback
from collections.abc import Mapping
from dataclasses import dataclass
from multiprocessing.connection import Client, Listener
from pathlib import Path
from typing import Any

import numpy as np

# Light imports only: the ClientApp imports this module for every message. The vehicle's
# own work (torch, SUMO) is imported in the vehicle process, by VehicleHost.
from frl.flower.frames import Arrays, decode_frame, encode_frame, prefixed, unprefixed

SERIES_PREFIX = "series/"
PARAMETERS_PREFIX = "parameters/"


class VehicleError(RuntimeError):
    """The vehicle process failed a request, or could not be reached."""


@dataclass(frozen=True)
class VehicleEndpoint:
    """Where a ClientApp finds its vehicle: a Unix socket and the handshake key."""

    address: str
    authkey: str
    """Hex text, so that it fits a Flower node config."""


# ----------------------------------------------------------------- the vehicle's state
class VehicleHost:
    """What the vehicle process holds across rounds, and the requests it answers.

    Requests (``header["op"]``): ``setup`` builds the vehicle of a run (idempotent);
    ``train`` runs local training; ``sync`` loads the global model and/or writes a
    checkpoint; ``load`` restores one; ``model`` returns the full model for saving.
    """

    def __init__(self, state_dir: str | os.PathLike[str]) -> None:
        self.state_dir = Path(state_dir)
        self.client: Any = None
        self.run_key: str | None = None
        self.spec_json: str | None = None

    def handle(self, header: Mapping[str, Any], arrays: Arrays) -> tuple[dict[str, Any], Arrays]:
        from frl.flower.codec import (
            arrays_to_tensors,
            tensors_to_arrays,
            update_to_parts,
        )

        op = header["op"]
        if op == "ping":
            return {"run_key": self.run_key}, {}
        if op == "setup":
            return self._setup(str(header["run_key"]), str(header["spec"])), {}
        client = self.client
        if client is None or header.get("run_key") != self.run_key:
            raise VehicleError(f"{op!r} for run {header.get('run_key')!r}, which was not set up")
        if op == "train":
            update = client.train(
                int(header["num_steps"]),
                upload=bool(header["upload"]),
                include_targets=bool(header["include_targets"]),
            )
            parameters, series, summary = update_to_parts(update)
            out = prefixed(series, SERIES_PREFIX)
            if parameters is not None:
                out.update(prefixed(parameters, PARAMETERS_PREFIX))
            return {"summary": summary, "upload": parameters is not None}, out
        if op == "sync":
            if header.get("parameters"):
                parameters = arrays_to_tensors(unprefixed(arrays, PARAMETERS_PREFIX))
                client.set_parameters(parameters, sync_targets=bool(header["sync_targets"]))
            if header.get("checkpoint"):
                self._save(str(header["checkpoint"]))
            return {}, {}
        if op == "load":
            client.load(self._path(str(header["checkpoint"])))
            return {}, {}
        if op == "model":
            return {}, prefixed(tensors_to_arrays(client.get_parameters(True)), PARAMETERS_PREFIX)
        raise VehicleError(f"unknown request {op!r}")

    def _setup(self, run_key: str, spec_json: str) -> dict[str, Any]:
        if self.client is not None and (run_key, spec_json) == (self.run_key, self.spec_json):
            return {"client": self.client.name, "built": False}  # a repeated setup
        self.close()
        from frl.federation.client import VehicleClient
        from frl.flower.codec import spec_from_json

        self.client = VehicleClient(spec_from_json(spec_json))
        self.run_key, self.spec_json = run_key, spec_json
        return {"client": self.client.name, "built": True}

    def _path(self, relative: str) -> Path:
        path = (self.state_dir / relative).resolve()
        if self.state_dir.resolve() not in path.parents:
            raise VehicleError(f"checkpoint {relative!r} lies outside the vehicle's state_dir")
        return path

    def _save(self, relative: str) -> None:
        directory = self._path(relative)
        self.client.save(directory)
        # Keep this round and the one before (the last committed one); drop older files
        # of this vehicle. Where state_dir is the run directory, the roadside unit prunes too.
        name = self.client.name
        rounds = sorted(p for p in directory.parent.glob("round_*") if p.name < directory.name)
        for old in rounds[:-1]:
            for suffix in (".pt", ".json"):
                (old / f"{name}{suffix}").unlink(missing_ok=True)
            with contextlib.suppress(OSError):
                old.rmdir()

    def close(self) -> None:
        if self.client is not None:
            with contextlib.suppress(Exception):
                self.client.close()
        self.client = None
        self.run_key = self.spec_json = None


# ----------------------------------------------------------------- the process
def serve(address: str, authkey: bytes, state_dir: str, num_threads: int) -> None:
    """Entry point of the vehicle process: answer requests on ``address`` until killed."""
    from frl.federation.workers import prepare_worker_process

    prepare_worker_process(num_threads)
    host = VehicleHost(state_dir)
    listener = Listener(address, family="AF_UNIX", authkey=authkey)
    try:
        while True:
            try:
                conn = listener.accept()
            except (mp.AuthenticationError, OSError, EOFError):
                continue
            with conn:
                try:
                    header, arrays = decode_frame(conn.recv_bytes())
                    try:
                        reply, out = host.handle(header, arrays)
                        frame = encode_frame({"ok": True, **reply}, out)
                    except Exception as error:
                        frame = encode_frame(
                            {
                                "ok": False,
                                "error": f"{type(error).__name__}: {error}",
                                "traceback": traceback.format_exc(),
                            }
                        )
                    conn.send_bytes(frame)
                except (EOFError, OSError):  # the ClientApp went away; keep serving
                    continue
    finally:
        host.close()
        listener.close()


def call_vehicle(
    endpoint: VehicleEndpoint,
    header: Mapping[str, Any],
    arrays: Mapping[str, np.ndarray] | None = None,
    timeout_s: float | None = None,
) -> tuple[dict[str, Any], Arrays]:
    """Send one request to a vehicle process and wait for its answer.

    Raises:
        VehicleError: the vehicle is unreachable, failed the request, or did not answer
            within ``timeout_s``.
    """
    try:
        conn = Client(endpoint.address, family="AF_UNIX", authkey=bytes.fromhex(endpoint.authkey))
    except (OSError, mp.AuthenticationError) as error:
        raise VehicleError(f"cannot reach the vehicle at {endpoint.address}: {error}") from None
    with conn:
        try:
            conn.send_bytes(encode_frame(header, arrays))
            if not conn.poll(timeout_s):
                raise VehicleError(f"no answer from the vehicle within {timeout_s:g} s")
            reply, out = decode_frame(conn.recv_bytes())
        except (EOFError, OSError) as error:
            raise VehicleError(f"the vehicle process went away: {error!r}") from None
    if not reply.pop("ok", False):
        raise VehicleError(
            f"{reply.get('error')}\n--- in the vehicle ---\n{reply.get('traceback')}"
        )
    return reply, out


class VehicleService:
    """Starts and stops one vehicle process (a context manager).

    Args:
        state_dir: where the vehicle writes its checkpoints.
        num_threads: torch threads of the vehicle process.
        socket_dir: directory of the Unix socket; default: a private temporary one.
        start_timeout_s: longest the process may take to answer its first ping.
        name: the process's name (``multiprocessing``'s, for logs and tests).
    """

    def __init__(
        self,
        state_dir: str | os.PathLike[str],
        num_threads: int = 1,
        socket_dir: str | os.PathLike[str] | None = None,
        start_timeout_s: float = 120.0,
        name: str = "frl-vehicle",
    ) -> None:
        self.name = name
        self.state_dir = Path(state_dir)
        self.num_threads = num_threads
        self.start_timeout_s = start_timeout_s
        self._own_dir = socket_dir is None
        # A short path: Unix socket paths are limited to about 100 bytes.
        directory = (
            Path(tempfile.mkdtemp(prefix="frl-v-")) if socket_dir is None else Path(socket_dir)
        )
        self.endpoint = VehicleEndpoint(
            address=os.fspath(directory / f"vehicle-{secrets.token_hex(4)}.sock"),
            authkey=secrets.token_hex(16),
        )
        self._process: mp.process.BaseProcess | None = None

    @property
    def pid(self) -> int | None:
        return None if self._process is None else self._process.pid

    def __enter__(self) -> VehicleService:
        self.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def start(self) -> None:
        context = mp.get_context("spawn")
        self._process = context.Process(
            target=serve,
            args=(
                self.endpoint.address,
                bytes.fromhex(self.endpoint.authkey),
                os.fspath(self.state_dir),
                self.num_threads,
            ),
            name=self.name,
            daemon=True,
        )
        self._process.start()
        deadline = time.monotonic() + self.start_timeout_s
        while True:
            if not self._process.is_alive():
                code = self._process.exitcode
                self.close()
                raise VehicleError(f"the vehicle process exited on start (exit code {code})")
            if os.path.exists(self.endpoint.address):
                with contextlib.suppress(VehicleError):
                    call_vehicle(self.endpoint, {"op": "ping"}, timeout_s=10.0)
                    return
            if time.monotonic() > deadline:
                self.close()
                raise VehicleError(f"the vehicle process did not start in {self.start_timeout_s} s")
            time.sleep(0.05)

    def close(self) -> None:
        """Stop the process (SIGTERM, then SIGKILL); safe to call twice."""
        process, self._process = self._process, None
        if process is not None:
            from frl.federation.workers import stop_processes

            stop_processes([process])
        with contextlib.suppress(OSError):
            os.unlink(self.endpoint.address)
        if self._own_dir:
            shutil.rmtree(Path(self.endpoint.address).parent, ignore_errors=True)
