"""Test a trained run, or a yardstick policy, on 100 seeded episodes per task (Section IV.B).

    python -m frl.evaluate RUN_DIR [--episodes N]            # the run's model(s) + yardsticks
    python -m frl.evaluate --policy oracle --task all         # a yardstick on the default traffic
    python -m frl.evaluate --policy all --traffic dense --seed 1
    python -m frl.evaluate RUN_DIR --policy gap_acceptance    # a yardstick on a run's seeds
    python -m frl.evaluate RUN_DIR --round-tests              # its yardsticks on its curve's seeds

Runs automatically at the end of ``python -m frl.train``. Each task is tested with the
model the scheme deploys for it (``models/index.json``): FedAvg-DDPG's one global model,
Sep-DDPG's task model, Central-DDPG's one model. Episodes run on SUMO seeds from a
branch disjoint from training (odd seeds; training uses even ones) on the training
traffic; every scheme and every yardstick tested with the same ``seed`` meets the same
traffic. Each task runs in its own worker process (one SUMO each). The run's
``yardsticks`` (full throttle and the oracle by default) are tested on the same seeds,
cached per traffic and seeds (frl.yardsticks). Results are merged into
``RUN_DIR/results.json`` atomically and printed.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym

from frl import run_directory as rundir
from frl import yardsticks as yardstick_cache
from frl.agents.checkpoint import read_checkpoint
from frl.cli import OneLineParser, seed_value
from frl.envs import TASKS, TRAFFIC_PRESETS, EnvConfig, IntersectionEnv, RewardConfig
from frl.envs.config import traffic_name
from frl.episodes import (
    TRAVEL_TIME_DEFINITION,
    EpisodeRecord,
    average_over_tasks,
    run_episode,
    run_episodes,
    summarize,
)
from frl.federation.assembly import evaluation_env, worker_threads
from frl.federation.plan import evaluation_seeds, round_test_seeds
from frl.federation.workers import WorkerPool, available_cores
from frl.policies import (
    DEFAULT_YARDSTICKS,
    YARDSTICK_LABELS,
    YARDSTICKS,
    load_model,
    make_yardstick,
)

MODEL = "model"
"""The policy name of a run's trained model(s) in :func:`evaluate_policies`."""
SEEDS_DEFINITION = (
    "odd SUMO seeds from SeedSequence(seed, spawn_key=(0xE7A1, task)); training uses even seeds"
)


class PolicyEvaluator:
    """Hosts one test environment and the task's saved model(s) (one per worker process):
    one, or Sep-DDPG's one per vehicle of a fleet, each driving every test seed."""

    def __init__(
        self,
        env: EnvConfig,
        reward: RewardConfig,
        model_path: str | Sequence[str] | None = None,
        device: str = "cpu",
    ) -> None:
        self.env = IntersectionEnv(env, reward)
        paths = [model_path] if isinstance(model_path, str) else list(model_path or [])
        self.agents = [load_model(path, self.env, device) for path in paths]

    def run(
        self,
        task: str,
        seeds: list[int],
        policy: str = MODEL,
        progress: Callable[..., None] | None = None,
    ) -> list[EpisodeRecord]:
        """One episode per seed with ``policy``: the model (exploration off) or a yardstick."""
        drivers: list[tuple[Callable[[Any], Any], Callable[[], None] | None]] = []
        if policy == MODEL:
            if not self.agents:
                raise ValueError("this evaluator holds no model")
            drivers = [
                (functools.partial(agent.act, explore=False), agent.episode_start)
                for agent in self.agents
            ]
        else:
            drivers = [(make_yardstick(policy, self.env), None)]
        records = []
        for act, on_reset in drivers:
            for seed in seeds:
                records.append(run_episode(self.env, act, task, seed, on_reset))
                if progress is not None:
                    progress(episodes=len(records) / len(drivers))
        return records

    def close(self) -> None:
        self.env.close()


