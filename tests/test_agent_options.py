"""The agent's learning options: n-step targets, held warm-up actions, the pre-tanh
penalty and inverting gradients, each against hand-computed numbers or its defining
property."""

from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium import spaces

from frl.agents import DDPG, CheckpointError, DDPGConfig
from frl.agents.n_step import NStepAccumulator

GRID = spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
ACCEL = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
SMALL = DDPGConfig(hidden_sizes=(16,), buffer_size=200, learning_starts=10, batch_size=4)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _obs(value: float) -> np.ndarray:
    return np.full(3, value, np.float32)


def test_n_step_targets_by_hand():
    acc = NStepAccumulator(3, gamma=0.5)
    out = [acc.push(_obs(t), _obs(0), r, _obs(t + 1), False) for t, r in enumerate([1, 2, 4])]
    assert out[0] == [] and out[1] == []
    (first,) = out[2]
    # r0 + 0.5 r1 + 0.25 r2 = 1 + 1 + 1, from s0 to s3 over 3 steps
    assert first.reward == pytest.approx(3.0) and first.horizon == 3
    assert first.obs[0] == 0 and first.next_obs[0] == 3 and not first.terminated
    # The episode terminates: every pending step becomes a terminal transition.
    last = acc.push(_obs(3), _obs(0), 8, _obs(4), True)
    assert [t.horizon for t in last] == [3, 2, 1]
    assert [t.reward for t in last] == pytest.approx([2 + 2 + 2, 4 + 4, 8])
    assert all(t.terminated and t.next_obs[0] == 4 for t in last)
    assert len(acc) == 0


def test_n_step_flush_bootstraps_a_cut_off_episode():
    acc = NStepAccumulator(5, gamma=0.9)
    for t in range(2):
        assert acc.push(_obs(t), _obs(0), 1.0, _obs(t + 1), False) == []
    flushed = acc.flush()
    assert [(t.horizon, t.terminated) for t in flushed] == [(2, False), (1, False)]
    assert flushed[0].reward == pytest.approx(1.9) and flushed[0].next_obs[0] == 2


def test_an_n_step_agent_stores_k_step_transitions_and_discounts_by_gamma_k():
    config = DDPGConfig(**{**SMALL.to_dict(), "n_step": 3, "hidden_sizes": (16,)})
    agent = DDPG(GRID, ACCEL, config)
    rng = np.random.default_rng(0)
    obs = [rng.uniform(0, 1, GRID.shape).astype(np.float32) for _ in range(5)]
    agent.episode_start()
    for t in range(4):
        agent.observe(obs[t], np.array([0.5], np.float32), 1.0, obs[t + 1], terminated=False)
    assert len(agent.buffer) == 2  # steps 0 and 1 have their 3 successors
    agent.episode_start()  # a time limit cut the episode: the last two bootstrap
    assert len(agent.buffer) == 4
    assert agent.buffer.horizons[:4].tolist() == [3, 3, 2, 1]
    assert agent.buffer.rewards[0] == pytest.approx(1 + 0.99 + 0.99**2)
    assert agent.buffer.terminated[:4].tolist() == [0, 0, 0, 0]


def test_held_warm_up_actions_last_geometric_stretches():
    options = {"learning_starts": 2000, "warmup_hold_steps": 10.0, "hidden_sizes": (16,)}
    held = DDPG(GRID, ACCEL, DDPGConfig(**{**SMALL.to_dict(), **options}))
    obs = np.zeros(GRID.shape, np.float32)
    actions = np.array([held.act(obs)[0] for _ in range(2000)])
    changes = int(np.sum(actions[1:] != actions[:-1]))
    assert 150 < changes < 250  # about one change in 10 steps
    assert actions.min() < -0.9 and actions.max() > 0.9  # still uniform over the range
    options = {"learning_starts": 100, "hidden_sizes": (16,), "warmup_hold_steps": 1.0}
    fresh = DDPG(GRID, ACCEL, DDPGConfig(**{**SMALL.to_dict(), **options}))
    table_two = np.array([fresh.act(obs)[0] for _ in range(100)])
    assert np.all(table_two[1:] != table_two[:-1])  # hold 1 (Table II): a new one each step


