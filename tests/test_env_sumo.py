"""IntersectionEnv on real SUMO: API contract, determinism, dynamics and episode ends."""

import multiprocessing
import threading
import time

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from frl.envs import ENV_ID, IntersectionEnv, RewardConfig, SumoError
from frl.envs.reward import REWARD_TERMS
from frl.envs.sumo_backend import one_port_pick_at_a_time

FULL_THROTTLE = np.array([1.0], dtype=np.float32)
FULL_BRAKE = np.array([-1.0], dtype=np.float32)


@pytest.fixture
def make_env():
    envs = []

    def make(**kwargs):
        env = IntersectionEnv(**kwargs)
        envs.append(env)
        return env

    yield make
    for env in envs:
        env.close()


def run_episode(env, policy, seed=None):
    observation, info = env.reset(seed=seed)
    steps = []
    while True:
        observation, reward, terminated, truncated, info = env.step(policy(observation))
        steps.append((observation, reward, terminated, truncated, info))
        if terminated or truncated:
            return steps


def test_gymnasium_check_env(make_env):
    check_env(make_env(task="left"), skip_render_check=True)


def test_registered_id_builds_the_env():
    env = gym.make(ENV_ID, task="right", max_episode_steps=50)
    try:
        observation, info = env.reset(seed=3)
        assert observation.shape == (26, 18, 3)
        assert info["task"] == "right"
    finally:
        env.close()


def test_same_seed_and_actions_give_identical_episodes(make_env):
    actions = np.random.default_rng(0).uniform(-1, 1, size=(150, 1)).astype(np.float32)

    def record(env):
        observation, _ = env.reset(seed=11)
        trace = [observation]
        rewards = []
        for action in actions:
            observation, reward, terminated, truncated, _ = env.step(action)
            trace.append(observation)
            rewards.append(reward)
            if terminated or truncated:
                observation, _ = env.reset()
                trace.append(observation)
        return np.stack(trace), np.array(rewards)

    env = make_env(task="random")
    first = record(env)
    second = record(env)  # reset(seed=11) restarts SUMO with the same seed
    np.testing.assert_array_equal(first[0], second[0])
    np.testing.assert_array_equal(first[1], second[1])


def test_traci_drives_and_restores_exactly_as_libsumo(make_env):
    """Over a socket the commands of a step travel in one message (sumo_backend): the
    episodes, and a restore's replay, stay those of libsumo to the last bit."""
    actions = np.random.default_rng(1).uniform(-1, 1, size=(300, 1)).astype(np.float32)

    def drive(env, steps):
        trace = []
        for action in steps:
            observation, reward, terminated, truncated, _ = env.step(action)
            trace.append((observation.tobytes(), reward))
            if terminated or truncated:
                observation, _ = env.reset()
                trace.append((observation.tobytes(), None))
        return trace

    fast, socket = make_env(task="random"), make_env(task="random", backend="traci")
    for env in (fast, socket):
        env.reset(seed=5)
    assert drive(fast, actions[:200]) == drive(socket, actions[:200])
    restored = make_env(task="random", backend="traci")
    restored.restore(socket.snapshot())
    assert drive(restored, actions[200:]) == drive(fast, actions[200:])


def test_always_braking_agent_never_collides_and_is_truncated(make_env):
    env = make_env(task="straight", max_episode_steps=120)
    for seed in range(3):
        steps = run_episode(env, lambda _: FULL_BRAKE, seed=seed)
        assert len(steps) == 120
        assert not any(info["collision"] for *_, info in steps)
        _, _, terminated, truncated, info = steps[-1]
        assert truncated and not terminated
        assert info["travel_time_steps"] == 120 and info["ego_speed"] == 0.0


def test_full_throttle_collides_in_some_episodes(make_env):
    """Proves the humans are aggressive and that collisions are detected."""
    collisions = 0
    for task in ("left", "straight", "right"):
        env = make_env(task=task)
        for seed in range(4):
            *_, (_, _, terminated, _, info) = run_episode(env, lambda _: FULL_THROTTLE, seed)
            if info["collision"]:
                collisions += 1
                assert terminated and not info["arrived"]
                assert info["reward_terms"]["collision"] == -10.0
                assert info["cost_terms"]["collision"] == 1.0 and info["cost"] == 1.0
        env.close()
    assert 0 < collisions < 12


