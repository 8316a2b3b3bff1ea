"""The reward critic learning episodes' returns to go (``DDPGConfig.reward_target="episode"``):
held episodes hand out the n-step transitions, those of an episode that terminated with
their discounted return to its end as reward and marked terminated, so the critic's target
is that return, without its target network; a cut-off episode keeps its n-step
transitions; costs to go are what they are without it; bad settings are refused."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from frl.agents import DDPGConfig, ReplayBuffer
from frl.agents.n_step import NStepAccumulator
from frl.agents.transitions import TransitionWriter
from tests.test_cost_to_go import RiskyRun, push_episode, run_agent

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.mark.parametrize("terminated", [True, False])
def test_a_terminated_episode_hands_out_its_returns_to_go(terminated: bool) -> None:
    costs = [0.0] * 4 + [1.0 if terminated else 0.0]  # rewards 0, 1, 2, 3, 4 (the step)
    held = push_episode(NStepAccumulator(2, 0.5, returns_to_go=True), costs, terminated)
    step_by_step = push_episode(NStepAccumulator(2, 0.5), costs, terminated)
    assert len(held) == len(step_by_step) == 5
    if not terminated:  # cut off: what follows is unknown, so the n-step transitions
        assert held == step_by_step
        return
    # G_t = r_t + 0.5 G_{t+1}, by hand from the last step back: 4, 5, 4.5, 3.25, 1.625
    assert [t.reward for t in held] == [1.625, 3.25, 4.5, 5.0, 4.0]
    assert all(t.terminated for t in held)
    for a, b in zip(held, step_by_step, strict=True):
        assert a._replace(reward=b.reward, terminated=b.terminated) == b
        assert a.cost_to_go is None  # costs to go are another option


def test_costs_to_go_are_unchanged_beside_returns_to_go() -> None:
    costs = [0.0] * 5 + [1.0]
    both = push_episode(
        NStepAccumulator(3, 0.9, hold_episode=True, returns_to_go=True), costs, True
    )
    costs_only = push_episode(NStepAccumulator(3, 0.9, hold_episode=True), costs, True)
    assert [t.cost_to_go for t in both] == [t.cost_to_go for t in costs_only]
    assert [t.cost for t in both] == [t.cost for t in costs_only]


def test_the_writer_stores_returns_to_go_as_terminated_rewards() -> None:
    buffer = ReplayBuffer(50, (1,), 1, np.random.default_rng(0))
    writer = TransitionWriter(buffer, 1, 0.5, returns_to_go=True)
    obs = np.zeros(1)
    for t in range(3):  # arrives at the third step with +4: 1 + 0.5 (1 + 0.5 * 4) = 2.5
        writer.write(obs, obs, 4.0 if t == 2 else 1.0, obs, t == 2)
    for _ in range(2):  # cut off after two steps
        writer.write(obs, obs, 1.0, obs, False)
    assert len(buffer) == 3  # the second episode is still held
    writer.end_episode()
    batch = buffer.gather(np.arange(5))
    np.testing.assert_allclose(batch.rewards.numpy(), [2.5, 3.0, 4.0, 1.0, 1.0])
    np.testing.assert_array_equal(batch.terminated.numpy(), [1, 1, 1, 0, 0])


def test_the_reward_critic_learns_towards_the_return_without_its_target_network() -> None:
    agent = run_agent(reward_target="episode")
    agent.learn(RiskyRun(), 300)
    batch = agent.buffer.gather(np.arange(len(agent.buffer)))
    ended = batch.terminated.numpy() == 1
    assert ended.any() and (~ended).any()  # collisions and time limits both happened
    np.testing.assert_array_equal(ended, batch.costs_final.numpy() == 1)
    nets = agent.networks

    def loss_on(rows: np.ndarray) -> float:
        sub = agent.buffer.gather(np.flatnonzero(rows))
        with torch.no_grad():
            return agent.critic_losses(sub).loss.item()

    before = (loss_on(ended), loss_on(~ended))
    with torch.no_grad():
        for p in nets.critic_target.parameters():
            p.add_(0.5)
    after = (loss_on(ended), loss_on(~ended))
    assert after[0] == before[0]  # returns to go: no bootstrap
    assert after[1] != before[1]  # cut-off episodes still bootstrap


def test_bad_settings_are_refused_in_one_line() -> None:
    with pytest.raises(ValueError, match="with a collision budget set cost_target=episode"):
        DDPGConfig(collision_budget=0.02, cost_target="n_step", reward_target="episode")
    with pytest.raises(ValueError, match="reward_target must be one of n_step, episode"):
        DDPGConfig(reward_target="monte_carlo")
    assert DDPGConfig(reward_target="episode").returns_to_go  # without a budget: allowed
    assert not DDPGConfig().returns_to_go
