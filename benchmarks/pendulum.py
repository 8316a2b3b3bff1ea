"""DDPG swings up gymnasium's Pendulum-v1 at each precision: the learning check of
tests/test_agent_learning.py (float32) run at the others too.

    python benchmarks/pendulum.py [--precisions float32,bf16] [--seed 0]

Each precision trains the test's agent for 8,000 steps (``DDPG.learn``) and passes when
the mean return of the last 10 episodes is above -400 (random play scores about -1200;
seeds 0-5 reached -120 to -270 in float32). bf16 where the CPU lacks it natively is
emulated and several times slower, which is why the test suite checks float32 alone.
Exit code 1 when a precision misses the bar.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings

import gymnasium as gym
import numpy as np
import torch

from frl.agents import DDPG, DDPGConfig
from frl.agents.config import NoiseConfig

STEPS = 8_000
THRESHOLD = -400.0


def pendulum_config(precision: str) -> DDPGConfig:
    """The test's agent: small networks, fast rates, Gaussian noise of 0.2 N m."""
    return DDPGConfig(
        hidden_sizes=(64, 64),
        buffer_size=STEPS,
        learning_starts=1_000,
        batch_size=128,
        tau=0.005,
        actor_lr=1e-3,
        critic_lr=1e-3,
        noise=NoiseConfig("gaussian", sigma=0.1),  # normalised: 0.2 N m on [-2, 2] torque
        precision=precision,
    )


def training_returns(precision: str, seed: int) -> list[float]:
    """The returns of the training episodes, in order (the first reset seeded with
    ``seed``, the agent's)."""
    env = gym.make("Pendulum-v1")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # emulated bf16 says so once
        agent = DDPG(env.observation_space, env.action_space, pendulum_config(precision), seed)
    agent.learn(env, STEPS)
    env.close()
    return agent.episode_returns


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--precisions", default="float32,bf16")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    failed = False
    for precision in args.precisions.split(","):
        began = time.perf_counter()
        score = float(np.mean(training_returns(precision, args.seed)[-10:]))
        passed = score > THRESHOLD
        failed |= not passed
        verdict = "passes" if passed else "MISSES"
        print(f"{precision}: last 10 episodes {score:.0f} ({verdict} > {THRESHOLD:.0f}), "
              f"{time.perf_counter() - began:.0f} s")  # fmt: skip
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
