"""The counterfactual probe: its options, its branches and an exact resume with it."""

import dataclasses

import numpy as np
import pytest
from train_helpers import TINY_AGENT, TINY_ENV, compose_config, tiny_spec

from frl.agents import DDPG
from frl.envs import IntersectionEnv
from frl.federation import VehicleClient
from frl.federation.codec import spec_from_json, spec_to_json
from frl.federation.drive import drive_path, read_drive
from frl.federation.probe import CounterfactualProbe, ProbeConfig
from frl.train import train
from frl.train_config import ConfigError, validate

# One xdist worker runs the SUMO tests of this module: libsumo holds one simulation per process.
pytestmark = pytest.mark.xdist_group("client")


@pytest.mark.parametrize(
    ("options", "key"),
    [
        ({"rate": -0.1}, "probe.rate"),
        ({"rate": 1.5}, "probe.rate"),
        ({"rate": 0.1, "distance_m": 0.0}, "probe.distance_m"),
        ({"rate": 0.1, "horizon": 0}, "probe.horizon"),
        ({"rate": 0.1, "hold_steps": True}, "probe.hold_steps"),
        ({"rate": 0.1, "per_episode": 0}, "probe.per_episode"),
        ({"rate": 0.1, "hold_steps": 12, "horizon": 10}, "probe.hold_steps"),
    ],
)
def test_a_bad_probe_option_is_refused_naming_its_key(options, key):
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        ProbeConfig(**options)


def test_the_training_config_refuses_a_bad_probe_before_any_work(tmp_path):
    with pytest.raises(ConfigError, match=r"probe\.rate"):
        validate(compose_config(tmp_path, ["probe.rate=2"]))
    settings = validate(compose_config(tmp_path, ["probe.rate=0.25"]))
    assert all(spec.probe == ProbeConfig(rate=0.25) for spec in settings.client_specs())
    assert validate(compose_config(tmp_path)).probe == ProbeConfig()  # off by default


def test_a_vehicle_spec_carries_its_probe_over_the_wire():
    spec = dataclasses.replace(tiny_spec(0, "left"), probe=ProbeConfig(rate=0.3, horizon=20))
    assert spec_from_json(spec_to_json(spec)) == spec


def _drive(env, seed, actions, probe=None, probe_at=()):
    """Observations and rewards of one seeded episode under fixed ``actions``, probing
    before the steps in ``probe_at``."""
    observation, _ = env.reset(seed=seed)
    observations, rewards = [observation], []
    for index, action in enumerate(actions):
        if index in probe_at:
            assert probe.maybe_probe(observation)
        observation, reward, terminated, truncated, _ = env.step(np.array([action], np.float32))
        observations.append(observation)
        rewards.append(reward)
        if terminated or truncated:
            break
    return np.stack(observations), rewards


def test_a_probe_leaves_the_episode_as_it_was_and_stores_both_branches():
    env = IntersectionEnv(dataclasses.replace(TINY_ENV, task="straight", max_episode_steps=60))
    agent = DDPG(
        env.observation_space, env.action_space,
        dataclasses.replace(TINY_AGENT, learning_starts=0, collision_budget=0.02), seed=3,
    )  # fmt: skip
    config = ProbeConfig(rate=1.0, hold_steps=5, horizon=15, per_episode=2)
    probe = CounterfactualProbe(config, env, agent, np.random.default_rng(0))
    actions = [0.3] * 8 + [-0.2] * 4 + [0.8] * 40
    try:
        plain_observations, plain_rewards = _drive(env, 11, actions)
        probed_observations, probed_rewards = _drive(env, 11, actions, probe, probe_at=(2, 9))
        assert not probe.maybe_probe(probed_observations[-1])  # two per episode at most
    finally:
        env.close()
    assert np.array_equal(plain_observations, probed_observations)
    assert plain_rewards == probed_rewards
    tally = probe.tally
    assert tally.probes == 2
    assert 2 * 2 * config.hold_steps <= tally.steps <= 2 * 2 * config.horizon
    # Every branch step is one stored transition, and none is one of the agent's steps.
    assert len(agent.buffer) == tally.steps
    assert agent.num_env_steps == 0 and agent.episode_steps == 0
    assert agent.lagrangian is not None and not agent.lagrangian.recent  # no episode counted
    stored = agent.buffer.actions[: tally.steps, 0]
    assert (stored == 1.0).sum() >= 2 * config.hold_steps  # the go branches' held throttle
    assert (stored == -1.0).sum() >= 2 * config.hold_steps  # the wait branches' held brake


def test_a_probe_outside_the_approach_or_in_the_warmup_does_not_fire():
    env = IntersectionEnv(dataclasses.replace(TINY_ENV, task="left"))
    agent = DDPG(env.observation_space, env.action_space, TINY_AGENT, seed=0)
    probe = CounterfactualProbe(ProbeConfig(rate=1.0), env, agent, np.random.default_rng(0))
    try:
        observation, _ = env.reset(seed=5)
        assert not probe.maybe_probe(observation)  # the warm-up: learning_starts not reached
        agent.num_env_steps = agent.config.learning_starts
        assert probe.maybe_probe(observation)
        narrow = CounterfactualProbe(
            ProbeConfig(rate=1.0, distance_m=2.0), env, agent, np.random.default_rng(0)
        )
        assert not narrow.maybe_probe(observation)  # 10 m before the stop line
    finally:
        env.close()


def test_a_probing_vehicle_loaded_mid_episode_drives_on_exactly(tmp_path):
    probing = ProbeConfig(rate=0.5, hold_steps=4, horizon=10, per_episode=2)
    spec = dataclasses.replace(tiny_spec(0, "straight"), probe=probing)
    driving = VehicleClient(spec)
    first = driving.train(45)
    assert first.probe is not None and first.probe["probes"] > 0
    assert driving._observation is not None  # mid-episode
    driving.save(tmp_path)
    went_on = driving.train(60)
    driving.close()
    assert read_drive(drive_path(tmp_path, spec.name)).probe is not None

    resumed = VehicleClient(spec)
    assert resumed.load(tmp_path)
    again = resumed.train(60)
    resumed.close()
    assert np.array_equal(went_on.step_rewards, again.step_rewards)
    for name in went_on.losses:
        assert np.array_equal(went_on.losses[name], again.losses[name], equal_nan=True), name
    assert went_on.probe == again.probe and again.probe["probes"] > first.probe["probes"]
    # A probing vehicle restarts SUMO at every episode, so that a restore replays one.
    assert resumed._restarts == len(first.episodes) + len(went_on.episodes) + 1


def test_a_probing_run_reports_each_vehicles_probes(tmp_path, caplog):
    cfg = compose_config(tmp_path / "run", ["probe.rate=0.5", "eval_episodes=0"])
    with caplog.at_level("INFO", logger="frl.train"):
        results = train(cfg)
    probes = results["training"]["probes"]
    assert set(probes) == {"client0_left", "client1_straight", "client2_right"}
    for tally in probes.values():
        assert tally["probes"] > 0 and tally["steps"] >= tally["probes"] * 2 * 10
    assert "counterfactual probe: at 0.5 of the approach states" in caplog.text
