"""The one learning test: DDPG swings up gymnasium's Pendulum-v1, trained by ``DDPG.learn``.

Pendulum episodes end only by the 200-step time limit (truncated, never terminated), so
learning here also depends on truncated transitions bootstrapping. Seeds 0-5 all reached
-120 to -270 mean return over the last 10 episodes at this budget; random play scores
about -1200 and the threshold is -400. ``benchmarks/pendulum.py`` runs the same check in
bf16, which most CPUs emulate several times slower.
"""

import gymnasium as gym
import numpy as np
import pytest

from frl.agents import DDPG, DDPGConfig

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.mark.slow
def test_learns_pendulum_swing_up() -> None:
    precision = "float32"
    steps = 8_000
    config = DDPGConfig(
        hidden_sizes=(64, 64),
        buffer_size=steps,
        learning_starts=1_000,
        batch_size=128,
        tau=0.005,
        actor_lr=1e-3,
        critic_lr=1e-3,
        noise="gaussian",
        noise_sigma=0.1,  # normalised units: 0.2 N m on Pendulum's [-2, 2] torque
        precision=precision,
    )
    env = gym.make("Pendulum-v1")
    agent = DDPG(env.observation_space, env.action_space, config, seed=0)
    agent.learn(env, steps)  # the first reset seeded with the agent's seed
    env.close()
    returns = agent.episode_returns
    assert len(returns) == steps // 200
    assert np.mean(returns[-10:]) > -400, returns[-10:]
