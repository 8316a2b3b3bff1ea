"""EnvConfig.route_observation: the ego's route beside the paper's grid, as a Dict
observation that frl's agent, its encoders, checkpoints, the gap-acceptance rule,
Stable-Baselines3 and evaluate_policy all read."""

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

import frl.envs  # noqa: F401 (registers frl/Intersection-v0)
from frl.agents import DDPG, DDPGConfig, SparseRows
from frl.agents.observations import ObservationLayout
from frl.envs import EnvConfig, IntersectionEnv
from frl.evaluate import evaluate_policy
from frl.policies import GapAcceptancePolicy

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def drive(env: IntersectionEnv, seed: int, action: float = 1.0, steps: int = 500) -> list:
    observations = [env.reset(seed=seed)[0]]
    for _ in range(steps):
        observation, _, terminated, truncated, _ = env.step([action])
        observations.append(observation)
        if terminated or truncated:
            break
    return observations


def test_the_route_is_the_task_one_hot_and_the_distance_to_the_stop_line():
    env = IntersectionEnv(EnvConfig(task="right", route_observation=True))
    try:
        assert isinstance(env.observation_space, gym.spaces.Dict)
        assert list(env.observation_space.spaces) == ["grid", "route"]
        observations = drive(env, seed=3)
        plain = IntersectionEnv(EnvConfig(task="right"), backend="traci")
        try:
            grids = drive(plain, seed=3)
        finally:
            plain.close()
    finally:
        env.close()
    assert len(observations) == len(grids)
    for observation, grid in zip(observations, grids, strict=True):
        assert env.observation_space.contains(observation)
        np.testing.assert_array_equal(observation["grid"], grid)  # Eq. (1) exactly
        assert observation["route"][:3].tolist() == [0.0, 0.0, 1.0]
    distances = np.array([o["route"][3] for o in observations]) * 10.0
    assert distances[0] == pytest.approx(10.0)  # the ego departs 10 m before the line
    assert np.all(np.diff(distances) <= 0) and distances[-1] < 0  # it drove past it
    # At full throttle from rest (1 m/s^2, 0.2 s steps) after k steps: 0.02 k (k + 1) m.
    assert distances[5] == pytest.approx(10.0 - 0.02 * 5 * 6, abs=1e-4)


def test_a_restored_snapshot_continues_the_route_exactly():
    env = IntersectionEnv(EnvConfig(task="left", route_observation=True))
    try:
        env.reset(seed=5)
        for _ in range(12):
            env.step([0.5])
        snapshot = env.snapshot()
        ahead = env.step([0.5])[0]["route"]
        env.restore(snapshot)
        assert env.step([0.5])[0]["route"].tolist() == ahead.tolist()
    finally:
        env.close()


def test_the_rule_reads_the_grid_of_a_route_observation():
    rule = GapAcceptancePolicy(EnvConfig())
    grid = np.zeros((26, 18, 3), np.float32)
    grid[13, 1] = [0.0, 0.0, 1.0]  # the ego
    grid[20, 8] = [0.7, -1.0, 1.0]  # a car from the right, heading for the ego's path
    route = np.array([0.0, 1.0, 0.0, 1.0], np.float32)
    assert rule({"grid": grid, "route": route}).tolist() == rule(grid).tolist()


ROUTE_SPACE = gym.spaces.Dict(
    {
        "grid": gym.spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32),
        "route": gym.spaces.Box(-10.0, 1.0, (4,), dtype=np.float32),
    }
)
ACCEL = gym.spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)


def route_observation(rng: np.random.Generator) -> dict[str, np.ndarray]:
    grid = np.zeros((26, 18, 3), np.float32)
    for cell in rng.choice(26 * 18, 4, replace=False):
        grid.reshape(-1, 3)[cell] = [rng.uniform(0, 1), rng.uniform(-1, 1), 1.0]
    route = np.array([0.0, 1.0, 0.0, rng.uniform(-3, 1)], np.float32)
    return {"grid": grid, "route": route}


def test_the_layout_flattens_parts_in_order_and_rebuilds_them():
    layout = ObservationLayout(ROUTE_SPACE)
    assert (layout.num_features, layout.grid_features, layout.extra_features) == (1408, 1404, 4)
    observation = route_observation(np.random.default_rng(0))
    flat = layout.flat(observation)
    np.testing.assert_array_equal(flat[:1404], observation["grid"].reshape(-1))
    np.testing.assert_array_equal(flat[1404:], observation["route"])
    back = layout.unflat(flat)
    assert all(np.array_equal(back[k], observation[k]) for k in ("grid", "route"))
    with pytest.raises(ValueError, match="parts"):
        layout.flat({"grid": observation["grid"]})
    with pytest.raises(ValueError, match="'route': expected shape"):
        layout.flat({**observation, "route": np.zeros(3)})
    with pytest.raises(TypeError, match="Box or Dict"):
        ObservationLayout(gym.spaces.Discrete(3))


