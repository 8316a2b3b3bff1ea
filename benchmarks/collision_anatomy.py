"""Where a trained model's test collisions come from, read against the gap-acceptance rule.

    python benchmarks/collision_anatomy.py RUN_DIR [RUN_DIR ...] [--episodes 100]
        [--window 10] [--tasks left,straight,right] [--against rule|committed]

Replays each run's test episodes (the seeds ``python -m frl.evaluate`` uses) with its
model, and at every step asks a rule what it would do on the same observation: the
memoryless rule (``frl.policies.GapAcceptancePolicy``), or with ``--against committed``
the committed rule (``CommittedGapAcceptancePolicy``, told the distance to the stop line
by the environment). The rules are bang-bang (+1 or -1); the model's action counts as
"go" when it is above 0. It then runs the rule itself on the same seeds.

Prints per task:
- how often the two agree, and the two kinds of disagreement: the model goes where the
  rule brakes (accepts a gap the rule refuses), or brakes where the rule goes (hesitates);
- each model collision, classed by the last ``--window`` steps before it (against the
  committed rule: the ``--window`` steps up to the model's commitment, the last step at
  which it could still stop before the line, since past that the committed rule always
  goes): the model went
  at a step where the rule braked ("went into a refused gap"), else it braked at a step
  where the rule went ("hesitated where the rule went"), else it did what the rule would
  have done throughout ("agreed with the rule"); and whether the rule collides on that
  seed too; the median speed when hit and the median of the model's
  mean action over the window;
- against the committed rule, the episodes in which the model committed after the rule
  braked within the window, and how many of them collided.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from frl import run_directory as rundir
from frl.agents import DDPG
from frl.envs import TASKS, IntersectionEnv
from frl.envs.conflicts import CrossingReader
from frl.episodes import run_episode
from frl.evaluate import run_settings
from frl.federation.assembly import evaluation_env
from frl.federation.plan import evaluation_seeds
from frl.policies import Policy, load_model, make_yardstick

RULES = {"rule": "gap_acceptance", "committed": "committed_gap_acceptance"}
"""``--against``: the yardstick each collision is read against."""


@dataclass
class TaskAnatomy:
    steps: int = 0
    agree: int = 0
    went_where_rule_brakes: int = 0
    braked_where_rule_goes: int = 0
    episodes: int = 0
    collisions: Counter[str] = field(default_factory=Counter)
    rule_collides_too: int = 0
    rule_collisions: int = 0
    collision_speeds: list[float] = field(default_factory=list)
    """The ego's speed when it was hit (m/s), per model collision."""
    collision_actions: list[float] = field(default_factory=list)
    """The model's mean action over the window before each collision."""
    committed_where_rule_braked: int = 0
    """Against the committed rule: episodes whose commitment followed a step at which the
    rule braked, within the window."""
    collided_after_committing_there: int = 0


def drive_model(
    env: IntersectionEnv,
    agent: DDPG,
    rule: Policy,
    task: str,
    seed: int,
    window: int,
    anatomy: TaskAnatomy,
    at_commitment: bool = False,
) -> bool:
    """One test episode with the model; returns whether it collided. ``at_commitment``:
    the window ends at the model's commitment (the committed rule's reading), not at the
    end of the episode."""
    observation, _ = env.reset(seed=seed, options={"task": task})
    agent.episode_start()
    crossings = CrossingReader(env.config)
    steps: list[tuple[float, bool]] = []  # (model's action, rule goes), every step
    commitment = None  # the first step at which the model could no longer stop before the line
    while True:
        action = agent.act(observation, explore=False)
        model_action = float(np.asarray(action).reshape(-1)[0])
        model_goes = model_action > 0.0
        rule_goes = float(rule(observation)[0]) > 0.0
        anatomy.steps += 1
        anatomy.agree += model_goes == rule_goes
        anatomy.went_where_rule_brakes += model_goes and not rule_goes
        anatomy.braked_where_rule_goes += rule_goes and not model_goes
        grid = observation["grid"] if isinstance(observation, dict) else observation
        if commitment is None and crossings.committed(grid, env.stop_line_distance_m):
            commitment = len(steps)
        steps.append((model_action, rule_goes))
        observation, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    anatomy.episodes += 1
    end = len(steps) if not at_commitment or commitment is None else commitment + 1
    recent = steps[max(0, end - window) : end]
    went_against = any(model > 0.0 and not rule_goes for model, rule_goes in recent)
    if at_commitment and commitment is not None and went_against:
        anatomy.committed_where_rule_braked += 1
        anatomy.collided_after_committing_there += bool(info["collision"])
    if not info["collision"]:
        return False
    anatomy.collision_speeds.append(float(info["ego_speed"]))
    anatomy.collision_actions.append(float(np.mean([model for model, _ in recent])))
    if went_against:
        anatomy.collisions["went into a refused gap"] += 1
    elif any(model <= 0.0 and rule_goes for model, rule_goes in recent):
        anatomy.collisions["hesitated where the rule went"] += 1
    else:
        anatomy.collisions["agreed with the rule"] += 1
    return True


