"""Environment steps per second with the full observation and reward, per task.

    python benchmarks/env_speed.py [--steps N] [--backend libsumo|traci]

Each task runs a fixed open-loop policy through ``--steps`` steps, resets included: a
pre-drawn sequence of accelerations, uniform in [-0.5, 1], so that the ego waits,
crosses, collides and arrives, and episodes end in every way. Policy cost is thus kept
out of the figure. Also prints a plain libsumo step loop on the same scenario as the
ceiling, and the episode outcomes so that the workload is visible.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from frl.envs import TASKS, EnvConfig, IntersectionEnv
from frl.envs.scenario import build_scenario
from frl.envs.sumo_backend import sumo_command


def env_steps_per_second(task: str, steps: int, backend: str) -> tuple[float, dict[str, int]]:
    """Steps per second, and how the episodes ended."""
    actions = np.random.default_rng(0).uniform(-0.5, 1.0, size=(steps, 1)).astype(np.float32)
    outcomes = {"collision": 0, "arrived": 0, "truncated": 0}
    env = IntersectionEnv(task=task, backend=backend)
    try:
        env.reset(seed=0)
        start = time.perf_counter()
        for action in actions:
            _, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                outcome = (
                    "collision"
                    if info["collision"]
                    else "arrived"
                    if info["arrived"]
                    else "truncated"
                )
                outcomes[outcome] += 1
                env.reset()
        return steps / (time.perf_counter() - start), outcomes
    finally:
        env.close()


def plain_libsumo_steps_per_second(steps: int) -> float:
    import libsumo

    config = EnvConfig().scenario
    libsumo.start(sumo_command(build_scenario(config), config, seed=0))
    try:
        start = time.perf_counter()
        for _ in range(steps):
            libsumo.simulationStep()
        return steps / (time.perf_counter() - start)
    finally:
        libsumo.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--backend", choices=("libsumo", "traci"), default="libsumo")
    args = parser.parse_args()
    build_scenario(EnvConfig().scenario)  # generation is not part of the measurement
    rates = {}
    for task in TASKS:
        rates[task], outcomes = env_steps_per_second(task, args.steps, args.backend)
        print(f"env[{args.backend}] {task:<9} {rates[task]:>9,.0f} steps/s   episodes: {outcomes}")
    print(f"env[{args.backend}] mean      {np.mean(list(rates.values())):>9,.0f} steps/s")
    if args.backend == "libsumo":
        print(f"plain libsumo loop  {plain_libsumo_steps_per_second(args.steps):>9,.0f} steps/s")


if __name__ == "__main__":
    main()