def evaluate_policies(
    settings: Any,
    tasks: Sequence[str],
    episodes: int,
    policies: Sequence[str],
    model_files: dict[str, str | list[str]] | None = None,
    progress: bool = False,
    seeds: Mapping[str, Sequence[int]] | None = None,
) -> dict[str, dict[str, dict[str, Any]]]:
    """Test each policy on each task's test seeds; ``{policy: {task: summary}}``.

    ``settings`` is a :class:`frl.train_config.TrainSettings`. ``model_files`` maps each
    task to its saved model, or models (needed when ``policies`` holds :data:`MODEL`);
    several models of a task each drive every seed and their episodes are pooled.
    ``seeds`` maps each task to the SUMO seeds to drive (``episodes`` of them); the
    default is the final test's. Yardsticks come from the cache when they ran on the
    same environment, reward and seeds before.
    """
    if seeds is None:
        seeds = {task: evaluation_seeds(settings.seed, task, episodes) for task in tasks}
    elif any(len(seeds[task]) != episodes for task in tasks):
        raise ValueError(f"every task needs {episodes} seeds")
    seeds = {task: [int(seed) for seed in seeds[task]] for task in tasks}
    results: dict[str, dict[str, dict[str, Any]]] = {name: {} for name in policies}
    keys: dict[tuple[str, str], str] = {}
    for name in policies:
        if name == MODEL:
            continue
        for task in tasks:
            key = yardstick_cache.cache_key(
                name, evaluation_env(settings, task), settings.reward, seeds[task]
            )
            cached = yardstick_cache.load(key)
            if cached is not None:
                results[name][task] = cached
            else:
                keys[name, task] = key
    to_run = [name for name in policies if name == MODEL or any((name, t) in keys for t in tasks)]
    if not to_run:
        return results
    clients = [
        (
            f"eval_{task}",
            functools.partial(
                PolicyEvaluator,
                evaluation_env(settings, task),
                settings.reward,
                _paths(model_files[task]) if model_files and MODEL in to_run else None,
                settings.device,
            ),
        )
        for task in tasks
    ]
    with WorkerPool(
        clients,
        num_threads=worker_threads(settings, len(clients)),
        timeout_s=settings.worker_timeout_s,
    ) as pool:
        for name in to_run:
            todo = [t for t in tasks if name == MODEL or (name, t) in keys]
            bar = _progress_bar(progress, episodes * len(todo), _label(name))
            done = [0] * len(tasks)

            def on_progress(
                index: int, info: dict[str, Any], bar: Any = bar, done: list[int] = done
            ) -> None:
                done[index] = int(info["episodes"])
                bar.update(sum(done) - bar.n)

            try:
                records = pool.call(
                    "run",
                    args=[(t, seeds[t] if t in todo else [], name) for t in tasks],
                    on_progress=on_progress,
                )
            finally:
                bar.close()
            for task, task_records in zip(tasks, records, strict=True):
                if task not in todo:
                    continue
                summary = summarize(task_records)
                results[name][task] = summary
                if name != MODEL:
                    yardstick_cache.store(keys[name, task], summary)
    return results


def _paths(files: str | os.PathLike[str] | Sequence[Any]) -> list[str]:
    return [os.fspath(files)] if isinstance(files, (str, os.PathLike)) else [
        os.fspath(f) for f in files]  # fmt: skip


