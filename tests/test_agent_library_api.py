"""The agent's Stable-Baselines3-style surface: DDPG.load, predict, learn."""

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from frl.agents import DDPG, CheckpointError, DDPGConfig

GRID = spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
ACCEL = spaces.Box(-3.0, 2.0, (1,), dtype=np.float32)
SMALL = DDPGConfig(hidden_sizes=(32, 16), buffer_size=500, learning_starts=20, batch_size=8)
TINY_PENDULUM = DDPGConfig(hidden_sizes=(16,), buffer_size=400, learning_starts=50, batch_size=16)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def grid_batch(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    batch = np.zeros((n, *GRID.shape), np.float32)
    for row in batch:
        for cell in rng.choice(26 * 18, size=4, replace=False):
            i, j = divmod(int(cell), 18)
            row[i, j] = (rng.uniform(0, 1), rng.choice([-1.0, 1.0]), 1.0)
    return batch


@pytest.mark.parametrize("encoder", ["flat", "vehicles"])
def test_load_rebuilds_the_agent_from_the_file_alone(encoder, tmp_path):
    config = DDPGConfig(**{**SMALL.to_dict(), "encoder": encoder})
    agent = DDPG(GRID, ACCEL, config, seed=3)
    agent.save(tmp_path / "model.pt")

    loaded = DDPG.load(tmp_path / "model.pt")

    assert loaded.config == config and loaded.seed == 3
    assert loaded.obs_shape == GRID.shape and loaded.action_shape == ACCEL.shape
    assert loaded.action_low.tolist() == [-3.0] and loaded.action_high.tolist() == [2.0]
    for obs in grid_batch(5):
        assert np.array_equal(loaded.act(obs, explore=False), agent.act(obs, explore=False))


def test_load_on_an_instance_says_how_to_restore_instead(tmp_path):
    agent = DDPG(GRID, ACCEL, SMALL)
    agent.save(tmp_path / "model.pt")
    with pytest.raises(TypeError, match=r"agent = DDPG.load\(path\).*agent.restore\(path\)"):
        agent.load(tmp_path / "model.pt")


def test_load_refuses_what_is_no_checkpoint(tmp_path):
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError):
        DDPG.load(tmp_path / "junk.pt")
    with pytest.raises(FileNotFoundError):
        DDPG.load(tmp_path / "missing.pt")


@pytest.mark.parametrize("precision", ["float32", "bf16"])
def test_predict_one_observation_or_a_batch(precision):
    agent = DDPG(GRID, ACCEL, DDPGConfig(**{**SMALL.to_dict(), "precision": precision}))
    batch = grid_batch(6)

    action, state = agent.predict(batch[0])
    assert state is None
    assert action.shape == (1,) and action.dtype == np.float32
    assert np.array_equal(action, agent.act(batch[0], explore=False))
    actions, _ = agent.predict(batch)
    assert actions.shape == (6, 1)
    singles = np.stack([agent.predict(obs)[0] for obs in batch])
    tolerance = 1e-6 if precision == "float32" else 2e-2  # bf16 sums in another order
    np.testing.assert_allclose(actions, singles, atol=tolerance)
    assert np.all((actions >= -3.0) & (actions <= 2.0))
    noisy, _ = agent.predict(batch, deterministic=False)
    assert not np.array_equal(noisy, actions)
    with pytest.raises(ValueError, match=r"shape \(26, 18, 3\) or a batch"):
        agent.predict(np.zeros((26, 18)))


def test_learn_trains_on_a_gymnasium_env_logs_and_stops_when_told(tmp_path):
    env = gym.make("Pendulum-v1")
    agent = DDPG(env.observation_space, env.action_space, TINY_PENDULUM, seed=1)

    assert agent.learn(env, 450, tensorboard_log=tmp_path / "tb") is agent
    assert agent.num_env_steps == 450 and agent.num_updates == 401  # from step 50 on
    assert agent.episode_returns and len(agent.episode_returns) == 2  # 200-step episodes
    events = EventAccumulator(str(tmp_path / "tb"))
    events.Reload()
    means = events.Scalars("rollout/ep_rew_mean")
    assert [e.step for e in means] == [200, 400]
    assert means[-1].value == pytest.approx(np.mean(agent.episode_returns), rel=1e-6)
    assert {"train/critic_loss", "train/actor_loss"} <= set(events.Tags()["scalars"])

    seen = []
    agent.learn(env, 100, callback=lambda a, step, info: seen.append(step) or step < 30)
    assert seen == list(range(1, 31)) and agent.num_env_steps == 480
    env.close()


def test_learn_is_reproducible_from_the_agent_seed():
    def trained() -> DDPG:
        env = gym.make("Pendulum-v1")
        agent = DDPG(env.observation_space, env.action_space, TINY_PENDULUM, seed=5)
        agent.learn(env, 260)
        env.close()
        return agent

    first, second = trained(), trained()
    assert first.episode_returns == second.episode_returns
    obs = np.array([1.0, 0.0, 0.0], np.float32)
    assert np.array_equal(first.predict(obs)[0], second.predict(obs)[0])


def test_learn_refuses_a_bad_budget_or_other_spaces():
    env = gym.make("Pendulum-v1")
    agent = DDPG(env.observation_space, env.action_space, TINY_PENDULUM)
    for budget in (0, -5, 2.5):
        with pytest.raises(ValueError, match="total_timesteps must be a positive integer"):
            agent.learn(env, budget)
    other = DDPG(GRID, ACCEL, SMALL)
    with pytest.raises(ValueError, match="do not match the agent's"):
        other.learn(env, 10)
    assert other.num_env_steps == 0
    env.close()


def test_a_runs_model_file_loads_without_its_spaces(tmp_path: Path):
    # what frl.train writes to models/*.pt: save without the buffer
    agent = DDPG(GRID, ACCEL, SMALL, seed=2)
    agent.save(tmp_path / "global.pt", include_buffer=False)
    loaded = DDPG.load(tmp_path / "global.pt")
    obs = grid_batch(1)[0]
    assert np.array_equal(loaded.predict(obs)[0], agent.predict(obs)[0])
