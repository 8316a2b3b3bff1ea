"""Yardsticks from one command, cached, beside the model; the traffic setting in configs."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf
from train_helpers import compose_config

from frl import evaluate
from frl.envs import EnvConfig, IntersectionEnv, traffic_preset
from frl.episodes import run_episodes, summarize
from frl.federation.assembly import evaluation_env
from frl.federation.plan import evaluation_seeds, round_test_seeds
from frl.policies import full_throttle
from frl.train_config import ConfigError, load_run_config, migrate_saved_config, validate
from frl.yardsticks import cache_dir

REPO = Path(__file__).resolve().parents[1]
OLD_RUN = REPO / "docs" / "results" / "data" / "edition1" / "fig4" / "fedavg-seed0"
CURVE_RUN = REPO / "docs" / "results" / "data" / "fig4" / "fedavg-seed0"
"""A run made with the per-round test curve (20 episodes per task)."""


def test_unknown_policy_fails_with_the_valid_names(capsys):
    with pytest.raises(SystemExit) as exit_info:
        evaluate.main(["--policy", "brave"])
    assert exit_info.value.code == 2
    error = capsys.readouterr().err
    assert "unknown policy 'brave'" in error
    for name in ("full_throttle", "always_brake", "gap_acceptance", "oracle", "all"):
        assert name in error


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--policy", "oracle", "--task", "uturn"], "unknown task 'uturn'"),
        (["--policy", "oracle", "--traffic", "rush"], "unknown traffic 'rush'"),
        ([], "give a RUN_DIR"),
        (["some/run", "--traffic", "dense"], "go with --policy"),
        (["--policy", "oracle", "--episodes", "0"], "--episodes must be positive"),
        (["--round-tests"], "--round-tests needs a RUN_DIR"),
        (["some/run", "--round-tests", "--episodes", "3"], "takes its episodes, traffic and seeds"),
        (["some/run", "--round-tests", "--task", "left"], "tests every task of the run's curve"),
    ],
)
def test_bad_arguments_fail_before_any_episode(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        evaluate.main(argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_a_yardstick_table_from_one_command_matches_the_episodes_and_is_cached(capsys, monkeypatch):
    argv = ["--policy", "full_throttle", "--task", "left", "--traffic", "dense", "--seed", "1"]
    argv += ["--episodes", "3", "--no-progress"]
    assert evaluate.main(argv) == 0
    out = capsys.readouterr().out
    assert "traffic dense, seed 1: 3 test episodes per task" in out
    assert "full throttle" in out and "left" in out

    # The same seeds driven directly give the same table.
    env = IntersectionEnv(EnvConfig(task="left", scenario=traffic_preset("dense")))
    try:
        direct = summarize(
            run_episodes(env, full_throttle(), "left", evaluation_seeds(1, "left", 3))
        )
    finally:
        env.close()
    settings = evaluate.default_settings("dense", 1)
    tables = evaluate.evaluate_policies(settings, ["left"], 3, ["full_throttle"])
    assert tables["full_throttle"]["left"] == direct
    assert any(cache_dir().glob("*.json"))

    # Cached now: no worker starts for it again.
    def no_workers(*args, **kwargs):
        raise AssertionError("a cached yardstick started workers")

    monkeypatch.setattr(evaluate, "WorkerPool", no_workers)
    assert evaluate.main(argv) == 0
    assert "full throttle" in capsys.readouterr().out


def test_yardsticks_join_an_old_runs_results_on_its_seeds(tmp_path, capsys):
    run_dir = tmp_path / "old-run"
    shutil.copytree(OLD_RUN, run_dir)
    results = json.loads((run_dir / "results.json").read_text())
    results["evaluation"]["episodes_per_task"] = 2  # keep the test short
    (run_dir / "results.json").write_text(json.dumps(results))

    assert evaluate.main([str(run_dir), "--policy", "always_brake", "--episodes", "2",
                          "--no-progress"]) == 0  # fmt: skip
    assert "traffic dense, seed 0" in capsys.readouterr().out  # the run's own traffic
    saved = json.loads((run_dir / "results.json").read_text())
    table = saved["evaluation"]["yardsticks"]["always_brake"]
    assert set(table["per_task"]) == {"left", "straight", "right"}
    assert table["average"]["collision_rate"] == 0.0
    assert saved["evaluation"]["per_task"] == results["evaluation"]["per_task"]  # untouched


def test_traffic_is_one_hydra_choice_for_training_and_testing():
    default = validate(compose_config(None))
    assert default.env.scenario == traffic_preset("paper")
    dense = validate(compose_config(None, ["traffic=dense"]))
    assert dense.env.scenario == traffic_preset("dense")
    assert evaluation_env(dense, "left").scenario == dense.env.scenario
    tuned = validate(compose_config(None, ["traffic=dense", "env.scenario.lane_width=3.6"]))
    assert tuned.env.scenario == traffic_preset("dense", lane_width=3.6)
    with pytest.raises(ConfigCompositionException):
        compose_config(None, ["traffic=rush"])
    with pytest.raises(ConfigError, match="unknown yardstick 'brave'"):
        validate(compose_config(None, ["yardsticks=[brave]"]))


def test_runs_saved_before_the_presets_load_as_they_ran(tmp_path):
    settings = validate(load_run_config(OLD_RUN))
    assert settings.env.scenario == traffic_preset("dense")  # no speed deviation then
    assert (settings.agent.n_step, settings.agent.warmup_hold_steps) == (1, 1.0)  # Table II
    saved = OmegaConf.to_container(OmegaConf.load(OLD_RUN / "config.yaml"))
    saved["eval_arrival_period_steps"] = 20.0  # tested on other traffic than it trained on
    with pytest.raises(ConfigError, match="tested on other traffic"):
        migrate_saved_config(saved)
    (tmp_path / "config.yaml").write_text("- not\n- a mapping\n")
    with pytest.raises(ConfigError, match="not an frl run config"):
        load_run_config(tmp_path)


def test_a_run_saved_with_the_retired_probe_loads_only_if_it_was_off():
    data = REPO / "docs" / "results" / "data"
    off = load_run_config(data / "study-data" / "guided" / "tf8" / "fedavg-seed4")
    assert "probe" not in off and validate(off).agent.guided  # saved with probe.rate: 0
    with pytest.raises(ConfigError, match=r"probe\.rate=0\.1 was retired: .*A collision budget"):
        load_run_config(data / "study-safety" / "probe-0.1" / "fedavg-seed0")
    with pytest.raises(ConfigCompositionException):  # no such key to set any more
        compose_config(None, ["probe.rate=0.1"])


def test_yardsticks_join_a_runs_curve_on_the_curves_own_seeds(tmp_path, capsys):
    run_dir = tmp_path / "curve-run"
    shutil.copytree(CURVE_RUN, run_dir)
    results = json.loads((run_dir / "results.json").read_text())
    results["round_tests"]["episodes_per_task"] = 2  # keep the test short
    results["round_tests"].pop("yardsticks", None)
    (run_dir / "results.json").write_text(json.dumps(results))

    argv = [str(run_dir), "--round-tests", "--policy", "full_throttle", "--no-progress"]
    assert evaluate.main(argv) == 0
    assert "per-round test seeds" in capsys.readouterr().out

    saved = json.loads((run_dir / "results.json").read_text())
    table = saved["round_tests"]["yardsticks"]["full_throttle"]
    settings = validate(load_run_config(run_dir))
    env = IntersectionEnv(evaluation_env(settings, "left"), settings.reward)
    try:  # the curve's seeds driven directly: the first two of each task's 20
        for task in ("left", "straight", "right"):
            seeds = round_test_seeds(0, task, 2, settings.eval_episodes)
            assert seeds == round_test_seeds(0, task, 20, 100)[:2]
            direct = summarize(run_episodes(env, full_throttle(), task, seeds))
            assert table["per_task"][task] == json.loads(json.dumps(direct))
    finally:
        env.close()
    assert saved["round_tests"]["points"] == results["round_tests"]["points"]  # untouched
    assert saved["evaluation"] == results["evaluation"]


def test_a_run_without_a_curve_is_refused_and_left_as_it_was(tmp_path, capsys):
    run_dir = tmp_path / "old-run"
    shutil.copytree(OLD_RUN, run_dir)
    before = (run_dir / "results.json").read_bytes()

    assert evaluate.main([str(run_dir), "--round-tests", "--no-progress"]) == 2
    assert "has no per-round test curve" in capsys.readouterr().err
    assert (run_dir / "results.json").read_bytes() == before


def test_the_module_runs_its_test_workers_from_the_command_line(tmp_path):
    # Under `python -m` the module is __main__, whose classes the workers cannot unpickle.
    command = [sys.executable, "-m", "frl.evaluate", "--policy", "full_throttle", "--task",
               "left", "--episodes", "1", "--no-progress"]  # fmt: skip
    env = {**os.environ, "FRL_CACHE_DIR": str(tmp_path)}  # nothing cached: workers start
    done = subprocess.run(command, capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "full throttle" in done.stdout


def test_seeds_that_do_not_match_the_episode_count_are_refused_before_any_episode():
    settings = evaluate.default_settings("paper", 0)
    with pytest.raises(ValueError, match="every task needs 3 seeds"):
        evaluate.evaluate_policies(settings, ["left"], 3, ["full_throttle"], seeds={"left": [1, 3]})
