"""Does a collision budget's cost critic know the risk it prices? Predicted against observed.

    python benchmarks/cost_calibration.py RUN_DIR [RUN_DIR ...] [--episodes 100]
        [--tasks left,straight,right]

Replays each run's test episodes (the seeds ``python -m frl.evaluate`` uses) with its
model, exploration off, and at every step reads the cost critic's Q_c(s_t, a_t): the
discounted collisions to come. What happened gives the observed value of each step,
gamma^(T - t) if the episode ended in a collision at step T, else 0. Prints per task:

- every step, binned by the prediction: mean predicted against mean observed, and how
  many steps fall in each bin (a calibrated critic has the two equal in every bin);
- the episode's first step, where the prediction is the discounted risk of the whole
  crossing: mean predicted, mean observed, and the mean prediction over the episodes
  that collided against those that did not (a critic that tells them apart ranks the
  first above the second);
- the largest prediction over each episode, collided against clean.

Only runs trained with ``agent.collision_budget`` have a cost critic.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from frl import run_directory as rundir
from frl.agents import DDPG
from frl.envs import TASKS, IntersectionEnv
from frl.evaluate import run_settings
from frl.federation.assembly import evaluation_env
from frl.federation.plan import evaluation_seeds
from frl.policies import load_model

BINS = (0.0, 0.01, 0.03, 0.1, 0.3, np.inf)
"""Edges of the prediction bins (the last open above)."""


@dataclass
class Calibration:
    predicted: list[float] = field(default_factory=list)
    observed: list[float] = field(default_factory=list)
    first_predicted: list[float] = field(default_factory=list)
    first_observed: list[float] = field(default_factory=list)
    largest: list[float] = field(default_factory=list)
    collided: list[bool] = field(default_factory=list)


def replay(env: IntersectionEnv, agent: DDPG, task: str, seed: int, into: Calibration) -> None:
    """One test episode with the model; adds its steps' predictions and outcomes."""
    observation, _ = env.reset(seed=seed, options={"task": task})
    agent.episode_start()
    observations, actions = [], []
    while True:
        action = agent.act(observation, explore=False)
        observations.append(observation)
        actions.append(action)
        observation, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    predicted = agent.critic_values(np.stack(observations), np.stack(actions), cost=True)
    steps = len(actions)
    collided = bool(info["collision"])
    to_go = np.arange(steps - 1, -1, -1)
    observed = agent.config.gamma**to_go if collided else np.zeros(steps)
    into.predicted += predicted.tolist()
    into.observed += observed.tolist()
    into.first_predicted.append(float(predicted[0]))
    into.first_observed.append(float(observed[0]))
    into.largest.append(float(predicted.max()))
    into.collided.append(collided)


def calibrate(run_dir: Path, tasks: list[str], episodes: int) -> dict[str, Calibration]:
    settings = run_settings(run_dir)
    if settings.agent.collision_budget is None:
        raise SystemExit(f"{run_dir}: trained without agent.collision_budget, no cost critic")
    files = rundir.model_files(run_dir)
    found = {}
    for task in [task for task in tasks if task in files]:
        env = IntersectionEnv(evaluation_env(settings, task), settings.reward)
        try:
            agent = load_model(files[task][0], env)
            found[task] = Calibration()
            for seed in evaluation_seeds(settings.seed, task, episodes):
                replay(env, agent, task, seed, found[task])
        finally:
            env.close()
    return found


def _mean(values: list[float] | np.ndarray) -> str:
    return f"{np.mean(values):.3f}" if len(values) else "-"


def print_tables(rows: list[tuple[str, str, Calibration]]) -> None:
    edges = list(itertools.pairwise(BINS))
    labels = [f"[{lo:g}, {hi:g})" if lo > 0 else f"< {hi:g}" for lo, hi in edges]
    print("Every step: mean predicted / mean observed (steps), by predicted Q_c\n")
    print("| run | task | " + " | ".join(labels) + " |")
    print("|---|---|" + "---|" * len(labels))
    for run, task, c in rows:
        predicted, observed = np.asarray(c.predicted), np.asarray(c.observed)
        cells = []
        for lo, hi in edges:
            inside = (predicted >= lo) & (predicted < hi) if lo > 0 else predicted < hi
            cells.append(
                f"{_mean(predicted[inside])} / {_mean(observed[inside])} ({int(inside.sum())})"
            )
        print(f"| {run} | {task} | " + " | ".join(cells) + " |")
    print("\nEach episode: Q_c at its first step and its largest Q_c, collided against clean\n")
    print(
        "| run | task | episodes | collisions | first step: predicted / observed | "
        "first step: collided / clean | largest: collided / clean |"
    )
    print("|---|---|---|---|---|---|---|")
    for run, task, c in rows:
        hit = np.asarray(c.collided)
        first, largest = np.asarray(c.first_predicted), np.asarray(c.largest)
        print(
            f"| {run} | {task} | {len(hit)} | {int(hit.sum())} | "
            f"{_mean(first)} / {_mean(c.first_observed)} | "
            f"{_mean(first[hit])} / {_mean(first[~hit])} | "
            f"{_mean(largest[hit])} / {_mean(largest[~hit])} |"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dirs", nargs="+", type=Path)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--tasks", default=",".join(TASKS))
    args = parser.parse_args(argv)
    tasks = args.tasks.split(",")
    unknown = sorted(set(tasks) - set(TASKS))
    if unknown or args.episodes < 1:
        parser.error(f"unknown task {unknown[0]!r}" if unknown else "--episodes must be >= 1")
    torch.set_num_threads(1)
    rows = []
    for run_dir in args.run_dirs:
        for task, calibration in calibrate(run_dir, tasks, args.episodes).items():
            rows.append((f"{run_dir.parent.name}/{run_dir.name}", task, calibration))
    print_tables(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
