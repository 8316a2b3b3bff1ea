"""The yardstick policies, the env's exact snapshot/restore, and their evaluation."""

import dataclasses

import numpy as np
import pytest

from frl.envs import EnvConfig, GridConfig, IntersectionEnv, traffic_preset
from frl.episodes import run_episode, run_episodes
from frl.federation.plan import evaluation_seeds
from frl.policies import (
    YARDSTICKS,
    CommittedGapAcceptancePolicy,
    GapAcceptancePolicy,
    LookaheadOracle,
    always_brake,
    full_throttle,
    make_yardstick,
)

GRID = GridConfig()
SEEDS = [101, 103, 105, 107, 109, 111, 113, 115]


@pytest.fixture
def left_env():
    """libsumo holds one simulation per process: each test opens and closes its own."""
    env = IntersectionEnv(EnvConfig(task="left"))
    yield env
    env.close()


def _trajectory(env, seed, actions, lookahead_every=0):
    """Observations and rewards of one episode; optionally a look-ahead every few steps."""
    observation, _ = env.reset(seed=seed)
    steps = [observation.tobytes()]
    for index, action in enumerate(actions):
        if lookahead_every and index % lookahead_every == 0:
            snapshot = env.snapshot()
            for _ in range(15):  # drive ahead hard, then put everything back
                *_, terminated, truncated, _ = env.step([1.0])
                if terminated or truncated:
                    break
            env.restore(snapshot)
        observation, reward, terminated, truncated, info = env.step([action])
        steps.append((observation.tobytes(), reward, info["collision"], info["arrived"]))
        if terminated or truncated:
            break
    return steps


@pytest.mark.parametrize("seed", [3, 8])
def test_restore_replays_the_simulation_exactly(left_env, seed):
    actions = [-1.0] * 6 + [1.0] * 60
    plain = _trajectory(left_env, seed, actions)
    with_lookaheads = _trajectory(left_env, seed, actions, lookahead_every=4)
    assert with_lookaheads == plain


def test_snapshot_needs_a_reset():
    env = IntersectionEnv(EnvConfig(task="left"))
    try:
        with pytest.raises(RuntimeError, match="reset"):
            env.snapshot()
    finally:
        env.close()


def test_full_throttle_and_always_brake(left_env):
    observation = np.zeros((26, 18, 3), np.float32)
    assert full_throttle()(observation).tolist() == [1.0]
    assert always_brake()(observation).tolist() == [-1.0]
    record = run_episode(left_env, full_throttle(), "left", SEEDS[0])
    assert record.collision or record.steps == 44  # a full-throttle left turn: 44 steps
    left_env.close()
    short = IntersectionEnv(EnvConfig(task="right", max_episode_steps=30))
    try:
        braking = run_episodes(short, always_brake(), "right", SEEDS[:2])
    finally:
        short.close()
    assert all(r.timeout and not r.collision and r.steps == 30 for r in braking)


def _grid_with(lateral_m, ahead_m, speed, heading_deg, ego_speed=0.0, grid=GRID):
    observation = np.zeros(grid.shape, np.float32)
    cell = (
        int(
            (lateral_m - grid.lateral_range[0])
            // ((grid.lateral_range[1] - grid.lateral_range[0]) / grid.lateral_cells)
        ),
        int(
            (ahead_m - grid.longitudinal_range[0])
            // ((grid.longitudinal_range[1] - grid.longitudinal_range[0]) / grid.longitudinal_cells)
        ),
    )
    observation[cell] = [speed / grid.speed_scale, heading_deg / grid.heading_scale_deg, 1.0]
    observation[13, 2] = [ego_speed / grid.speed_scale, 0.0, 1.0]  # the ego's own cell
    return observation


def test_gap_acceptance_reads_the_cross_traffic():
    policy = GapAcceptancePolicy()
    assert policy(_grid_with(0.0, 0.0, 0.0, 0.0)).tolist() == [1.0]  # only the ego: go
    # A car 70 m to the left of a lane 15 m ahead, driving right at 15 m/s, is in the
    # ego's path 3-6 s from now, just when the ego (5-7 s to cross, from rest) is: wait.
    assert policy(_grid_with(-70.0, 15.0, 15.0, 90.0)).tolist() == [-1.0]
    # 30 m away it has passed before the ego gets there: go.
    assert policy(_grid_with(-30.0, 15.0, 15.0, 90.0)).tolist() == [1.0]
    # Driving away from the path: go. Far and slow: it comes long after: go.
    assert policy(_grid_with(30.0, 15.0, 15.0, 90.0)).tolist() == [1.0]
    assert policy(_grid_with(-78.0, 15.0, 5.0, 90.0)).tolist() == [1.0]
    # A car driving along the ego's heading (after a turn) is left to car following.
    assert policy(_grid_with(0.0, 20.0, 10.0, 0.0)).tolist() == [1.0]
    # 45 m away: a rolling ego (3 m/s) would meet it and can still stop: brake. At 8 m/s
    # it cannot stop short of the lane, and stopping inside it is worse: keep going.
    assert policy(_grid_with(-45.0, 15.0, 15.0, 90.0, ego_speed=3.0)).tolist() == [-1.0]
    assert policy(_grid_with(-45.0, 15.0, 15.0, 90.0, ego_speed=8.0)).tolist() == [1.0]