def test_the_vehicles_encoder_reads_the_route_beside_the_pooled_vehicles_sparse_or_dense():
    config = DDPGConfig(encoder="vehicles", hidden_sizes=(16,), batch_size=4, buffer_size=50)
    agent = DDPG(ROUTE_SPACE, ACCEL, config, seed=0)
    rng = np.random.default_rng(1)
    rows = torch.from_numpy(np.stack([agent.layout.flat(route_observation(rng)) for _ in range(5)]))
    encoder = agent.actor.encoder
    dense, sparse = encoder(rows), encoder(SparseRows.from_dense(rows))
    assert dense.shape == (5, 2 * 64 + 4)
    torch.testing.assert_close(dense, sparse)
    torch.testing.assert_close(dense[:, -4:], rows[:, -4:])  # the route, as it is
    moved = rows.clone()
    moved[:, -1] += 1.0  # another distance: the same vehicles, another input
    assert not torch.equal(agent.actor(moved), agent.actor(rows))


def test_an_agent_learns_on_route_observations_predicts_batches_and_reloads(tmp_path: Path):
    config = DDPGConfig(
        encoder="vehicles", hidden_sizes=(16,), batch_size=4, buffer_size=50, learning_starts=4
    )
    agent = DDPG(ROUTE_SPACE, ACCEL, config, seed=2)
    rng = np.random.default_rng(3)
    agent.episode_start()
    observation = route_observation(rng)
    for _ in range(10):
        following = route_observation(rng)
        agent.observe(observation, agent.act(observation), 0.1, following, False)
        agent.update()
        observation = following
    assert agent.num_updates > 0
    single = agent.predict(observation)[0]
    batch = {key: np.stack([value, value]) for key, value in observation.items()}
    assert agent.predict(batch)[0].shape == (2, 1)
    np.testing.assert_array_equal(agent.predict(batch)[0][0], single)
    agent.save(tmp_path / "route.pt")
    loaded = DDPG.load(tmp_path / "route.pt")
    assert isinstance(loaded.layout.parts, dict)
    np.testing.assert_array_equal(loaded.predict(observation)[0], single)
    grid_only = gym.spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
    with pytest.raises(Exception, match="observation parts"):
        DDPG.from_checkpoint(tmp_path / "route.pt", grid_only, ACCEL)


def test_a_guided_agent_asks_its_teacher_on_the_observation_as_the_env_gave_it():
    config = DDPGConfig(
        hidden_sizes=(16,), batch_size=4, buffer_size=50, guide="gap_acceptance", n_step=1
    )
    agent = DDPG(ROUTE_SPACE, ACCEL, config, seed=4)
    seen = []
    agent.set_guide(lambda observation: seen.append(observation) or np.ones(1, np.float32))
    rng = np.random.default_rng(5)
    first, second = route_observation(rng), route_observation(rng)
    agent.observe(first, np.zeros(1), 0.0, second, False)
    assert [sorted(o) for o in seen] == [["grid", "route"]]
    np.testing.assert_array_equal(seen[0]["route"], first["route"])
    np.testing.assert_array_equal(seen[0]["grid"], first["grid"])


def test_stable_baselines3_trains_on_route_observations_and_evaluate_policy_scores_it():
    stable_baselines3 = pytest.importorskip("stable_baselines3")
    env = gym.make("frl/Intersection-v0", task="random", route_observation=True)
    model = stable_baselines3.TD3(
        "MultiInputPolicy", env, learning_starts=50, batch_size=32,
        policy_kwargs={"net_arch": [32]}, seed=0,
    )  # fmt: skip
    model.learn(total_timesteps=120)
    env.close()  # libsumo: one simulation per process, so the test's SUMO starts after

    scored = evaluate_policy(
        model, episodes=2, tasks=["left"], yardsticks=("gap_acceptance",), route_observation=True
    )
    assert scored["per_task"]["left"]["episodes"] == 2
    with pytest.raises(ValueError, match="pass route_observation=True"):
        evaluate_policy(model, episodes=1, tasks=["left"], yardsticks=(), verbose=False)


def test_evaluate_policy_refuses_an_agent_the_wrong_observation_before_any_episode():
    grid_only = gym.spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
    agent = DDPG(grid_only, ACCEL, DDPGConfig(hidden_sizes=(16,)), seed=0)
    with pytest.raises(ValueError, match="pass route_observation=False"):
        evaluate_policy(agent, episodes=1, yardsticks=(), route_observation=True)
