"""EnvConfig.window_observation: the grid's crossing cars as time windows beside the grid
(frl/envs/conflicts.py), read by the env, the gap-acceptance rules, frl's agent and
evaluate_policy."""

import dataclasses
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from frl.agents import DDPG, DDPGConfig
from frl.envs import EnvConfig, IntersectionEnv, RewardConfig
from frl.envs.conflicts import WINDOW_FEATURES, CrossingReader
from frl.evaluate import evaluate_policy
from frl.yardsticks import cache_key

pytestmark = pytest.mark.usefixtures("one_torch_thread")

EGO = (13, 2)  # the default grid's ego cell
NO_CAR = [0.0, 0.0, 1.0, 1.0, 0.0, 0.0]  # no car comes: its times read as far away


def grid_with(*cars: tuple[int, int, float, float], ego_speed: float = 0.0) -> np.ndarray:
    """A default grid with the ego and ``(row, column, speed channel, heading channel)`` cars."""
    grid = np.zeros((26, 18, 3), np.float32)
    grid[EGO] = [ego_speed, 0.0, 1.0]
    for row, column, speed, heading in cars:
        grid[row, column] = [speed, heading, 1.0]
    return grid


def test_a_coming_car_gives_its_window_and_the_egos_hand_computed():
    # Row 20 lies 46.15 m to the right, column 8 16.25 m ahead (cells of 6.15 m x 2.5 m).
    # Speed channel 0.5 (10 m/s), heading -1 (-90 degrees): it drives straight at the
    # ego's path. It enters the path (2.5 m half-width, 5 m long) after
    # (46.15 - 7.5) / 10 s and leaves it after (46.15 + 2.5) / 10 s; the ego from rest
    # at 1 m/s^2 reaches its lane (2.5 m half-width) after sqrt(2 * 13.75) s and is past
    # it (and its own 5 m) after sqrt(2 * 23.75) s.
    lateral = -80.0 + 20.5 * 160.0 / 26.0
    features = CrossingReader(EnvConfig()).features(grid_with((20, 8, 0.5, -1.0)))
    assert features.dtype == np.float32 and features.shape == (WINDOW_FEATURES,)
    assert features[:6].tolist() == NO_CAR  # nothing on the left
    expected = [
        1.0,
        0.0,
        (lateral - 7.5) / 10.0 / 10.0,
        (lateral + 2.5) / 10.0 / 10.0,
        np.sqrt(2 * 13.75) / 10.0,
        np.sqrt(2 * 23.75) / 10.0,
    ]
    np.testing.assert_allclose(features[6:], expected, rtol=1e-6)


def test_the_binding_car_is_the_one_that_leaves_the_ego_the_least_time():
    reader = CrossingReader(EnvConfig())
    near, far = (20, 8, 0.5, -1.0), (24, 8, 0.5, -1.0)
    # The near car passes 0.38 s before the ego arrives; the far one overlaps its window.
    both = reader.features(grid_with(near, far))
    np.testing.assert_array_equal(both, reader.features(grid_with(far)))
    assert not np.array_equal(both, reader.features(grid_with(near)))


def test_cars_behind_along_the_heading_or_driving_away_are_left_out_a_car_in_the_path_is_not():
    reader = CrossingReader(EnvConfig())
    ignored = [
        (20, 0, 0.5, -1.0),  # behind the ego
        (20, 8, 0.5, 0.0),  # driving along the ego's heading
        (20, 8, 0.5, 1.0),  # driving away to the right
    ]
    for car in ignored:
        assert reader.features(grid_with(car)).tolist() == NO_CAR + NO_CAR, car
    standing = reader.features(grid_with((12, 6, 0.0, 1.0)))  # 3 m to the left, stopped
    assert standing[:6].tolist() == [0.0, 1.0, 1.0, 1.0, 0.0, 0.0]
    assert standing[6:].tolist() == NO_CAR


def test_the_env_adds_the_windows_of_its_own_grid_after_the_route():
    config = EnvConfig(task="left", window_observation=True)
    reader = CrossingReader(config)
    for route, parts in ((False, ["grid", "windows"]), (True, ["grid", "route", "windows"])):
        env = IntersectionEnv(dataclasses.replace(config, route_observation=route))
        try:
            assert list(env.observation_space.spaces) == parts
            observation, _ = env.reset(seed=3)
            seen_a_car = False
            for _ in range(60):
                assert env.observation_space.contains(observation)
                np.testing.assert_array_equal(
                    observation["windows"], reader.features(observation["grid"])
                )
                seen_a_car |= bool(observation["windows"][[0, 6]].any())
                observation, _, terminated, truncated, _ = env.step([0.3])
                if terminated or truncated:
                    break
            assert seen_a_car  # the windows are not all empty in traffic
        finally:
            env.close()
    with pytest.raises(ValueError, match="window_observation must be true or false"):
        EnvConfig(window_observation="yes")


def test_committed_means_the_braking_distance_reaches_the_line():
    reader = CrossingReader(EnvConfig())  # full brake: 1 m/s^2
    five_metres_a_second = grid_with(ego_speed=0.25)  # speed channel x 20 m/s: 12.5 m to stop
    assert reader.committed(five_metres_a_second, 12.4)
    assert not reader.committed(five_metres_a_second, 12.6)
    assert reader.committed(grid_with(), -0.1)  # at rest past the line
    assert not reader.committed(grid_with(), 0.1)
    assert reader.no_car_features((26, 18, 3)).tolist() == NO_CAR + NO_CAR


def test_the_yardsticks_cache_ignores_what_the_model_observes():
    seeds = [1, 3]
    plain = cache_key("gap_acceptance", EnvConfig(), RewardConfig(), seeds)
    both = EnvConfig(window_observation=True, route_observation=True)
    assert cache_key("gap_acceptance", both, RewardConfig(), seeds) == plain


WINDOW_SPACE = gym.spaces.Dict(
    {
        "grid": gym.spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32),
        "windows": gym.spaces.Box(0.0, 1.0, (WINDOW_FEATURES,), dtype=np.float32),
    }
)
ACCEL = gym.spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)


def test_an_agent_reads_the_windows_saves_and_is_refused_the_grid_alone(tmp_path: Path):
    config = DDPGConfig(hidden_sizes=(16,), batch_size=4, buffer_size=50, learning_starts=4)
    agent = DDPG(WINDOW_SPACE, ACCEL, config, seed=0)
    rng = np.random.default_rng(0)
    reader = CrossingReader(EnvConfig())

    def observation() -> dict[str, np.ndarray]:
        grid = grid_with((int(rng.integers(14, 26)), int(rng.integers(3, 18)), 0.5, -1.0))
        return {"grid": grid, "windows": reader.features(grid)}

    agent.episode_start()
    current = observation()
    for _ in range(8):
        following = observation()
        agent.observe(current, agent.act(current), 0.1, following, False)
        agent.update()
        current = following
    assert agent.num_updates > 0
    moved = {**current, "windows": 1.0 - current["windows"]}
    assert not np.array_equal(agent.predict(moved)[0], agent.predict(current)[0])
    agent.save(tmp_path / "windows.pt")
    np.testing.assert_array_equal(
        DDPG.load(tmp_path / "windows.pt").predict(current)[0], agent.predict(current)[0]
    )
    with pytest.raises(ValueError, match="pass window_observation=True"):
        evaluate_policy(agent, episodes=1, yardsticks=(), verbose=False)