def test_arrival_pays_mu_and_terms_sum_to_reward(make_env):
    env = make_env(task="right")
    arrived = 0
    for seed in range(8):
        steps = run_episode(env, lambda _: FULL_THROTTLE, seed=seed)
        for _, reward, _, _, info in steps:
            assert set(info["reward_terms"]) == set(REWARD_TERMS)
            assert sum(info["reward_terms"].values()) == pytest.approx(reward)
            assert info["cost"] == sum(info["cost_terms"].values()) == 0.0
        *_, (_, reward, terminated, _, info) = steps
        if info["arrived"]:
            arrived += 1
            assert terminated
            assert info["reward_terms"]["arrival"] == 5.0
            # A clean full-throttle pass lands in the paper's 6-7 range.
            assert 5.5 < sum(step[1] for step in steps) < 7.5
            assert 30 <= info["travel_time_steps"] <= 60
    assert arrived > 0


def test_reference_reward_is_selectable(make_env):
    env = make_env(task="straight", max_episode_steps=5)
    env.reward_config = RewardConfig.named("reference")
    steps = run_episode(env, lambda _: FULL_BRAKE, seed=0)
    assert [reward for _, reward, *_ in steps] == pytest.approx([-0.01] * 5)


def test_random_task_is_drawn_per_episode(make_env):
    env = make_env(task="random", max_episode_steps=1)
    tasks = set()
    env.reset(seed=0)
    for _ in range(15):
        env.step(FULL_BRAKE)
        tasks.add(env.reset()[1]["task"])
    assert tasks == {"left", "straight", "right"}


def test_non_finite_action_raises(make_env):
    env = make_env()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan], dtype=np.float32))


def test_step_before_reset_raises(make_env):
    with pytest.raises(RuntimeError, match="reset"):
        make_env().step(FULL_BRAKE)


def test_second_libsumo_env_raises_and_first_keeps_running(make_env):
    first = make_env(task="left")
    first.reset(seed=0)
    second = make_env(task="left")
    with pytest.raises(SumoError, match="one simulation per process"):
        second.reset(seed=0)
    first.step(FULL_BRAKE)  # the first simulation is untouched
    first.close()
    second.reset(seed=0)  # once the first is closed, the second may open


def test_close_is_idempotent(make_env):
    env = make_env()
    env.close()
    env.reset(seed=0)
    env.close()
    env.close()


def test_traci_backend_runs_beside_libsumo(make_env):
    fast = make_env(task="left")
    fast.reset(seed=1)
    socket = make_env(task="left", backend="traci", max_episode_steps=30)
    steps = run_episode(socket, lambda _: FULL_BRAKE, seed=1)
    assert len(steps) == 30
    fast.step(FULL_BRAKE)


def test_human_render_mode_needs_traci():
    with pytest.raises(ValueError, match="traci"):
        IntersectionEnv(render_mode="human")


def test_rgb_array_render_shows_agent_red_and_humans_yellow(make_env):
    env = make_env(task="straight", render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(5):
        env.step(FULL_THROTTLE)
    frame = env.render()
    assert frame.shape == (480, 480, 3) and frame.dtype == np.uint8
    red = (frame[..., 0] > 200) & (frame[..., 1] < 60) & (frame[..., 2] < 60)
    yellow = (frame[..., 0] > 200) & (frame[..., 1] > 180) & (frame[..., 2] < 60)
    assert red.sum() > 20 and yellow.sum() > 20


def _hold_the_port_lock(lock_file, held, release) -> None:
    with one_port_pick_at_a_time(lock_file):
        held.set()
        release.wait(10)


def test_one_process_at_a_time_picks_a_port_for_its_sumo(tmp_path):
    # Two processes picking a free port at once can be handed the same one.
    context = multiprocessing.get_context("fork")
    held, release = context.Event(), context.Event()
    lock_file = tmp_path / "port.lock"
    holder = context.Process(target=_hold_the_port_lock, args=(lock_file, held, release))
    holder.start()
    assert held.wait(30)
    threading.Timer(0.5, release.set).start()
    began = time.perf_counter()
    with one_port_pick_at_a_time(lock_file):
        waited = time.perf_counter() - began
    holder.join(10)
    assert waited >= 0.4
    with one_port_pick_at_a_time(lock_file):  # released: taken at once
        pass
