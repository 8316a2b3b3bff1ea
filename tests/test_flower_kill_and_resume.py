"""A Flower run killed at any moment and resumed ends bit-identical to the run never killed.

Flower's simulation runtime: the roadside unit (the ServerApp, in the ``python -m
frl.train`` process, with Ray's processes bound to it) and a vehicle process per client.
Each session of the killed run is ``python -m frl.train`` in a session of its own, killed
at a chosen moment (tests/kill_points/sitecustomize.py): one vehicle's process alone
mid-round (its host lost; the run stops, as ``accept_failures=false`` says), the whole
host mid-round and just before the roadside unit commits a round. Flower's deployment
runtime (a SuperLink and a SuperNode per vehicle on 127.0.0.1): one SuperNode killed
mid-round (the run stops once its heartbeats are missed), then the SuperLink's host with
everything on it. The twin each must end as is the in-process backend's run of the same
config, which Flower reproduces bit for bit (tests/test_flower_backend.py).

Skipped (not failed) where Flower is not installed: ``pip install -e '.[flower]'``.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Sequence
from pathlib import Path

import pytest
from test_kill_and_resume import (
    OVERRIDES,
    ROOT,
    _committed_rounds,
    never_killed,  # noqa: F401 (a fixture)
)
from test_kill_and_resume import _session as kill_session
from train_helpers import load_script

pytest.importorskip("flwr")

from frl.flower.messages import PARTITION_KEY

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("ray-and-flower")]

same_run = load_script("same_run")
FLOWER = ["federation.backend=flower", "federation.flower.accept_failures=false"]
DEPLOYMENT = ["federation.flower.runtime=deployment"]
MARKER = "FRL_KILL_TEST_SESSION"
"""Set in each killed session's environment: every process it starts inherits it, so
none can outlive the kill unseen."""


def _processes_marked(marker: str) -> list[int]:
    needle = f"{MARKER}={marker}".encode()
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if needle in (entry / "environ").read_bytes().split(b"\0"):
                    found.append(int(entry.name))
            except OSError:
                pass
    return found


def _session(
    run_dir: Path,
    kill_at: str | None,
    resume: bool,
    overrides: Sequence[str] = (),
    known_left: str | None = None,
) -> subprocess.CompletedProcess:
    """One session of the killed Flower run; afterwards, no process of it is left (but
    ``known_left``, an open problem the output names)."""
    marker = uuid.uuid4().hex
    done = kill_session(run_dir, kill_at, resume, [*FLOWER, *overrides], {MARKER: marker})
    _assert_none_left(marker, str(kill_at), known_left)
    return done


def _supernodes_marked(marker: str, partition: int) -> list[int]:
    """The ``flower-supernode`` processes of a session that host ``partition``."""
    found = []
    for pid in _processes_marked(marker):
        with contextlib.suppress(OSError):
            command = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
            if any(b"flower-supernode" in part for part in command) and any(
                part.startswith(f"{PARTITION_KEY}={partition} ".encode()) for part in command
            ):
                found.append(pid)
    return found


def _deployment_losing_a_supernode(run_dir: Path, partition: int) -> tuple[int, str]:
    """A deployment session whose SuperNode of ``partition`` is killed (SIGKILL, the
    node's host lost) once round 1 is committed; its exit code and stderr."""
    marker = uuid.uuid4().hex
    env = {**os.environ, MARKER: marker}
    env.pop("FRL_KILL_AT", None)
    command = [
        sys.executable,
        "-m",
        "frl.train",
        *OVERRIDES,
        *FLOWER,
        *DEPLOYMENT,
        f"run_dir={run_dir}",
    ]
    with subprocess.Popen(
        command, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        text=True, start_new_session=True,
    ) as session:  # fmt: skip
        try:
            while _committed_rounds(run_dir) < 1 and session.poll() is None:
                time.sleep(0.2)
            for pid in _supernodes_marked(marker, partition):
                os.kill(pid, signal.SIGKILL)
            _, stderr = session.communicate(timeout=600)  # a guard against a hang
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(session.pid, signal.SIGKILL)
    _assert_none_left(marker, "a SuperNode's kill")
    return session.returncode, stderr


KNOWN_LEFT_AFTER_HOST_KILL = "flwr-clientapp"
"""A ClientApp caught mid-message when the SuperLink's host dies has been seen to outlive
it on a loaded machine (docs/flower.md, "Runtimes"): an open problem, named in the
test's output rather than hidden; any other process left fails the test."""


def _assert_none_left(marker: str, kill: str, known: str | None = None) -> None:
    """Every process of the session ends with it: those signalled when their parent died
    shut down on their own, which on a loaded machine takes a while; a process left
    behind lives on for good (before the fix, for 40 min and more)."""
    began = time.monotonic()
    while (left := _processes_marked(marker)) and time.monotonic() < began + 90:
        time.sleep(0.5)
    commands = {pid: _command_line(pid) for pid in left}
    for pid in left:  # do not leak them into the rest of the suite
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    tolerated = {pid: c for pid, c in commands.items() if known is not None and known in c}
    if tolerated:
        print(f"KNOWN PROBLEM: after the kill at {kill}, left and killed: {tolerated}")
    unexpected = {pid: c for pid, c in commands.items() if pid not in tolerated}
    assert unexpected == {}, f"processes outlived the session killed at {kill}: {unexpected}"
    print(f"after the kill at {kill}, its processes ended in {time.monotonic() - began:.1f} s")


def _command_line(pid: int) -> str:
    with contextlib.suppress(OSError):
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()[:300]
    return "(gone)"


# Starts no Ray cluster, so it may run beside the Ray tests on another xdist worker: a
# group of its own (xdist joins a test's group names: "flower-deployment_ray-and-flower").
@pytest.mark.xdist_group("flower-deployment")
def test_a_killed_deployment_resumes_to_its_twin(never_killed, tmp_path):  # noqa: F811
    """A SuperLink and a SuperNode per vehicle on 127.0.0.1. The run it must end as is
    the in-process run: this is also the deployment runtime's parity test."""
    run_dir = tmp_path / "killed"

    # The right-turn vehicle's SuperNode lost mid-round 2: once its heartbeats stop, the
    # SuperLink answers for it and the roadside unit stops the run in one line.
    returncode, stderr = _deployment_losing_a_supernode(run_dir, partition=1)
    assert returncode == 1, stderr[-3000:]
    last_line = stderr.strip().splitlines()[-1]
    assert last_line.startswith("frl.train: vehicle client1_right failed: "), last_line
    assert "Node Unavailable" in last_line and "resume=" in last_line
    assert 1 <= _committed_rounds(run_dir) < 4

    # The SuperLink's host killed with everything on it, mid-round (a vehicle's 100th
    # step of this session): the SuperNodes and the ServerApp go with it.
    committed = _committed_rounds(run_dir)
    done = _session(
        run_dir, "step:100", resume=True, overrides=DEPLOYMENT,
        known_left=KNOWN_LEFT_AFTER_HOST_KILL,
    )  # fmt: skip
    assert done.returncode == -signal.SIGKILL, done.stderr[-3000:]
    assert _committed_rounds(run_dir) == committed + 1

    done = _session(run_dir, None, resume=True, overrides=DEPLOYMENT)
    assert done.returncode == 0, done.stderr[-3000:]
    assert same_run.differences(never_killed, run_dir) == []
    logs = sorted(path.name for path in (run_dir / "flower").iterdir())
    assert logs == ["flwr_run.log", "superlink.log", "supernode0.log", "supernode1.log"]


def test_a_killed_flower_run_resumes_to_its_twin(never_killed, tmp_path):  # noqa: F811
    """``never_killed``: the in-process backend's run of the same config."""
    run_dir = tmp_path / "killed"

    # One vehicle's host lost mid-round 2: the roadside unit stops the run in one line.
    done = _session(run_dir, "vehicle:130:right", resume=False)
    assert done.returncode == 1, done.stderr[-3000:]
    stderr_lines = done.stderr.strip().splitlines()
    assert stderr_lines[-1].startswith("frl.train: vehicle client1_right failed"), stderr_lines
    assert "resume=" in stderr_lines[-1]
    assert _committed_rounds(run_dir) == 1

    # The roadside unit's host killed, with everything on it: mid-round 3 (a vehicle's
    # 100th step of this session), then after round 4's step rewards, before its commit.
    for kill_at, committed in [("step:100", 2), ("commit:2", 3)]:
        done = _session(run_dir, kill_at, resume=True)
        assert done.returncode == -signal.SIGKILL, done.stderr[-3000:]
        assert _committed_rounds(run_dir) == committed, kill_at

    done = _session(run_dir, None, resume=True)
    assert done.returncode == 0, done.stderr[-3000:]
    assert same_run.differences(never_killed, run_dir) == []
