"""The vehicle process: one long-lived :class:`VehicleClient` that Flower messages reach.

Flower runs a ClientApp afresh for every message: in a new ``flwr-clientapp`` process
under the deployment runtime, in whichever Ray actor is free under the simulation
runtime. A vehicle's replay buffer, exploration noise, optimizer moments and running
SUMO simulation cannot live there (and libsumo allows one simulation per process). So
each vehicle keeps them in its own long-lived process, this module's *vehicle service*,
and the ClientApp only relays: it opens the service's Unix socket, forwards the request
and returns the answer as the Flower reply.

The local channel carries :mod:`frl.federation.frames` frames (JSON
and ``.npz``, no pickle; the same requests as the process backend's worker pipes) after
``multiprocessing``'s HMAC handshake with a random key.
Requests are served one at a time, in order: a vehicle does one thing at a time.

Checkpoints are written under the service's ``state_dir`` (the run directory when
vehicles run beside the roadside unit, the vehicle's own disk otherwise): replay
buffers never leave the vehicle.
"""

from __future__ import annotations

import contextlib
import functools
import multiprocessing as mp
import os
import secrets
import shutil
import tempfile
import threading
import traceback
from collections.abc import Mapping
from dataclasses import dataclass
from multiprocessing.connection import Client, Listener
from pathlib import Path
from typing import Any

import numpy as np

# Light imports only: the ClientApp imports this module for every message. The vehicle's
# own work (torch, SUMO) is imported in the vehicle process, by VehicleHost.
from frl.federation.frames import Arrays, decode_frame, encode_frame
from frl.federation.vehicle_host import (
    PARAMETERS_PREFIX,
    SERIES_PREFIX,
    VehicleError,
    VehicleHost,
)

__all__ = [
    "PARAMETERS_PREFIX",
    "SERIES_PREFIX",
    "SocketVehicle",
    "VehicleEndpoint",
    "VehicleError",
    "VehicleHost",
    "VehicleService",
    "call_vehicle",
]


@dataclass(frozen=True)
class VehicleEndpoint:
    """Where a ClientApp finds its vehicle: a Unix socket and the handshake key."""

    address: str
    authkey: str
    """Hex text, so that it fits a Flower node config."""


# ----------------------------------------------------------------- the process
class SocketVehicle:
    """A :class:`VehicleHost` answering frames on a Unix socket, one connection per request.

    Hosted in a worker process of :class:`frl.federation.WorkerPool`, which starts,
    watches and stops it as it does the process backend's vehicles; a thread serves the
    socket while the worker's own loop keeps its pipe to the parent.
    """

    def __init__(self, address: str, authkey: str, state_dir: str) -> None:
        self.host = VehicleHost(state_dir)
        self.closed = False
        self.listener = Listener(address, family="AF_UNIX", authkey=bytes.fromhex(authkey))
        self.thread = threading.Thread(target=self._serve, name="frl-vehicle-socket", daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        while not self.closed:
            try:
                conn = self.listener.accept()
            except (mp.AuthenticationError, OSError, EOFError):
                continue
            with conn:
                try:
                    request = conn.recv_bytes()
                    try:
                        frame = self.host.serve(request)
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

    def close(self) -> None:
        self.closed = True
        with contextlib.suppress(OSError):
            self.listener.close()
        self.host.close()


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
        start_timeout_s: longest the process may take to open its socket.
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
        self._pool: Any = None

    @property
    def pid(self) -> int | None:
        return None if self._pool is None else self._pool.pids[0]

    def __enter__(self) -> VehicleService:
        self.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def start(self) -> None:
        """Spawn the vehicle process; return once its socket accepts requests."""
        from frl.federation.workers import ClientFailure, WorkerPool

        host = functools.partial(
            SocketVehicle,
            self.endpoint.address,
            self.endpoint.authkey,
            os.fspath(self.state_dir),
        )
        self._pool = WorkerPool(
            [(self.name.removeprefix("frl-"), host)],
            num_threads=self.num_threads,
            start_timeout_s=self.start_timeout_s,
        )
        try:
            self._pool.start()
        except ClientFailure as error:
            self.close()
            raise VehicleError(f"the vehicle process did not start: {error.reason}") from None

    def close(self) -> None:
        """Stop the process (politely, then SIGTERM, then SIGKILL); safe to call twice."""
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.close(graceful=True)
        with contextlib.suppress(OSError):
            os.unlink(self.endpoint.address)
        if self._own_dir:
            shutil.rmtree(Path(self.endpoint.address).parent, ignore_errors=True)
