"""A few episodes of a hand-written policy on each task, a summary table and a GIF.

python -m frl.demo [--episodes N] [--seed S] [--gif PATH]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from frl.envs import TASKS, IntersectionEnv
from frl.policies import GapAcceptancePolicy
from frl.recording import record_episode


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=5, help="episodes per task")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--gif", type=Path, default=Path("outputs/demo.gif"))
    args = parser.parse_args(argv)
    if args.episodes <= 0:
        parser.error("--episodes must be positive")

    policy = GapAcceptancePolicy()
    print(f"{'task':<9} {'return':>8} {'collisions':>11} {'arrived':>8} {'travel steps':>13}")
    for task in TASKS:
        env = IntersectionEnv(task=task)
        returns, collisions, arrivals, travel = [], 0, 0, []
        try:
            for episode in range(args.episodes):
                observation, info = env.reset(seed=args.seed * 1000 + episode)
                total, done = 0.0, False
                while not done:
                    observation, reward, terminated, truncated, info = env.step(policy(observation))
                    total += float(reward)
                    done = terminated or truncated
                returns.append(total)
                collisions += info["collision"]
                arrivals += info["arrived"]
                if info["arrived"]:
                    travel.append(info["travel_time_steps"])
        finally:
            env.close()
        mean_travel = f"{np.mean(travel):.1f}" if travel else "-"
        print(
            f"{task:<9} {np.mean(returns):>8.2f} {collisions:>5}/{args.episodes:<5} "
            f"{arrivals:>4}/{args.episodes:<3} {mean_travel:>13}"
        )
    path = record_episode(args.gif, task="left", seed=args.seed, policy=policy)
    print(f"saved an animated episode to {path}")


if __name__ == "__main__":
    main()
