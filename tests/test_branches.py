"""Counterfactual branches: driven from a saved state, stored, and undone exactly."""

import dataclasses

import numpy as np
import pytest
from train_helpers import TINY_AGENT, tiny_spec

from frl.agents import DDPG, BranchConfig, DDPGConfig
from frl.envs import IntersectionEnv
from frl.federation import VehicleClient
from frl.federation.branches import Brancher

# One xdist worker runs this module: libsumo holds one simulation per process.
pytestmark = pytest.mark.xdist_group("client")

ALWAYS = BranchConfig(probability=1.0)


def _branching_spec(task: str = "straight", branches: BranchConfig = ALWAYS):
    spec = tiny_spec(0, task)
    return dataclasses.replace(spec, agent=dataclasses.replace(TINY_AGENT, branches=branches))


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("probability", 1.5, "branches.probability must lie in [0, 1]"),
        ("probability", float("nan"), "branches.probability must lie in [0, 1]"),
        ("hold_steps", 0, "branches.hold_steps must be a positive integer"),
        ("past_line_m", -1.0, "branches.past_line_m must be >= 0"),
    ],
)
def test_bad_branch_settings_are_refused(field, value, message):
    fields = {"probability": 0.5, field: value}
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        BranchConfig(**fields)


def test_branch_settings_without_branches_are_refused():
    with pytest.raises(ValueError, match=r"set branches\.probability above 0 too"):
        BranchConfig(hold_steps=5)


def test_an_agent_config_round_trips_its_branches():
    config = DDPGConfig(branches=BranchConfig(probability=0.1, hold_steps=4))
    assert DDPGConfig.from_dict(config.to_dict()) == config
    old = config.to_dict()
    del old["branches"]  # a checkpoint written before branches
    assert not DDPGConfig.from_dict(old).branches.enabled


def test_learn_refuses_an_agent_with_branches():
    env = IntersectionEnv()
    agent = DDPG(
        env.observation_space, env.action_space, dataclasses.replace(TINY_AGENT, branches=ALWAYS)
    )
    with pytest.raises(ValueError, match=r"branches\.probability"):
        agent.learn(env, 10)
    env.close()


def test_a_branch_leaves_the_cars_own_drive_as_it_was():
    """The same actions with a branch in the middle give the same observations, rewards
    and outcome as without it; the branch's steps reach the replay buffer alone."""
    env = IntersectionEnv(task="straight", warmup_steps=10)
    agent = DDPG(
        env.observation_space, env.action_space, dataclasses.replace(TINY_AGENT, learning_starts=0)
    )

    def drive(branch_at: int | None):
        observation, _ = env.reset(seed=11)
        seen = [observation]
        for step in range(200):
            action = np.array([0.6 if step % 7 else -0.4], np.float32)
            if step == branch_at:
                Brancher(ALWAYS, 0).branch(env, agent, observation, action)
            observation, reward, terminated, truncated, info = env.step(action)
            seen.append((observation, reward))
            if terminated or truncated:
                return seen, info
        raise AssertionError("the episode did not end")

    plain, plain_end = drive(None)
    assert len(agent.buffer) == 0
    branched, branched_end = drive(5)
    assert len(agent.buffer) > 0 and agent.num_env_steps == 0
    assert len(plain) == len(branched)
    for a, b in zip(plain[1:], branched[1:], strict=True):
        assert np.array_equal(a[0], b[0]) and a[1] == b[1]
    assert (plain_end["collision"], plain_end["arrived"]) == (
        branched_end["collision"],
        branched_end["arrived"],
    )
    env.close()


def test_a_branching_vehicle_stores_branches_and_tallies_them():
    vehicle = VehicleClient(_branching_spec())
    update = vehicle.train(120)
    tally = vehicle.brancher.tally
    branches = tally.brake.branches + tally.go.branches
    assert branches >= 2  # one per episode after the warm-up
    assert vehicle.agent.num_env_steps == 120  # branch steps are no environment steps
    assert len(vehicle.agent.buffer) > 120 - 4  # the branches' transitions are there
    assert vehicle._restarts == len(update.episodes) + (vehicle._observation is not None)
    vehicle.close()


def test_a_branching_vehicle_resumed_mid_episode_drives_the_same_run(tmp_path):
    spec = _branching_spec(branches=BranchConfig(probability=0.3))
    driving = VehicleClient(spec)
    driving.train(45)
    assert driving._observation is not None
    driving.save(tmp_path)
    saved = driving.brancher.tally.brake.branches + driving.brancher.tally.go.branches
    went_on = driving.train(90)
    tally = driving.brancher.tally.to_dict()
    assert tally["brake"]["branches"] + tally["go"]["branches"] > saved  # it branched on
    driving.close()

    resumed = VehicleClient(spec)
    assert resumed.load(tmp_path)
    again = resumed.train(90)
    assert np.array_equal(went_on.step_rewards, again.step_rewards)
    for name in went_on.losses:
        assert np.array_equal(went_on.losses[name], again.losses[name], equal_nan=True), name
    assert resumed.brancher.tally.to_dict() == tally
    resumed.close()
