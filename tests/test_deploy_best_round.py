"""``deploy=best_round``: the run deploys and tests the model(s) of the round whose
per-round test returned most. The choice, its refusals, and runs with it: the same training
as ``deploy=last``, the kept model the chosen round's (an earlier round made to test best:
its checkpoint's networks, and its real test reproduced on the round-test seeds), a kill
and resume that keeps it, and Sep-DDPG's per-vehicle files."""

import json

import numpy as np
import pytest
import torch
from train_helpers import compose_config

from frl.agents.checkpoint import read_checkpoint
from frl.evaluate import MODEL, evaluate_policies, format_table
from frl.federation.plan import round_test_seeds
from frl.federation.round_tests import RoundTester, best_round_index
from frl.train import train
from frl.train_config import ConfigError, validate

FEDAVG = [
    "federation=fedavg",
    "federation.tasks=[left,right]",
    "round_test_episodes=2",
    "eval_episodes=2",
]


def _point(average_reward):
    return {"average": {"average_reward": average_reward}}


def test_the_best_round_is_the_highest_test_return_and_the_later_of_equals():
    assert best_round_index([_point(1.0), _point(3.0), _point(2.0)]) == 1
    assert best_round_index([_point(3.0), _point(-1.0), _point(3.0)]) == 2
    assert best_round_index([_point(-5.0)]) == 0
    assert best_round_index([]) is None


def test_a_bad_deploy_is_refused_before_any_work(tmp_path):
    with pytest.raises(ConfigError, match="unknown deploy 'best'; choose one of last, best_round"):
        validate({"deploy": "best"})
    with pytest.raises(ConfigError, match="deploy=best_round picks the round by its per-round"):
        validate({"deploy": "best_round"})
    assert validate({"deploy": "best_round", "round_test_episodes": 5}).deploy == "best_round"
    assert validate({}).deploy == "last"


def _networks(path):
    return read_checkpoint(path)["networks"]


def _assert_same_networks(a, b):
    for name, network in a.items():
        for key, tensor in network.items():
            torch.testing.assert_close(tensor, b[name][key], rtol=0, atol=0)


def _retest(run_dir, results, model):
    """The deployed model's average return on the round-test seeds, driven again."""
    settings = validate(compose_config(run_dir, FEDAVG))
    episodes = results["round_tests"]["episodes_per_task"]
    tasks = list(results["round_tests"]["points"][0]["per_task"])
    seeds = {t: round_test_seeds(settings.seed, t, episodes, settings.eval_episodes) for t in tasks}
    tested = evaluate_policies(
        settings, tasks, episodes, [MODEL], {t: str(model) for t in tasks}, seeds=seeds
    )
    return np.mean([tested[MODEL][t]["average_reward"] for t in tasks])


def test_best_round_deploys_the_best_tested_round_and_trains_as_last(tmp_path):
    best = train(compose_config(tmp_path / "best", [*FEDAVG, "deploy=best_round"]))
    last = train(compose_config(tmp_path / "last", FEDAVG))

    # Choosing the deployed round changes nothing of the training.
    np.testing.assert_array_equal(
        np.load(tmp_path / "best" / "step_rewards.npy"),
        np.load(tmp_path / "last" / "step_rewards.npy"),
    )
    models = tmp_path / "best" / "models"
    _assert_same_networks(
        _networks(models / "global.pt"), _networks(tmp_path / "last" / "models" / "global.pt")
    )
    assert best["round_tests"]["points"] == last["round_tests"]["points"]

    points = best["round_tests"]["points"]
    chosen = best_round_index(points)
    assert best["round_tests"]["deploy"] == "best_round"
    assert best["round_tests"]["deployed_round"] == chosen + 1
    assert last["round_tests"]["deploy"] == "last" and last["round_tests"]["deployed_round"] == 3
    index = json.loads((models / "index.json").read_text())
    assert index == {"left": "best_round/global.pt", "right": "best_round/global.pt"}
    assert best["evaluation"]["models"] == index
    assert not (tmp_path / "best" / "checkpoints" / "best_round").exists()

    # The kept file drives its round's test again to the digit (here the last round's: tiny
    # runs test better every round; the next test makes an earlier round win).
    kept = models / "best_round" / "global.pt"
    assert _retest(tmp_path / "best", best, kept) == pytest.approx(
        points[chosen]["average"]["average_reward"], abs=1e-9
    )


def test_an_earlier_round_that_tested_best_is_the_one_deployed(tmp_path, monkeypatch):
    # Tiny runs test better every round; a bonus on round 2's score makes it the best.
    real_test, bonuses, real_scores = RoundTester.test, iter([0.0, 100.0, 0.0]), []

    def scored_with_a_bonus(self, models):
        point = real_test(self, models)
        real_scores.append(point["average"]["average_reward"])
        point["average"]["average_reward"] += next(bonuses)
        return point

    monkeypatch.setattr(RoundTester, "test", scored_with_a_bonus)
    run_dir = tmp_path / "run"
    round_two = {}

    def keep_round_two(state):
        if state.completed_rounds == 2:
            round_two.update(_networks(run_dir / state.checkpoint / "client0_left.pt"))

    results = train(
        compose_config(run_dir, [*FEDAVG, "deploy=best_round"]), on_round_end=keep_round_two
    )

    assert results["round_tests"]["deployed_round"] == 2
    kept = run_dir / "models" / "best_round" / "global.pt"
    _assert_same_networks(_networks(kept), round_two)
    last = _networks(run_dir / "models" / "global.pt")
    assert any(
        not torch.equal(t, last[n][k])
        for n, network in round_two.items()
        for k, t in network.items()
    )
    assert _retest(run_dir, results, kept) == pytest.approx(real_scores[1], abs=1e-9)
    assert "model of round 2 of 3" in format_table(results).splitlines()[0]


class _Killed(Exception):
    pass


def test_a_killed_run_resumes_to_the_same_deployed_round(tmp_path):
    overrides = [*FEDAVG, "deploy=best_round", "eval_episodes=0"]
    whole = train(compose_config(tmp_path / "whole", overrides))

    def kill_after_round(state):
        if state.completed_rounds == 2:
            raise _Killed

    with pytest.raises(_Killed):
        train(compose_config(tmp_path / "killed", overrides), on_round_end=kill_after_round)
    kept = list((tmp_path / "killed" / "checkpoints" / "best_round").iterdir())
    assert len(kept) == 1  # only the best-tested round so far
    resumed = train(compose_config(tmp_path / "killed", [*overrides, "resume=true"]))

    assert resumed["round_tests"]["deployed_round"] == whole["round_tests"]["deployed_round"]
    _assert_same_networks(
        _networks(tmp_path / "killed" / "models" / "best_round" / "global.pt"),
        _networks(tmp_path / "whole" / "models" / "best_round" / "global.pt"),
    )


def test_separate_vehicles_each_keep_their_best_round_file(tmp_path):
    overrides = [
        "federation=separate", "federation.tasks=[left,right]", "round_test_episodes=1",
        "eval_episodes=1", "deploy=best_round",
    ]  # fmt: skip
    results = train(compose_config(tmp_path / "run", overrides))

    models = tmp_path / "run" / "models"
    index = json.loads((models / "index.json").read_text())
    assert index == {
        "left": "best_round/client0_left.pt",
        "right": "best_round/client1_right.pt",
    }
    assert all((models / name).is_file() for name in index.values())
    assert (models / "client0_left.pt").is_file()  # the last round's stay beside them
    assert results["evaluation"]["per_task"]["left"]["episodes"] == 1
