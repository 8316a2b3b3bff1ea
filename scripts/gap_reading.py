"""What a trained driver's networks make of the gaps that the committed rule refuses.

    python scripts/gap_reading.py RUN_DIR [--episodes 100]

Drives the run's model without noise on its own test episodes and, at every state before
its commitment (the last step at which it can still stop before the line), asks the
committed rule (``frl.policies.CommittedGapAcceptancePolicy``) whether it would brake
there. On those states it prints, split by the rule's verdict and by whether the episode
went on to collide:

- the actor's mean action and the share of states where it brakes (action < 0);
- the reward critic's Q_r(s, brake) - Q_r(s, go), brake and go being -1 and +1;
- under a collision budget, the cost critic's Q_c(s, brake) - Q_c(s, go), and the actor's
  objective (Q_r - lambda Q_c) / (1 + lambda) at brake minus at go, with the final
  multiplier of the vehicle that learned the task (``results.json``), and the share of
  states where that objective prefers braking.

Where the rule brakes and the episode then collided, a critic that knows the gap is
refused prefers braking (a positive objective difference).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from frl import run_directory as rundir
from frl.agents import DDPG
from frl.envs import IntersectionEnv
from frl.envs.conflicts import CrossingReader
from frl.evaluate import run_settings
from frl.federation.assembly import evaluation_env
from frl.federation.plan import evaluation_seeds
from frl.policies import load_model, make_yardstick

BRAKE, GO = -1.0, 1.0


@dataclass
class Readings:
    """The networks' answers on one group of states (one verdict, one outcome)."""

    actions: list[float] = field(default_factory=list)
    reward_gap: list[float] = field(default_factory=list)
    """Q_r(s, brake) - Q_r(s, go)."""
    cost_gap: list[float] = field(default_factory=list)
    """Q_c(s, brake) - Q_c(s, go)."""
    objective_gap: list[float] = field(default_factory=list)
    """The priced objective at brake minus at go."""


def priced_gap(reward_gap: np.ndarray, cost_gap: np.ndarray, multiplier: float) -> np.ndarray:
    """(Q_r - lambda Q_c) / (1 + lambda) at brake minus the same at go, from the two critics'
    gaps: the difference the actor climbs under a collision budget with multiplier lambda."""
    return (reward_gap - multiplier * cost_gap) / (1.0 + multiplier)


def approach_states(
    env: IntersectionEnv, agent: DDPG, seed: int
) -> tuple[list[np.ndarray], list[bool], list[float], bool]:
    """One noise-free test episode: the observations before the model's commitment, the
    committed rule's verdict on each (True: it brakes), the model's actions there, and
    whether the episode collided."""
    rule = make_yardstick("committed_gap_acceptance", env)
    crossings = CrossingReader(env.config)
    observation, _ = env.reset(seed=seed)
    states, rule_brakes, actions = [], [], []
    committed = False
    while True:
        grid = observation["grid"] if isinstance(observation, dict) else observation
        committed = committed or crossings.committed(grid, env.stop_line_distance_m)
        action = agent.act(observation, explore=False)
        if not committed:
            states.append(agent.layout.flat(observation))
            rule_brakes.append(float(rule(observation)[0]) < 0.0)
            actions.append(float(np.asarray(action).reshape(-1)[0]))
        observation, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            return states, rule_brakes, actions, bool(info["collision"])


def read_task(
    env: IntersectionEnv, agent: DDPG, seeds: list[int], multiplier: float | None
) -> dict[tuple[bool, bool], Readings]:
    """The readings by (rule brakes, episode collided)."""
    groups: dict[tuple[bool, bool], Readings] = {}
    for seed in seeds:
        states, rule_brakes, actions, collided = approach_states(env, agent, seed)
        if not states:
            continue
        flat = np.stack(states).astype(np.float32)
        brake, go = np.full((len(flat), 1), BRAKE), np.full((len(flat), 1), GO)
        reward_gap = agent.critic_values(flat, brake) - agent.critic_values(flat, go)
        cost_gap = objective_gap = None
        if multiplier is not None:
            cost_gap = agent.critic_values(flat, brake, cost=True) - agent.critic_values(
                flat, go, cost=True
            )
            objective_gap = priced_gap(reward_gap, cost_gap, multiplier)
        for i, brakes in enumerate(rule_brakes):
            group = groups.setdefault((brakes, collided), Readings())
            group.actions.append(actions[i])
            group.reward_gap.append(float(reward_gap[i]))
            if cost_gap is not None and objective_gap is not None:
                group.cost_gap.append(float(cost_gap[i]))
                group.objective_gap.append(float(objective_gap[i]))
    return groups


def multipliers(run_dir: Path) -> dict[str, float]:
    """Each task's final Lagrange multiplier (its first vehicle's), from ``results.json``;
    empty without a collision budget."""
    results = json.loads((run_dir / rundir.RESULTS_FILE).read_text())
    budgets = results.get("training", {}).get("collision_budget") or {}
    tasks: dict[str, float] = {}
    for client, state in sorted(budgets.items()):
        tasks.setdefault(client.rsplit("_", 1)[-1], float(state["multiplier"]))
    return tasks


def _mean(values: list[float], spec: str) -> str:
    return format(float(np.mean(values)), spec) if values else "-"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--episodes", type=int, default=100)
    args = parser.parse_args()
    if args.episodes <= 0:
        parser.error("--episodes must be positive")
    try:
        files = rundir.model_files(args.run_dir)
    except FileNotFoundError as error:
        parser.error(str(error))
    torch.set_num_threads(1)  # one observation at a time: threads only add overhead
    settings = run_settings(args.run_dir)
    prices = multipliers(args.run_dir)
    print(
        "| task | committed rule | episode | states | actor's action (share braking) | "
        "Q_r(brake) - Q_r(go) | Q_c(brake) - Q_c(go) | objective, brake - go (share "
        "preferring brake) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for task, paths in files.items():
        env = IntersectionEnv(replace(evaluation_env(settings, task), task=task))
        try:
            agent = load_model(paths[0], env)
            multiplier = prices.get(task) if agent.constraint is not None else None
            seeds = evaluation_seeds(settings.seed, task, args.episodes)
            groups = read_task(env, agent, seeds, multiplier)
        finally:
            env.close()
        for (brakes, collided), group in sorted(groups.items(), reverse=True):
            braking = np.mean(np.asarray(group.actions) < 0.0)
            preferring = (
                f" ({np.mean(np.asarray(group.objective_gap) > 0.0):.2f})"
                if group.objective_gap
                else ""
            )
            print(
                f"| {task} | {'brakes' if brakes else 'goes'} | "
                f"{'collided' if collided else 'clean'} | {len(group.actions)} | "
                f"{_mean(group.actions, '+.2f')} ({braking:.2f}) | "
                f"{_mean(group.reward_gap, '+.3f')} | {_mean(group.cost_gap, '+.4f')} | "
                f"{_mean(group.objective_gap, '+.3f')}{preferring} |"
            )


if __name__ == "__main__":
    main()
