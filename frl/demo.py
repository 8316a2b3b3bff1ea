"""Watch a driver: the gap-acceptance rule, or a trained run's model and its collisions.

python -m frl.demo [--episodes N] [--seed S] [--traffic paper|dense] [--gif PATH]
python -m frl.demo RUN_DIR [--episodes N] [--gif PATH]
python -m frl.demo RUN_DIR --collisions [--episodes N] [--out DIR]

Without RUN_DIR it drives the rule through a few episodes per task. With RUN_DIR it
drives the run's model on the run's own test episodes (those of its test table, so its
collisions are the table's), prints the table and saves its first left turn. With
``--collisions`` it draws every test episode where the model collided, beside the
committed gap-acceptance rule (frl.policies) on the same seed, one GIF each.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Any

from frl.cli import OneLineParser, seed_value
from frl.envs import TASKS, TRAFFIC_PRESETS, EnvConfig, IntersectionEnv, traffic_preset
from frl.episodes import EpisodeRecord, run_episode, summarize
from frl.federation.assembly import evaluation_env
from frl.policies import GapAcceptancePolicy, load_model, make_yardstick
from frl.recording import Driver, film_episode, record_episode, side_by_side, write_gif

GIF_TASK = "left"
BESIDE = "committed_gap_acceptance"
"""The yardstick each collision is drawn beside."""


def main(argv: list[str] | None = None) -> None:
    parser = OneLineParser(prog="python -m frl.demo", description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", nargs="?", type=Path, help="a finished training run")
    parser.add_argument("--episodes", type=int, help="episodes per task (5; a run: its test's)")
    parser.add_argument("--seed", type=seed_value, help="without RUN_DIR (0)")
    parser.add_argument("--traffic", choices=list(TRAFFIC_PRESETS), help="without RUN_DIR")
    parser.add_argument("--gif", type=Path, help="the animation (outputs/demo.gif)")
    parser.add_argument(
        "--collisions", action="store_true", help="with RUN_DIR: draw each test collision"
    )
    parser.add_argument("--out", type=Path, help="with --collisions: RUN_DIR/collisions")
    args = parser.parse_args(argv)
    if args.episodes is not None and args.episodes <= 0:
        parser.error("--episodes must be positive")
    if args.run_dir is None:
        for flag, given in (("--collisions", args.collisions), ("--out", args.out)):
            if given:
                parser.error(f"{flag} needs RUN_DIR")
        seed = 0 if args.seed is None else args.seed
        rule_demo(args.episodes or 5, seed, args.traffic or "paper", args.gif)
        return
    for flag, given in (("--seed", args.seed is not None), ("--traffic", args.traffic)):
        if given:
            parser.error(f"{flag} is the run's own with RUN_DIR")
    if args.out is not None and not args.collisions:
        parser.error("--out needs --collisions")
    try:
        model = RunModel(args.run_dir)
    except (OSError, ValueError) as error:
        parser.error(str(error).splitlines()[0])
    if args.collisions:
        draw_collisions(model, args.episodes, args.out or args.run_dir / "collisions")
    else:
        drive_model(model, args.episodes, args.gif or Path("outputs/demo.gif"))


def rule_demo(episodes: int, seed: int, traffic: str, gif: Path | None) -> None:
    """The rule on each task: a summary table, and a GIF of a left turn that arrived."""
    scenario = traffic_preset(traffic)
    print(f"gap-acceptance driver, traffic {traffic}")
    seeds = range(seed * 1000, seed * 1000 + episodes)
    gif_seed = seeds[0]
    _print_header()
    for task in TASKS:
        config = EnvConfig(task=task, scenario=scenario)
        env = IntersectionEnv(config)
        try:
            policy = GapAcceptancePolicy(config)
            records = [run_episode(env, policy, task, s) for s in seeds]
        finally:
            env.close()
        if task == GIF_TASK:  # show a crossing: the first episode of the table that arrived
            gif_seed = next((s for s, r in zip(seeds, records, strict=True) if r.arrived), gif_seed)
        _print_row(task, records)
    config = EnvConfig(scenario=scenario)
    path = record_episode(
        gif or Path("outputs/demo.gif"), GIF_TASK, gif_seed, GapAcceptancePolicy(config), config
    )
    print(f"saved the {GIF_TASK} turn of seed {gif_seed} as an animation to {path}")


class RunModel:
    """A finished run's model(s), test settings and test seeds.

    Raises:
        ValueError: ``run_dir`` is no run directory, or its model is missing.
    """

    def __init__(self, run_dir: Path) -> None:
        from frl import run_directory as rundir
        from frl.agents.checkpoint import read_checkpoint
        from frl.evaluate import run_settings

        if not (run_dir / rundir.CONFIG_FILE).is_file():
            raise ValueError(f"{run_dir} is not a training run (no {rundir.CONFIG_FILE})")
        try:
            self.files = rundir.model_files(run_dir)
        except FileNotFoundError as error:
            raise ValueError(str(error)) from None
        for path in {p for paths in self.files.values() for p in paths}:
            read_checkpoint(path)  # a corrupt model fails here, before any episode
        self.run_dir = run_dir
        self.settings = run_settings(run_dir)

    @property
    def tasks(self) -> list[str]:
        return list(self.files)

    def seeds(self, task: str, episodes: int | None) -> list[int]:
        """The run's test seeds of ``task`` (the first ``episodes`` of its test's)."""
        from frl.federation.plan import evaluation_seeds

        count = self.settings.eval_episodes if episodes is None else episodes
        return evaluation_seeds(self.settings.seed, task, max(count, 1))

    def env_config(self, task: str) -> EnvConfig:
        return evaluation_env(self.settings, task)

    def drivers(self, task: str) -> list[Driver]:
        """One driver per model of ``task`` (Sep-DDPG's fleets have several)."""
        paths = self.files[task]
        return [
            Driver(
                "model" if len(paths) == 1 else f"model {index + 1}",
                functools.partial(_model_policy, os.fspath(path)),
            )
            for index, path in enumerate(paths)
        ]


def _model_policy(path: str, env: IntersectionEnv) -> Any:
    """The model at ``path`` on ``env``'s spaces, acting without exploration."""
    return functools.partial(load_model(path, env).act, explore=False)


def _test_records(model: RunModel, task: str, episodes: int | None) -> list[list[EpisodeRecord]]:
    """Each model of ``task`` on the run's test seeds: its episode records, seed by seed."""
    seeds = model.seeds(task, episodes)
    env = IntersectionEnv(model.env_config(task))
    try:
        records = []
        for driver in model.drivers(task):
            policy = driver.make(env)
            records.append([run_episode(env, policy, task, s) for s in seeds])
    finally:
        env.close()
    return records


def drive_model(model: RunModel, episodes: int | None, gif: Path) -> None:
    """The run's model on its test seeds: the table, and a GIF of its first left turn."""
    print(f"{model.run_dir}: the model on the run's test episodes")
    _print_header()
    for task in model.tasks:
        _print_row(task, [r for runs in _test_records(model, task, episodes) for r in runs])
    task = GIF_TASK if GIF_TASK in model.tasks else model.tasks[0]
    seed = model.seeds(task, 1)[0]
    frames, _ = film_episode(model.drivers(task)[0], task, seed, model.env_config(task))
    path = write_gif(gif, frames, _fps(model, task))
    print(f"saved the model's {task} test episode of seed {seed} as an animation to {path}")


def draw_collisions(model: RunModel, episodes: int | None, out: Path) -> list[Path]:
    """Every test episode where a model collided, beside the committed rule on its seed."""
    beside = Driver("committed rule", functools.partial(make_yardstick, BESIDE))
    written = []
    for task in model.tasks:
        seeds = model.seeds(task, episodes)
        config = model.env_config(task)
        tested = zip(model.drivers(task), _test_records(model, task, episodes), strict=True)
        for driver, records in tested:
            name = task if driver.label == "model" else f"{task}-{driver.label.replace(' ', '')}"
            for seed, record in zip(seeds, records, strict=True):
                if not record.collision:
                    continue
                own, _ = film_episode(driver, task, seed, config)
                rule, _ = film_episode(beside, task, seed, config)
                path = write_gif(
                    out / f"{name}-seed{seed}.gif", side_by_side(own, rule), _fps(model, task)
                )
                written.append(path)
                print(f"{name}: collided at seed {seed} after {record.steps} steps: {path}")
    print(f"{len(written)} collision(s) drawn beside the committed rule under {out}")
    return written


def _fps(model: RunModel, task: str) -> int:
    return round(1 / model.env_config(task).scenario.step_length)


def _print_header() -> None:
    print(f"{'task':<9} {'return':>8} {'collisions':>11} {'arrived':>8} {'travel steps':>13}")


def _print_row(task: str, records: list[EpisodeRecord]) -> None:
    m = summarize(records)
    count = len(records)
    collisions = sum(r.collision for r in records)
    arrivals = sum(r.arrived for r in records)
    travel = "-" if m["average_travel_time"] is None else f"{m['average_travel_time']:.1f}"
    print(
        f"{task:<9} {m['average_reward']:>8.2f} {collisions:>5}/{count:<5} "
        f"{arrivals:>4}/{count:<3} {travel:>13}"
    )


if __name__ == "__main__":
    main()
