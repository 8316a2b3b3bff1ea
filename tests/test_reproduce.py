"""The reproduction path on real, tiny runs: resume=auto continues a killed run, skips a
finished one, and the report reads the run directory ``frl.train`` wrote; then one
subprocess sweep of a figure preset through ``python -m frl.reproduce`` (its rerun skips
the same way: it runs train() with resume=auto in the same directory)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from train_helpers import TINY_OVERRIDES, compose_config

from frl import run_directory as rundir
from frl.federation.tensorboard import TrainingLogger
from frl.report.runs import export_run, has_complete_results, load_run
from frl.train import train

ONE_CLIENT = [
    "federation=central",
    "federation.tasks=[left]",
    "total_steps=160",
    "eval_episodes=1",
    "resume=auto",
]
"""One agent, two rounds of 80 steps."""


class _Killed(Exception):
    pass


def test_auto_resumes_a_killed_run_skips_a_finished_one_and_the_report_reads_it(tmp_path):
    run_dir = tmp_path / "fig4" / "central-seed0"
    cfg = compose_config(run_dir, ONE_CLIENT)
    with TrainingLogger(run_dir / "tb") as stale:  # a session killed before its first commit
        for step in range(1, 6):
            stale.writer.add_scalar("train/step_reward", 99.0, step)

    def kill_after_first_round(state):
        if state.completed_rounds == 1:
            raise _Killed

    with pytest.raises(_Killed):
        train(cfg, on_round_end=kill_after_first_round)
    assert not has_complete_results(run_dir)

    results = train(cfg)  # continues from round 1
    assert results["rounds"] == 2 and has_complete_results(run_dir)
    events = sorted((run_dir / "tb").iterdir())
    saved = (run_dir / "results.json").read_text()

    assert train(cfg) == json.loads(saved)  # skipped: nothing trained, nothing written
    assert sorted((run_dir / "tb").iterdir()) == events
    assert (run_dir / "results.json").read_text() == saved

    run = load_run(run_dir)
    every_step = np.load(run_dir / "step_rewards.npy")
    np.testing.assert_array_equal(run.step_rewards, every_step)
    assert run.step_rewards.size == 160
    # TensorBoard: a mean per window of each round's steps (rounds of 80 steps, windows of
    # 100), the killed sessions' events purged, not doubled.
    events = EventAccumulator(str(run_dir / "tb"), size_guidance={"scalars": 0})
    events.Reload()
    logged = events.Scalars("train/step_reward")
    assert [event.step for event in logged] == [80, 160]
    means = every_step.reshape(2, 80).mean(axis=1)
    np.testing.assert_allclose([event.value for event in logged], means, rtol=1e-6)
    (client,) = run.episodes
    assert client == "client0_random"
    assert run.episodes[client].end_step.size == results["training"]["episodes"][client]
    assert run.evaluation["per_task"]["left"]["episodes"] == 1
    exported = load_run(export_run(run_dir, tmp_path / "data" / "fig4" / run_dir.name))
    np.testing.assert_allclose(exported.step_rewards, run.step_rewards, rtol=1e-6)


def test_auto_tests_a_trained_run_whose_test_failed_without_training_again(tmp_path, monkeypatch):
    run_dir = tmp_path / "fig4" / "central-seed0"
    cfg = compose_config(run_dir, ONE_CLIENT)

    def failing_test(*args, **kwargs):
        raise RuntimeError("test stopped")

    monkeypatch.setattr("frl.evaluate.evaluate_run", failing_test)
    with pytest.raises(RuntimeError, match="test stopped"):
        train(cfg)
    assert "evaluation" not in json.loads((run_dir / "results.json").read_text())
    assert not has_complete_results(run_dir) and not rundir.is_finished(run_dir)
    monkeypatch.undo()

    rounds_seen = []
    results = train(cfg, on_round_end=lambda s: rounds_seen.append(s.completed_rounds))

    assert rounds_seen == [] and results["rounds"] == 2  # tested, not trained
    assert results["evaluation"]["per_task"]["left"]["episodes"] == 1
    assert has_complete_results(run_dir) and rundir.is_finished(run_dir)


def test_reproduce_runs_a_preset_sweep_exports_and_reports(tmp_path):
    overrides = [o for o in TINY_OVERRIDES if not o.startswith("progress")]
    command = [
        sys.executable,
        "-m",
        "frl.reproduce",
        "--figures",
        "fig5",
        "--seeds",
        "0",
        "--runs-dir",
        str(tmp_path / "runs"),
        "--data-dir",
        str(tmp_path / "data"),
        "--report",
        str(tmp_path / "results.md"),
        "--",
        "federation=central",
        "federation.tasks=[left]",
        *overrides,
        "total_steps=160",
        "eval_episodes=0",
        "round_test_episodes=1",  # the preset's 20, shrunk
    ]
    repo = Path(__file__).resolve().parents[1]

    def reproduce() -> subprocess.CompletedProcess:
        return subprocess.run(
            command,
            cwd=repo,
            env={**os.environ, "HYDRA_FULL_ERROR": "1"},
            capture_output=True,
            text=True,
            timeout=300,
        )

    done = reproduce()
    assert done.returncode == 0, done.stderr[-3000:]
    run_dir = tmp_path / "runs" / "fig4" / "central-seed0"
    assert has_complete_results(run_dir)
    data = tmp_path / "data" / "fig4" / "central-seed0"
    assert sorted(p.name for p in data.iterdir()) == [
        "config.yaml",
        "episodes.csv",
        "results.json",
        "step_rewards.csv",
    ]
    report = (tmp_path / "results.md").read_text()
    assert "| Central-DDPG | 1 (0) |" in report and (tmp_path / "results" / "fig4.png").exists()
    assert json.loads((data / "results.json").read_text()) == json.loads(
        (run_dir / "results.json").read_text()
    )
    exported = json.loads((data / "results.json").read_text())
    assert [point["step"] for point in exported["round_tests"]["points"]] == [80, 160]


def test_reproduce_runs_jobs_side_by_side_each_on_its_share(tmp_path):
    overrides = [o for o in TINY_OVERRIDES if not o.startswith("progress")]
    command = [
        sys.executable, "-m", "frl.reproduce", "--jobs", "2", "--figures", "fig4",
        "--seeds", "0,1", "--runs-dir", str(tmp_path / "runs"), "--data-dir",
        str(tmp_path / "data"), "--no-report", "--", "federation=central",
        "federation.tasks=[left]", *overrides, "total_steps=160", "eval_episodes=0",
        "round_test_episodes=0",
    ]  # fmt: skip
    repo = Path(__file__).resolve().parents[1]
    done = subprocess.run(command, cwd=repo, capture_output=True, text=True, timeout=300)

    assert done.returncode == 0, done.stderr[-3000:]
    for seed in (0, 1):
        run_dir = tmp_path / "runs" / "fig4" / f"central-seed{seed}"
        assert has_complete_results(run_dir)
        assert "cores: 1\n" in (run_dir / "config.yaml").read_text()
        assert (tmp_path / "data" / "fig4" / f"central-seed{seed}" / "results.json").exists()
    logs = sorted(p.name for p in (tmp_path / "runs" / "logs").iterdir())
    assert logs == ["fig4_seed=0.log", "fig4_seed=1.log"]
    assert "finished" in done.stderr and "started fig4 seed=1" in done.stderr
