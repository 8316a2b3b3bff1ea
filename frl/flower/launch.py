"""Running the rounds of a run under Flower: the simulation and the deployment runtime.

- ``simulation``: one vehicle process per client on this machine, Flower's simulation
  runtime (Ray) runs the ClientApps, and the ServerApp runs in this process.
- ``deployment``: a SuperLink and one SuperNode per vehicle, separate processes talking
  over the network. With ``federation.flower.superlink`` unset they are started here on
  127.0.0.1 (:class:`LocalFederation`) and stopped afterwards; otherwise the run is
  submitted to that SuperLink, whose SuperNodes were started on the vehicles' hosts
  with ``python -m frl.flower.node``. Either way ``flwr run`` submits the
  app in ``frl/flower/app/``, and its ServerApp (:func:`frl.flower.server_app.serve_run_dir`)
  trains the run whose directory ``python -m frl.train`` prepared.

Both end in the same :class:`~frl.federation.coordinator.Coordinator` as the
in-process backend, so TensorBoard tags, checkpoints, ``state.json`` and (back in
:func:`frl.training.train`) ``results.json`` and the evaluation are the same.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import signal
import subprocess
import tempfile
import time
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from frl import run_directory as rundir
from frl.federation.assembly import worker_threads
from frl.federation.client import ClientSpec
from frl.federation.workers import ClientFailure, stop_processes
from frl.fileio import read_json
from frl.flower.node import (
    StartedProcesses,
    VehicleNode,
    ends_with_this_process,
    flower_env,
    flower_executable,
    free_port,
)
from frl.flower.vehicle import VehicleEndpoint, VehicleService
from frl.run_directory import RoundHook, RunState
from frl.train_config import TrainSettings

log = logging.getLogger("frl.flower")

APP_DIR = Path(__file__).resolve().parent / "app"
"""The Flower app that ``flwr run`` submits (its ServerApp and ClientApp live in frl)."""
POLL_ENV = {"FLWR_SUPEREXEC_TASK_POLL_INTERVAL": "0.1"}
"""Flower's process launchers look for new work every second by default; on a local
federation that second is added to every message, so look more often."""
TOKEN_VAR = "FRL_FLOWER_TOKEN"
"""Set in every process a local federation starts, so that none can be left behind."""


def train_rounds(
    settings: TrainSettings,
    specs: Sequence[ClientSpec],
    run_dir: Path,
    state: RunState,
    progress: bool = False,
    on_round_end: RoundHook | None = None,
) -> RunState:
    """Train from ``state`` to the end of the budget under Flower; the final state."""
    if settings.flower.runtime == "simulation":
        return _simulate(settings, specs, run_dir, state, progress, on_round_end)
    return _deploy(settings, run_dir)


# ------------------------------------------------------------------ simulation
def _simulate(
    settings: TrainSettings,
    specs: Sequence[ClientSpec],
    run_dir: Path,
    state: RunState,
    progress: bool,
    on_round_end: RoundHook | None,
) -> RunState:
    from flwr.serverapp import ServerApp
    from flwr.simulation import run_simulation

    from frl.flower.client_app import make_client_app
    from frl.flower.messages import PARTITION_KEY
    from frl.flower.server_app import run_roadside_unit

    threads = worker_threads(settings, len(specs))
    outcome: dict[str, Any] = {}
    with contextlib.ExitStack() as stack:
        services = [
            stack.enter_context(VehicleService(run_dir, threads, name=f"frl-vehicle-{spec.name}"))
            for spec in specs
        ]
        endpoints = [service.endpoint for service in services]
        client_app = make_client_app(_SimulatedEndpoints(endpoints, PARTITION_KEY))
        server_app = ServerApp()

        @server_app.main()
        def main(grid: Any, context: Any) -> None:
            try:
                outcome["state"] = run_roadside_unit(
                    grid, settings, specs, run_dir, state, progress, on_round_end
                )
            except BaseException as error:  # run_simulation only logs what the app raises
                outcome["error"] = error

        run_simulation(
            server_app=server_app,
            client_app=client_app,
            num_supernodes=len(specs),
            backend_config={
                # The ClientApps only relay; the vehicle processes do the work.
                "client_resources": {"num_cpus": 1, "num_gpus": 0.0},
                "init_args": {"num_cpus": len(specs), "include_dashboard": False},
            },
        )
    if "error" in outcome:
        raise outcome["error"]
    if "state" not in outcome:
        raise RuntimeError("Flower's simulation ended without running the roadside unit")
    return outcome["state"]


class _SimulatedEndpoints:
    """Maps a simulated SuperNode (by ``partition-id``) to its vehicle process."""

    def __init__(self, endpoints: Sequence[VehicleEndpoint], key: str) -> None:
        self.endpoints = list(endpoints)
        self.key = key

    def __call__(self, context: Any) -> VehicleEndpoint:
        return self.endpoints[int(context.node_config[self.key])]


# ------------------------------------------------------------------ deployment
def _deploy(settings: TrainSettings, run_dir: Path) -> RunState:
    """Submit the run with ``flwr run`` and wait; a local federation if none is named."""
    flower = settings.flower
    (run_dir / rundir.FLOWER_FAILURE_FILE).unlink(missing_ok=True)
    logs = run_dir / rundir.FLOWER_LOG_DIR
    logs.mkdir(parents=True, exist_ok=True)
    with contextlib.ExitStack() as stack:
        if flower.superlink is None:
            federation = stack.enter_context(
                LocalFederation(
                    len(settings.plan.client_tasks),
                    state_dir=run_dir,
                    log_dir=logs,
                    num_threads=worker_threads(settings, len(settings.plan.client_tasks)),
                )
            )
            address, env = federation.address, federation.env()
        else:
            address, env = flower.superlink, flower_env()
        _submit(address, run_dir, env, logs / "flwr_run.log")
    failure = run_dir / rundir.FLOWER_FAILURE_FILE
    if failure.exists():
        info = read_json(failure)
        raise ClientFailure(info.get("client") or "(roadside unit)", info["message"])
    state = rundir.read_state(run_dir)
    if state is None or not state.training_finished:
        raise RuntimeError(f"the Flower run ended before training finished; see {logs}/*.log")
    return state


def _submit(address: str, run_dir: Path, env: dict[str, str], log_path: Path) -> None:
    """``flwr run APP frl --run-config run-dir=... --stream``, with its own Flower home."""
    with tempfile.TemporaryDirectory(prefix="frl-flwr-cli-") as home:
        (Path(home) / "config.toml").write_text(
            f'[superlink]\ndefault = "frl"\n\n[superlink.frl]\naddress = "{address}"\n'
            "insecure = true\n"
        )
        command = [
            flower_executable("flwr"), "run", os.fspath(APP_DIR), "frl",
            "--run-config", f"run-dir={_toml_string(os.fspath(run_dir.resolve()))}",
            "--stream",
        ]  # fmt: skip
        log.info("submitting the run to the SuperLink at %s", address)
        with open(log_path, "ab") as out:
            result = subprocess.run(
                command,
                env={**env, "FLWR_HOME": home},
                stdout=out,
                stderr=subprocess.STDOUT,
                preexec_fn=ends_with_this_process(),
            )
        if result.returncode != 0:
            raise RuntimeError(f"`flwr run` failed (exit code {result.returncode}); see {log_path}")


def _toml_string(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


class LocalFederation(StartedProcesses):
    """A SuperLink and one SuperNode per vehicle (each with its vehicle process) on
    127.0.0.1, as separate processes; a context manager that leaves none behind.

    Every process it starts, and every process those start, carries ``FRL_FLOWER_TOKEN``
    in its environment; :meth:`close` stops the SuperNodes and the SuperLink, then
    sweeps whatever still carries the token.
    """

    def __init__(
        self,
        num_vehicles: int,
        state_dir: Path,
        log_dir: Path,
        num_threads: int = 1,
        start_timeout_s: float = 60.0,
    ) -> None:
        self.num_vehicles = num_vehicles
        self.state_dir = Path(state_dir)
        self.log_dir = Path(log_dir)
        self.num_threads = num_threads
        self.start_timeout_s = start_timeout_s
        self.token = uuid.uuid4().hex
        self.port = 0
        self._home: Path | None = None
        self._superlink: subprocess.Popen[bytes] | None = None
        self._nodes: list[VehicleNode] = []

    @property
    def address(self) -> str:
        return f"127.0.0.1:{self.port}"

    def env(self) -> dict[str, str]:
        return flower_env({**POLL_ENV, TOKEN_VAR: self.token})

    def start(self) -> None:
        self._home = Path(tempfile.mkdtemp(prefix="frl-flwr-"))
        self.port = free_port()
        link_home = self._home / "superlink"
        link_home.mkdir()
        command = [
            flower_executable("flower-superlink"), "--insecure",
            "--host", "127.0.0.1", "--port", str(self.port),
            "--database", os.fspath(link_home / "state.db"),
            "--disable-runtime-dependency-installation",
        ]  # fmt: skip
        with open(self.log_dir / "superlink.log", "ab") as out:
            self._superlink = subprocess.Popen(
                command,
                env={**self.env(), "FLWR_HOME": os.fspath(link_home)},
                stdout=out,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                # A SuperLink waits out its runs on SIGTERM; one whose roadside unit is
                # gone must not wait.
                preexec_fn=ends_with_this_process(signal.SIGKILL),
            )
        _wait_for_port(self.port, self._superlink, self.start_timeout_s, "the SuperLink")
        # One at a time, from this thread: starting a vehicle process swaps sys.modules'
        # __main__ for a moment (frl.federation.workers), which threads would race on.
        for index in range(self.num_vehicles):
            node = VehicleNode(
                superlink=self.address,
                partition_id=index,
                num_partitions=self.num_vehicles,
                state_dir=self.state_dir,
                num_threads=self.num_threads,
                flwr_home=self._home / f"supernode{index}",
                log_path=self.log_dir / f"supernode{index}.log",
                env=self.env(),
            )
            self._nodes.append(node)
            node.start()

    def close(self) -> None:
        # A SuperNode takes seconds to sign off from the SuperLink: signal them together.
        stop_processes([node.supernode for node in self._nodes if node.supernode is not None])
        for node in self._nodes:
            node.close()
        self._nodes = []
        if self._superlink is not None:
            stop_processes([self._superlink])
            self._superlink = None
        sweep_token(self.token)
        if self._home is not None:
            shutil.rmtree(self._home, ignore_errors=True)
            self._home = None


def _wait_for_port(
    port: int, process: subprocess.Popen[bytes], timeout_s: float, what: str
) -> None:
    import socket

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"{what} exited on start (exit code {process.returncode})")
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.5):
            return
        time.sleep(0.2)
    raise RuntimeError(f"{what} did not open port {port} within {timeout_s:g} s")


def processes_with_token(token: str) -> list[int]:
    """PIDs of the processes whose environment carries ``FRL_FLOWER_TOKEN=token``."""
    needle = f"{TOKEN_VAR}={token}".encode()
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        with contextlib.suppress(OSError):
            if needle in (entry / "environ").read_bytes().split(b"\0"):
                found.append(int(entry.name))
    return found


def sweep_token(token: str, grace_s: float = 5.0) -> None:
    """SIGTERM, then SIGKILL, every process still carrying ``token`` (all started by us)."""
    if not Path("/proc").is_dir():
        return
    for sig in (signal.SIGTERM, signal.SIGKILL):
        pids = processes_with_token(token)
        if not pids:
            return
        log.warning("stopping %d leftover Flower process(es): %s", len(pids), pids)
        for pid in pids:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, sig)
        deadline = time.monotonic() + grace_s
        while processes_with_token(token) and time.monotonic() < deadline:
            time.sleep(0.1)
