"""The cost critic learning episodes' costs to go (``DDPGConfig.cost_target="episode"``):
held episodes hand out the same n-step transitions, each with its discounted cost to the
episode's end where the episode terminated; the buffer keeps it and marks it; the cost
critic's target is that cost there, without its target network; checkpoints resume a held
episode exactly; bad settings are refused."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces

from frl.agents import DDPG, DDPGConfig, ReplayBuffer
from frl.agents.config import NoiseConfig
from frl.agents.n_step import NStepAccumulator
from frl.agents.transitions import TransitionWriter

pytestmark = pytest.mark.usefixtures("one_torch_thread")

ONE = spaces.Box(-1.0, 1.0, (1,), np.float32)


def push_episode(steps: NStepAccumulator, costs: list[float], terminated: bool) -> list:
    """One episode of ``len(costs)`` steps (observation = step index), every transition
    the accumulator hands out along the way."""
    out = []
    for t, cost in enumerate(costs):
        last = terminated and t == len(costs) - 1
        out += steps.push(np.full(1, t), np.zeros(1), float(t), np.full(1, t + 1), last, 1, cost)
    if not terminated:
        out += steps.flush()
    return out


@pytest.mark.parametrize("terminated", [True, False])
def test_a_held_episode_hands_out_the_transitions_n_steps_would(terminated: bool) -> None:
    costs = [0.0] * 6 + [1.0 if terminated else 0.0]
    held = push_episode(NStepAccumulator(3, 0.5, hold_episode=True), costs, terminated)
    step_by_step = push_episode(NStepAccumulator(3, 0.5), costs, terminated)
    assert len(held) == len(step_by_step) == 7
    for a, b in zip(held, step_by_step, strict=True):
        assert a._replace(cost_to_go=None) == b
        assert b.cost_to_go is None
    if terminated:  # a collision at the 7th step, discounted back by 0.5 a step
        assert [t.cost_to_go for t in held] == [0.5**k for k in range(6, -1, -1)]
    else:  # cut off: what follows is unknown, so no cost to go
        assert all(t.cost_to_go is None for t in held)


def test_a_held_episode_hands_out_nothing_before_its_end_and_an_arrival_costs_nothing() -> None:
    steps = NStepAccumulator(2, 0.9, hold_episode=True)
    obs = np.zeros(1)
    assert steps.push(obs, obs, 1.0, obs, False) == []
    assert steps.push(obs, obs, 1.0, obs, False) == []
    assert len(steps) == 2
    done = steps.push(obs, obs, 5.0, obs, True)
    assert [t.cost_to_go for t in done] == [0.0, 0.0, 0.0]
    assert [t.horizon for t in done] == [2, 2, 1]


def test_a_held_episode_round_trips_a_checkpoint_mid_way() -> None:
    steps = NStepAccumulator(3, 0.5, hold_episode=True)
    push_episode(steps, [0.0] * 5, terminated=True)  # an episode before (arrived)
    obs = np.zeros(1)
    for t in range(4):
        steps.push(np.full(1, t), obs, 1.0, np.full(1, t + 1), False, 1, 0.0)
    restored = NStepAccumulator(3, 0.5, hold_episode=True)
    restored.load_state_dict(steps.state_dict())
    end = (np.full(1, 4), obs, -10.0, np.full(1, 5), True, 1, 1.0)
    a, b = steps.push(*end), restored.push(*end)
    assert len(a) == 5
    for x, y in zip(a, b, strict=True):
        assert x.cost_to_go == y.cost_to_go and x.cost == y.cost and x.horizon == y.horizon
        np.testing.assert_array_equal(x.obs, y.obs)


def test_the_buffer_keeps_costs_to_go_marked_and_the_writer_stores_them() -> None:
    buffer = ReplayBuffer(50, (1,), 1, np.random.default_rng(0), costed=True, costs_to_go=True)
    writer = TransitionWriter(buffer, 2, 0.5, hold_episode=True)
    obs = np.zeros(1)
    for t in range(3):  # a collision at the third step
        writer.write(obs, obs, 0.0, obs, t == 2, cost=float(t == 2))
    for _ in range(3):  # cut off after three steps
        writer.write(obs, obs, 0.0, obs, False, cost=0.0)
    assert len(buffer) == 3  # the second episode is still held
    writer.end_episode()
    batch = buffer.gather(np.arange(6))
    np.testing.assert_allclose(batch.costs.numpy(), [0.25, 0.5, 1.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(batch.costs_final.numpy(), [1, 1, 1, 0, 0, 0])
    state = buffer.state_dict()
    copy = ReplayBuffer(50, (1,), 1, np.random.default_rng(1), costed=True, costs_to_go=True)
    copy.load_state_dict(state)
    np.testing.assert_array_equal(copy.gather(np.arange(6)).costs_final, batch.costs_final)


def test_bad_settings_are_refused_in_one_line() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="costs to go only where it keeps costs"):
        ReplayBuffer(10, (1,), 1, rng, costs_to_go=True)
    with pytest.raises(ValueError, match="needs a buffer that keeps them"):
        TransitionWriter(ReplayBuffer(10, (1,), 1, rng, costed=True), 1, 0.9, hold_episode=True)
    with pytest.raises(ValueError, match="does not keep costs to go"):
        ReplayBuffer(10, (1,), 1, rng, costed=True).add(
            np.zeros(1), np.zeros(1), 0.0, np.zeros(1), True, cost=1.0, cost_final=True
        )
    with pytest.raises(ValueError, match="cost_target tunes the collision budget"):
        DDPGConfig(cost_target="n_step")
    with pytest.raises(ValueError, match="cost_target must be one of n_step, episode"):
        DDPGConfig(collision_budget=0.1, cost_target="monte_carlo")


def test_a_budget_learns_costs_to_go_by_default_and_one_saved_before_loads_as_it_ran() -> None:
    assert DDPGConfig(collision_budget=0.02).costs_to_go
    assert not DDPGConfig().costs_to_go  # no budget, no cost critic
    saved = DDPGConfig(collision_budget=0.02).to_dict()
    del saved["cost_target"]  # a budget saved before the field learned by n-step targets
    assert DDPGConfig.from_dict(saved).cost_target == "n_step"
    unbudgeted = {**DDPGConfig().to_dict(), "cost_target": "n_step"}  # saved then, no budget
    assert DDPGConfig.from_dict(unbudgeted) == DDPGConfig()


class RiskyRun(gym.Env):
    """Up to 6 steps: a speed a pays 1 + a; above 0.5 from the third step on it crashes
    (cost 1, terminated); after 6 steps a time limit cuts the episode off."""

    observation_space = ONE
    action_space = ONE

    def reset(self, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(1, np.float32), {}

    def step(self, action):
        self.t += 1
        speed = float(np.clip(np.asarray(action).reshape(-1)[0], -1.0, 1.0))
        crash = self.t >= 3 and speed > 0.5
        obs = np.full(1, self.t / 6, np.float32)
        return obs, 1.0 + speed, crash, self.t >= 6 and not crash, {"cost": float(crash)}


def run_agent(seed: int = 0, **options: object) -> DDPG:
    config = DDPGConfig(
        hidden_sizes=(16, 16), learning_starts=40, batch_size=16, buffer_size=2000, n_step=2,
        noise=NoiseConfig("gaussian", 0.5), actor_lr=1e-3, critic_lr=1e-3, tau=0.05,
        warmup_hold_steps=1.0, collision_budget=0.1, cost_target="episode", **options,
    )  # fmt: skip
    return DDPG(ONE, ONE, config, seed=seed)


def test_the_cost_critic_learns_towards_the_cost_to_go_without_its_target_network() -> None:
    agent = run_agent()
    agent.learn(RiskyRun(), 300)
    batch = agent.buffer.gather(np.arange(len(agent.buffer)))
    final = batch.costs_final.numpy() == 1
    assert final.any() and (~final).any()  # collisions and time limits both happened
    assert batch.costs.numpy()[final].max() == 1.0  # a crash's own step
    nets, constraint = agent.networks, agent.constraint

    def loss_on(rows: np.ndarray) -> float:
        sub = agent.buffer.gather(np.flatnonzero(rows))
        with torch.no_grad():
            _, hidden = nets.critic.values_and_hidden(sub.obs, sub.actions)
            next_actions = nets.actor_target(sub.next_obs)
            _, next_hidden = nets.critic_target.values_and_hidden(sub.next_obs, next_actions)
            loss, _ = constraint.losses(sub, next_actions, agent.discount(sub), hidden, next_hidden)
        return loss.item()

    before = (loss_on(final), loss_on(~final))
    with torch.no_grad():
        for p in nets.cost_critic_target.parameters():
            p.add_(0.5)
    after = (loss_on(final), loss_on(~final))
    assert after[0] == before[0]  # costs to go: no bootstrap
    assert after[1] != before[1]  # cut-off episodes still bootstrap


def test_an_agent_learning_costs_to_go_resumes_exactly_mid_episode(tmp_path: Path) -> None:
    agent = run_agent(seed=3)
    agent.learn(RiskyRun(), 200)
    env = RiskyRun()
    obs, _ = env.reset(seed=1)
    for _ in range(2):  # two steps into an episode, held, not yet stored
        action = agent.act(obs)
        next_obs, reward, terminated, truncated, info = env.step(action)
        agent.observe(obs, action, reward, next_obs, terminated, cost=info["cost"])
        agent.update()
        obs = next_obs
    assert len(agent.writer.pending) == 2
    agent.save(tmp_path / "a.pt", include_buffer=True)
    restored = run_agent(seed=99)
    restored.restore(tmp_path / "a.pt")
    assert len(restored.writer.pending) == 2
    np.testing.assert_array_equal(restored.buffer.costs_final, agent.buffer.costs_final)
    for learner in (agent, restored):
        copy = RiskyRun()
        copy.reset(seed=1)
        copy.t = 2
        o = obs
        for _ in range(30):
            action = learner.act(o)
            next_o, reward, terminated, truncated, info = copy.step(action)
            learner.observe(o, action, reward, next_o, terminated, cost=info["cost"])
            learner.update()
            o = next_o
            if terminated or truncated:
                o, _ = copy.reset()
                learner.episode_start()
    state, other = agent.federated_state(), restored.federated_state()
    for key, tensor in state.items():
        assert torch.equal(tensor, other[key]), key
    np.testing.assert_array_equal(restored.buffer.costs, agent.buffer.costs)