def test_gap_acceptance_collides_less_than_full_throttle_and_arrives():
    env = IntersectionEnv(EnvConfig(task="straight"))
    try:
        blind = run_episodes(env, full_throttle(), "straight", SEEDS)
        rules = run_episodes(env, GapAcceptancePolicy(env.config), "straight", SEEDS)
    finally:
        env.close()
    assert sum(r.collision for r in rules) < sum(r.collision for r in blind)
    assert sum(r.arrived for r in rules) >= len(SEEDS) - 1


def _route(distance_m):
    return np.array([1.0, 0.0, 0.0, distance_m / 10.0], np.float32)


def test_the_committed_rule_is_the_plain_rule_until_it_cannot_stop_before_the_line():
    plain, committed = GapAcceptancePolicy(), CommittedGapAcceptancePolicy()
    # A car 45 m to the left will meet a rolling ego (3 m/s): the plain rule brakes.
    grid = _grid_with(-45.0, 15.0, 15.0, 90.0, ego_speed=3.0)
    assert plain(grid).tolist() == [-1.0]
    # 10 m before the line the ego can still stop (4.5 m at 1 m/s^2): it brakes too.
    assert committed({"grid": grid, "route": _route(10.0)}).tolist() == [-1.0]
    # 4 m before it, or past it, it can no longer stop short: it goes.
    assert committed({"grid": grid, "route": _route(4.0)}).tolist() == [1.0]
    assert committed({"grid": grid, "route": _route(-2.0)}).tolist() == [1.0]
    standing = _grid_with(-70.0, 15.0, 15.0, 90.0)
    assert committed({"grid": standing, "route": _route(-0.5)}).tolist() == [1.0]
    assert committed({"grid": standing, "route": _route(3.0)}).tolist() == [-1.0]
    # On the grid alone it reads the distance from its source, here the env's.
    told = CommittedGapAcceptancePolicy(stop_line_distance=lambda: 4.0)
    assert told(grid).tolist() == [1.0]
    with pytest.raises(ValueError, match=r"distance to the stop line.*route_observation=true"):
        committed(grid)


def test_the_committed_rule_never_brakes_past_the_line_and_collides_less_than_the_plain_rule():
    """Run seed 0's first 40 left-turn test episodes: the plain rule collides in three of
    them, each after braking with its nose past the line."""
    seeds = evaluation_seeds(0, "left", 40)
    env = IntersectionEnv(EnvConfig(task="left"))
    decisions = []  # (distance to the line, braking distance, action), committed rule

    def watched(rule):
        def drive(observation):
            action = rule(observation)
            speed = float(observation[13, 2, 0]) * GRID.speed_scale
            decisions.append((env.stop_line_distance_m, speed * speed / 2.0, float(action[0])))
            return action

        return drive

    try:
        plain = run_episodes(env, watched(GapAcceptancePolicy(env.config)), "left", seeds)
        braked_past_line = sum(a < 0 and d < 0 for d, _, a in decisions)
        decisions.clear()
        committed_rule = make_yardstick("committed_gap_acceptance", env)
        committed = run_episodes(env, watched(committed_rule), "left", seeds)
    finally:
        env.close()
    assert braked_past_line > 0  # the plain rule waits inside the junction
    assert all(a == 1.0 for d, braking, a in decisions if braking >= d)
    assert any(a < 0 for *_, a in decisions)  # it still waits, before the line
    plain_collisions = sum(r.collision for r in plain)
    assert plain_collisions >= 3
    assert sum(r.collision for r in committed) < plain_collisions
    assert sum(r.arrived for r in committed) >= sum(r.arrived for r in plain)


def test_oracle_arrives_where_full_throttle_collides_and_its_plan_replays(left_env):
    blind = run_episodes(left_env, full_throttle(), "left", SEEDS)
    assert any(r.collision for r in blind)  # the seeds hold a dangerous episode
    oracle = LookaheadOracle(left_env)
    for seed, blind_record in zip(SEEDS, blind, strict=True):
        record = run_episode(left_env, oracle, "left", seed)
        assert record.arrived and not record.collision, seed
        best = max(r.episode_return for r in oracle.last_search)
        assert record.episode_return == pytest.approx(best)
        assert record.episode_return >= blind_record.episode_return - 1e-9
        # The look-ahead left no trace: the chosen plan, driven plainly, scores the same.
        plan = next(r for r in oracle.last_search if r.episode_return == best)
        replay = run_episode(
            left_env,
            lambda _, plan=plan: np.array(
                [1.0 if left_env.episode_steps >= plan.wait_steps else -1.0], np.float32
            ),
            "left",
            seed,
        )
        assert replay == dataclasses.replace(record)


def test_yardstick_names():
    env = IntersectionEnv(EnvConfig(task="left"))
    try:
        for name in YARDSTICKS:
            assert callable(make_yardstick(name, env))
        with pytest.raises(ValueError, match=r"unknown policy 'brave'.*full_throttle"):
            make_yardstick("brave", env)
    finally:
        env.close()
    with pytest.raises(ValueError, match="extra_waits"):
        LookaheadOracle(env, extra_waits=-1)


def test_dense_preset_runs_the_yardsticks():
    env = IntersectionEnv(EnvConfig(task="right", scenario=traffic_preset("dense")))
    try:
        record = run_episode(env, LookaheadOracle(env), "right", 7)
    finally:
        env.close()
    assert not record.collision
