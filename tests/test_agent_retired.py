"""Retired agent options (frl.agents.retired): their off values still load, anything else
is refused in one line naming the key, its study (or that none measured it) and the
retiring commit."""

from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium import spaces

from frl.agents import DDPG, CheckpointError, DDPGConfig
from frl.agents.config import CriticConfig
from frl.agents.retired import (
    RETIRED_CRITIC_KINDS,
    RETIRED_CRITIC_OPTIONS,
    RETIRED_OPTIONS,
    RetiredOptionError,
)
from frl.train_config import ConfigError, migrate_saved_config

GRID = spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
ACCEL = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
SMALL = {"hidden_sizes": (16,), "buffer_size": 50, "batch_size": 4}
ON = {
    "action_repeat": 4,
    "explore_hold_probability": 0.1,
    "terminal_fraction": 0.2,
    "critic_layer_norm": True,
    "warmup_policy": "gap_acceptance",
    "twin_critics": True,
    "target_noise": 0.2,
    "target_noise_clip": 0.3,
    "policy_delay": 2,
    "replay": "lap",
    "lap_alpha": 0.6,
    "lap_min_priority": 2.0,
    "guide_residual": True,
    "preactivation_l2": 0.1,
    "guide_decay_steps": 5000,
    "guide_filter_margin": 0.25,
    "guide_filter": "q",
    "gradient_steps": 4,
    "random_warmup": False,
    "average_multiplier": True,
    "budget_noise_free_every": 4,
    "branches": {"probability": 0.1, "before_line_m": 10.0, "past_line_m": 5.0, "hold_steps": 10},
    "self_imitation": 1.0,
    "reward_target": "episode",
    "bang_bang": True,
}
CONTEXT = {
    "guide_filter": {"guide": "gap_acceptance", "guide_weight": 1.0},
    "budget_noise_free_every": {"collision_budget": 0.02},
}
"""Other options under which a retired key's on value did something."""


def test_every_retired_option_has_an_on_value_here_and_is_no_field_any_more():
    assert set(ON) == set(RETIRED_OPTIONS)
    assert not set(RETIRED_OPTIONS) & set(DDPGConfig.__dataclass_fields__)
    assert len(DDPGConfig.__dataclass_fields__) <= 31


@pytest.mark.parametrize("key", sorted(RETIRED_OPTIONS))
def test_a_config_at_the_off_value_loads_and_any_other_value_is_refused(key):
    off = RETIRED_OPTIONS[key].off
    assert DDPGConfig.from_dict({key: off}) == DDPGConfig.from_dict({})
    with pytest.raises(RetiredOptionError) as refused:
        DDPGConfig.from_dict({key: ON[key], **CONTEXT.get(key, {})})
    message = str(refused.value)
    assert "\n" not in message and f"agent.{key}=" in message
    option = RETIRED_OPTIONS[key]
    assert (option.study or "no study measured it") in message
    assert f"commit {option.commit}" in message and len(option.commit) == 7


def test_a_checkpoint_written_with_retired_keys_loads_at_off_and_is_refused_on(tmp_path: Path):
    agent = DDPG(GRID, ACCEL, DDPGConfig(**SMALL), seed=1)
    agent.save(tmp_path / "agent.pt")
    data = torch.load(tmp_path / "agent.pt", weights_only=True)
    data["config"].update({key: option.off for key, option in RETIRED_OPTIONS.items()})
    torch.save(data, tmp_path / "off.pt")
    loaded = DDPG.load(tmp_path / "off.pt")
    assert loaded.config == agent.config
    data["config"]["twin_critics"] = True
    torch.save(data, tmp_path / "on.pt")
    with pytest.raises(CheckpointError, match=r"agent\.twin_critics=True was retired"):
        DDPG.load(tmp_path / "on.pt")
    with pytest.raises(CheckpointError, match="was retired"):
        agent.restore(tmp_path / "on.pt")


def test_a_saved_run_config_with_a_retired_option_on_is_refused_in_one_line():
    assert "replay" not in migrate_saved_config({"agent": {"replay": "uniform"}})["agent"]
    with pytest.raises(ConfigError, match=r"agent\.replay='lap' was retired"):
        migrate_saved_config({"agent": {"replay": "lap"}})


