"""A run's actor made bang-bang at test: full throttle where its action exceeds a threshold,
full brake elsewhere, on the run's own test episodes.

    python scripts/bang_bang.py RUN_DIR [--thresholds 0,0.25,0.5]

The rules are bang-bang; the learned actor often answers in between (a gentle
acceleration where the committed rule brakes). This drives the run's model, its action
replaced by +1 or -1 by its sign against each threshold, on the episodes ``python -m
frl.evaluate`` tests it on, and prints the test table's averages beside the run's own.
The model is unchanged; only how its answer is executed differs. A model that learned one
policy for every task (FedAvg, Central) is read from its first task's file.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from frl import run_directory as rundir
from frl.envs import IntersectionEnv
from frl.envs.config import traffic_name
from frl.evaluate import evaluate_policy, run_settings
from frl.federation.assembly import evaluation_env
from frl.policies import load_model


def bang_bang(actor: Callable[[Any], np.ndarray], threshold: float) -> Callable[[Any], np.ndarray]:
    """``actor`` with its action replaced by +1 above ``threshold`` and -1 elsewhere."""

    def act(observation: Any) -> np.ndarray:
        action = float(np.asarray(actor(observation)).reshape(-1)[0])
        return np.array([1.0 if action > threshold else -1.0], dtype=np.float32)

    return act


def summary(average: dict[str, Any]) -> str:
    """Return / collisions / arrivals / travel time of a test table's averages."""
    return (
        f"{average['average_reward']:.2f} / {100 * average['collision_rate']:.1f}% / "
        f"{100 * average['arrival_rate']:.1f}% / {average['average_travel_time']:.1f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--thresholds", default="0")
    args = parser.parse_args()
    try:
        thresholds = [float(value) for value in args.thresholds.split(",")]
        files = rundir.model_files(args.run_dir)
    except (ValueError, FileNotFoundError) as error:
        parser.error(str(error))
    settings = run_settings(args.run_dir)
    if len({str(paths[0]) for paths in files.values()}) != 1:
        parser.error(f"{args.run_dir}: one model per task; this probe reads one model")
    task, paths = next(iter(files.items()))
    env = IntersectionEnv(evaluation_env(settings, task), settings.reward)
    agent = load_model(paths[0], env)
    env.close()
    own = json.loads((args.run_dir / rundir.RESULTS_FILE).read_text())["evaluation"]
    print(f"{args.run_dir.name}: the run's own test {summary(own['average'])}")
    for threshold in thresholds:
        actor = bang_bang(lambda o: agent.act(o, explore=False), threshold)
        evaluation = evaluate_policy(
            actor, traffic=traffic_name(settings.env.scenario), seed=settings.seed,
            episodes=settings.eval_episodes, yardsticks=(), verbose=False,
            route_observation=settings.env.route_observation,
            window_observation=settings.env.window_observation,
        )  # fmt: skip
        per_task = " / ".join(
            f"{100 * evaluation['per_task'][t]['collision_rate']:.0f}"
            for t in evaluation["per_task"]
        )
        print(
            f"{args.run_dir.name}: bang-bang at {threshold:+.2f}: "
            f"{summary(evaluation['average'])} (collisions per task {per_task} %)"
        )


if __name__ == "__main__":
    main()
