"""Sweeps through Hydra's launchers (the cluster extra): each job an ordinary frl run in its
own directory, resumable, its cores asked of the launcher and given to the run."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from train_helpers import TINY_OVERRIDES

from frl import launchers
from frl.launchers import cores_per_job, launcher_overrides, require_launcher
from frl.train import override_error
from frl.train_config import register_configs

# One xdist worker runs this module and test_flower_backend.py: both start local Ray clusters.
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("ray-and-flower")]

REPO = Path(__file__).resolve().parents[1]


def test_each_job_asks_for_a_core_per_vehicle_and_one_more_and_uses_them():
    assert cores_per_job() == 4  # the paper's three vehicles and the roadside unit
    assert cores_per_job(6) == 7
    if importlib.util.find_spec("hydra_plugins.hydra_submitit_launcher") is not None:
        assert launcher_overrides("submitit_slurm", 4) == [
            "hydra/launcher=submitit_slurm", "hydra.launcher.cpus_per_task=4", "cores=4",
        ]  # fmt: skip
    if importlib.util.find_spec("hydra_plugins.hydra_ray_launcher") is not None:
        assert launcher_overrides("ray", 2)[1] == "+hydra.launcher.ray.remote.num_cpus=2"


def test_an_unknown_or_missing_launcher_says_what_to_install(monkeypatch):
    with pytest.raises(ValueError, match="unknown launcher 'slurm'"):
        require_launcher("slurm")
    monkeypatch.setattr(launchers.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(ValueError, match=r"needs hydra-ray-launcher.*\.\[cluster\]"):
        require_launcher("ray")
    with pytest.raises(ValueError, match="at least one vehicle"):
        cores_per_job(0)


def test_a_sweep_for_a_launcher_leaves_cores_and_device_to_the_machines_that_run_it():
    register_configs()
    assert "exceeds" in override_error(["-m", "cores=64", "seed=0,1"])
    assert override_error(["-m", "hydra/launcher=submitit_slurm", "cores=64", "seed=0,1"]) is None
    assert override_error(["-m", "hydra/launcher=ray", "device=cuda", "seed=0,1"]) is None
    # What is wrong anywhere is still refused before any job.
    assert "interval" in override_error(["-m", "hydra/launcher=ray", "interval=abc"])


@pytest.mark.parametrize(
    ("launcher", "plugin"),
    [
        ("submitit_local", "hydra_plugins.hydra_submitit_launcher"),
        ("ray", "hydra_plugins.hydra_ray_launcher"),
    ],
)
def test_a_two_job_sweep_through_a_launcher_finishes_and_compares(launcher, plugin, tmp_path):
    if importlib.util.find_spec(plugin) is None:
        pytest.skip(f"{plugin} is not installed (the cluster extra)")
    sweep = tmp_path / "sweep"
    tiny = [o for o in TINY_OVERRIDES if not o.startswith(("progress", "eval_episodes"))]
    command = [
        sys.executable, "-m", "frl.train", "-m", *launcher_overrides(launcher, 1),
        "seed=0,1", "federation=central", "federation.tasks=[left]", *tiny,
        "eval_episodes=1", "yardsticks=[full_throttle]", "resume=auto",
        f"hydra.sweep.dir={sweep}", "hydra.sweep.subdir=central-seed${seed}",
    ]  # fmt: skip
    if launcher == "ray":  # a local Ray of one CPU: the two jobs run one after the other
        command.append("+hydra.launcher.ray.init.num_cpus=1")
    env = {**os.environ, "HYDRA_FULL_ERROR": "1"}
    run = subprocess.run(
        command, cwd=REPO, env=env, capture_output=True, text=True, timeout=900
    )  # A guard against a hang: each took about a minute on a busy 2-core machine.
    assert run.returncode == 0, run.stderr[-3000:]
    runs = [sweep / f"central-seed{seed}" for seed in (0, 1)]
    results = [json.loads((r / "results.json").read_text()) for r in runs]
    assert [r["seed"] for r in results] == [0, 1]
    assert all(r["training"]["steps_per_client"] == 240 and r["evaluation"] for r in results)
    if launcher == "submitit_local":  # the same skipping whatever the launcher: once
        stamps = [(r / "results.json").stat().st_mtime_ns for r in runs]
        again = subprocess.run(
            command, cwd=REPO, env=env, capture_output=True, text=True, timeout=900
        )
        assert again.returncode == 0, again.stderr[-3000:]
        assert [(r / "results.json").stat().st_mtime_ns for r in runs] == stamps  # skipped

    report = subprocess.run(
        [sys.executable, "-m", "frl.report.compare", *map(str, runs)],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert report.returncode == 0, report.stderr[-2000:]
    assert "central-seed0" in report.stdout and "central-seed1" in report.stdout
