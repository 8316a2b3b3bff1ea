"""Loss-adjusted prioritised replay (agent.replay=lap): priorities, proportional draws and
the Huber critic loss by hand, and an agent that samples by TD error and resumes exactly."""

from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium import spaces

from frl.agents import DDPG, DDPGConfig, ReplayBuffer
from frl.agents.prioritized import lap_critic_loss, lap_priority, proportional_slots

OBS = spaces.Box(-1.0, 1.0, (3,), dtype=np.float32)
ACCEL = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def lap(**options: object) -> DDPGConfig:
    base = {"hidden_sizes": (16,), "buffer_size": 64, "learning_starts": 4, "batch_size": 8}
    return DDPGConfig(**{**base, "n_step": 1, "replay": "lap", **options})


def test_priorities_by_hand():
    priorities = lap_priority(np.array([0.0, 0.5, 1.0, 3.0, 32.0]), alpha=0.4, min_priority=1.0)
    expected = [1.0, 1.0, 1.0, 3.0**0.4, 4.0]  # below the minimum: 1; 32 ** 0.4 = 4
    np.testing.assert_allclose(priorities, expected, rtol=1e-6)


def test_the_huber_loss_is_quadratic_below_the_threshold_and_linear_above():
    q, target = torch.tensor([0.5, 3.0]), torch.zeros(2)
    # 0.5 * 0.5**2 = 0.125; 1 * (3 - 0.5) = 2.5
    assert lap_critic_loss(q, target, 1.0).item() == pytest.approx((0.125 + 2.5) / 2)


def test_draws_follow_the_priorities():
    rng = np.random.default_rng(0)
    slots = proportional_slots(np.array([1.0, 0.0, 3.0]), 40_000, rng)
    counts = np.bincount(slots, minlength=3) / 40_000
    assert counts[1] == 0 and counts[2] == pytest.approx(0.75, abs=0.01)


def test_new_transitions_enter_at_the_largest_priority_stored():
    buffer = ReplayBuffer(8, (3,), 1, np.random.default_rng(0), prioritized=True)
    buffer.add(np.ones(3), np.zeros(1), 0.0, np.ones(3), False)
    assert buffer.priorities[0] == 1.0
    buffer.set_priorities(np.array([0]), np.array([2.5]))
    buffer.add(np.ones(3), np.zeros(1), 0.0, np.ones(3), False)
    assert buffer.priorities[:2].tolist() == [2.5, 2.5]
    plain = ReplayBuffer(8, (3,), 1, np.random.default_rng(0))
    with pytest.raises(ValueError, match="no priorities"):
        plain.sample_slots_prioritized(2)


def feed(agent: DDPG, steps: int, seed: int = 0) -> list[dict[str, float]]:
    rng = np.random.default_rng(seed)
    losses = []
    agent.episode_start()
    for t in range(steps):
        o, o2 = (rng.uniform(-1, 1, 3).astype(np.float32) for _ in range(2))
        # A rare large reward: its transitions get large TD errors.
        reward = 20.0 if t % 10 == 9 else float(rng.normal(0, 0.1))
        agent.observe(o, agent.act(o), reward, o2, terminated=t % 10 == 9)
        losses.append(agent.update())
    return losses


def test_a_lap_agent_raises_the_priority_of_its_surprising_transitions():
    agent = DDPG(OBS, ACCEL, lap(), seed=3)
    feed(agent, 40)
    size = len(agent.buffer)
    priorities = agent.buffer.priorities[:size]
    surprising = agent.buffer.rewards[:size] > 10
    assert priorities[surprising].mean() > 2.0 * priorities[~surprising].mean()
    assert priorities.min() >= 1.0  # the minimum priority, never below


def test_a_lap_agent_resumes_exactly(tmp_path: Path):
    agent = DDPG(OBS, ACCEL, lap(), seed=5)
    feed(agent, 30)
    agent.save(tmp_path / "lap.pt", include_buffer=True)
    restored = DDPG.from_checkpoint(tmp_path / "lap.pt", OBS, ACCEL)
    np.testing.assert_array_equal(restored.buffer.priorities[:30], agent.buffer.priorities[:30])
    assert feed(agent, 12, seed=1) == feed(restored, 12, seed=1)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"replay": "per"}, "replay must be one of"),
        ({"lap_alpha": 0.0}, "lap_alpha"),
        ({"lap_alpha": 1.5}, "lap_alpha"),
        ({"lap_min_priority": 0.0}, "lap_min_priority"),
        ({"terminal_fraction": 0.2}, "terminal_fraction"),
    ],
)
def test_bad_replay_settings_fail_clearly(options, message):
    with pytest.raises(ValueError, match=message):
        lap(**options)
