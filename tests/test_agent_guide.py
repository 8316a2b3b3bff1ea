"""A guided agent (DDPGConfig.guide): the teacher's actions stored with every transition,
the Q-filtered imitation term and its schedule, each against hand-computed numbers or
its defining property."""

from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium import spaces
from test_agent_options import feed

from frl.agents import DDPG, DDPGConfig
from frl.agents.guide import imitation_loss, imitation_term, lower_only, q_filter

GRID = spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
ACCEL = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def guided(**options: object) -> DDPGConfig:
    base = {
        "hidden_sizes": (16,),
        "buffer_size": 200,
        "learning_starts": 4,
        "batch_size": 4,
        "n_step": 1,
        "guide": "gap_acceptance",
        "guide_weight": 1.0,
    }
    return DDPGConfig(**{**base, **options})


def brake_when_crowded(observation: np.ndarray) -> np.ndarray:
    """A teacher that brakes when the first cell is occupied, else goes: -1 or +1."""
    return np.array([-1.0 if observation.reshape(-1)[0] > 0.5 else 1.0], np.float32)


def test_the_q_filter_lets_the_actor_leave_only_where_the_critic_prefers_it():
    q_teacher = torch.tensor([1.0, 1.0, 1.0, 1.0])
    q_actor = torch.tensor([0.5, 1.0, 1.4, 2.0])
    assert q_filter(q_teacher, q_actor).tolist() == [1.0, 1.0, 0.0, 0.0]


def test_a_lower_only_filter_lets_the_actor_leave_the_teacher_only_to_brake():
    mask = torch.tensor([0.0, 0.0, 1.0, 0.0])  # the Q-filter: leave on 0, 1 and 3
    actor = torch.tensor([[-1.0], [1.0], [-1.0], [0.5]])
    teacher = torch.tensor([[1.0], [-1.0], [1.0], [0.5]])
    # 0: brakes where the teacher goes (may leave); 1: goes where it brakes (imitates);
    # 2: the critic prefers the teacher (imitates); 3: the same action (imitates).
    assert lower_only(mask, actor, teacher).tolist() == [0.0, 1.0, 1.0, 1.0]


def test_the_imitation_loss_by_hand():
    preactivation = torch.tensor([[0.5], [1.5], [-0.5], [-1.5], [0.0]])
    teacher = torch.tensor([[1.0], [1.0], [-1.0], [1.0], [-1.0]])
    mask = torch.tensor([1.0, 1.0, 1.0, 1.0, 0.0])
    # 0.25; past the teacher's +1 bound: 0; 0.25; 6.25; masked out: 0
    expected = (0.25 + 0.0 + 0.25 + 6.25 + 0.0) / 5
    assert imitation_loss(preactivation, teacher, mask).item() == pytest.approx(expected)


def test_a_guided_agent_stores_the_teachers_actions_at_both_ends_and_resumes_them(tmp_path: Path):
    agent = DDPG(GRID, ACCEL, guided(), seed=1)
    with pytest.raises(RuntimeError, match="set_guide"):
        agent.observe(np.zeros(GRID.shape), np.zeros(1), 0.0, np.zeros(GRID.shape), False)
    agent.set_guide(brake_when_crowded)
    empty, crowded = np.zeros(GRID.shape, np.float32), np.ones(GRID.shape, np.float32)
    agent.observe(empty, np.zeros(1), 0.0, crowded, False)
    agent.observe(crowded, np.zeros(1), 0.0, empty, True)
    assert agent.buffer.guide_actions[:2, 0].tolist() == [1.0, -1.0]
    assert agent.buffer.next_guide_actions[:2, 0].tolist() == [-1.0, 1.0]
    batch = agent.buffer.gather(np.array([1, 0]), sparse=agent.sparse)
    assert batch.guide_actions[:, 0].tolist() == [-1.0, 1.0]
    agent.save(tmp_path / "guided.pt", include_buffer=True)
    restored = DDPG.from_checkpoint(tmp_path / "guided.pt", GRID, ACCEL)
    assert restored.buffer.next_guide_actions[:2, 0].tolist() == [-1.0, 1.0]
    plain = DDPG(GRID, ACCEL, DDPGConfig(hidden_sizes=(16,), buffer_size=200, batch_size=4), seed=1)
    assert plain.buffer.guide_actions.size == 0  # no teacher: nothing stored


def test_without_its_teacher_a_guided_agent_refuses_to_learn_before_any_step():
    from frl.agents.learn import learn

    agent = DDPG(GRID, ACCEL, guided(), seed=1)

    class NeverStepped:
        observation_space, action_space = GRID, ACCEL

        def reset(self, **kwargs: object) -> None:
            raise AssertionError("the environment must not be touched")

    with pytest.raises(RuntimeError, match="set_guide"):
        learn(agent, NeverStepped(), 10)


def test_the_imitation_term_pulls_the_actor_to_the_teacher_on_the_filtered_states():
    config = guided(guide_filter="none", guide_weight=10.0, actor_lr=1e-3)
    agent = DDPG(GRID, ACCEL, config, seed=2)
    agent.set_guide(brake_when_crowded)
    crowded, empty = np.ones(GRID.shape, np.float32), np.zeros(GRID.shape, np.float32)
    stats = []
    for _ in range(300):
        agent.observe(crowded, np.zeros(1), 0.0, empty, False)
        agent.observe(empty, np.zeros(1), 0.0, crowded, False)
        stats.append(agent.update())
    assert "imitation_loss" in stats[-1] and stats[-1]["guide_share"] == 1.0
    assert stats[-1]["imitation_loss"] < 0.1 * stats[3]["imitation_loss"]
    assert agent.predict(crowded)[0][0] < -0.5 < 0.5 < agent.predict(empty)[0][0]


@pytest.mark.parametrize("kind", ["q", "q_lower"])
def test_the_q_filtered_term_uses_the_critics_values_of_both_actions(kind):
    agent = DDPG(GRID, ACCEL, guided(guide_filter=kind), seed=3)
    agent.set_guide(brake_when_crowded)
    feed(agent, 8)
    batch = agent.buffer.gather(np.arange(4), sparse=agent.sparse)
    with torch.no_grad():
        preactivation = agent.actor.preactivation(batch.obs)
        q_actor = agent.critic(batch.obs, preactivation.clamp(-1, 1))
        q_teacher = agent.critic(batch.obs, batch.guide_actions)
    loss, share = imitation_term(
        agent.config, agent.critic, batch, preactivation, q_actor, agent._autocast
    )
    mask = (q_actor <= q_teacher).float()
    if kind == "q_lower":
        mask = lower_only(mask, preactivation.clamp(-1, 1), batch.guide_actions)
    assert share.item() == pytest.approx(mask.mean().item())
    assert loss.item() == pytest.approx(imitation_loss(preactivation, batch.guide_actions, mask))


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"guide": "oracle"}, "guide must be one of"),
        ({"guide_weight": -1.0}, "guide_weight"),
        ({"guide_filter": "sometimes"}, "guide_filter must be one of q, q_lower, none"),
        ({"guide": "none", "guide_weight": 1.0}, "set guide=gap_acceptance"),
    ],
)
def test_bad_guide_settings_fail_clearly(options, message):
    with pytest.raises(ValueError, match=message):
        guided(**options)