def evaluate_policy(
    policy: Any,
    traffic: str = "paper",
    seed: int = 0,
    episodes: int = 100,
    tasks: Sequence[str] = TASKS,
    yardsticks: Sequence[str] = DEFAULT_YARDSTICKS,
    on_reset: Callable[[], None] | None = None,
    progress: bool = False,
    verbose: bool = True,
    route_observation: bool = False,
    window_observation: bool = False,
) -> dict[str, Any]:
    """Test any driver on frl's test protocol, beside the yardsticks on the same seeds.

    The episodes are those ``python -m frl.evaluate`` runs for a run with ``seed`` on the
    ``traffic`` preset (odd SUMO seeds, ``episodes`` per task, the paper's reward), so a
    Stable-Baselines3 or CleanRL agent is scored exactly as frl's models and yardsticks.

    Args:
        policy: a callable ``observation -> action``, or an object with
            ``predict(observation, deterministic=True) -> (action, state)`` (a
            Stable-Baselines3 model, :class:`frl.agents.DDPG`). It drives in this process,
            one task after the other.
        on_reset: called after every reset (a recurrent policy's episode start).
        yardsticks: tested on the same seeds (cached, in worker processes); ``()`` for none.
        verbose: print the table (as ``frl.evaluate`` does).
        route_observation: the policy observes the ego's route beside the grid (a Dict
            observation, :attr:`frl.envs.EnvConfig.route_observation`), as it trained;
            the same episodes either way.
        window_observation: the policy observes the grid's crossing cars as times
            beside the grid (:attr:`frl.envs.EnvConfig.window_observation`), as it trained.

    Returns:
        ``{"per_task", "average", "yardsticks": {name: {"per_task", "average"}},
        "episodes_per_task", "traffic", "seed"}``, the keys of a run's ``evaluation``.

    Raises:
        ValueError: an unknown traffic, task or yardstick, a seed or episode count that
            is not a non-negative (positive) integer, or a policy that cannot act;
            all before any episode runs.
    """
    act = _policy_callable(policy)
    _check_observation_parts(policy, route_observation, window_observation)
    settings = default_settings(traffic, seed)  # refuses an unknown traffic, a bad seed
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes <= 0:
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    tasks = list(tasks)
    unknown = [task for task in tasks if task not in TASKS] or ([] if tasks else ["(none)"])
    if unknown:
        raise ValueError(f"unknown task {unknown[0]!r}; choose from {', '.join(TASKS)}")
    unknown = [name for name in yardsticks if name not in YARDSTICKS]
    if unknown:
        raise ValueError(f"unknown yardstick {unknown[0]!r}; choose from {', '.join(YARDSTICKS)}")
    per_task = {}
    bar = _progress_bar(progress, episodes * len(tasks), "policy")
    try:
        for task in tasks:
            env_config = dataclasses.replace(
                evaluation_env(settings, task),
                route_observation=route_observation,
                window_observation=window_observation,
            )
            env = IntersectionEnv(env_config, settings.reward)
            try:
                seeds = evaluation_seeds(seed, task, episodes)
                per_task[task] = summarize(run_episodes(env, act, task, seeds, on_reset))
            finally:
                env.close()
            bar.update(episodes)
    finally:
        bar.close()
    tested = evaluate_policies(settings, tasks, episodes, list(yardsticks), progress=progress)
    evaluation = {
        **_table(per_task),
        "yardsticks": {name: _table(tested[name]) for name in yardsticks},
        "episodes_per_task": episodes,
        "traffic": traffic,
        "seed": seed,
    }
    if verbose:
        print(format_table({"scheme": "policy", "seed": seed, "evaluation": evaluation}))
    return evaluation


def _check_observation_parts(policy: Any, route: bool, windows: bool) -> None:
    """A policy whose observation space is known must get the observation it expects."""
    space = getattr(policy, "observation_space", None)
    layout = getattr(policy, "layout", None)
    if layout is not None and getattr(layout, "parts", None) is not None:
        parts = set(layout.parts)
    elif isinstance(space, gym.spaces.Dict):
        parts = set(space.spaces)
    elif isinstance(space, gym.spaces.Box) or layout is not None:
        parts = set()
    else:
        return  # a plain callable: it gets what it asks for
    for part, option, given in (
        ("route", "route_observation", route),
        ("windows", "window_observation", windows),
    ):
        if (part in parts) != given:
            wanted = "observes" if part in parts else "does not observe"
            raise ValueError(
                f"this policy {wanted} the {part} beside the grid: pass {option}={part in parts}"
            )


def _policy_callable(policy: Any) -> Callable[[Any], Any]:
    """``observation -> action`` from a callable or a ``predict``-er."""
    predict = getattr(policy, "predict", None)
    if callable(predict):
        return lambda observation: predict(observation, deterministic=True)[0]
    if callable(policy):
        return policy
    raise ValueError(
        "policy must be a callable observation -> action or have "
        f"predict(observation, deterministic=True); got {type(policy).__name__}"
    )


