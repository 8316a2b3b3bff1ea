"""The per-round test curve (``round_test_episodes``): its seeds, its refusal of a bad
value, and a run with it on: a point per round, the same training as without it, and
a tester that drives exactly the actor it is sent."""

import json

import numpy as np
import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from train_helpers import TINY_AGENT, TINY_ENV, compose_config

import frl.federation.plan as plan_module
from frl.agents import DDPG
from frl.agents.checkpoint import read_checkpoint
from frl.envs import IntersectionEnv, RewardConfig
from frl.episodes import run_episodes, summarize
from frl.federation.assembly import evaluation_env, round_tester
from frl.federation.plan import evaluation_seeds, round_test_seeds
from frl.federation.round_tests import TaskTester, actor_state
from frl.policies import make_yardstick
from frl.train import train
from frl.train_config import ConfigError, validate


def test_round_test_seeds_are_odd_fixed_and_never_the_final_tests():
    seeds = round_test_seeds(3, "left", 20, 100)

    assert len(seeds) == len(set(seeds)) == 20
    assert all(seed % 2 == 1 for seed in seeds)  # training seeds are even
    assert seeds == round_test_seeds(3, "left", 20, 100)
    assert seeds[:5] == round_test_seeds(3, "left", 5, 100)  # a longer curve extends it
    assert not set(seeds) & set(evaluation_seeds(3, "left", 100))
    assert seeds != round_test_seeds(3, "straight", 20, 100)
    assert seeds != round_test_seeds(4, "left", 20, 100)


def test_a_round_test_seed_that_is_a_final_test_seed_is_skipped(monkeypatch):
    natural = round_test_seeds(0, "right", 4, 100)
    monkeypatch.setattr(plan_module, "evaluation_seeds", lambda *_: [natural[1]])

    seeds = round_test_seeds(0, "right", 4, 100)

    assert len(seeds) == 4 and natural[1] not in seeds
    assert seeds[:3] == [natural[0], *natural[2:]]


def test_a_negative_round_test_episodes_is_refused():
    with pytest.raises(ConfigError, match="round_test_episodes must be a non-negative integer"):
        validate({"round_test_episodes": -1})
    assert round_tester(validate({})) is None  # off by default


def _tags(run_dir):
    accumulator = EventAccumulator(str(run_dir / "tb"), size_guidance={"scalars": 0})
    accumulator.Reload()
    return {tag: accumulator.Scalars(tag) for tag in accumulator.Tags()["scalars"]}


def test_round_tests_draw_a_curve_and_leave_training_as_it_was(tmp_path):
    overrides = ["federation=fedavg", "federation.tasks=[left,right]", "eval_episodes=0"]
    tested = train(compose_config(tmp_path / "tested", [*overrides, "round_test_episodes=2"]))
    plain = train(compose_config(tmp_path / "plain", overrides))

    # The tests run apart from the vehicles: the training is the same, step for step.
    np.testing.assert_array_equal(
        np.load(tmp_path / "tested" / "step_rewards.npy"),
        np.load(tmp_path / "plain" / "step_rewards.npy"),
    )
    model = read_checkpoint(tmp_path / "tested" / "models" / "global.pt")
    reference = read_checkpoint(tmp_path / "plain" / "models" / "global.pt")
    for name, network in model["networks"].items():
        for key, tensor in network.items():
            torch.testing.assert_close(tensor, reference["networks"][name][key], rtol=0, atol=0)
    assert plain["round_tests"] is None and plain["training"]["round_test_s"] == 0.0

    curve = tested["round_tests"]
    assert curve["episodes_per_task"] == 2 and curve["exploration"] is False
    assert [point["step"] for point in curve["points"]] == [80, 160, 240]
    for point in curve["points"]:
        assert set(point["per_task"]) == {"left", "right"}
        assert all(metrics["episodes"] == 2 for metrics in point["per_task"].values())
        assert point["average"]["episodes"] == 4
    assert 0 < tested["training"]["round_test_s"] < tested["training"]["wall_time_s"]
    saved = json.loads((tmp_path / "tested" / "results.json").read_text())
    assert saved["round_tests"] == json.loads(json.dumps(curve))

    tags = _tags(tmp_path / "tested")
    for group in ("left", "right", "average"):
        steps = [event.step for event in tags[f"eval/round/{group}/average_reward"]]
        assert steps == [80, 160, 240]
    last = tags["eval/round/average/collision_rate"][-1].value
    assert last == pytest.approx(curve["points"][-1]["average"]["collision_rate"])
    assert not any(tag.startswith("eval/round") for tag in _tags(tmp_path / "plain"))

    # The yardsticks on the curve's own seeds: each round pairs with the rule.
    assert set(curve["yardsticks"]) == {
        "full_throttle",
        "gap_acceptance",
        "committed_gap_acceptance",
        "oracle",
    }
    assert curve["yardsticks_wall_time_s"] > 0
    settings = validate(compose_config(tmp_path / "tested", overrides))
    env = IntersectionEnv(evaluation_env(settings, "right"), settings.reward)
    try:
        seeds = round_test_seeds(0, "right", 2, 0)
        direct = summarize(run_episodes(env, make_yardstick("gap_acceptance", env), "right", seeds))
    finally:
        env.close()
    assert curve["yardsticks"]["gap_acceptance"]["per_task"]["right"] == direct


@pytest.mark.parametrize("bias, yardstick", [(20.0, "full_throttle"), (-20.0, "always_brake")])
def test_a_task_tester_drives_the_actor_it_is_sent(bias, yardstick):
    tester = TaskTester(TINY_ENV, RewardConfig(), TINY_AGENT)
    try:
        agent = DDPG(tester.env.observation_space, tester.env.action_space, TINY_AGENT)
        actor = actor_state(agent.federated_state())
        actor = {key: torch.zeros_like(value) for key, value in actor.items()}
        last_bias = [key for key in actor if key.endswith("bias")][-1]
        actor[last_bias] += bias  # tanh(+-20) is +-1 in float32: a constant pedal
        seeds = round_test_seeds(0, "straight", 3, 100)

        records = tester.run("straight", seeds, [actor, actor])

        expected = run_episodes(
            tester.env, make_yardstick(yardstick, tester.env), "straight", seeds
        )
        assert records == expected + expected  # two actors: their episodes pooled
        with pytest.raises(ValueError, match="not an actor parameter"):
            tester.run("straight", seeds, [{**actor, "critic.layers.0.bias": actor[last_bias]}])
    finally:
        tester.close()