def test_options_survive_a_checkpoint_and_old_checkpoints_still_load(tmp_path: Path):
    config = DDPGConfig(**{**SMALL.to_dict(), "n_step": 4, "hidden_sizes": (16,)})
    agent = DDPG(GRID, ACCEL, config, seed=3)
    rng = np.random.default_rng(2)
    agent.episode_start()
    for _ in range(6):
        o = rng.uniform(0, 1, GRID.shape).astype(np.float32)
        agent.observe(o, agent.act(o), 0.1, o, terminated=False)
    agent.save(tmp_path / "a.pt", include_buffer=True)
    restored = DDPG(GRID, ACCEL, config, seed=99)
    restored.restore(tmp_path / "a.pt")
    assert len(restored.writer.pending) == len(agent.writer.pending) == 3
    restored.episode_start()
    agent.episode_start()
    np.testing.assert_array_equal(restored.buffer.horizons[:6], agent.buffer.horizons[:6])

    # A checkpoint written before these options existed: its config lacks their keys,
    # and its agent ran with one-step targets and fresh warm-up actions every step.
    legacy = {"n_step": 1, "warmup_hold_steps": 1.0, "hidden_sizes": (16,)}
    plain = DDPG(GRID, ACCEL, DDPGConfig(**{**SMALL.to_dict(), **legacy}))
    plain.save(tmp_path / "old.pt")
    data = torch.load(tmp_path / "old.pt", weights_only=True)
    for key in ("n_step", "warmup_hold_steps"):
        del data["config"][key]
    del data["n_step"], data["warmup_action"]
    torch.save(data, tmp_path / "old.pt")
    plain.restore(tmp_path / "old.pt")
    rebuilt = DDPG.from_checkpoint(tmp_path / "old.pt", GRID, ACCEL)
    assert (rebuilt.config.n_step, rebuilt.config.warmup_hold_steps) == (1, 1.0)
    with pytest.raises(CheckpointError, match="n_step"):  # not today's default agent
        DDPG(GRID, ACCEL, DDPGConfig(**{**SMALL.to_dict(), "hidden_sizes": (16,)})).restore(
            tmp_path / "old.pt"
        )


def test_n_step_over_transitions_that_span_several_steps():
    acc = NStepAccumulator(2, gamma=0.5)
    assert acc.push(_obs(0), _obs(0), 1.0, _obs(3), False, horizon=3) == []
    (first,) = acc.push(_obs(3), _obs(0), 4.0, _obs(5), False, horizon=2)
    # 1 + 0.5**3 * 4: the second reward comes 3 steps after the first
    assert first.reward == pytest.approx(1.5) and first.horizon == 5


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("n_step", 0),
        ("warmup_hold_steps", 0.5),
        ("actor_update", "clip"),
    ],
)
def test_bad_option_values_fail_clearly(field, value):
    with pytest.raises(ValueError, match=field):
        DDPGConfig(**{field: value})


def quick_config(**options: object) -> DDPGConfig:
    base = {"hidden_sizes": (16,), "n_step": 1, "learning_starts": 4, "batch_size": 4}
    return DDPGConfig(**{**SMALL.to_dict(), **base, **options})


def feed(agent: DDPG, steps: int, seed: int = 0) -> list[dict[str, float]]:
    rng = np.random.default_rng(seed)
    losses = []
    agent.episode_start()
    for t in range(steps):
        o, o2 = (rng.uniform(0, 1, GRID.shape).astype(np.float32) for _ in range(2))
        agent.observe(o, agent.act(o), float(rng.normal()), o2, terminated=t % 5 == 4)
        losses.append(agent.update())
    return losses


class SlopeCritic(torch.nn.Module):
    """Q(s, a) = slope * a: the critic's gradient dQ/da is ``slope`` everywhere."""

    def __init__(self, slope: float) -> None:
        super().__init__()
        self.slope = slope

    def forward(self, obs: object, action: torch.Tensor) -> torch.Tensor:
        return self.slope * action.squeeze(-1)


def inverting_gradients_loss_of(agent: DDPG, batch) -> torch.Tensor:
    """The actor's loss as its update computes it, inverting gradients."""
    preactivation = agent.actor.preactivation(batch.obs)
    action = agent.bounded_action(preactivation)
    q_policy = agent.objective(batch.obs, action)
    (dq_da,) = torch.autograd.grad(q_policy.sum(), action)
    return agent.actor_losses(batch, preactivation, q_policy, dq_da)[0]


def test_inverting_gradients_scale_dq_da_by_the_room_left_and_turn_round_past_a_bound():
    agent = DDPG(GRID, ACCEL, quick_config(actor_update="inverting_gradients"), seed=10)
    assert agent.actor.output == agent.actor_target.output == "clip"
    feed(agent, 4)
    batch = agent.buffer.gather(np.arange(4), sparse=agent.sparse)
    agent.networks.critic = SlopeCritic(-2.0)  # the critic asks for less everywhere
    with torch.no_grad():
        agent.actor.layers[-1].bias.fill_(1.5)  # past the upper bound
        p = agent.actor.preactivation(batch.obs).squeeze(-1)
    agent.actor_optimizer.zero_grad()
    inverting_gradients_loss_of(agent, batch).backward()
    # d(surrogate)/d(bias) = mean of -(dQ/da) * (p + 1) / 2 = mean of (p + 1)
    expected = float((p + 1.0).mean())
    assert agent.actor.layers[-1].bias.grad.item() == pytest.approx(expected, rel=1e-5)
    for _ in range(300):  # comes back from past +1 and settles at the lower bound
        agent._descend(agent.actor_optimizer, inverting_gradients_loss_of(agent, batch))
    with torch.no_grad():
        actions = agent.actor(batch.obs)
        p = agent.actor.preactivation(batch.obs)
    assert torch.all(actions < -0.9) and torch.all(p > -1.2)