def evaluate_run(
    run_dir: str | os.PathLike[str],
    episodes: int | None = None,
    progress: bool = False,
    log_tensorboard: bool = True,
    verbose: bool = True,
) -> dict[str, Any]:
    """Test the run's final model(s) and its yardsticks; merge ``evaluation`` into
    results.json; return it. ``episodes`` overrides the run's ``eval_episodes``."""
    run_dir = Path(run_dir)
    settings = run_settings(run_dir)
    episodes = settings.eval_episodes if episodes is None else int(episodes)
    if episodes <= 0:
        raise ValueError(f"episodes must be positive, got {episodes}")
    files = rundir.model_files(run_dir)
    for path in {p for paths in files.values() for p in paths}:
        read_checkpoint(path)  # a missing or corrupt model fails here, not in a worker
    model_files: dict[str, str | list[str]] = {
        task: paths[0].name if len(paths) == 1 else [p.name for p in paths]
        for task, paths in files.items()
    }
    tasks = list(model_files)
    paths: dict[str, str | list[str]] = {
        task: [os.fspath(p) for p in task_paths] for task, task_paths in files.items()
    }
    tested = evaluate_policies(
        settings, tasks, episodes, [MODEL, *settings.yardsticks], paths, progress
    )
    evaluation = {
        "episodes_per_task": episodes,
        "exploration": False,
        "traffic": traffic_name(settings.env.scenario),
        "human_arrival_period_steps": settings.env.scenario.human_arrival_period_steps,
        "seeds": SEEDS_DEFINITION,
        "models": model_files,
        "travel_time_definition": TRAVEL_TIME_DEFINITION,
        **_table(tested.pop(MODEL)),
        "yardsticks": {name: _table(per_task) for name, per_task in tested.items()},
    }
    rundir.merge_evaluation(run_dir, evaluation)
    if log_tensorboard:
        from frl.federation.tensorboard import TrainingLogger

        with TrainingLogger(run_dir / rundir.TB_DIR) as logger:
            step = settings.plan.total_steps
            logger.log_evaluation(evaluation["per_task"], evaluation["average"], step)
            for name, table in evaluation["yardsticks"].items():
                # Same seeds as eval/*: the model's line sits between these in TensorBoard.
                logger.log_evaluation(
                    table["per_task"], table["average"], step, prefix=f"eval_yardstick/{name}"
                )
    if verbose:
        print(format_table(rundir.read_results(run_dir) or {"evaluation": evaluation}))
    return evaluation


def _check_yardsticks(names: Sequence[str]) -> None:
    unknown = [name for name in names if name not in YARDSTICKS]
    if unknown:
        raise ValueError(f"unknown policy {unknown[0]!r}; choose one of {', '.join(YARDSTICKS)}")


def evaluate_yardsticks(
    names: Sequence[str],
    tasks: Sequence[str],
    run_dir: str | os.PathLike[str] | None = None,
    traffic: str | None = None,
    seed: int | None = None,
    episodes: int | None = None,
    progress: bool = False,
) -> dict[str, dict[str, Any]]:
    """Test yardsticks on a run's test seeds, or on the default config's; ``{name: table}``.

    With ``run_dir`` the run's config decides the traffic, reward and seeds, and the
    tables join the run's ``results.json`` when they match its evaluation's episodes.
    Without, the default config with the ``traffic`` preset and ``seed`` decides.
    """
    _check_yardsticks(names)
    if run_dir is not None:
        if traffic is not None or seed is not None:
            raise ValueError(
                "--traffic and --seed come from the run's config when RUN_DIR is given"
            )
        settings = run_settings(Path(run_dir))
    else:
        settings = default_settings(traffic or "paper", 0 if seed is None else seed)
    episodes = (settings.eval_episodes or 100) if episodes is None else int(episodes)
    if episodes <= 0:
        raise ValueError(f"episodes must be positive, got {episodes}")
    tested = evaluate_policies(settings, tasks, episodes, names, progress=progress)
    tables = {name: _table(per_task) for name, per_task in tested.items()}
    if run_dir is not None:
        results = rundir.read_results(Path(run_dir)) or {}
        evaluation = results.get("evaluation")
        if (
            evaluation
            and evaluation.get("episodes_per_task") == episodes
            and set(evaluation.get("per_task", {})) == set(tasks)
        ):
            evaluation.setdefault("yardsticks", {}).update(tables)
            rundir.write_results(Path(run_dir), results)
    header = (
        f"traffic {traffic_name(settings.env.scenario)}, seed {settings.seed}: "
        f"{episodes} test episodes per task"
    )
    print(header)
    for name, table in tables.items():
        print(_format_rows(_label(name), table))
    return tables


