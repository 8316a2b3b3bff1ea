"""Synthetic run directories for the report tests (not a test module).

They hold what ``frl.train`` writes and the report reads: ``results.json``,
``config.yaml``, ``state.json`` and TensorBoard events from frl's own logger.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from frl.federation.tensorboard import TrainingLogger
from frl.fileio import write_json_atomic

REWARDS = {
    "paper": {"name": "paper", "alpha": -0.05, "lambda_": -10.0},
    "reference": {"name": "reference", "alpha": -0.01, "lambda_": -1.0},
    "alpha-0.005_lambda-10": {"name": "paper", "alpha": -0.005, "lambda_": -10.0},
}
TASKS = ("left", "straight", "right")


def make_run(
    run_dir: Path,
    scheme: str,
    seed: int,
    *,
    total_steps: int = 20,
    interval: int = 10,
    reward: str = "paper",
    episodes: dict[str, list[tuple[int, float]]] | None = None,
    step_rewards: np.ndarray | None = None,
    evaluation: dict | None = None,
    total_bytes: int = 0,
    wall_time_s: float = 60.0,
    learning_starts: int = 0,
    round_tests: list[tuple[float, ...]] | None = None,
    round_test_yardsticks: dict[str, tuple[float, float, float]] | None = None,
) -> Path:
    """A finished run. ``episodes``: per client, (end step, return) pairs; ``round_tests``:
    the per-round test curve's (step, mean test return[, collisions, arrivals]) points;
    ``round_test_yardsticks``: each yardstick's (return, collisions, arrivals) on them."""
    clients = (
        ["client0_random"]
        if scheme == "central"
        else [f"client{i}_{t}" for i, t in enumerate(TASKS)]
    )
    if episodes is None:
        episodes = {c: [(10, 5.0), (20, 7.0)] for c in clients}
    if step_rewards is None:
        step_rewards = np.linspace(0.0, 1.0, total_steps)
    with TrainingLogger(run_dir / "tb") as logger:
        for step, value in enumerate(step_rewards.tolist(), start=1):
            logger.writer.add_scalar("train/step_reward", value, step)
        for client, rows in episodes.items():
            for end_step, episode_return in rows:
                logger.writer.add_scalar(f"{client}/episode_return", episode_return, end_step)
                logger.writer.add_scalar(f"{client}/episode_collision", 0, end_step)
                logger.writer.add_scalar(f"{client}/episode_arrived", 1, end_step)
                logger.writer.add_scalar(f"{client}/episode_travel_time_steps", 10, end_step)
    config = {
        "seed": seed,
        "total_steps": total_steps,
        "interval": interval,
        "eval_episodes": 100 if evaluation else 0,
        "reward": REWARDS[reward],
        "federation": {"scheme": scheme},
        "agent": {"learning_starts": learning_starts},
    }
    (run_dir / "config.yaml").write_text(yaml.safe_dump(config))
    write_json_atomic(run_dir / "state.json", {"training_finished": True})
    results = {
        "scheme": scheme,
        "seed": seed,
        "interval": interval,
        "total_steps": total_steps,
        "clients": clients,
        "communication": {"total_bytes": total_bytes},
        "training": {
            "steps_per_client": total_steps,
            "wall_time_s": wall_time_s,
            "final_step_reward": float(np.mean(step_rewards[-2:])),
        },
        "versions": {"git_commit": "0123456789abcdef"},
        "job_wall_time_s": wall_time_s,
    }
    if evaluation is not None:
        results["evaluation"] = evaluation
    if round_tests is not None:
        names = ("average_reward", "collision_rate", "arrival_rate")
        points = [
            {
                "step": point[0],
                "per_task": {},
                "average": dict(zip(names[: len(point) - 1], point[1:], strict=True)),
            }
            for point in round_tests
        ]
        results["round_tests"] = {"episodes_per_task": 20, "points": points}
        if round_test_yardsticks is not None:
            results["round_tests"]["yardsticks"] = {
                name: {"per_task": {}, "average": dict(zip(names, values, strict=True))}
                for name, values in round_test_yardsticks.items()
            }
    write_json_atomic(run_dir / "results.json", results)
    return run_dir


def evaluation(reward: float, collision: float, steps: float) -> dict:
    """Every task (and the average) with the same metrics."""
    metrics = {
        "average_reward": reward,
        "collision_rate": collision,
        "arrival_rate": 1 - collision,
        "timeout_rate": 0.0,
        "average_travel_time": steps,
        "average_episode_steps": steps,
        "episodes": 100,
    }
    return {"per_task": {t: dict(metrics) for t in TASKS}, "average": dict(metrics)}
