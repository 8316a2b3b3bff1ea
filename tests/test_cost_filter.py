"""The model driven through its own cost critic at test time (``frl.evaluate RUN_DIR
--cost-filter PRICE``): which action the filter takes, against hand-set critic values and
the real critics; a run's test through it, stored beside its own; bad input refused."""

from __future__ import annotations

import json

import numpy as np
import pytest
from gymnasium import spaces
from test_agent_budget import ONE, dash_agent
from test_cli_errors import assert_one_line_error, run_cli  # noqa: F401 (a fixture)
from train_helpers import compose_config

from frl.agents import DDPG, DDPGConfig
from frl.agents.cost_filter import CANDIDATES, CostFilteredPolicy
from frl.train import train
from frl.train_config import ConfigError, validate

pytestmark = pytest.mark.usefixtures("one_torch_thread")

OBS = np.ones(1, np.float32)


def priced(agent: DDPG, monkeypatch, cost, value) -> None:
    """The agent's critics answer with ``cost`` and ``value`` per candidate row (the
    actor's action first, then the grid's from -1 to 1)."""

    def critic_values(observations, actions, cost_: bool = False):
        assert len(observations) == len(actions) == CANDIDATES + 1
        return np.array(cost if cost_ else value, dtype=np.float64)

    monkeypatch.setattr(agent, "critic_values", lambda o, a, cost=False: critic_values(o, a, cost))


def test_an_action_priced_within_the_threshold_is_the_actors_own(monkeypatch):
    agent = dash_agent(0.1)
    own = agent.act(OBS, explore=False)
    priced(agent, monkeypatch, [0.1] + [0.0] * CANDIDATES, [0.0] * (CANDIDATES + 1))
    policy = CostFilteredPolicy(agent, 0.1)

    assert np.array_equal(policy(OBS), own)
    assert (policy.steps, policy.overridden) == (1, 0)


def test_an_action_priced_above_it_gives_way_to_the_best_valued_allowed_one(monkeypatch):
    agent = dash_agent(0.1)
    grid = np.linspace(-1.0, 1.0, CANDIDATES)
    cost = [0.5, *np.where(grid <= 0.0, 0.05, 0.9)]  # braking allowed, going not
    value = [9.0, *(10.0 - (grid - 0.5) ** 2)]  # the best value overall is at +0.5
    priced(agent, monkeypatch, cost, value)
    policy = CostFilteredPolicy(agent, 0.1)

    action = policy(OBS)

    assert action.shape == agent.act(OBS, explore=False).shape
    assert action[0] == pytest.approx(0.0)  # the best valued of those priced at most 0.1
    assert (policy.overridden, policy.overridden_share) == (1, 1.0)


def test_where_every_action_is_priced_above_it_the_least_priced_is_taken(monkeypatch):
    agent = dash_agent(0.1)
    grid = np.linspace(-1.0, 1.0, CANDIDATES)
    priced(agent, monkeypatch, [0.9, *(0.5 + (grid + 0.4) ** 2)], [0.0] * (CANDIDATES + 1))

    assert CostFilteredPolicy(agent, 0.1)(OBS)[0] == pytest.approx(-0.4)