def evaluate_round_test_yardsticks(
    run_dir: str | os.PathLike[str],
    names: Sequence[str] | None = None,
    progress: bool = False,
    verbose: bool = True,
) -> dict[str, dict[str, Any]]:
    """Test yardsticks on the seeds of the run's per-round test curve; ``{name: table}``.

    The curve's model and these yardsticks then meet the same traffic, so each round's
    tested return can be paired with the gap-acceptance rule's seed by seed, as the final
    test is. ``names`` defaults to the run's ``yardsticks``. The tables join the run's
    ``results.json`` under ``round_tests.yardsticks``; ``frl.train`` calls this for every
    run made with ``round_test_episodes``.

    Raises:
        ValueError: the run has no per-round test curve, or a name is no yardstick.
    """
    run_dir = Path(run_dir)
    settings = run_settings(run_dir)
    names = list(settings.yardsticks if names is None else names)
    _check_yardsticks(names)
    results = rundir.read_results(run_dir) or {}
    curve = results.get("round_tests") or {}
    if not curve.get("points"):
        raise ValueError(
            f"{run_dir} has no per-round test curve: it was trained without round_test_episodes"
        )
    episodes = int(curve["episodes_per_task"])
    tasks = list(curve["points"][0]["per_task"])
    seeds = {
        task: round_test_seeds(settings.seed, task, episodes, settings.eval_episodes)
        for task in tasks
    }
    tested = evaluate_policies(settings, tasks, episodes, names, progress=progress, seeds=seeds)
    tables = {name: _table(per_task) for name, per_task in tested.items()}
    curve.setdefault("yardsticks", {}).update(tables)
    rundir.write_results(run_dir, results)
    if verbose:
        print(f"the per-round test seeds of {run_dir}: {episodes} episodes per task")
        for name, table in tables.items():
            print(_format_rows(_label(name), table))
    return tables


def default_settings(traffic: str, seed: int) -> Any:
    """The default training config on the ``traffic`` preset and ``seed``, validated."""
    from frl.train_config import validate

    if traffic not in TRAFFIC_PRESETS:
        raise ValueError(
            f"unknown traffic preset {traffic!r}; choose one of {', '.join(TRAFFIC_PRESETS)}"
        )
    return validate({"seed": seed, "env": {"scenario": dict(TRAFFIC_PRESETS[traffic])}})


def format_table(results: dict[str, Any]) -> str:
    """The test table of a results.json: the model per task, then its yardsticks."""
    evaluation = results["evaluation"]
    traffic = evaluation.get("traffic")
    header = (
        f"{results.get('scheme', '?')}, seed {results.get('seed', '?')}: "
        f"{evaluation['episodes_per_task']} test episodes per task, exploration off"
        + (f", traffic {traffic}" if traffic else "")
    )
    lines = [header, _format_rows("model", evaluation)]
    for name, table in evaluation.get("yardsticks", {}).items():
        lines.append(_format_rows(f"{_label(name)} (same seeds)", table, per_task=False))
    lines.append("travel time: steps to arrival, over arrived episodes only; ep. steps: all")
    return "\n".join(lines)


def _format_rows(title: str, table: dict[str, Any], per_task: bool = True) -> str:
    columns = f"{title:<37} {'avg reward':>10} {'collision':>9} {'arrived':>8} {'timeout':>8} "
    columns += f"{'travel time':>11} {'ep. steps':>9}"
    lines = [columns] if per_task else []
    rows = [*table["per_task"].items()] if per_task else []
    rows.append(("average" if per_task else title, table["average"]))
    for name, m in rows:
        travel = "-" if m["average_travel_time"] is None else f"{m['average_travel_time']:.1f}"
        lines.append(
            f"{name:<37} {m['average_reward']:>10.2f} {m['collision_rate']:>9.1%} "
            f"{m['arrival_rate']:>8.1%} {m['timeout_rate']:>8.1%} {travel:>11} "
            f"{m['average_episode_steps']:>9.1f}"
        )
    return "\n".join(lines)


def _table(per_task: dict[str, dict[str, Any]]) -> dict[str, Any]:
    return {"per_task": per_task, "average": average_over_tasks(per_task)}


def _label(name: str) -> str:
    return YARDSTICK_LABELS.get(name, name)


