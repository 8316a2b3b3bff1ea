"""What a trained driver does at the stop line, and whether its networks read the line.

    python scripts/line_behaviour.py RUN_DIR [--episodes N]

Drives the run's model, the plain gap-acceptance rule and the committed rule on the run's
first ``N`` test episodes per task (its own test seeds) and, for each, counts:

- **braked past the line**: episodes where the car braked with its nose past the stop
  line (action < 0 at a negative distance to the line, within the junction's first
  15 m), and how many of those collided, against the collisions of the others;
- **speed at the line**: the mean speed when the car crossed the line (m/s).

For a model that observes the crossing cars' windows (``env.window_observation=true``),
it asks the actor, on every state before the line with a car coming, for its action with
the windows as seen against the windows blanked, where the plain rule brakes and where it
goes: an actor that does not read the windows answers the same.

For a model that observes its route (``env.route_observation=true``) it then asks, on
every state it visited within 10 m of the line, what the networks make of the distance:
the actor's action, the critic's Q(s, brake) - Q(s, go) and, under a collision budget, the
cost critic's Q_c(s, brake) - Q_c(s, go) with the distance set to 5 m before the line
against 2 m past it, the grid unchanged. A network that does not read
the line answers the same for both.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from frl import run_directory as rundir
from frl.agents import DDPG, SparseRows
from frl.envs import IntersectionEnv
from frl.envs.conflicts import FEATURES_PER_SIDE, WINDOW_FEATURES, CrossingReader
from frl.envs.intersection import ROUTE_DISTANCE_SCALE_M
from frl.evaluate import run_settings
from frl.federation.assembly import evaluation_env
from frl.federation.plan import evaluation_seeds
from frl.policies import load_model, make_yardstick

JUNCTION_DEPTH_M = 15.0
"""A brake counts as one past the stop line while the nose is past it by less than this
(the junction's first metres, where the committed rule never brakes)."""


def drive(env: IntersectionEnv, policy, seeds: list[int]) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """Drive ``seeds`` and count brakes past the line and the collisions after them."""
    inside = inside_collisions = other_collisions = 0
    line_speeds = []
    for seed in seeds:
        observation, _ = env.reset(seed=seed)
        waited, crossed = False, False
        while True:
            before = env.stop_line_distance_m
            action = float(np.asarray(policy(observation)).reshape(-1)[0])
            if action < 0 and -JUNCTION_DEPTH_M < before < 0:
                waited = True
            observation, _, terminated, truncated, info = env.step([action])
            if not crossed and env.stop_line_distance_m <= 0 < before:
                crossed = True
                line_speeds.append(info["ego_speed"])
            if terminated or truncated:
                break
        inside += waited
        inside_collisions += waited and info["collision"]
        other_collisions += (not waited) and info["collision"]
    return {
        "episodes": len(seeds),
        "braked_past_line": inside,
        "collisions_after_braking_past_line": inside_collisions,
        "other_collisions": other_collisions,
        "speed_at_line": float(np.mean(line_speeds)) if line_speeds else float("nan"),
    }


def part_offset(agent: DDPG, part: str) -> int:
    """Where the Dict observation's ``part`` starts in the agent's flat vector."""
    assert agent.layout.parts is not None
    offset = 0
    for key, shape in agent.layout.parts.items():
        if key == part:
            return offset
        offset += int(np.prod(shape))
    raise KeyError(part)


def model_states(agent: DDPG, env: IntersectionEnv, seeds: list[int]) -> list[tuple[Any, float]]:
    """Every observation the model met driving ``seeds`` without noise, each with the
    distance to the stop line (m) it was met at: the states the probes below ask about."""
    visited = []
    for seed in seeds:
        observation, _ = env.reset(seed=seed)
        while True:
            visited.append((observation, env.stop_line_distance_m))
            action = agent.act(observation, explore=False)
            observation, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                break
    return visited


def window_reading(
    agent: DDPG, env: IntersectionEnv, visited: list[tuple[Any, float]]
) -> dict[str, float]:
    """Whether the actor reads the crossing cars' windows: on the states it visited before
    the line with a car coming, its action with the windows as seen against the windows
    blanked (no car coming on either side), where the plain rule brakes and where it goes."""
    rule = make_yardstick("gap_acceptance", env)
    states, rule_brakes = [], []
    for observation, distance in visited:
        car_coming = observation["windows"][::FEATURES_PER_SIDE].any()  # each side's first
        if distance > 0 and car_coming:
            states.append(agent.layout.flat(observation))
            rule_brakes.append(float(np.asarray(rule(observation)).reshape(-1)[0]) < 0)
    flat = np.stack(states).astype(np.float32)
    brakes = np.array(rule_brakes)
    start = part_offset(agent, "windows")
    blank = flat.copy()
    # the windows of an empty grid: no car coming on either side
    no_car = CrossingReader(env.config).no_car_features(env.config.grid.shape)
    blank[:, start : start + WINDOW_FEATURES] = no_car
    answers: dict[str, float] = {"states": len(states), "rule_brakes": int(brakes.sum())}
    for name, rows in (("seen", flat), ("blanked", blank)):
        x = torch.from_numpy(rows)
        with torch.no_grad():
            actions = agent.actor(SparseRows.from_dense(x) if agent.sparse else x).reshape(-1)
        actions = actions.numpy()
        for verdict, where in (("brakes", brakes), ("goes", ~brakes)):
            mean = float(actions[where].mean()) if where.any() else float("nan")
            answers[f"action_{name}_rule_{verdict}"] = mean
    return answers


def line_reading(agent: DDPG, visited: list[tuple[Any, float]]) -> dict[str, float]:
    """The actor's and critic's answers with the distance set before against past the line."""
    states = [
        agent.layout.flat(observation) for observation, distance in visited if abs(distance) <= 10.0
    ]
    flat = np.stack(states).astype(np.float32)
    distance_column = part_offset(agent, "route") + 3  # the route's last entry
    answers = {}
    for name, metres in (("before", 5.0), ("past", -2.0)):
        moved = flat.copy()
        moved[:, distance_column] = metres / ROUTE_DISTANCE_SCALE_M
        x = torch.from_numpy(moved)
        obs = SparseRows.from_dense(x) if agent.sparse else x
        with torch.no_grad():
            actions = agent.actor(obs).reshape(-1).numpy()
            brake = agent.critic(obs, -torch.ones(len(x), 1))
            go = agent.critic(obs, torch.ones(len(x), 1))
        answers[f"action_{name}"] = float(actions.mean())
        answers[f"brake_minus_go_{name}"] = float((brake - go).mean())
        if agent.networks.cost_critic is not None:  # the collisions to come, Q_c
            ones = np.ones((len(moved), 1))
            cost_brake = agent.critic_values(moved, -ones, cost=True)
            cost_go = agent.critic_values(moved, ones, cost=True)
            answers[f"cost_brake_minus_go_{name}"] = float((cost_brake - cost_go).mean())
    answers["states"] = len(states)
    return answers


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--episodes", type=int, default=100)
    args = parser.parse_args()
    settings = run_settings(args.run_dir)
    files = rundir.model_files(args.run_dir)
    for task, paths in files.items():
        seeds = evaluation_seeds(settings.seed, task, args.episodes)
        env = IntersectionEnv(replace(evaluation_env(settings, task), task=task))
        try:
            agent = load_model(paths[0], env)
            drivers = {
                "model": lambda o, agent=agent: agent.act(o, explore=False),
                "gap acceptance": make_yardstick("gap_acceptance", env),
                "committed rule": make_yardstick("committed_gap_acceptance", env),
            }
            for name, policy in drivers.items():
                counts = drive(env, policy, seeds)
                print(
                    f"{task:<9} {name:<15} braked past the line {counts['braked_past_line']:>3}/"
                    f"{counts['episodes']} (collided after it "
                    f"{counts['collisions_after_braking_past_line']}, other collisions "
                    f"{counts['other_collisions']}), "
                    f"speed at the line {counts['speed_at_line']:.2f} m/s"
                )
            # the model's own drive once more, its states kept for both probes of its networks
            probed = settings.env.route_observation or settings.env.window_observation
            visited = model_states(agent, env, seeds) if probed else []
            if settings.env.route_observation:
                reading = line_reading(agent, visited)
                print(
                    f"{task:<9} model reads the line on {reading['states']} states within 10 m: "
                    f"action {reading['action_before']:+.3f} (5 m before) vs "
                    f"{reading['action_past']:+.3f} (2 m past); Q(brake) - Q(go) "
                    f"{reading['brake_minus_go_before']:+.3f} vs "
                    f"{reading['brake_minus_go_past']:+.3f}"
                    + (
                        f"; Q_c(brake) - Q_c(go) {reading['cost_brake_minus_go_before']:+.4f} "
                        f"vs {reading['cost_brake_minus_go_past']:+.4f}"
                        if "cost_brake_minus_go_past" in reading
                        else ""
                    )
                )
            if settings.env.window_observation:
                seen = window_reading(agent, env, visited)
                print(
                    f"{task:<9} model reads the windows on {seen['states']} states before the "
                    f"line with a car coming (the rule brakes on {seen['rule_brakes']}): action "
                    f"where the rule brakes {seen['action_seen_rule_brakes']:+.3f} "
                    f"(windows blanked {seen['action_blanked_rule_brakes']:+.3f}), where it goes "
                    f"{seen['action_seen_rule_goes']:+.3f} "
                    f"(blanked {seen['action_blanked_rule_goes']:+.3f})"
                )
        finally:
            env.close()


if __name__ == "__main__":
    main()
