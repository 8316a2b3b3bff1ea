"""Test a trained run: 100 episodes per task, exploration off (Section IV.B).

    python -m frl.evaluate RUN_DIR [--episodes N] [--no-progress] [--no-tensorboard]

Runs automatically at the end of ``python -m frl.train``. Each task is tested with the
model the scheme deploys for it (``models/index.json``): FedAvg-DDPG's one global model,
Sep-DDPG's task model, Central-DDPG's one model. Episodes run on SUMO seeds from a
branch disjoint from training (odd seeds; training uses even ones) with test traffic of
one human arrival per ``eval_arrival_period_steps`` (10) steps; every scheme trained with
the same ``seed`` meets the same test traffic. Each task runs in its own worker process
(one SUMO each). Results are merged into ``RUN_DIR/results.json`` atomically and printed.
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from frl.agents import DDPG
from frl.envs import EnvConfig, IntersectionEnv, RewardConfig
from frl.episodes import (
    TRAVEL_TIME_DEFINITION,
    EpisodeRecord,
    average_over_tasks,
    run_episode,
    summarize,
)
from frl.federation.plan import evaluation_seeds
from frl.federation.workers import WorkerPool, threads_per_worker
from frl.fileio import read_json, write_json_atomic

RESULTS_FILE = "results.json"


class PolicyEvaluator:
    """Hosts one test environment and one saved model (one per worker process)."""

    def __init__(
        self, env: EnvConfig, reward: RewardConfig, model_path: str, device: str = "cpu"
    ) -> None:
        self.env = IntersectionEnv(env, reward)
        self.agent = DDPG.from_checkpoint(
            model_path, self.env.observation_space, self.env.action_space, device=device
        )

    def run(
        self, task: str, seeds: list[int], progress: Callable[..., None] | None = None
    ) -> list[EpisodeRecord]:
        """One deterministic-policy episode per seed."""
        records = []
        policy = functools.partial(self.agent.act, explore=False)
        for number, seed in enumerate(seeds, start=1):
            records.append(run_episode(self.env, policy, task, seed))
            if progress is not None:
                progress(episodes=number)
        return records

    def close(self) -> None:
        self.env.close()


def evaluate_run(
    run_dir: str | os.PathLike[str],
    episodes: int | None = None,
    progress: bool = False,
    log_tensorboard: bool = True,
    verbose: bool = True,
) -> dict[str, Any]:
    """Test the run's final model(s); merge ``evaluation`` into results.json; return it.

    ``episodes`` overrides the run's ``eval_episodes``.
    """
    from frl.train_config import load_run_config, validate

    run_dir = Path(run_dir)
    settings = validate(load_run_config(run_dir))
    episodes = settings.eval_episodes if episodes is None else int(episodes)
    if episodes <= 0:
        raise ValueError(f"episodes must be positive, got {episodes}")
    index_path = run_dir / "models" / "index.json"
    if not index_path.exists():
        raise FileNotFoundError(
            f"{run_dir} has no models/index.json: training has not finished "
            "(resume it with `python -m frl.train resume=RUN_DIR`)"
        )
    model_files: dict[str, str] = read_json(index_path)
    tasks = list(model_files)
    clients = [
        (
            f"eval_{task}",
            functools.partial(
                PolicyEvaluator,
                settings.eval_env(task),
                settings.reward,
                os.fspath(run_dir / "models" / model_files[task]),
                settings.device,
            ),
        )
        for task in tasks
    ]
    seeds = {task: evaluation_seeds(settings.seed, task, episodes) for task in tasks}
    bar = _progress_bar(progress, episodes * len(tasks))
    done = [0] * len(tasks)

    def on_progress(index: int, info: dict[str, Any]) -> None:
        done[index] = int(info["episodes"])
        bar.update(sum(done) - bar.n)

    try:
        with WorkerPool(
            clients,
            num_threads=threads_per_worker(len(clients)),
            timeout_s=settings.worker_timeout_s,
        ) as pool:
            records = pool.call(
                "run", args=[(task, seeds[task]) for task in tasks], on_progress=on_progress
            )
    finally:
        bar.close()
    per_task = {task: summarize(r) for task, r in zip(tasks, records, strict=True)}
    average = average_over_tasks(per_task)
    evaluation = {
        "episodes_per_task": episodes,
        "exploration": False,
        "arrival_period_steps": settings.eval_arrival_period_steps,
        "seeds": "odd SUMO seeds from SeedSequence(seed, spawn_key=(0xE7A1, task)); "
        "training uses even seeds",
        "models": model_files,
        "travel_time_definition": TRAVEL_TIME_DEFINITION,
        "per_task": per_task,
        "average": average,
    }
    results_path = run_dir / RESULTS_FILE
    results = read_json(results_path) if results_path.exists() else {}
    results["evaluation"] = evaluation
    write_json_atomic(results_path, results)
    if log_tensorboard:
        from frl.federation.tensorboard import TrainingLogger

        with TrainingLogger(run_dir / "tb") as logger:
            logger.log_evaluation(per_task, average, settings.plan.total_steps)
    if verbose:
        print(format_table(results))
    return evaluation


def format_table(results: dict[str, Any]) -> str:
    """The test table of a results.json (per task and averaged)."""
    evaluation = results["evaluation"]
    scheme = results.get("scheme", "?")
    header = (
        f"{scheme}, seed {results.get('seed', '?')}: {evaluation['episodes_per_task']} test "
        f"episodes per task, exploration off"
    )
    columns = f"{'task':<9} {'avg reward':>10} {'collision':>9} {'arrived':>8} {'timeout':>8} "
    columns += f"{'travel time':>11} {'ep. steps':>9}"
    lines = [header, columns, "-" * len(columns)]
    rows = [*evaluation["per_task"].items(), ("average", evaluation["average"])]
    for name, m in rows:
        travel = "-" if m["average_travel_time"] is None else f"{m['average_travel_time']:.1f}"
        lines.append(
            f"{name:<9} {m['average_reward']:>10.2f} {m['collision_rate']:>9.1%} "
            f"{m['arrival_rate']:>8.1%} {m['timeout_rate']:>8.1%} {travel:>11} "
            f"{m['average_episode_steps']:>9.1f}"
        )
    lines.append("travel time: steps to arrival, over arrived episodes only; ep. steps: all")
    return "\n".join(lines)


def _progress_bar(enabled: bool, total: int) -> Any:
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="episode", desc="evaluation", disable=not enabled)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m frl.evaluate", description=__doc__.splitlines()[0]
    )
    parser.add_argument("run_dir", type=Path, help="a run directory written by frl.train")
    parser.add_argument("--episodes", type=int, default=None, help="test episodes per task")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.add_argument(
        "--no-tensorboard", action="store_true", help="do not log eval/* to the run's tb/"
    )
    args = parser.parse_args(argv)
    if args.episodes is not None and args.episodes <= 0:
        parser.error("--episodes must be positive")
    try:
        evaluate_run(
            args.run_dir,
            episodes=args.episodes,
            progress=not args.no_progress,
            log_tensorboard=not args.no_tensorboard,
        )
    except (FileNotFoundError, ValueError) as error:
        print(f"frl.evaluate: error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
