"""An ensemble critic: bootstrap masks, the masked loss, heads that disagree where the
data are few, the price the actor pays on it, the agent's state and bad options."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium import spaces

from frl.agents import DDPG, DDPGConfig
from frl.agents.config import CriticConfig, NoiseConfig
from frl.agents.ensemble import (
    bootstrap_masks,
    disagreement,
    ensemble_critic_loss,
    pessimistic_value,
)
from frl.agents.networks import Critic

pytestmark = pytest.mark.usefixtures("one_torch_thread")

ONE = spaces.Box(-1.0, 1.0, (1,), np.float32)


def ensemble_config(heads: int = 4, price: float = 1.0, **options: object) -> DDPGConfig:
    return DDPGConfig(
        hidden_sizes=(16, 16), learning_starts=50, batch_size=16, buffer_size=500,
        noise=NoiseConfig("gaussian", 0.1), actor_lr=1e-3, critic_lr=1e-3, tau=0.01,
        critic=CriticConfig("ensemble", heads=heads, disagreement_price=price),
        precision="float32", **options,
    )  # fmt: skip


def trained_agent(config: DDPGConfig, seed: int = 0, steps: int = 120) -> DDPG:
    agent = DDPG(ONE, ONE, config, seed=seed)
    rng = np.random.default_rng(seed)
    obs = np.ones(1, np.float32)
    for _ in range(steps):
        action = agent.act(obs)
        reward = float(1.0 + action[0] + 0.1 * rng.standard_normal())
        agent.observe(obs, action, reward, obs, True)
        agent.update()
    return agent


def test_bootstrap_masks_are_a_fixed_half_per_slot_and_head() -> None:
    masks = bootstrap_masks(np.random.SeedSequence(7), 4000, 5)
    assert masks.shape == (4000, 5) and masks.dtype == torch.bool
    assert masks.float().mean().item() == pytest.approx(0.5, abs=0.02)
    assert torch.equal(masks, bootstrap_masks(np.random.SeedSequence(7), 4000, 5))
    assert not torch.equal(masks, bootstrap_masks(np.random.SeedSequence(8), 4000, 5))
    # Heads learn from different halves: no two columns are the same.
    assert all(not torch.equal(masks[:, i], masks[:, j]) for i in range(5) for j in range(i))


def test_a_masked_pair_neither_counts_in_the_loss_nor_learns() -> None:
    q = torch.tensor([[1.0, 2.0], [3.0, 5.0]], requires_grad=True)
    rewards, terminated = torch.tensor([1.0, 0.0]), torch.tensor([0.0, 1.0])
    next_q = torch.tensor([[2.0, 4.0], [9.0, 9.0]])
    mask = torch.tensor([[True, False], [True, True]])
    loss, error = ensemble_critic_loss(q, rewards, terminated, next_q, 0.5, mask)
    # Targets: [1 + 0.5 * 2, 1 + 0.5 * 4] = [2, 3]; [0, 0] (terminated).
    assert loss.item() == pytest.approx(((1 - 2) ** 2 + 3**2 + 5**2) / 3)
    assert error.item() == pytest.approx((abs(1.5 - 2.5) + abs(4.0 - 0.0)) / 2)
    loss.backward()
    assert q.grad[0, 1].item() == 0.0 and q.grad[0, 0].item() != 0.0


def test_the_price_is_the_heads_spread() -> None:
    values = torch.tensor([[1.0, 3.0], [2.0, 2.0]])
    assert disagreement(values).tolist() == [1.0, 0.0]
    assert pessimistic_value(values, 2.0).tolist() == [0.0, 2.0]
    assert pessimistic_value(values, 0.0).tolist() == [2.0, 2.0]


def test_bootstrapped_heads_disagree_where_crashes_are_rare() -> None:
    """Many safe slow samples, a handful of fast ones of which some crashed: the heads
    agree where the data are many and disagree where each saw another few crashes."""
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    slow = rng.uniform(-1.0, 0.0, 600)
    fast = rng.uniform(0.6, 1.0, 8)
    actions = torch.tensor(np.concatenate([slow, fast]), dtype=torch.float32).view(-1, 1)
    rewards = torch.tensor(
        np.concatenate([np.ones(600), np.where(np.arange(8) % 2 == 0, -10.0, 2.0)]),
        dtype=torch.float32,
    )
    observations = torch.ones(len(actions), 1)
    critic = Critic(1, 1, (32, 32), outputs=6)
    masks = bootstrap_masks(np.random.SeedSequence(1), len(actions), 6)
    optimizer = torch.optim.Adam(critic.parameters(), lr=3e-3)
    done = torch.ones(len(actions))
    for _ in range(600):
        q = critic(observations, actions)
        loss, _ = ensemble_critic_loss(q, rewards, done, torch.zeros_like(q), 0.99, masks)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    with torch.no_grad():
        probe = torch.tensor([[-0.5], [0.8]])
        spread = disagreement(critic(torch.ones(2, 1), probe))
    assert spread[1] > 5 * spread[0] and spread[1] > 1.0


def test_the_agent_learns_heads_and_its_actor_pays_for_their_spread() -> None:
    agent = trained_agent(ensemble_config(heads=4, price=2.0))
    assert agent.head_masks is not None and agent.head_masks.shape == (500, 4)
    losses = agent.update()
    assert losses and losses["critic_disagreement"] > 0
    obs = torch.ones(8, 1)
    actions = torch.linspace(-1, 1, 8).view(-1, 1)
    with torch.no_grad():
        heads = agent.networks.critic(obs, actions)
        objective = agent._objective(obs, actions)
    assert heads.shape == (8, 4)
    torch.testing.assert_close(objective, heads.mean(-1) - 2.0 * heads.std(-1, correction=0))
    # What the analysis tools read: the heads' mean.
    readings = agent.critic_values(np.ones((8, 1), np.float32), actions.numpy())
    np.testing.assert_allclose(readings, heads.mean(-1).double().numpy(), rtol=1e-6)


def test_one_seed_gives_one_ensemble_run_and_a_checkpoint_restores_it(tmp_path: Path) -> None:
    config = ensemble_config()
    first, second = trained_agent(config, seed=3), trained_agent(config, seed=3)
    for key, tensor in first.federated_state().items():
        assert torch.equal(tensor, second.federated_state()[key]), key
    other = trained_agent(config, seed=4)
    assert not torch.equal(other.head_masks, first.head_masks)
    path = tmp_path / "ensemble.pt"
    first.save(path)
    loaded = DDPG.load(path)
    assert loaded.config.critic == config.critic
    assert torch.equal(loaded.head_masks, first.head_masks)
    probe = np.ones((3, 1), np.float32), np.array([[-0.5], [0.0], [0.5]], np.float32)
    np.testing.assert_array_equal(loaded.critic_values(*probe), first.critic_values(*probe))


def test_a_plain_critic_has_no_masks() -> None:
    plain = DDPG(ONE, ONE, DDPGConfig(hidden_sizes=(8,), buffer_size=100, batch_size=8), seed=5)
    assert plain.head_masks is None


@pytest.mark.parametrize(
    ("critic", "message"),
    [
        ({"heads": 3}, "critic.heads is the ensemble critic's: set critic.kind=ensemble"),
        ({"disagreement_price": 2.0}, "critic.disagreement_price is the ensemble critic's"),
        ({"kind": "ensemble", "heads": 1}, "critic.heads must be at least 2, got 1"),
        ({"kind": "ensemble", "heads": 0}, "critic.heads must be a positive integer"),
        ({"kind": "ensemble", "disagreement_price": -1.0}, "disagreement_price must be >= 0"),
        ({"kind": "ensemble", "disagreement_price": float("nan")}, "disagreement_price must"),
    ],
)
def test_bad_ensemble_options_are_refused_naming_the_key(critic: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        DDPGConfig(critic=critic)
