"""frl.report.compare on small synthetic run directories."""

import yaml
from report_helpers import evaluation, make_run

from frl.report.compare import (
    compare_table,
    differing_settings,
    flat_settings,
    main,
    training_rewards,
)
from frl.report.runs import load_run

EPISODES = {"client0_random": [(5, 2.0), (10, 8.0), (15, 4.0), (20, 4.0)]}


def _set_config(run_dir, key, value):
    config = yaml.safe_load((run_dir / "config.yaml").read_text())
    section, name = key.split(".")
    config.setdefault(section, {})[name] = value
    (run_dir / "config.yaml").write_text(yaml.safe_dump(config))


def test_final_and_best_training_reward_by_hand(tmp_path):
    run = make_run(tmp_path / "a", "central", 0, episodes=EPISODES)
    # Window 2: 5 at step 10, 6 at steps 15-19, 4 at step 20.
    assert training_rewards(load_run(run), episode_window=2) == (4.0, 6.0)
    late = make_run(tmp_path / "b", "central", 0, episodes=EPISODES, learning_starts=19)
    assert training_rewards(load_run(late), episode_window=2) == (4.0, 4.0)


def test_only_the_settings_the_runs_differ_in_become_columns(tmp_path):
    base = make_run(tmp_path / "base", "central", 0, evaluation=evaluation(1.0, 0.25, 50.0))
    fast = make_run(tmp_path / "fast", "central", 1)
    older = make_run(tmp_path / "older", "central", 2)
    _set_config(base, "agent.actor_lr", 0.0001)
    _set_config(fast, "agent.actor_lr", 0.001)
    _set_config(base, "federation.initial_model", "independent")  # older runs lack the key
    _set_config(fast, "federation.initial_model", "independent")
    runs = [load_run(path) for path in (base, fast, older)]
    # Not the seed, not the key the older run lacks; eval_episodes: only base was tested.
    per_run = [dict(flat_settings(run.config)) for run in runs]
    assert differing_settings(per_run) == ["agent.actor_lr", "eval_episodes"]
    table = compare_table(runs, episode_window=2).splitlines()
    assert table[0].startswith("| run | seed | agent.actor_lr | eval_episodes | final")
    assert table[2].split(" | ")[:4] == ["| base", "0", "0.0001", "100"]
    assert "| 1.00 | 25.0% | 75.0% | 50.0 |" in table[2]
    assert table[4].split(" | ")[2] == "–"  # the older run has no actor_lr
    assert table[3].endswith("| – | – | – | – |")  # not tested


def test_cli_prints_the_table_or_names_the_bad_directory(tmp_path, capsys):
    run = make_run(tmp_path / "run", "central", 0, episodes=EPISODES)
    assert main([str(run), "--episode-window", "2"]) == 0
    assert "| run | seed |" in capsys.readouterr().out
    assert main([str(run), str(tmp_path / "missing")]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and "missing" in captured.err