def anatomy_of(
    run_dir: Path, tasks: list[str], episodes: int, window: int, against: str = "rule"
) -> dict[str, TaskAnatomy]:
    settings = run_settings(run_dir)
    files = rundir.model_files(run_dir)
    result = {}
    for task in [task for task in tasks if task in files]:
        env = IntersectionEnv(evaluation_env(settings, task), settings.reward)
        try:
            agent = load_model(files[task][0], env)
            rule = make_yardstick(RULES[against], env)
            anatomy = TaskAnatomy()
            for seed in evaluation_seeds(settings.seed, task, episodes):
                model_collided = drive_model(
                    env, agent, rule, task, seed, window, anatomy, against == "committed"
                )
                rule_collided = run_episode(env, rule, task, seed).collision
                anatomy.rule_collisions += rule_collided
                anatomy.rule_collides_too += model_collided and rule_collided
            result[task] = anatomy
        finally:
            env.close()
    return result


def print_table(rows: list[tuple[str, str, TaskAnatomy]], against: str = "rule") -> None:
    kinds = ("went into a refused gap", "hesitated where the rule went", "agreed with the rule")
    print(
        "| run | task | steps agreeing with the rule | model goes, rule brakes | model brakes, "
        "rule goes | model collisions | " + " | ".join(kinds) + " | rule collides too | "
        "rule's collisions | median speed when hit | median mean action before |"
    )
    print("|---|---|---|---|---|---|" + "---|" * len(kinds) + "---|---|---|---|")
    for run, task, a in rows:
        steps = max(a.steps, 1)
        agree, goes, brakes = (
            f"{100 * n / steps:.1f}%"
            for n in (a.agree, a.went_where_rule_brakes, a.braked_where_rule_goes)
        )
        total = sum(a.collisions.values())
        print(
            f"| {run} | {task} | {agree} | {goes} | {brakes} | {total}/{a.episodes} | "
            + " | ".join(str(a.collisions[k]) for k in kinds)
            + f" | {a.rule_collides_too} | {a.rule_collisions}/{a.episodes} | "
            + f"{_median(a.collision_speeds, '.1f')} m/s | {_median(a.collision_actions, '+.2f')} |"
        )
    if against == "committed":
        print(
            "\n| run | task | committed where the committed rule braked (of episodes) | "
            "of those collided | other collisions |"
        )
        print("|---|---|---|---|---|")
        for run, task, a in rows:
            there = a.collided_after_committing_there
            others = sum(a.collisions.values()) - there
            print(
                f"| {run} | {task} | {a.committed_where_rule_braked}/{a.episodes} | "
                f"{there} | {others} |"
            )


def _median(values: list[float], spec: str) -> str:
    return format(float(np.median(values)), spec) if values else "-"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--window", type=int, default=10)
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--against", choices=tuple(RULES), default="rule")
    args = parser.parse_args()
    torch.set_num_threads(1)  # one observation at a time: threads only add overhead
    tasks = args.tasks.split(",")
    unknown = [task for task in tasks if task not in TASKS]
    if unknown:
        parser.error(f"unknown task {unknown[0]!r}; choose from {', '.join(TASKS)}")
    if args.episodes <= 0 or args.window <= 0:
        parser.error("--episodes and --window must be positive")
    for run in args.runs:
        try:
            rundir.model_files(run)
        except FileNotFoundError as error:
            parser.error(str(error))
    rows = []
    for run in args.runs:
        anatomies = anatomy_of(run, tasks, args.episodes, args.window, args.against)
        for task, anatomy in anatomies.items():
            rows.append((run.name, task, anatomy))
            print(f"{run.name} {task}: done", file=sys.stderr)
    print_table(rows, args.against)


if __name__ == "__main__":
    main()