def test_on_the_real_critics_the_filter_agrees_with_the_critics_own_readings(monkeypatch):
    agent = dash_agent(0.1, seed=3)
    readings = agent.critic_values  # an untrained cost head reads about 0, either side:
    monkeypatch.setattr(  # lifted by 0.5, every price is one the filter can be set at
        agent, "critic_values", lambda o, a, cost=False: readings(o, a, cost) + 0.5 * cost
    )
    grid = np.linspace(-1.0, 1.0, CANDIDATES, dtype=np.float32)[:, None]
    own = agent.act(OBS, explore=False)
    rows = np.concatenate([own.reshape(1, 1), grid])
    cost = agent.critic_values(np.repeat(OBS[None], len(rows), 0), rows, cost=True)
    value = agent.critic_values(np.repeat(OBS[None], len(rows), 0), rows)

    assert np.array_equal(CostFilteredPolicy(agent, float(cost.max()))(OBS), own)
    below = float(np.sort(cost)[len(cost) // 2])  # about half the candidates allowed
    allowed = np.where(cost <= below, value, -np.inf)
    expected = own if cost[0] <= below else rows[int(np.argmax(allowed))]
    assert np.array_equal(CostFilteredPolicy(agent, below)(OBS), expected.reshape(own.shape))
    least = rows[int(np.argmin(cost))]
    assert np.array_equal(CostFilteredPolicy(agent, float(cost.min()) / 2)(OBS), least)


@pytest.mark.parametrize("threshold", [-0.1, float("nan"), float("inf"), "0.1", True, None])
def test_a_price_that_is_no_price_is_refused(threshold):
    with pytest.raises(ValueError, match="cost_filter must be a number >= 0"):
        CostFilteredPolicy(dash_agent(0.1), threshold)  # type: ignore[arg-type]


def test_an_agent_without_a_cost_critic_is_refused():
    with pytest.raises(ValueError, match="needs a model with a cost critic"):
        CostFilteredPolicy(dash_agent(None), 0.1)


def test_an_agent_of_two_actions_is_refused():
    two = spaces.Box(-1.0, 1.0, (2,), np.float32)
    agent = DDPG(ONE, two, DDPGConfig(hidden_sizes=(8,), collision_budget=0.1), seed=0)
    with pytest.raises(ValueError, match="chooses one acceleration; this agent has 2"):
        CostFilteredPolicy(agent, 0.1)


@pytest.fixture(scope="module")
def budget_run(tmp_path_factory):
    """A tiny run under the default collision budget, tested through its filter too."""
    run_dir = tmp_path_factory.mktemp("filter") / "run"
    train(compose_config(run_dir, ["eval_episodes=3", "eval_cost_filter=1000000"]))
    return run_dir


def test_training_with_a_filter_tests_twice_and_a_price_nothing_exceeds_changes_nothing(
    budget_run,
):
    results = json.loads((budget_run / "results.json").read_text())
    own, filtered = results["evaluation"], results["evaluation_cost_filtered"]["1e+06"]

    assert "cost_filter" not in own and filtered["cost_filter"] == 1e6
    # Priced within a million, every action is the actor's: the run's own test again.
    assert filtered["per_task"] == own["per_task"] and filtered["average"] == own["average"]
    assert filtered["yardsticks"] == own["yardsticks"]


def test_a_run_tested_through_its_filter_keeps_its_own_test(run_cli, budget_run):  # noqa: F811
    before = json.loads((budget_run / "results.json").read_text())

    tight = run_cli("frl.evaluate", str(budget_run), "--cost-filter", "0", cwd=budget_run)

    assert tight.returncode == 0, tight.stderr
    assert "the model through its cost filter at 0" in tight.stdout
    after = json.loads((budget_run / "results.json").read_text())
    assert after["evaluation"] == before["evaluation"]  # the run's own test, untouched
    filtered = after["evaluation_cost_filtered"]
    assert filtered["1e+06"] == before["evaluation_cost_filtered"]["1e+06"]
    assert filtered["0"]["cost_filter"] == 0.0 and filtered["0"]["episodes_per_task"] == 3


@pytest.mark.parametrize(
    ("override", "text"),
    [
        ("eval_cost_filter=-1", "eval_cost_filter must be a number >= 0"),
        ("eval_cost_filter=nan", "eval_cost_filter must be a number >= 0"),
        (
            "eval_cost_filter=0.2 agent.collision_budget=null",
            "eval_cost_filter reads the model's cost critic: set agent.collision_budget",
        ),
        ("eval_cost_filter=0.2 eval_episodes=0", "set eval_episodes > 0"),
    ],
)
def test_a_training_config_with_a_bad_filter_is_refused(override, text):
    with pytest.raises(ConfigError, match=text):
        validate(compose_config(None, override.split(), tiny=False))


@pytest.mark.parametrize(
    ("args", "text"),
    [
        (["--cost-filter", "-1"], "--cost-filter must be a number >= 0"),
        (["--cost-filter", "nan"], "--cost-filter must be a number >= 0"),
        (["--cost-filter", "0.1", "--policy", "oracle"], "not with --policy"),
    ],
)
def test_a_bad_filter_is_refused_in_one_line(run_cli, tmp_path, args, text):  # noqa: F811
    result = run_cli("frl.evaluate", str(tmp_path), *args, cwd=tmp_path)
    assert_one_line_error(result, "python -m frl.evaluate: error:", text)


def test_a_run_without_a_cost_critic_is_refused_before_any_work(run_cli, tmp_path):  # noqa: F811
    run_dir = tmp_path / "run"
    (run_dir / "models").mkdir(parents=True)
    from omegaconf import OmegaConf

    saved = compose_config(run_dir, ["agent.collision_budget=null"])
    OmegaConf.save(saved, run_dir / "config.yaml")
    (run_dir / "models" / "index.json").write_text(json.dumps({"left": "global.pt"}))

    result = run_cli("frl.evaluate", str(run_dir), "--cost-filter", "0.1", cwd=run_dir)

    assert_one_line_error(result, "frl.evaluate: error:", "model has no cost critic")
    assert not (run_dir / "results.json").exists()
