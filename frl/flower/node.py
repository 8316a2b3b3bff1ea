"""A vehicle's host: its vehicle process and its Flower SuperNode, started and stopped together.

    python -m frl.flower.node --superlink RSU_HOST:9093 --partition-id 0 \\
        --num-partitions 3 [--state-dir frl-vehicle-state] [--insecure]

``--partition-id`` i makes this host the run's client i (``client0_left`` for 0 under
the default tasks). The SuperNode's ClientApps reach the vehicle process through a
private Unix socket named in the node config; checkpoints (replay buffer included)
stay under ``--state-dir`` on this host. Ctrl-C or SIGTERM stops both.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Self

from frl.cli import OneLineParser
from frl.federation.reachability import unreachable_reason
from frl.federation.workers import stop_processes
from frl.flower.vehicle import VehicleService


def flower_executable(name: str) -> str:
    """A Flower command of this environment (beside this Python, else on PATH)."""
    beside = Path(sys.executable).parent / name
    found = os.fspath(beside) if beside.exists() else shutil.which(name)
    if found is None:
        raise RuntimeError(f"`{name}` not found; install Flower with `pip install frl[flower]`")
    return found


def flower_env(extra: dict[str, str] | None = None) -> dict[str, str]:
    """This environment, with this Python's scripts first on PATH: Flower's processes
    start further Flower commands (``flower-superexec``) by name."""
    path = os.pathsep.join([os.fspath(Path(sys.executable).parent), os.environ.get("PATH", "")])
    return {**os.environ, "PATH": path, **(extra or {})}


_PR_SET_PDEATHSIG = 1


def ends_with_this_process(sig: int = signal.SIGTERM) -> Callable[[], None]:
    """A ``Popen`` ``preexec_fn``: the child gets ``sig`` when this process dies, however
    it dies (Linux; elsewhere nothing). A SuperLink or SuperNode runs in a session of its
    own, so without this a killed ``frl.train`` would leave them training on."""
    parent = os.getpid()

    def arrange() -> None:
        if sys.platform.startswith("linux"):
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, sig)
            if os.getppid() != parent:  # the parent died before the request was made
                os._exit(1)

    return arrange


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


class StartedProcesses:
    """Processes started on entering a ``with`` block (:meth:`start`) and stopped on
    leaving it (:meth:`close`); a start that fails half way stops what it started."""

    def start(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        try:
            self.start()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class VehicleNode(StartedProcesses):
    """One vehicle process and the ``flower-supernode`` that serves it.

    Args:
        superlink: the SuperLink's address, ``host:port``.
        partition_id: which client of the run this node hosts.
        num_partitions: how many clients the run has.
        state_dir: where the vehicle writes its checkpoints.
        num_threads: torch threads of the vehicle process.
        insecure: talk to the SuperLink without TLS (fine on 127.0.0.1).
        flwr_home: the SuperNode's Flower home (installed apps); default: a temporary one.
        clientapp_port: port of the SuperNode's local API for its ClientApps.
        log_path: where the SuperNode's output goes; default: inherited.
        env: environment of the SuperNode.
    """

    def __init__(
        self,
        superlink: str,
        partition_id: int,
        num_partitions: int,
        state_dir: str | os.PathLike[str],
        num_threads: int = 1,
        insecure: bool = True,
        flwr_home: str | os.PathLike[str] | None = None,
        clientapp_port: int | None = None,
        log_path: str | os.PathLike[str] | None = None,
        env: dict[str, str] | None = None,
    ) -> None:
        self.superlink = superlink
        self.partition_id = partition_id
        self.num_partitions = num_partitions
        self.insecure = insecure
        self.flwr_home = flwr_home
        self.clientapp_port = clientapp_port
        self.log_path = log_path
        self.env = flower_env() if env is None else dict(env)
        self.service = VehicleService(state_dir, num_threads, name=f"frl-vehicle-{partition_id}")
        self.supernode: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        from frl.flower.messages import AUTHKEY_KEY, NUM_PARTITIONS_KEY, PARTITION_KEY, SOCKET_KEY

        self.service.start()
        endpoint = self.service.endpoint
        node_config = (
            f"{PARTITION_KEY}={self.partition_id} {NUM_PARTITIONS_KEY}={self.num_partitions} "
            f'{SOCKET_KEY}="{endpoint.address}" {AUTHKEY_KEY}="{endpoint.authkey}"'
        )
        home = self.flwr_home or tempfile.mkdtemp(prefix="frl-flwr-node-")
        Path(home).mkdir(parents=True, exist_ok=True)
        command = [
            flower_executable("flower-supernode"),
            "--superlink", self.superlink,
            "--node-config", node_config,
            "--port", str(self.clientapp_port or free_port()),
            *(["--insecure"] if self.insecure else []),
        ]  # fmt: skip
        out = open(self.log_path, "ab") if self.log_path is not None else None  # noqa: SIM115
        try:
            self.supernode = subprocess.Popen(
                command,
                env={**self.env, "FLWR_HOME": os.fspath(home)},
                stdout=out,
                stderr=subprocess.STDOUT if out is not None else None,
                start_new_session=True,
                preexec_fn=ends_with_this_process(),
            )
        finally:
            if out is not None:
                out.close()

    def wait(self) -> int:
        """Block until the SuperNode exits; its exit code."""
        assert self.supernode is not None
        return self.supernode.wait()

    def close(self) -> None:
        if self.supernode is not None:
            stop_processes([self.supernode])
            self.supernode = None
        self.service.close()


def main(argv: Sequence[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m frl.flower.node", description=__doc__.splitlines()[0])
    parser.add_argument("--superlink", required=True, help="the SuperLink's host:port")
    parser.add_argument("--partition-id", type=int, required=True, help="this vehicle's index")
    parser.add_argument("--num-partitions", type=int, required=True, help="vehicles in the run")
    parser.add_argument("--state-dir", default="frl-vehicle-state", help="checkpoint directory")
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1, help="torch threads")
    parser.add_argument("--insecure", action="store_true", help="no TLS (trusted networks only)")
    parser.add_argument("--clientapp-port", type=int, default=None, help="local ClientApp API port")
    args = parser.parse_args(argv)
    if args.num_partitions < 1:
        parser.error(f"--num-partitions must be at least 1, got {args.num_partitions}")
    if not 0 <= args.partition_id < args.num_partitions:
        parser.error(
            f"--partition-id {args.partition_id} is not in [0, --num-partitions "
            f"{args.num_partitions})"
        )
    why = unreachable_reason(args.superlink)
    if why is not None:  # before the vehicle process starts, so nothing is left behind
        parser.error(f"--superlink {args.superlink}: nothing answers there ({why})")
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    node = VehicleNode(
        args.superlink,
        args.partition_id,
        args.num_partitions,
        state_dir=args.state_dir,
        num_threads=args.threads,
        insecure=args.insecure,
        clientapp_port=args.clientapp_port,
    )
    with node:
        print(
            f"vehicle {args.partition_id} of {args.num_partitions} -> {args.superlink}", flush=True
        )
        with contextlib.suppress(KeyboardInterrupt):
            return node.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())
