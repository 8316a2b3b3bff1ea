"""Reward terms and config validation (no SUMO)."""

import dataclasses

import pytest

from frl.envs.config import EnvConfig, GridConfig, RewardConfig, ScenarioConfig
from frl.envs.reward import COST_TERMS, REWARD_TERMS, RewardSignals, cost_terms, reward_terms
from frl.retirement import RetiredOptionError


def signals(**kwargs):
    base = dict(
        moving=False, others_braking=False, others_waiting=False, collision=False, arrived=False
    )
    return RewardSignals(**{**base, **kwargs})


def test_paper_defaults_are_section_iv_b():
    config = RewardConfig()
    assert (config.alpha, config.beta, config.gamma, config.lambda_, config.mu) == (
        -0.05, 0.04, -0.025, -10.0, 5.0,
    )  # fmt: skip


def test_terms_are_the_weighted_indicators():
    config = RewardConfig()
    terms = reward_terms(signals(moving=True, others_braking=True, arrived=True), config)
    assert set(terms) == set(REWARD_TERMS)
    assert terms == {
        "time": -0.05,
        "speed": 0.04,
        "disturbance": -0.025,
        "undisturbed": 0.0,
        "collision": 0.0,
        "arrival": 5.0,
    }
    both = reward_terms(signals(others_braking=True, others_waiting=True), config)
    assert both["disturbance"] == pytest.approx(-0.05) and both["undisturbed"] == 0.0
    calm = reward_terms(signals(), config)
    assert calm["undisturbed"] == pytest.approx(0.05)


def test_collision_term():
    terms = reward_terms(signals(collision=True), RewardConfig())
    assert terms["collision"] == -10.0


def test_the_cost_is_the_collision_unweighted_whatever_the_reward():
    crash = cost_terms(signals(collision=True, arrived=True), RewardConfig(lambda_=-3.0))
    assert set(crash) == set(COST_TERMS)
    assert crash == {"collision": 1.0}
    calm = cost_terms(signals(moving=True, others_braking=True), RewardConfig())
    assert sum(calm.values()) == 0.0


def test_a_retired_reward_option_loads_off_and_is_refused_on():
    """Runs saved with the priced brake past the line still read at 0; on, one line."""
    saved = {**dataclasses.asdict(RewardConfig()), "brake_past_line_cost": 0.0}
    assert RewardConfig.from_dict(saved) == RewardConfig()
    with pytest.raises(
        RetiredOptionError,
        match=r"^reward\.brake_past_line_cost=0\.1 was retired: "
        r"docs/studies\.md, \"Where the car stands",
    ):
        RewardConfig.from_dict({**saved, "brake_past_line_cost": 0.1})
    with pytest.raises(TypeError, match="unknown_weight"):
        RewardConfig.from_dict({"unknown_weight": 1.0})


@pytest.mark.parametrize("option", ["commit_at_line", "windows_until_committed"])
def test_a_retired_env_option_loads_off_and_is_refused_on(option: str):
    """Runs saved with a retired env option (the shield at the stop line, the windows
    blanked once committed) still read with it off; on, one line."""
    saved = {**EnvConfig().to_dict(), option: False}
    assert EnvConfig.from_dict(saved) == EnvConfig()
    with pytest.raises(RetiredOptionError, match=rf"^env\.{option}=True was retired: "):
        EnvConfig.from_dict({**saved, option: True})


def test_a_retired_reward_override_at_off_is_dropped_from_the_command_line():
    from frl.train import without_retired_overrides

    argv = ["reward.brake_past_line_cost=0", "seed=1", "env.commit_at_line=false", "reward.alpha=0"]
    assert without_retired_overrides(argv) == ["seed=1", "reward.alpha=0"]


def test_the_retired_traffic_by_round_loads_off_and_is_refused_on():
    """Run configs saved while traffic by round existed (null: none) still read; one
    that trained with a schedule is refused in one line naming the study."""
    from frl.train import without_retired_overrides
    from frl.train_config import ConfigError, migrate_saved_config

    key = "round_arrival_period_factors"
    saved = {"federation": {"strategy": "fedavg", key: None}}
    assert migrate_saved_config(saved)["federation"] == {"strategy": "fedavg"}
    with pytest.raises(
        ConfigError,
        match=rf"^federation\.{key}=\[0\.6, 1\] was retired: docs/studies\.md, \"Busy rounds",
    ):
        migrate_saved_config({"federation": {key: [0.6, 1]}})
    assert without_retired_overrides([f"federation.{key}=null", "seed=1"]) == ["seed=1"]


def test_reference_reward_by_name():
    reference = RewardConfig.named("reference")
    step = sum(reward_terms(signals(moving=True), reference).values())
    crash = sum(reward_terms(signals(collision=True), reference).values())
    success = sum(reward_terms(signals(arrived=True), reference).values())
    assert step == pytest.approx(-0.01)
    assert crash == pytest.approx(-1.01)
    assert success == pytest.approx(0.99)
    assert RewardConfig.named("paper", alpha=-0.005).alpha == -0.005


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: EnvConfig(task="uturn"), "unknown task 'uturn'"),
        (lambda: ScenarioConfig(human_arrival_period_steps=-1), "human_arrival_period_steps"),
        (lambda: ScenarioConfig(human_arrival_period_steps=0), "human_arrival_period_steps"),
        (lambda: GridConfig(lateral_range=(10.0, 10.0)), "non-empty range"),
        (lambda: GridConfig(longitudinal_range=(40.0, -5.0)), "non-empty range"),
        (lambda: GridConfig(lateral_cells=0), "positive integer"),
        (lambda: RewardConfig(name="shaped"), "reward.name"),
        (lambda: RewardConfig.named("shaped"), "unknown reward 'shaped'"),
        (lambda: EnvConfig(backend="carla"), "unknown backend"),
        (lambda: EnvConfig(max_episode_steps=0), "max_episode_steps"),
        (lambda: ScenarioConfig(human_arrival_process="bursty"), "human_arrival_process"),
        (lambda: ScenarioConfig(step_length=float("nan")), "finite"),
        (lambda: ScenarioConfig(ego_destination_distance=500.0), "exit arm"),
    ],
)
def test_bad_config_values_raise_clear_errors(build, message):
    with pytest.raises(ValueError, match=message):
        build()


def test_configs_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        EnvConfig().task = "left"  # type: ignore[misc]
