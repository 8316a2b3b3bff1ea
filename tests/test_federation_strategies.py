"""The roadside unit's strategies: frl's maths, and Flower's classes on the same inputs."""

from __future__ import annotations

import pytest
import torch

from frl.federation.strategies import STRATEGIES, ServerStrategy, StrategySpec


def _model(seed: int, scale: float = 1.0) -> dict[str, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    return {
        "actor.layers.0.weight": torch.randn(4, 3, generator=generator) * scale,
        "critic_target.layers.0.bias": torch.randn(5, generator=generator) * scale,
    }


def _rounds(strategy, rounds: int = 3, clients: int = 5, weights=None):
    """Three rounds in which the clients move away from the global model."""
    current = _model(100)
    history = []
    for server_round in range(1, rounds + 1):
        uploads = [
            {k: v + 0.1 * _model(10 * server_round + i)[k] for k, v in current.items()}
            for i in range(clients)
        ]
        current = strategy.aggregate(uploads, weights, current, server_round)
        history.append(current)
    return history


def test_fedavg_fedprox_and_momentum_free_fedavgm_are_the_mean():
    uploads = [_model(i) for i in range(3)]
    mean = {k: sum(u[k] for u in uploads) / 3 for k in uploads[0]}
    for spec in (StrategySpec(), StrategySpec("fedprox", {"proximal_mu": 0.1}),
                 StrategySpec("fedavgm")):  # fmt: skip
        result = ServerStrategy(spec).aggregate(uploads, None, _model(9), 1)
        for key in mean:
            torch.testing.assert_close(result[key], mean[key])


def test_fedmedian_and_trimmed_mean_resist_one_wild_client():
    uploads = [_model(i) for i in range(4)] + [_model(99, scale=1e6)]
    median = ServerStrategy(StrategySpec("fedmedian")).aggregate(uploads, None, None, 1)
    trimmed = ServerStrategy(StrategySpec("fedtrimmedavg", {"beta": 0.2})).aggregate(
        uploads, None, None, 1
    )
    for result in (median, trimmed):
        assert all(v.abs().max() < 10 for v in result.values())
    stacked = torch.stack([u["actor.layers.0.weight"] for u in uploads[:4]])
    ordered = stacked.sort(dim=0).values
    # An even count of clients: NumPy's median, the mean of the middle two.
    even = ServerStrategy(StrategySpec("fedmedian")).aggregate(uploads[:4], None, None, 1)
    torch.testing.assert_close(even["actor.layers.0.weight"], (ordered[1] + ordered[2]) / 2)


def test_fedavgm_momentum_carries_the_last_step():
    strategy = ServerStrategy(StrategySpec("fedavgm", {"server_momentum": 0.9}))
    current = _model(0)
    moved = {k: v + 1.0 for k, v in current.items()}
    first = strategy.aggregate([moved], None, current, 1)
    second = strategy.aggregate([first], None, first, 2)  # no client change: momentum alone
    for key in current:
        torch.testing.assert_close(first[key], current[key] + 1.0)
        torch.testing.assert_close(second[key], first[key] + 0.9)


def test_server_state_round_trips_through_state_dict():
    spec = StrategySpec("fedadam", {"eta": 0.01})
    straight = ServerStrategy(spec)
    history = _rounds(straight)
    resumed = ServerStrategy(spec)
    _rounds(resumed, rounds=2)
    restored = ServerStrategy(spec)
    restored.load_state_dict(resumed.state_dict())
    uploads = [{k: v + 0.1 * _model(30 + i)[k] for k, v in history[1].items()} for i in range(5)]
    third = restored.aggregate(uploads, None, history[1], 3)
    for key, value in history[2].items():
        torch.testing.assert_close(third[key], value)


@pytest.mark.parametrize(
    ("name", "params", "match"),
    [
        ("fedsgd", {}, "unknown federation.strategy 'fedsgd'"),
        ("fedavg", {"eta": 0.1}, "fedavg takes no parameters; got 'eta'"),
        ("fedadam", {"momentum": 0.1}, "fedadam takes eta, eta_l, beta_1, beta_2, tau"),
        ("fedtrimmedavg", {"beta": 0.5}, r"beta must be in \[0, 0.5\)"),
        ("fedprox", {"proximal_mu": -1}, "proximal_mu must be >= 0"),
        ("fedadam", {"eta": "fast"}, "must be a number"),
    ],
)
def test_bad_strategies_are_refused(name, params, match):
    with pytest.raises(ValueError, match=match):
        StrategySpec(name, params)


@pytest.mark.parametrize("name", STRATEGIES)
@pytest.mark.parametrize("weighted", [False, True])
def test_flower_classes_give_the_same_global_model(name, weighted, monkeypatch):
    pytest.importorskip("flwr")
    from flwr.supercore.task_identity import TaskIdentity

    from frl.flower.strategies import FlowerServerStrategy

    # Flower messages carry the run's id, which a ServerApp has and a test must set.
    monkeypatch.setattr(TaskIdentity, "_run_id", 1)
    monkeypatch.setattr(TaskIdentity, "_node_id", 0)
    monkeypatch.setattr(TaskIdentity, "_task_id", 1)

    params = {"fedtrimmedavg": {"beta": 0.2}, "fedavgm": {"server_momentum": 0.5},
              "fedprox": {"proximal_mu": 0.1}}.get(name, {})  # fmt: skip
    spec = StrategySpec(name, params)
    weights = [1.0, 2.0, 3.0, 4.0, 5.0] if weighted else None
    ours = _rounds(ServerStrategy(spec), weights=weights)
    flowers = _rounds(FlowerServerStrategy(spec), weights=weights)
    for mine, theirs in zip(ours, flowers, strict=True):
        for key in mine:
            torch.testing.assert_close(mine[key], theirs[key], rtol=1e-5, atol=1e-6)
    # Resume: Flower's state goes out and back in, and the next round agrees.
    strategy = FlowerServerStrategy(spec)
    _rounds(strategy, rounds=2, weights=weights)
    restored = FlowerServerStrategy(spec)
    restored.load_state_dict(strategy.state_dict())
    straight = FlowerServerStrategy(spec)
    expected = _rounds(straight, rounds=3, weights=weights)[2]
    history = _rounds(FlowerServerStrategy(spec), rounds=2, weights=weights)
    uploads = [{k: v + 0.1 * _model(30 + i)[k] for k, v in history[1].items()} for i in range(5)]
    third = restored.aggregate(uploads, weights, history[1], 3)
    for key, value in expected.items():
        torch.testing.assert_close(third[key], value, rtol=1e-5, atol=1e-6)
