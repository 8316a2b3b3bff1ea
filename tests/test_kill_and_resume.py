"""A run killed at any moment and resumed ends bit-identical to the run never killed.

The killed run is ``python -m frl.train`` in a session of its own, and each kill is a
SIGKILL to its whole process group (run, forkserver, workers) at a chosen moment
(tests/kill_points/sitecustomize.py): mid-round, mid-checkpoint-write, just before the
roadside unit commits a round, and while a resumed vehicle replays its simulation.
"""

import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import pytest
from train_helpers import TINY_OVERRIDES, compose_config, load_script

from frl import run_directory as rundir
from frl.federation.vehicle_snapshot import SNAPSHOT_SUFFIX
from frl.train import train

ROOT = Path(__file__).resolve().parents[1]
KILL_POINTS = Path(__file__).resolve().parent / "kill_points"

pytestmark = pytest.mark.slow

same_run = load_script("same_run")

# 4 rounds of 80 environment steps per vehicle, episodes of at most 50 steps: most
# commits fall inside an episode. Each vehicle has a worker process of its own, whose
# count of steps is 80 a round and of drives one a round. One yardstick keeps the test
# cheap; the comparison covers it all the same.
OVERRIDES = [
    *TINY_OVERRIDES, "total_steps=320", "eval_episodes=1", "yardsticks=[full_throttle]",
    "federation=fedavg", "federation.tasks=[left,right]", "cores=1",
]  # fmt: skip


def _session(
    run_dir: Path,
    kill_at: str | None,
    resume: bool,
    overrides: Sequence[str] = (),
    env_extra: Mapping[str, str] | None = None,
) -> subprocess.CompletedProcess:
    """One session of the killed run: ``python -m frl.train`` (:data:`OVERRIDES`, then
    ``overrides``), killed at ``kill_at``."""
    env = {key: value for key, value in os.environ.items() if key != "FRL_KILL_AT"}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(KILL_POINTS), env.get("PYTHONPATH")]))
    env.update(env_extra or {})
    if kill_at is not None:
        env["FRL_KILL_AT"] = kill_at
    command = [sys.executable, "-m", "frl.train", *OVERRIDES, *overrides, f"run_dir={run_dir}"]
    if resume:
        command.append(f"resume={run_dir}")
    # A guard against a hang, not a speed target.
    return subprocess.run(
        command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
        start_new_session=True,
    )  # fmt: skip


def _committed_rounds(run_dir: Path) -> int:
    state = rundir.read_state(run_dir)
    return 0 if state is None else state.completed_rounds


@pytest.fixture(scope="module")
def never_killed(tmp_path_factory) -> Path:
    run_dir = tmp_path_factory.mktemp("never_killed") / "run"
    train(compose_config(run_dir, [o for o in OVERRIDES if o not in TINY_OVERRIDES]))
    return run_dir


def test_killed_at_any_moment_the_resumed_run_is_the_run_never_killed(never_killed, tmp_path):
    run_dir = tmp_path / "killed"
    kills = [
        ("step:130", False, 1),  # mid-round 2: round 1 is committed
        ("drive:2", True, 2),  # round 3's checkpoint half written: round 2 stands
        ("restore:1", True, 2),  # killed again while resuming, replaying SUMO
        ("commit:2", True, 3),  # round 4's step rewards written, the round not committed
    ]
    for kill_at, resume, committed in kills:
        done = _session(run_dir, kill_at, resume)
        assert done.returncode == -signal.SIGKILL, done.stderr[-3000:]
        assert _committed_rounds(run_dir) == committed, kill_at
        if kill_at == "step:130":  # kept for the run without drives below
            shutil.copytree(run_dir, tmp_path / "without_drives")
    done = _session(run_dir, None, resume=True)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "saved their drive" not in done.stdout + done.stderr
    assert same_run.differences(never_killed, run_dir) == []

    # The same kill with one vehicle's drive left out of the checkpoint (written before
    # vehicles saved them): the episode it was running at the commit is dropped, the run
    # names that vehicle alone, and it is not the run never killed.
    without = tmp_path / "without_drives"
    for drive in (without / "checkpoints").glob(f"round_*/client0_left{SNAPSHOT_SUFFIX}"):
        drive.unlink()
    done = _session(without, None, resume=True)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "written before vehicles saved their drive (client0_left)" in done.stdout + done.stderr
    assert same_run.differences(never_killed, without) != []
