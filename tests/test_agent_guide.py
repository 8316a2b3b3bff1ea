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
        ({"guide_drives": 1.5}, "guide_drives must lie in \\[0, 1\\]"),
        ({"guide_drives": -0.1}, "guide_drives must lie in \\[0, 1\\]"),
        ({"guide": "none", "guide_weight": 0.0, "guide_drives": 0.5}, "guide_drives learns fr"),
    ],
)
def test_bad_guide_settings_fail_clearly(options, message):
    with pytest.raises(ValueError, match=message):
        guided(**options)


# ---------------------------------------------------------------- the teacher at the wheel
def at_the_wheel(share: float, **options: object) -> DDPG:
    """A guided agent past its warm-up whose teacher drives ``share`` of the episodes."""
    agent = DDPG(GRID, ACCEL, guided(guide_drives=share, learning_starts=0, **options), seed=3)
    agent.set_guide(brake_when_crowded)
    return agent


def drive_episodes(agent: DDPG, count: int, steps: int = 3, cost: float = 0.0) -> list[bool]:
    """``count`` episodes of ``steps`` steps on a crowded grid: who drove each (True: the
    teacher), read from the actions (the teacher brakes there, the untrained actor not)."""
    crowded = np.ones(GRID.shape, np.float32)
    drivers = []
    for _ in range(count):
        agent.episode_start()
        for step in range(steps):
            action = agent.act(crowded)
            agent.observe(crowded, action, 0.0, crowded, step == steps - 1, cost=cost)
        drivers.append(bool(agent.explorer.teacher_driving))
    return drivers


def test_the_teacher_drives_its_share_of_episodes_with_the_exploration_noise():
    noiseless = {"noise": {"sigma": 0.0}}
    teacher_driven = at_the_wheel(1.0, **noiseless)
    crowded = np.ones(GRID.shape, np.float32)
    teacher_driven.episode_start()
    assert teacher_driven.act(crowded).tolist() == [-1.0]  # the teacher's brake
    assert np.isnan(teacher_driven.last_policy_action).all()
    own = at_the_wheel(0.0, **noiseless)
    own.episode_start()
    assert own.act(crowded) == pytest.approx(own.act(crowded, explore=False))
    assert own.act(crowded).tolist() != [-1.0]
    noisy = at_the_wheel(1.0, noise={"kind": "gaussian", "sigma": 0.3})
    noisy.episode_start()
    actions = np.array([noisy.act(np.zeros(GRID.shape, np.float32))[0] for _ in range(50)])
    assert actions.max() == 1.0 and actions.min() < 0.8  # the teacher's +1 plus noise, clipped
    drivers = drive_episodes(at_the_wheel(0.3), 400)
    assert 0.24 < np.mean(drivers) < 0.36  # 0.3 of 400 episodes: 5 standard deviations
    assert not any(drive_episodes(at_the_wheel(0.0), 50))


def test_who_drives_is_drawn_once_an_episode_and_never_while_testing():
    agent = at_the_wheel(0.5)
    before = agent.explorer.state_dict()["wheel_rng"]
    crowded = np.ones(GRID.shape, np.float32)
    for _ in range(5):
        agent.episode_start()
        agent.act(crowded, explore=False)
    assert agent.explorer.state_dict()["wheel_rng"] == before
    drivers = []
    for _ in range(40):
        agent.episode_start()
        driver = [agent.explorer.teacher_at_wheel() for _ in range(4)]
        assert len(set(driver)) == 1
        drivers.append(driver[0])
    assert 0 < sum(drivers) < 40


def test_an_episode_begun_in_the_warm_up_is_the_agents():
    agent = DDPG(GRID, ACCEL, guided(guide_drives=1.0, learning_starts=2), seed=3)
    agent.set_guide(brake_when_crowded)
    drivers = drive_episodes(agent, 2)
    assert drivers == [False, True]


def test_the_teachers_episodes_do_not_count_for_the_budget():
    agent = at_the_wheel(1.0, collision_budget=0.02)
    drive_episodes(agent, 5, cost=1.0)
    assert agent.constraint is not None
    assert len(agent.constraint.lagrangian.recent) == 0
    own = at_the_wheel(0.0, collision_budget=0.02)
    drive_episodes(own, 5, cost=1.0)
    assert own.constraint is not None
    assert len(own.constraint.lagrangian.recent) == 5


def test_who_drives_resumes_from_a_checkpoint(tmp_path: Path):
    agent = at_the_wheel(0.5)
    drive_episodes(agent, 7)
    crowded = np.ones(GRID.shape, np.float32)
    agent.episode_start()
    agent.act(crowded)  # mid-episode: its driver drawn
    agent.save(tmp_path / "mid.pt", include_buffer=True)
    restored = DDPG.from_checkpoint(tmp_path / "mid.pt", GRID, ACCEL)
    restored.set_guide(brake_when_crowded)
    assert restored.explorer.teacher_driving == agent.explorer.teacher_driving
    assert restored.act(crowded).tolist() == agent.act(crowded).tolist()
    assert drive_episodes(restored, 20) == drive_episodes(agent, 20)


def test_a_default_agent_draws_its_streams_as_before_the_teachers_wheel():
    """Adding the wheel's generator (a fifth child of the seed) left the first four, and
    so every default agent's noise, warm-up and sampling, as they were."""
    _, _, buffer, warm_up = np.random.SeedSequence(11).spawn(4)
    config = DDPGConfig(hidden_sizes=(16,), buffer_size=200, batch_size=4)
    agent = DDPG(GRID, ACCEL, config, seed=11)
    expected = np.random.default_rng(warm_up).random(3)
    assert agent.explorer.warmup_rng.random(3).tolist() == expected.tolist()
    assert agent.buffer.rng.random(3).tolist() == np.random.default_rng(buffer).random(3).tolist()
    wheel = np.random.SeedSequence(11).spawn(5)[4]
    assert agent.explorer.wheel_rng.random() == np.random.default_rng(wheel).random()


def test_a_loaded_model_drives_as_saved_and_a_guided_one_gets_its_teacher(tmp_path: Path):
    from frl.envs import IntersectionEnv
    from frl.policies import GapAcceptancePolicy, load_model

    env = IntersectionEnv()
    try:
        grid, accel = env.observation_space, env.action_space
        for config, teacher in (
            (guided(), GapAcceptancePolicy),
            (DDPGConfig(hidden_sizes=(16,)), None),
        ):
            agent = DDPG(grid, accel, config, seed=3)
            agent.save(tmp_path / "model.pt")
            loaded = load_model(tmp_path / "model.pt", env)
            observation = np.random.default_rng(0).random(grid.shape).astype(np.float32)
            assert np.array_equal(
                loaded.act(observation, explore=False), agent.act(observation, explore=False)
            )
            assert not loaded.needs_guide
            if teacher is None:
                assert loaded.teacher is None
            else:
                assert isinstance(loaded.teacher.driver, teacher)
    finally:
        env.close()
