"""DDPGConfig: Table II defaults, validation with clear messages, plain-dict round trip."""

import pytest

from frl.agents import DDPGConfig
from frl.agents.config import CriticConfig, NoiseConfig, SparseConfig, flat_key_message


def test_defaults_follow_table_ii() -> None:
    config = DDPGConfig()
    assert config.hidden_sizes == (512, 512, 256, 64)
    assert (config.buffer_size, config.learning_starts, config.batch_size) == (100_000, 1000, 256)
    assert (config.tau, config.gamma, config.actor_lr, config.critic_lr) == (
        0.001,
        0.99,
        1e-4,
        1e-4,
    )
    assert config.noise.kind == "ou"


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"actor_lr": -1e-3}, "actor_lr"),
        ({"critic_lr": 0.0}, "critic_lr"),
        ({"tau": 0.0}, "tau"),
        ({"tau": 1.5}, "tau"),
        ({"gamma": 1.01}, "gamma"),
        ({"batch_size": 512, "buffer_size": 256}, "batch_size"),
        ({"noise": {"kind": "pink"}}, "noise.kind"),
        ({"hidden_sizes": ()}, "hidden_sizes"),
        ({"hidden_sizes": (64, 0)}, "hidden_sizes"),
        ({"learning_starts": -1}, "learning_starts"),
        ({"train_freq": 0}, "train_freq"),
        ({"train_freq": 1.5}, "train_freq"),
        ({"noise": {"sigma": -0.1}}, "noise.sigma"),
        ({"noise": {"dt": 0.0}}, "noise.dt"),
        ({"noise": {"theta": 150.0, "dt": 0.02}}, "stable"),
        ({"sparse": {"input": "yes"}}, "sparse.input"),
        ({"sparse": {"capacity": 0}}, "sparse.capacity"),
        ({"noise": "gaussian"}, "noise must be a NoiseConfig"),
        ({"gamma": float("nan")}, "gamma"),
    ],
)
def test_bad_values_raise_value_error_naming_the_field(overrides: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        DDPGConfig(**overrides)


def test_dict_round_trip_and_list_hidden_sizes() -> None:
    config = DDPGConfig(
        hidden_sizes=[64, 32], noise=NoiseConfig("gaussian"), sparse=SparseConfig(input=True)
    )
    assert config.hidden_sizes == (64, 32)
    assert DDPGConfig.from_dict(config.to_dict()) == config


def test_configs_saved_with_the_flat_keys_load_into_their_groups() -> None:
    """Checkpoints and run configs written before the groups hold ``noise: gaussian``,
    ``noise_sigma``, ``sparse_input``, ``critic: quantile``, ``cvar_alpha``, ..."""
    flat = {
        key: value
        for key, value in DDPGConfig().to_dict().items()
        if key not in ("noise", "sparse", "critic")
    }
    flat.update(noise="gaussian", noise_sigma=0.2, noise_theta=0.1, noise_dt=0.02,
                sparse_input=False, sparse_min_features=10, sparse_capacity=8,
                critic="quantile", quantiles=8, cvar_alpha=0.5)  # fmt: skip
    config = DDPGConfig.from_dict(flat)
    assert config.noise == NoiseConfig("gaussian", 0.2, 0.1, 0.02)
    assert config.sparse == SparseConfig(False, 10, 8)
    assert config.critic == CriticConfig("quantile", 8, 0.5)
    assert flat_key_message("noise_sigma") == "agent.noise_sigma is now agent.noise.sigma"


def test_auto_sparse_picks_large_observations_only() -> None:
    config = DDPGConfig()
    assert config.use_sparse(26 * 18 * 3)
    assert not config.use_sparse(3)
    assert DDPGConfig(sparse=SparseConfig(input=True)).use_sparse(3)
    assert not DDPGConfig(sparse=SparseConfig(input=False)).use_sparse(1404)
