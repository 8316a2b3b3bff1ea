"""A collision budget and a risk-averse critic: the multiplier's rule, the cost critic in
the agent's state, checkpoints and FedAvg, the quantile loss and CVaR against hand-computed
numbers, and a budget met on a small problem."""

from __future__ import annotations

import itertools
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces
from train_helpers import TINY_AGENT, tiny_spec

from frl.agents import DDPG, DDPGConfig, is_target_key
from frl.agents.config import CriticConfig, NoiseConfig
from frl.agents.functional import lower_tail_mean, quantile_huber_loss
from frl.agents.lagrange import LAMBDA_MAX, PIDLagrangian
from frl.agents.n_step import NStepAccumulator

pytestmark = pytest.mark.usefixtures("one_torch_thread")

ONE = spaces.Box(-1.0, 1.0, (1,), np.float32)


class RiskyDash(gym.Env):
    """One-step episodes: a speed a in [-1, 1] pays 1 + a, and above 0.5 it crashes.

    The return alone says full speed and a crash every episode; a budget of 0.1 crashes
    says slower than 0.5, with the exploration noise now and then over it."""

    observation_space = ONE
    action_space = ONE

    def reset(self, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        return np.ones(1, np.float32), {}

    def step(self, action):
        speed = float(np.clip(np.asarray(action).reshape(-1)[0], -1.0, 1.0))
        crash = speed > 0.5
        return np.ones(1, np.float32), 1.0 + speed, True, False, {"cost": float(crash)}


def small_config(**options: object) -> DDPGConfig:
    return DDPGConfig(
        hidden_sizes=(16, 16), learning_starts=100, batch_size=16, buffer_size=2000, n_step=1,
        noise=NoiseConfig("gaussian", 0.1), actor_lr=1e-3, critic_lr=1e-3, tau=0.01,
        warmup_hold_steps=1.0, **options,
    )  # fmt: skip


def dash_agent(budget: float | None, seed: int = 0, cost_critic: str = "head") -> DDPG:
    costed = {} if budget is None else {"cost_critic": cost_critic}
    return DDPG(ONE, ONE, small_config(collision_budget=budget, **costed), seed=seed)


def pendulum_agent(**options: object) -> tuple[DDPG, gym.Env]:
    env = gym.make("Pendulum-v1")
    return DDPG(env.observation_space, env.action_space, small_config(**options)), env


def train_dash(agent: DDPG, steps: int) -> list[float]:
    costs: list[float] = []
    agent.learn(RiskyDash(), steps, callback=lambda _, __, info: costs.append(info["cost"]))
    return costs


# ------------------------------------------------------------------ the multiplier
def test_the_multiplier_follows_the_pid_rule_by_hand() -> None:
    rule = PIDLagrangian(0.1, (10.0, 0.1, 1.0), window=2)
    # rate 1: error 0.9, I = 0.09, rising 1 -> 9 + 0.09 + 1
    assert rule.episode_end(1.0) == pytest.approx(10.09)
    # rate 0.5: error 0.4, I = 0.13, falling -> 4 + 0.13
    assert rule.episode_end(0.0) == pytest.approx(4.13)
    # rate 0: error -0.1, I = 0.12 -> -1 + 0.12 < 0 -> 0
    assert rule.episode_end(0.0) == 0.0
    assert rule.integral == pytest.approx(0.12)


def test_the_multiplier_rises_over_budget_falls_under_it_and_stays_bounded() -> None:
    rule = PIDLagrangian(0.05, (10.0, 0.1, 0.0), window=20)
    over = [rule.episode_end(1.0 if i % 2 == 0 else 0.0) for i in range(200)]
    assert all(b >= a for a, b in itertools.pairwise(over[40:]))  # window full
    assert over[-1] > over[40] > 0
    under = [rule.episode_end(0.0) for _ in range(2000)]  # I falls by Ki * budget each
    assert under[19] < over[-1]  # the proportional part leaves with the collisions
    assert all(b <= a for a, b in itertools.pairwise(under[20:]))  # window clean
    assert under[-1] == 0.0 and rule.integral == 0.0
    crashes = [rule.episode_end(1.0) for _ in range(100_000)]
    assert max(crashes) == LAMBDA_MAX


def test_the_rule_state_round_trips() -> None:
    rule = PIDLagrangian(0.02, (10.0, 0.1, 0.0), window=5)
    for cost in (1, 0, 0, 1, 0, 0, 0):
        rule.episode_end(cost)
    copy = PIDLagrangian(0.02, (10.0, 0.1, 0.0), window=5)
    copy.load_state_dict(rule.state_dict())
    assert copy.episode_end(1.0) == rule.episode_end(1.0)


# ------------------------------------------------------------ the quantile critic
def test_quantile_huber_loss_by_hand() -> None:
    # taus 0.25 and 0.75; u = 0.5 and -0.5; weights 0.25 and 0.25; Huber 0.125 each
    loss = quantile_huber_loss(torch.tensor([[0.0, 1.0]]), torch.tensor([[0.5]]))
    assert loss.item() == pytest.approx(0.0625)
    # one quantile (tau 0.5), u = 3 beyond kappa 1: Huber 2.5, weight 0.5
    loss = quantile_huber_loss(torch.tensor([[0.0]]), torch.tensor([[3.0]]))
    assert loss.item() == pytest.approx(1.25)
    with pytest.raises(ValueError, match="batch"):
        quantile_huber_loss(torch.zeros(3), torch.zeros(3, 2))


def test_quantile_regression_finds_the_quantiles_of_samples() -> None:
    generator = torch.Generator().manual_seed(0)
    samples = torch.cat([torch.zeros(900), torch.full((100,), -10.0)])  # a crash in ten
    quantiles = torch.zeros(1, 10, requires_grad=True)
    optimizer = torch.optim.Adam([quantiles], lr=0.05)
    for _ in range(1000):
        batch = samples[torch.randint(0, len(samples), (64,), generator=generator)]
        loss = quantile_huber_loss(quantiles, batch.view(1, -1))
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    learned = quantiles.detach().view(-1)
    assert learned[0] < -8 and learned[1:].abs().max() < 1.0  # tau 0.05 in the crash
    # The mean sees a tenth of a crash; the worst 10% are the crash itself.
    assert lower_tail_mean(quantiles.detach(), 1.0).item() == pytest.approx(-1, abs=0.3)
    assert lower_tail_mean(quantiles.detach(), 0.1).item() < -8


def test_lower_tail_mean_by_hand() -> None:
    quantiles = torch.tensor([[3.0, 1.0, 2.0, 4.0]])
    assert lower_tail_mean(quantiles, 1.0).item() == 2.5
    assert lower_tail_mean(quantiles, 0.5).item() == 1.5
    assert lower_tail_mean(quantiles, 0.1).item() == 1.0
    with pytest.raises(ValueError, match="alpha"):
        lower_tail_mean(quantiles, 0.0)


# ---------------------------------------------------------------- configuration
@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"collision_budget": -0.01}, "collision_budget must lie in \\[0, 1\\)"),
        ({"collision_budget": 1.0}, "collision_budget must lie in \\[0, 1\\)"),
        ({"collision_budget": True}, "collision_budget must lie"),
        ({"critic": {"cvar_alpha": 0.0, "kind": "quantile"}}, "cvar_alpha must lie in \\(0, 1\\]"),
        ({"critic": {"cvar_alpha": 1.5, "kind": "quantile"}}, "cvar_alpha must lie in \\(0, 1\\]"),
        ({"critic": {"cvar_alpha": 0.25}}, "cvar_alpha below 1 needs .* critic.kind=quantile"),
        ({"critic": {"quantiles": 8}}, "quantiles is the quantile critic's"),
        ({"lagrange_window": 10}, "lagrange_window tunes the collision budget"),
        ({"lagrange_gains": (1.0, 0.1, 0.0)}, "lagrange_gains tunes the collision budget"),
        ({"collision_budget": 0.1, "lagrange_gains": (1.0, -1.0, 0.0)}, "lagrange_gains must"),
        ({"collision_budget": 0.1, "lagrange_gains": (1.0,)}, "lagrange_gains must"),
        ({"critic": {"kind": "distributional"}}, "critic.kind must be one of expected, quantile"),
        ({"cost_critic": "separate"}, "cost_critic tunes the collision budget"),
        ({"collision_budget": 0.1, "cost_critic": "shared"}, "cost_critic must be one of"),
    ],
)
def test_bad_cost_options_are_refused_naming_the_key(overrides: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        DDPGConfig(**overrides)


def test_cost_options_round_trip_a_dict() -> None:
    config = DDPGConfig(collision_budget=0.02, lagrange_gains=[5, 0.2, 1],
                        critic=CriticConfig("quantile", 16, 0.25), cost_critic="head")  # fmt: skip
    assert config.lagrange_gains == (5, 0.2, 1)
    assert DDPGConfig.from_dict(config.to_dict()) == config


# -------------------------------------------------------------------- the agent
def test_without_a_budget_the_agent_has_no_cost_critic_and_ignores_costs() -> None:
    agent = DDPG(ONE, ONE, DDPGConfig(hidden_sizes=(8,)), seed=0)
    assert agent.constraint is None
    assert not any(key.startswith("cost_critic") for key in agent.federated_state())
    agent.observe(np.ones(1), np.ones(1), 1.0, np.ones(1), True, cost=1.0)
    assert agent.writer.pending.flush() == []  # terminated: stored, cost not kept
    assert agent.buffer.costs.size == 0


@pytest.mark.parametrize("cost_critic", ["separate", "head"])
def test_a_budget_that_never_prices_a_crash_trains_exactly_as_no_budget(cost_critic: str) -> None:
    # Pendulum has no collisions: lambda stays 0, and the cost critic, built after the
    # others from the same stream, changes neither their initial weights nor any draw;
    # a cost head's loss does not reach the critic it reads. On n-step cost targets: costs
    # to go hold each episode until it ends, so updates sample another buffer.
    plain, env = pendulum_agent()
    budgeted, other_env = pendulum_agent(
        collision_budget=0.1, cost_critic=cost_critic, cost_target="n_step"
    )
    plain.learn(env, 300)
    budgeted.learn(other_env, 300)
    assert budgeted.constraint.lagrangian.multiplier == 0.0
    state, other = plain.federated_state(), budgeted.federated_state()
    extra = set(other) - set(state)
    assert extra and all(key.startswith("cost_critic") for key in extra)
    for key, tensor in state.items():
        assert torch.equal(tensor, other[key]), key


def test_n_step_transitions_carry_the_discounted_cost() -> None:
    steps = NStepAccumulator(3, 0.5)
    obs = np.zeros(1)
    assert steps.push(obs, obs, 1.0, obs, False, cost=0.0) == []
    assert steps.push(obs, obs, 1.0, obs, False, cost=0.0) == []
    done = steps.push(obs, obs, -10.0, obs, True, cost=1.0)
    assert [t.cost for t in done] == [0.25, 0.5, 1.0]
    restored = NStepAccumulator(3, 0.5)
    steps.push(obs, obs, 1.0, obs, False, cost=0.5)
    restored.load_state_dict(steps.state_dict())
    assert restored.flush()[0].cost == 0.5


@pytest.mark.parametrize("cost_critic", ["separate", "head"])
def test_a_budget_is_met_on_a_small_problem_that_the_return_alone_crashes(
    cost_critic: str,
) -> None:
    agent = dash_agent(0.1, cost_critic=cost_critic)
    costs = train_dash(agent, 1000)
    # The return alone drives at full speed into a crash every episode (the critic
    # learns 1 + a, whose gradient always says faster); under the budget:
    assert np.mean(costs[-300:]) < 0.3  # near the budget, the noise now and then over it
    assert agent.predict(np.ones(1, np.float32))[0][0] < 0.5  # the policy itself: none
    # A crash has its price; the separate critic's, at this seed, above the speed it buys
    # (the head's Q_c is steeper in the action, so a smaller multiplier holds the budget:
    # 0.04-0.2 at the end, by the CPU's arithmetic, so only "still priced" is asked of it).
    assert agent.constraint.lagrangian.multiplier > (1.0 if cost_critic == "separate" else 0.0)
    # The cost critic learned that going fast crashes and going slow does not.
    fast, slow = agent.critic_values(np.ones((2, 1)), np.array([[1.0], [-1.0]]), cost=True)
    assert fast > 0.5 > 0.2 > slow
    plain = dash_agent(None)
    assert np.mean(train_dash(plain, 500)[-100:]) > 0.9


def test_a_cvar_actor_on_a_quantile_critic_trains() -> None:
    agent, env = pendulum_agent(critic=CriticConfig("quantile", 8, 0.25))
    agent.learn(env, 200)
    assert agent.networks.critic(torch.ones(4, 3), torch.zeros(4, 1)).shape == (4, 8)
    assert agent.critic_values(np.ones((2, 3)), np.zeros((2, 1))).shape == (2,)
    losses = agent.update()
    assert losses and all(np.isfinite(list(losses.values())))


@pytest.mark.parametrize("cost_critic", ["separate", "head"])
def test_checkpoints_hold_the_cost_critic_and_the_multiplier(
    tmp_path: Path, cost_critic: str
) -> None:
    agent = dash_agent(0.1, seed=3, cost_critic=cost_critic)
    train_dash(agent, 300)
    agent.constraint.observe_cost(1.0)  # an episode running at the save, with a collision
    agent.save(tmp_path / "a.pt", include_buffer=True)
    restored = dash_agent(0.1, seed=99, cost_critic=cost_critic)
    restored.restore(tmp_path / "a.pt")
    assert restored.constraint.lagrangian.state_dict() == agent.constraint.lagrangian.state_dict()
    assert restored.constraint.state_dict() == agent.constraint.state_dict()
    np.testing.assert_array_equal(restored.buffer.costs, agent.buffer.costs)
    agent.episode_start()
    restored.episode_start()
    assert train_dash(agent, 50) == train_dash(restored, 50)
    state, other = agent.federated_state(), restored.federated_state()
    assert any(key.startswith("cost_critic_target.") for key in state)
    for key, tensor in state.items():
        assert torch.equal(tensor, other[key]), key
    assert restored.constraint.lagrangian.multiplier == agent.constraint.lagrangian.multiplier


def test_a_cost_head_is_a_small_mlp_on_the_critics_last_hidden_layer() -> None:
    state = dash_agent(0.1, cost_critic="head").federated_state()
    head = {key: tuple(tensor.shape) for key, tensor in state.items() if "cost" in key}
    assert head == {
        f"{network}.layers.{layer}.{kind}": shape
        for network in ("cost_critic", "cost_critic_target")
        for layer, kind, shape in [(0, "weight", (16, 16)), (0, "bias", (16,)),
                                   (1, "weight", (1, 16)), (1, "bias", (1,))]
    }  # fmt: skip
    separate = dash_agent(0.1, cost_critic="separate").federated_state()
    assert separate["cost_critic.layers.0.weight"].shape == state["critic.layers.0.weight"].shape


def test_a_budget_saved_before_the_cost_head_loads_with_a_separate_cost_critic() -> None:
    saved = DDPGConfig(collision_budget=0.02, cost_critic="separate").to_dict()
    del saved["cost_critic"]
    assert DDPGConfig.from_dict(saved).cost_critic == "separate"
    assert DDPGConfig(collision_budget=0.02).cost_critic == "head"
    unbudgeted = DDPGConfig().to_dict()
    del unbudgeted["cost_critic"]
    assert DDPGConfig.from_dict(unbudgeted) == DDPGConfig.from_dict(DDPGConfig().to_dict())


def test_cost_critic_targets_are_target_keys() -> None:
    assert is_target_key("cost_critic_target.layers.0.weight")
    assert not is_target_key("cost_critic.layers.0.weight")


def test_a_fedavg_round_averages_the_cost_critic_and_keeps_each_multiplier() -> None:
    from dataclasses import replace

    from frl.federation import fedavg
    from frl.federation.client import VehicleClient

    agent = replace(TINY_AGENT, collision_budget=0.05)
    clients = [VehicleClient(replace(tiny_spec(i, task), agent=agent)) for i, task in
               enumerate(("left", "straight"))]  # fmt: skip
    updates = []
    for client in clients:  # libsumo: one simulation at a time in this process
        updates.append(client.train(60))
        client.close()
    for client in clients:  # an episode each, with and without a collision
        client.agent.constraint.lagrangian.episode_end(float(client.spec.index))
    uploads = [update.parameters for update in updates]
    key = "cost_critic.layers.0.weight"
    assert key in uploads[0] and not torch.equal(uploads[0][key], uploads[1][key])
    global_model = fedavg(uploads)
    for client in clients:
        client.set_parameters(global_model)
        assert torch.equal(client.agent.federated_state()[key], global_model[key])
    torch.testing.assert_close(global_model[key], (uploads[0][key] + uploads[1][key]) / 2)
    multipliers = [client.agent.constraint.lagrangian.multiplier for client in clients]
    assert multipliers[0] != multipliers[1]  # the multiplier stays with its vehicle
    assert np.isfinite(updates[0].losses["cost_q_mean"]).any()
