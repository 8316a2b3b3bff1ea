"""Self-imitation (DDPGConfig.self_imitation): each stored transition's realised return to
its episode's end, the imitation term, the comparison with the reward critic, resume;
each against hand-computed numbers or its defining property."""

from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium import spaces

from frl.agents import DDPG, DDPGConfig
from frl.agents.guide import self_imitation_loss
from frl.agents.replay_buffer import ReplayBuffer
from frl.agents.transitions import TransitionWriter

GRID = spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
ACCEL = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def writer_of(capacity: int = 50, n_step: int = 3) -> TransitionWriter:
    buffer = ReplayBuffer(capacity, (2,), 1, np.random.default_rng(0), tracks_returns=True)
    return TransitionWriter(buffer, n_step, gamma=0.5)


def write_episode(writer: TransitionWriter, rewards: list[float], costs: list[float],
                  terminated: bool) -> None:  # fmt: skip
    obs = np.zeros(2, np.float32)
    for t, (reward, cost) in enumerate(zip(rewards, costs, strict=True)):
        last = terminated and t == len(rewards) - 1
        writer.write(obs, np.zeros(1, np.float32), reward, obs, last, cost)
    writer.end_episode()


def test_an_ended_episode_labels_each_transition_with_its_return_to_go():
    writer = writer_of()
    write_episode(writer, [1.0, 2.0, 4.0, 8.0], [0.0, 0.0, 0.0, 1.0], terminated=True)
    buffer = writer.buffer
    # gamma 0.5: G3 = 8, G2 = 4 + 4 = 8, G1 = 2 + 4 = 6, G0 = 1 + 3 = 4
    assert buffer.returns_to_go[:4].tolist() == [4.0, 6.0, 8.0, 8.0]
    batch = buffer.gather(np.array([3, 0]))
    assert batch.returns_to_go.tolist() == [8.0, 4.0]


def test_a_cut_off_episode_stays_unknown_and_a_rewritten_slot_forgets_its_return():
    writer = writer_of(capacity=6)
    write_episode(writer, [1.0, 1.0, 1.0], [0.0] * 3, terminated=False)  # a time limit
    assert np.isnan(writer.buffer.returns_to_go[:3]).all()
    write_episode(writer, [2.0, 2.0], [0.0] * 2, terminated=True)
    assert writer.buffer.returns_to_go[3:5].tolist() == [3.0, 2.0]
    write_episode(writer, [5.0, 5.0], [0.0] * 2, terminated=False)  # wraps onto slot 0
    assert np.isnan(writer.buffer.returns_to_go[[5, 0]]).all()
    assert writer.buffer.returns_to_go[3:5].tolist() == [3.0, 2.0]


def test_an_episode_longer_than_the_buffer_labels_only_the_slots_it_still_holds():
    writer = writer_of(capacity=3, n_step=1)
    write_episode(writer, [0.0, 0.0, 4.0, 2.0, 8.0], [0.0] * 5, terminated=True)
    # Steps 2, 3, 4 (returns 7, 6, 8) now lie in slots 2, 0, 1.
    assert writer.buffer.returns_to_go.tolist() == [6.0, 8.0, 7.0]


def test_the_self_imitation_loss_by_hand():
    preactivation = torch.tensor([[0.5], [1.5], [-0.5], [0.0]])
    taken = torch.tensor([[1.0], [1.0], [0.5], [-1.0]])
    realised = torch.tensor([2.0, 2.0, 0.0, float("nan")])
    expected = torch.tensor([1.0, 1.0, 1.0, -5.0])
    loss, share = self_imitation_loss(preactivation, taken, realised, expected)
    # Better than expected: samples 0 (gap 0.25) and 1 (past +1: 0); 2 worse; 3 unknown.
    assert loss.item() == pytest.approx(0.25 / 4)
    assert share.item() == pytest.approx(0.5)


def small(**options: object) -> DDPGConfig:
    base = {
        "hidden_sizes": (16,), "buffer_size": 200, "learning_starts": 4, "batch_size": 8,
        "n_step": 2, "precision": "float32", "self_imitation": 1.0,
    }  # fmt: skip
    return DDPGConfig(**{**base, **options})