def run_settings(run_dir: Path) -> Any:
    """A finished run's validated settings, ready to test its model on this machine
    (``cores`` falls back to every core here when the run was saved on a larger one)."""
    from frl.train_config import load_run_config, validate

    config = load_run_config(run_dir)
    if config.get("cores", 0) > available_cores():  # saved on a larger machine
        config.cores = 0
    return validate(config)


def _first_line(error: BaseException) -> str:
    if isinstance(error, FileNotFoundError) and not error.strerror:
        return f"no such file: {error}"
    lines = str(error).strip().splitlines()
    return lines[0] if lines else type(error).__name__


def _progress_bar(enabled: bool, total: int, description: str) -> Any:
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="episode", desc=description, disable=not enabled)


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m frl.evaluate", description=__doc__.splitlines()[0])
    parser.add_argument(
        "run_dir", type=Path, nargs="?", help="a run directory written by frl.train"
    )
    parser.add_argument(
        "--policy",
        help=f"test a yardstick instead of the run's model: {', '.join(YARDSTICKS)}, or all",
    )
    parser.add_argument(
        "--task", default="all", help=f"with --policy: {', '.join(TASKS)} or all (default)"
    )
    parser.add_argument(
        "--traffic", help=f"with --policy and no RUN_DIR: {', '.join(TRAFFIC_PRESETS)} (paper)"
    )
    parser.add_argument(
        "--seed",
        type=seed_value,
        help="with --policy and no RUN_DIR: the run seed whose test seeds to use (0)",
    )
    parser.add_argument("--episodes", type=int, default=None, help="test episodes per task")
    parser.add_argument(
        "--round-tests",
        action="store_true",
        help="test the yardsticks (the run's, or --policy) on the seeds of RUN_DIR's "
        "per-round test curve, and add them to its results.json",
    )
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.add_argument(
        "--no-tensorboard", action="store_true", help="do not log eval/* to the run's tb/"
    )
    args = parser.parse_args(argv)
    if args.episodes is not None and args.episodes <= 0:
        parser.error("--episodes must be positive")
    if args.round_tests:
        if args.run_dir is None:
            parser.error("--round-tests needs a RUN_DIR made with round_test_episodes")
        if args.episodes is not None or args.traffic is not None or args.seed is not None:
            parser.error("--round-tests takes its episodes, traffic and seeds from the run")
        if args.task != "all":
            parser.error("--round-tests tests every task of the run's curve")
    if args.policy is None:
        if args.run_dir is None:
            parser.error("give a RUN_DIR to test its model, or --policy NAME")
        if args.traffic is not None or args.seed is not None or args.task != "all":
            parser.error("--traffic, --seed and --task go with --policy")
    else:
        names = list(YARDSTICKS) if args.policy == "all" else [args.policy]
        if any(name not in YARDSTICKS for name in names):
            parser.error(
                f"unknown policy {args.policy!r}; choose one of {', '.join(YARDSTICKS)}, or all"
            )
        if args.task != "all" and args.task not in TASKS:
            parser.error(f"unknown task {args.task!r}; choose one of {', '.join(TASKS)}, or all")
        if args.traffic is not None and args.traffic not in TRAFFIC_PRESETS:
            parser.error(
                f"unknown traffic {args.traffic!r}; choose one of {', '.join(TRAFFIC_PRESETS)}"
            )
    try:
        if args.round_tests:
            evaluate_round_test_yardsticks(
                args.run_dir,
                names=None if args.policy is None else names,
                progress=not args.no_progress,
            )
        elif args.policy is None:
            evaluate_run(
                args.run_dir,
                episodes=args.episodes,
                progress=not args.no_progress,
                log_tensorboard=not args.no_tensorboard,
            )
        else:
            evaluate_yardsticks(
                names,
                list(TASKS) if args.task == "all" else [args.task],
                run_dir=args.run_dir,
                traffic=args.traffic,
                seed=args.seed,
                episodes=args.episodes,
                progress=not args.no_progress,
            )
    except (OSError, ValueError) as error:  # a user's mistake: one line, no traceback
        print(f"frl.evaluate: error: {_first_line(error)}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    # The test workers unpickle PolicyEvaluator by its module's name, which under
    # ``python -m`` is __main__: run the importable module's main so they find it.
    from frl.evaluate import main as importable_main

    sys.exit(importable_main())
