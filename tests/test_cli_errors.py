"""A user's mistake on the command line: one line on stderr, exit code 2, no traceback.

Most cases call the entry points in this process (fast); one per command runs
``python -m`` for real.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf
from train_helpers import TINY_OVERRIDES, compose_config

from frl import evaluate, train
from frl.fileio import write_json_atomic


@pytest.fixture
def run_cli(monkeypatch, capsys):
    """``run_cli(module, *args, cwd=...)``: the command's exit code, stdout and stderr."""

    def run(module: str, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
        monkeypatch.chdir(cwd)
        monkeypatch.setattr(sys, "argv", [module, *args])
        try:
            code = evaluate.main(list(args)) if module == "frl.evaluate" else train.main()
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else 1
        out = capsys.readouterr()
        return subprocess.CompletedProcess([module, *args], code or 0, out.out, out.err)

    return run


def run_for_real(module: str, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", module, *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def assert_one_line_error(result: subprocess.CompletedProcess[str], prefix: str, text: str):
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith(prefix) and text in lines[0], lines[0]
    assert "Traceback" not in result.stderr + result.stdout


@pytest.mark.parametrize(
    ("override", "text"),
    [
        ("interval=abc", "could not be converted to Integer"),
        ("agent.lrr=1", "Key 'lrr' not in 'AgentSchema'"),
        ("federation=bogus", "federation/bogus"),
        ("budget=huge", "budget/huge"),
        ("nonsense", "Error parsing override 'nonsense'"),
        ("eval_episodes=-1", "eval_episodes must be a non-negative integer"),
        ("round_test_episodes=-2", "round_test_episodes must be a non-negative integer"),
        ("device=gpu0", "device='gpu0' is not a torch device"),
        ("agent.guide=oracle", "guide must be one of none, gap_acceptance"),
        (
            "agent=ddpg-guided agent.guide=committed_gap_acceptance",
            "reads the distance to the stop line from the student's observation: set "
            "env.route_observation=true",
        ),
        ("agent.replay=lap", "agent.replay='lap' was retired: docs/studies.md"),
        ("agent.twin_critics=true", "agent.twin_critics=True was retired"),
        ("env.route_observation=maybe", "route_observation"),
        ("env.window_observation=maybe", "window_observation"),
        ("env.windows_until_committed=true", "env.windows_until_committed=True was retired"),
        ("agent.collision_budget=1.0", "collision_budget must lie in [0, 1)"),
        ("agent.collision_budget=-0.1", "collision_budget must lie in [0, 1)"),
        ("agent.critic.cvar_alpha=0", "critic.cvar_alpha must lie in (0, 1]"),
        ("agent.critic.cvar_alpha=0.25", "cvar_alpha below 1 needs the return's quantiles"),
        ("agent.critic.kind=ensemble", "agent.critic.kind='ensemble' was retired: docs/studies.md"),
        ("agent.critic.heads=3", "agent.critic.heads=3 was retired: docs/studies.md"),
        ("agent.cvar_alpha=0.25", "agent.cvar_alpha is now agent.critic.cvar_alpha"),
        ("agent.noise_sigma=0.2", "agent.noise_sigma is now agent.noise.sigma"),
        ("agent.noise=gaussian", "agent.noise=gaussian is now agent.noise.kind=gaussian"),
        # the paper's budget trains without a collision budget
        ("budget=paper agent.lagrange_window=10", "lagrange_window tunes the collision budget"),
        ("budget=paper agent.cost_critic=separate", "cost_critic tunes the collision budget"),
        ("agent.collision_budget=null agent.cost_target=n_step", "cost_target tunes the collision"),
        ("agent.cost_target=monte_carlo", "cost_target must be one of n_step, episode"),
        ("reward.brake_past_line_cost=0.1", "reward.brake_past_line_cost=0.1 was retired"),
        ("env.commit_at_line=true", "env.commit_at_line=True was retired"),
        (
            "federation.round_arrival_period_factors=[0.6,1]",
            "federation.round_arrival_period_factors=[0.6, 1] was retired",
        ),
        (
            "+agent.collision_budget_by_task={left:0.1,straight:0.02}",
            "collision_budget_by_task must name each task of the fleet once (left, straight, "
            "right), got left, straight",
        ),
        (
            "+agent.collision_budget_by_task={left:0.1,straight:0.02,right:1.5}",
            "agent.collision_budget_by_task.right must lie in [0, 1)",
        ),
        (
            "agent.collision_budget=null "
            "+agent.collision_budget_by_task={left:0.1,straight:0.1,right:0.1}",
            "collision_budget_by_task sets each task's collision budget: set agent.collision",
        ),
        (
            "federation=central +agent.collision_budget_by_task={left:0.1,straight:0.1,right:0.1}",
            "collision_budget_by_task needs a vehicle per task",
        ),
        (
            "agent.budget_noise_free_every=4",
            "agent.budget_noise_free_every=4 was retired: docs/studies.md",
        ),
    ],
)
def test_a_bad_override_to_frl_train(run_cli, override, text, tmp_path):
    result = run_cli("frl.train", *override.split(), f"run_dir={tmp_path / 'run'}", cwd=tmp_path)
    assert_one_line_error(result, "frl.train: config error:", text)
    assert not (tmp_path / "run").exists()


def test_a_device_torch_cannot_use_here_is_refused_before_any_directory(
    run_cli, tmp_path, monkeypatch
):
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    result = run_cli("frl.train", "device=cuda", f"run_dir={tmp_path / 'run'}", cwd=tmp_path)
    assert_one_line_error(result, "frl.train: config error:", "no usable cuda device")
    assert not (tmp_path / "run").exists()
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    result = run_cli("frl.train", "device=cuda:3", f"run_dir={tmp_path / 'run'}", cwd=tmp_path)
    assert_one_line_error(result, "frl.train: config error:", "has 1 cuda device (cuda:0)")
    assert not (tmp_path / "run").exists()


def test_python_m_frl_train_with_a_bad_override(tmp_path):
    result = run_for_real("frl.train", "interval=abc", cwd=tmp_path)
    assert_one_line_error(result, "frl.train: config error:", "could not be converted to Integer")


def test_a_bad_value_in_a_sweep_is_found_before_any_job(run_cli, tmp_path):
    result = run_cli("frl.train", "-m", "seed=0,x", cwd=tmp_path)
    assert_one_line_error(result, "frl.train: config error:", "seed=x")
    assert not (tmp_path / "multirun").exists()


@pytest.mark.parametrize("key", ["run_dir", "hydra.run.dir", "-m hydra.sweep.dir"])
def test_a_run_directory_that_cannot_be_made_is_refused_in_one_line(run_cli, key, tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    *flags, name = key.split()
    result = run_cli("frl.train", *flags, f"{name}={blocker / 'run'}", "seed=0", cwd=tmp_path)
    assert_one_line_error(result, "frl.train: config error:", f"{blocker} is not a directory")
    assert blocker.read_text() == "not a directory" and sorted(tmp_path.iterdir()) == [blocker]


def test_a_run_directory_on_an_unwritable_parent_is_refused_in_one_line(
    run_cli, monkeypatch, tmp_path
):
    # Root writes through permission bits, so the read-only parent (as on a read-only or
    # full mount) is what os.access reports for it.
    parent = tmp_path / "read-only"
    parent.mkdir()
    real_access = os.access
    monkeypatch.setattr(
        os, "access", lambda path, mode: Path(path) != parent and real_access(path, mode)
    )
    # Tiny, so that without the check the run ends quickly and the assertions fail.
    overrides = [*TINY_OVERRIDES, "eval_episodes=0", f"run_dir={parent / 'run'}"]
    result = run_cli("frl.train", *overrides, cwd=tmp_path)
    assert_one_line_error(result, "frl.train: config error:", f"{parent} is not writable")
    assert sorted(tmp_path.rglob("*")) == [parent]


def test_resuming_a_directory_with_no_run(run_cli, tmp_path):
    result = run_cli("frl.train", f"resume={tmp_path}", cwd=tmp_path)
    assert_one_line_error(result, "frl.train: config error:", "no checkpointed run there")


@pytest.fixture
def finished_looking_run(tmp_path: Path) -> Path:
    """A run directory with a valid config and a model index, but no real models."""
    run_dir = tmp_path / "run"
    (run_dir / "models").mkdir(parents=True)
    OmegaConf.save(compose_config(run_dir), run_dir / "config.yaml")
    write_json_atomic(run_dir / "models" / "index.json", {"left": "global.pt"})
    return run_dir


def test_frl_evaluate_on_a_directory_that_is_no_run(run_cli, tmp_path):
    result = run_cli("frl.evaluate", str(tmp_path), cwd=tmp_path)
    assert_one_line_error(result, "frl.evaluate: error:", "is not an frl run directory")


def test_frl_evaluate_with_a_missing_model(run_cli, finished_looking_run):
    result = run_cli("frl.evaluate", str(finished_looking_run), cwd=finished_looking_run)
    assert_one_line_error(result, "frl.evaluate: error:", "no such file")


def test_frl_evaluate_with_a_corrupt_model(finished_looking_run):
    (finished_looking_run / "models" / "global.pt").write_bytes(b"PK\x03\x04 not a checkpoint")
    result = run_for_real("frl.evaluate", str(finished_looking_run), cwd=finished_looking_run)
    assert_one_line_error(result, "frl.evaluate: error:", "is not a readable checkpoint")


def test_frl_evaluate_with_a_corrupt_config(run_cli, finished_looking_run):
    (finished_looking_run / "config.yaml").write_text("seed: [\n")
    result = run_cli("frl.evaluate", str(finished_looking_run), cwd=finished_looking_run)
    assert_one_line_error(result, "frl.evaluate: error:", "is not a readable config")


def test_a_negative_seed_is_refused_before_any_directory(run_cli, tmp_path):
    result = run_cli("frl.train", "seed=-1", cwd=tmp_path)
    assert_one_line_error(result, "frl.train: config error:", "seed must be a non-negative")
    assert list(tmp_path.iterdir()) == []  # not even Hydra's output directory


@pytest.mark.parametrize("seed", ["-3", "1.5"])
def test_frl_evaluate_refuses_a_seed_that_is_no_seed(run_cli, seed, tmp_path):
    result = run_cli("frl.evaluate", "--policy", "oracle", "--seed", seed, cwd=tmp_path)
    assert_one_line_error(result, "python -m frl.evaluate: error:", "a seed is a non-negative")


def test_python_m_frl_demo_refuses_a_negative_seed(tmp_path):
    result = run_for_real("frl.demo", "--seed", "-2", cwd=tmp_path)
    assert_one_line_error(result, "python -m frl.demo: error:", "a seed is a non-negative")


@pytest.mark.parametrize("content", ["{not json", "[1, 2]"])
def test_resuming_a_run_whose_state_is_corrupt(run_cli, finished_looking_run, content):
    (finished_looking_run / "state.json").write_text(content)
    cwd = finished_looking_run.parent
    result = run_cli("frl.train", f"resume={finished_looking_run}", cwd=cwd)
    assert_one_line_error(result, "frl.train: config error:", "state.json: not a readable run")
    assert sorted(p.name for p in cwd.iterdir()) == ["run"]  # no Hydra directory either


def test_a_vehicle_that_dies_stops_the_run_in_one_line_that_says_how_to_resume(
    run_cli, monkeypatch, tmp_path
):
    real_train = train.train

    def kill_a_worker_after_round_1(state):
        if state.completed_rounds == 1:
            victim = next(p for p in multiprocessing.active_children() if "client1" in p.name)
            os.kill(victim.pid, signal.SIGKILL)

    monkeypatch.setattr(
        train, "train", lambda cfg: real_train(cfg, on_round_end=kill_a_worker_after_round_1)
    )
    run_dir = tmp_path / "run"
    overrides = [*TINY_OVERRIDES, "eval_episodes=0", "federation.tasks=[left,right]"]
    result = run_cli("frl.train", *overrides, f"run_dir={run_dir}", cwd=tmp_path)

    assert result.returncode == 1
    assert "Traceback" not in result.stderr + result.stdout
    ours = [line for line in result.stderr.splitlines() if line.startswith("frl.train:")]
    assert len(ours) == 1, result.stderr
    assert "vehicle client1_right failed" in ours[0] and "SIGKILL" in ours[0]
    assert "round 1 is saved" in ours[0]
    command = f"python -m frl.train resume={run_dir}"
    assert command in ours[0]
    assert "Traceback" in (run_dir / "failure.log").read_text()
    assert multiprocessing.active_children() == []

    monkeypatch.setattr(train, "train", real_train)  # the printed command finishes the run
    resumed = run_cli("frl.train", f"resume={run_dir}", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    state = json.loads((run_dir / "state.json").read_text())
    assert state["completed_rounds"] == 3 and state["training_finished"]