def test_the_term_pulls_the_actor_towards_actions_that_went_better_than_expected():
    agent = DDPG(GRID, ACCEL, small(actor_lr=1e-3, critic_lr=1e-6, self_imitation=10.0), seed=2)
    empty = np.zeros(GRID.shape, np.float32)
    stats = []
    for _ in range(300):  # one-step episodes: braking pays +1, the critic barely learns
        agent.observe(empty, np.array([-0.8], np.float32), 1.0, empty, True)
        stats += [losses for losses in [agent.update()] if losses]
    assert stats[-1]["self_imitation_share"] == 1.0
    assert stats[-1]["self_imitation_loss"] < 0.1 * stats[0]["self_imitation_loss"]
    assert agent.predict(empty)[0][0] == pytest.approx(-0.8, abs=0.05)


def test_under_a_budget_the_return_is_compared_with_the_reward_critic_not_the_objective():
    agent = DDPG(GRID, ACCEL, small(collision_budget=0.02), seed=2)
    agent.constraint.multiplier_now.fill_(3.0)
    agent.constraint.price_denominator.fill_(4.0)
    empty = np.zeros(GRID.shape, np.float32)
    for _ in range(8):
        agent.observe(empty, np.array([0.5], np.float32), 1.0, empty, True)
    batch = agent.buffer.gather(np.arange(8), agent.sparse, transposed=False)
    with torch.no_grad():
        action = torch.full((8, 1), 0.5)
        objective, value = agent.objective_and_value(batch.obs, action)
        assert torch.equal(value, agent.critic(batch.obs, action))
        assert torch.equal(objective, agent.objective(batch.obs, action))
        preactivation = torch.zeros(8, 1)
        below = batch._replace(returns_to_go=value - 0.01)
        _, stats = agent.actor_losses(below, preactivation, value - 1.0, None, value)
        assert stats["self_imitation_share"].item() == 0.0  # the objective would say 1
        _, stats = agent.actor_losses(below, preactivation, value - 1.0, None)
        assert stats["self_imitation_share"].item() == 1.0  # no value given: the objective


def test_a_run_interrupted_mid_episode_labels_the_episode_as_the_uninterrupted_one(
    tmp_path: Path,
):
    def steps(agent: DDPG, start: int, stop: int) -> None:
        for t in range(start, stop):
            obs = np.full(GRID.shape, 0.01 * (t % 7), np.float32)
            agent.observe(obs, np.array([0.1 * (t % 5) - 0.2]), float(t % 3), obs, t % 9 == 8)
            agent.update()

    config = small(collision_budget=0.1)
    whole = DDPG(GRID, ACCEL, config, seed=5)
    steps(whole, 0, 40)
    first = DDPG(GRID, ACCEL, config, seed=5)
    steps(first, 0, 22)  # mid-episode: steps 18-21 of the episode ending at 26
    first.save(tmp_path / "mid.pt", include_buffer=True)
    resumed = DDPG.from_checkpoint(tmp_path / "mid.pt", GRID, ACCEL)
    steps(resumed, 22, 40)
    np.testing.assert_array_equal(resumed.buffer.returns_to_go, whole.buffer.returns_to_go)
    assert not np.isnan(whole.buffer.returns_to_go[18:27]).any()
    for key, value in whole.federated_state().items():
        assert torch.equal(value, resumed.federated_state()[key]), key


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"self_imitation": -1.0}, "self_imitation must be >= 0"),
        ({"self_imitation": float("nan")}, "self_imitation must be >= 0"),
        ({"critic": {"kind": "quantile"}}, "self_imitation .* needs critic.kind=expected"),
    ],
)
def test_bad_self_imitation_settings_fail_clearly(options, message):
    with pytest.raises(ValueError, match=message):
        small(**options)


def test_without_the_term_the_buffer_keeps_no_returns():
    agent = DDPG(GRID, ACCEL, small(self_imitation=0.0), seed=1)
    assert agent.buffer.returns_to_go.size == 0 and agent.writer.returns is None
