"""Stable-Baselines3's TD3 trained on frl's intersection, scored on frl's test protocol.

    pip install -c constraints.txt -e '.[dev]'     # Stable-Baselines3 comes with the tests
    python examples/sb3_td3.py [--steps 10000] [--task random] [--seed 0] [--episodes 100]

One TD3 at Stable-Baselines3's defaults learns on ``frl/Intersection-v0`` (a random task
per episode, as Central-DDPG), then ``frl.evaluate.evaluate_policy`` tests it on the
episodes ``python -m frl.evaluate`` uses for a run with ``--seed``, beside full throttle,
the gap-acceptance driver and the oracle on the same seeds.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
from stable_baselines3 import TD3

import frl.envs  # noqa: F401 (registers frl/Intersection-v0)
from frl.evaluate import evaluate_policy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--task", default="random")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=100)
    args = parser.parse_args()
    env = gym.make("frl/Intersection-v0", task=args.task)
    model = TD3("MlpPolicy", env, seed=args.seed).learn(total_timesteps=args.steps)
    env.close()  # libsumo runs one simulation per process: close it before the test
    evaluate_policy(model, seed=args.seed, episodes=args.episodes, progress=False)


if __name__ == "__main__":
    main()
