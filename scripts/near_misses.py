"""How many near misses a driver has beside its collisions: whether a near miss would add
much to what a collision budget's cost critic learns from.

    python scripts/near_misses.py POLICY_OR_RUN_DIR [--episodes 100]

Drives a yardstick (``frl.policies``), or a run's model without noise, on fixed SUMO
seeds (90,000 on, even) for each task
and, at every step without a collision, finds the time to overlap: the first moment
within the horizon at which the ego's rectangle and a human's (5 m x 1.8 m behind the
front bumper) would overlap with both driving on at their present velocities, compared
ten times a second. An episode has a near miss at horizon H where that time was at most
H at some step. Prints, per task and horizon, the episodes with a near miss and those of
them that did not collide: the labels a near-miss cost would add to the collisions.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from frl import run_directory as rundir
from frl.envs import TASKS, IntersectionEnv
from frl.envs.sumo_backend import EGO_ID
from frl.evaluate import run_settings
from frl.federation.assembly import evaluation_env
from frl.policies import YARDSTICKS, Policy, load_model, make_yardstick

HORIZONS_S = (0.5, 1.0, 1.5)
LENGTH_M, WIDTH_M = 5.0, 1.8
SEED_BASE = 90_000


def axes(angle_deg: float) -> np.ndarray:
    """Unit vectors along and across a SUMO heading (degrees clockwise from north)."""
    heading = math.radians(angle_deg)
    along = (math.sin(heading), math.cos(heading))
    return np.array([along, (along[1], -along[0])])


def time_to_overlap(vehicles, horizon_s: float) -> float:  # type: ignore[no-untyped-def]
    """The first moment in [0, horizon_s] at which the ego and a human would overlap."""
    ego = next((v for v in vehicles if v.id == EGO_ID), None)
    if ego is None:
        return math.inf
    times = np.linspace(0.0, horizon_s, math.ceil(horizon_s * 10) + 1)
    halves = np.array([LENGTH_M / 2, WIDTH_M / 2])

    def centres(vehicle):  # type: ignore[no-untyped-def]
        along = axes(vehicle.angle)[0]
        start = np.array([vehicle.x, vehicle.y]) - along * LENGTH_M / 2
        return start + np.outer(times * vehicle.speed, along)

    ego_axes, ego_centres = axes(ego.angle), centres(ego)
    hit = np.zeros(len(times), bool)
    for human in vehicles:
        if human.id == EGO_ID or (human.x - ego.x) ** 2 + (human.y - ego.y) ** 2 > 60.0**2:
            continue
        human_axes, offsets = axes(human.angle), centres(human) - ego_centres
        overlap = np.ones(len(times), bool)
        for axis in (*ego_axes, *human_axes):
            reach = halves @ np.abs(ego_axes @ axis) + halves @ np.abs(human_axes @ axis)
            overlap &= np.abs(offsets @ axis) <= reach
        hit |= overlap
    hits = np.flatnonzero(hit)
    return float(times[hits[0]]) if hits.size else math.inf


def driver(name: str, task: str) -> tuple[IntersectionEnv, Policy]:
    """The env of ``task`` and the yardstick ``name``, or the model of the run in the
    directory ``name`` (its own scenario), acting without noise."""
    if name in YARDSTICKS:
        env = IntersectionEnv()
        return env, make_yardstick(name, env)
    run_dir = Path(name)
    settings = run_settings(run_dir)
    env = IntersectionEnv(evaluation_env(settings, task), settings.reward)
    agent = load_model(rundir.model_files(run_dir)[task][0], env)
    return env, lambda observation: agent.act(observation, explore=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy", help=f"one of {', '.join(YARDSTICKS)}, or a run directory")
    parser.add_argument("--episodes", type=int, default=100)
    args = parser.parse_args()
    if args.policy not in YARDSTICKS:
        try:
            rundir.model_files(Path(args.policy))
        except FileNotFoundError as error:
            parser.error(str(error))
    for task in TASKS:
        env, policy = driver(args.policy, task)
        try:
            collisions = 0
            near = dict.fromkeys(HORIZONS_S, 0)
            near_clean = dict.fromkeys(HORIZONS_S, 0)
            for k in range(args.episodes):
                observation, _ = env.reset(seed=SEED_BASE + 2 * k, options={"task": task})
                least = math.inf
                while True:
                    observation, _, terminated, truncated, info = env.step(policy(observation))
                    if not info["collision"]:
                        least = min(least, time_to_overlap(env._vehicles, max(HORIZONS_S)))
                    if terminated or truncated:
                        break
                collisions += info["collision"]
                for horizon in HORIZONS_S:
                    near[horizon] += least <= horizon
                    near_clean[horizon] += least <= horizon and not info["collision"]
            counts = ", ".join(
                f"{h} s: {near[h]} ({near_clean[h]} without a collision)" for h in HORIZONS_S
            )
            tally = f"collisions {collisions}/{args.episodes}; near misses {counts}"
            print(f"{args.policy} {task}: {tally}")
        finally:
            env.close()


if __name__ == "__main__":
    main()
