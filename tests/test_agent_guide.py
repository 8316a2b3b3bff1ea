"""A guided agent (DDPGConfig.guide): the teacher's action stored with every transition
and the imitation term, each against hand-computed numbers or its defining property."""

from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium import spaces

from frl.agents import DDPG, DDPGConfig
from frl.agents.guide import imitation_loss

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


def test_the_imitation_loss_by_hand():
    preactivation = torch.tensor([[0.5], [1.5], [-0.5], [-1.5], [-1.5]])
    teacher = torch.tensor([[1.0], [1.0], [-1.0], [1.0], [-1.0]])
    # 0.25; past the teacher's +1 bound: 0; 0.25; 6.25; past its -1 bound: 0
    expected = (0.25 + 0.0 + 0.25 + 6.25 + 0.0) / 5
    assert imitation_loss(preactivation, teacher).item() == pytest.approx(expected)


def test_a_guided_agent_stores_the_teachers_action_and_resumes_it(tmp_path: Path):
    agent = DDPG(GRID, ACCEL, guided(), seed=1)
    with pytest.raises(RuntimeError, match="set_guide"):
        agent.observe(np.zeros(GRID.shape), np.zeros(1), 0.0, np.zeros(GRID.shape), False)
    agent.set_guide(brake_when_crowded)
    empty, crowded = np.zeros(GRID.shape, np.float32), np.ones(GRID.shape, np.float32)
    agent.observe(empty, np.zeros(1), 0.0, crowded, False)
    agent.observe(crowded, np.zeros(1), 0.0, empty, True)
    assert agent.buffer.guide_actions[:2, 0].tolist() == [1.0, -1.0]
    batch = agent.buffer.gather(np.array([1, 0]), sparse=agent.sparse)
    assert batch.guide_actions[:, 0].tolist() == [-1.0, 1.0]
    agent.save(tmp_path / "guided.pt", include_buffer=True)
    restored = DDPG.from_checkpoint(tmp_path / "guided.pt", GRID, ACCEL)
    assert restored.buffer.guide_actions[:2, 0].tolist() == [1.0, -1.0]
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


def test_the_imitation_term_pulls_the_actor_to_the_teacher():
    config = guided(guide_weight=10.0, actor_lr=1e-3)
    agent = DDPG(GRID, ACCEL, config, seed=2)
    agent.set_guide(brake_when_crowded)
    crowded, empty = np.ones(GRID.shape, np.float32), np.zeros(GRID.shape, np.float32)
    stats = []
    for _ in range(300):
        agent.observe(crowded, np.zeros(1), 0.0, empty, False)
        agent.observe(empty, np.zeros(1), 0.0, crowded, False)
        stats.append(agent.update())
    assert "imitation_loss" in stats[-1]
    assert stats[-1]["imitation_loss"] < 0.1 * stats[3]["imitation_loss"]
    assert agent.predict(crowded)[0][0] < -0.5 < 0.5 < agent.predict(empty)[0][0]


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"guide": "oracle"}, "guide must be one of"),
        ({"guide_weight": -1.0}, "guide_weight"),
        ({"guide": "none", "guide_weight": 1.0}, "set guide to one of gap_acceptance, commi"),
    ],
)
def test_bad_guide_settings_fail_clearly(options, message):
    with pytest.raises(ValueError, match=message):
        guided(**options)