def test_a_command_line_override_at_the_off_value_is_dropped_and_any_other_refused():
    from frl.train import without_retired_overrides

    argv = ["seed=1", "agent.twin_critics=false", "+agent.replay=uniform", "agent.tau=0.01"]
    assert without_retired_overrides(argv) == ["seed=1", "agent.tau=0.01"]
    with pytest.raises(RetiredOptionError, match="policy_delay"):
        without_retired_overrides(["agent.policy_delay=2"])


def test_a_key_of_a_retired_group_is_dropped_at_its_off_value_and_refused_at_any_other():
    from frl.train import without_retired_overrides

    off = ["agent.branches.probability=0", "agent.branches.hold_steps=10", "seed=2"]
    assert without_retired_overrides(off) == ["seed=2"]
    with pytest.raises(RetiredOptionError, match=r"agent\.branches\.probability=0\.1 was retired"):
        without_retired_overrides(["agent.branches.probability=0.1"])
    saved = migrate_saved_config({"agent": {"branches": dict(RETIRED_OPTIONS["branches"].off)}})
    assert "branches" not in saved["agent"]


def test_a_q_filter_without_an_imitation_term_did_nothing_and_loads():
    # Every unguided agent saved before the retirement carries the old default filter "q".
    assert DDPGConfig.from_dict({"guide_filter": "q", "guide_weight": 0.0}) == DDPGConfig.from_dict(
        {}
    )
    unguided = migrate_saved_config({"agent": {"guide_filter": "q_lower", "guide_weight": 0}})
    assert "guide_filter" not in unguided["agent"]
    guided = {"guide": "gap_acceptance", "guide_weight": 1.0}
    assert DDPGConfig.from_dict({**guided, "guide_filter": "none"}).guide_weight == 1.0
    with pytest.raises(RetiredOptionError, match=r"agent\.guide_filter='q' was retired"):
        DDPGConfig.from_dict({**guided, "guide_filter": "q"})
    # On the command line there is no term to read: only the off value is dropped.
    from frl.train import without_retired_overrides

    assert without_retired_overrides(["agent.guide_filter=none"]) == []
    with pytest.raises(RetiredOptionError, match="guide_filter"):
        without_retired_overrides(["agent.guide_filter=q"])


def test_the_ensemble_critic_is_refused_and_its_keys_load_at_their_off_values(tmp_path: Path):
    from frl.train import without_retired_overrides

    assert not {"heads", "disagreement_price"} & set(CriticConfig.__dataclass_fields__)
    off = {key: option.off for key, option in RETIRED_CRITIC_OPTIONS.items()}
    plain = DDPGConfig.from_dict({})
    assert DDPGConfig.from_dict({"critic": {"kind": "expected", **off}}) == plain
    with pytest.raises(RetiredOptionError) as refused:
        DDPGConfig.from_dict({"critic": {"kind": "ensemble", **off}})
    message = str(refused.value)
    option = RETIRED_CRITIC_KINDS["ensemble"]
    assert "\n" not in message and "agent.critic.kind='ensemble' was retired" in message
    assert option.study in message and f"commit {option.commit}" in message
    with pytest.raises(RetiredOptionError, match=r"agent\.critic\.heads=3 was retired"):
        DDPGConfig.from_dict({"critic": {"heads": 3}})
    # A checkpoint an ensemble agent wrote is refused; one with the keys at off loads.
    agent = DDPG(GRID, ACCEL, DDPGConfig(**SMALL), seed=1)
    agent.save(tmp_path / "agent.pt")
    data = torch.load(tmp_path / "agent.pt", weights_only=True)
    data["config"]["critic"].update(off)
    torch.save(data, tmp_path / "off.pt")
    assert DDPG.load(tmp_path / "off.pt").config == agent.config
    data["config"]["critic"]["kind"] = "ensemble"
    torch.save(data, tmp_path / "on.pt")
    with pytest.raises(CheckpointError, match=r"agent\.critic\.kind='ensemble' was retired"):
        DDPG.load(tmp_path / "on.pt")
    # On the command line: the off values are dropped, the rest refused.
    argv = ["agent.critic.heads=5", "agent.critic.disagreement_price=1"]
    argv.append("agent.critic.kind=expected")
    assert without_retired_overrides(argv) == ["agent.critic.kind=expected"]
    with pytest.raises(RetiredOptionError, match=r"agent\.critic\.kind='ensemble' was retired"):
        without_retired_overrides(["agent.critic.kind=ensemble"])
    with pytest.raises(RetiredOptionError, match=r"agent\.critic\.disagreement_price=10"):
        without_retired_overrides(["agent.critic.disagreement_price=10"])
