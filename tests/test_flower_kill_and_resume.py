"""A Flower run killed at any moment and resumed ends bit-identical to the run never killed.

Flower's simulation runtime: the roadside unit (the ServerApp, in the ``python -m
frl.train`` process, with Ray's processes bound to it) and a vehicle process per client.
Each session of the killed run is ``python -m frl.train`` in a session of its own, killed
at a chosen moment (tests/kill_points/sitecustomize.py): one vehicle's process alone
mid-round (its host lost; the run stops, as ``accept_failures=false`` says), the whole
host mid-round and just before the roadside unit commits a round. The twin it must end
as is the in-process backend's run of the same config, which Flower reproduces bit for
bit (tests/test_flower_backend.py).

Skipped (not failed) where Flower is not installed: ``pip install -e '.[flower]'``.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time
import uuid
from pathlib import Path

import pytest
from test_kill_and_resume import _committed_rounds, never_killed  # noqa: F401 (a fixture)
from test_kill_and_resume import _session as kill_session
from train_helpers import load_script

pytest.importorskip("flwr")


pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("ray-and-flower")]

same_run = load_script("same_run")
FLOWER = ["federation.backend=flower", "federation.flower.accept_failures=false"]
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


def _session(run_dir: Path, kill_at: str | None, resume: bool) -> subprocess.CompletedProcess:
    """One session of the killed Flower run; afterwards, no process of it is left."""
    marker = uuid.uuid4().hex
    done = kill_session(run_dir, kill_at, resume, FLOWER, {MARKER: marker})
    deadline = time.monotonic() + 30
    while (left := _processes_marked(marker)) and time.monotonic() < deadline:
        time.sleep(0.5)
    for pid in left:  # do not leak them into the rest of the suite
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    assert left == [], f"processes outlived the session killed at {kill_at}: {left}"
    return done


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
