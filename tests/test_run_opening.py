"""open_run: the one place that decides where a run writes and what it runs with."""

import json

import pytest
import yaml
from omegaconf import OmegaConf
from train_helpers import compose_config

from frl import run_directory as rundir
from frl.run_opening import open_run
from frl.train_config import ConfigError


def _saved_run(run_dir, overrides=(), finished=False):
    """A run directory as a killed (or finished) run leaves it, without training."""
    opened = open_run(compose_config(run_dir, list(overrides)), None)
    run_dir.mkdir(parents=True)
    OmegaConf.save(OmegaConf.create(opened.config), run_dir / rundir.CONFIG_FILE)
    rundir.write_state(run_dir, rundir.RunState(completed_rounds=1, training_finished=finished))
    if finished:
        (run_dir / rundir.RESULTS_FILE).write_text(json.dumps({"evaluation": {}}))


def test_a_new_run_is_validated_and_writes_nothing(tmp_path):
    opened = open_run(compose_config(tmp_path / "run", ["seed=5"]), None)
    assert opened.status == "new" and opened.run_dir == tmp_path / "run"
    assert opened.settings.seed == 5
    assert opened.config["run_dir"] == str(tmp_path / "run") and opened.config["resume"] is False
    assert not (tmp_path / "run").exists()


def test_a_resume_runs_the_saved_config_with_this_machines_cores(tmp_path, caplog):
    run_dir = tmp_path / "run"
    _saved_run(run_dir, ["seed=5", "cores=2"])
    cfg = compose_config(None, [f"resume={run_dir}", "seed=9", "cores=1"])
    opened = open_run(cfg, None)
    assert opened.status == "resume"
    assert (opened.settings.seed, opened.config["seed"]) == (5, 5)  # the saved one wins
    assert opened.config["cores"] == 1  # the resuming machine's share


def test_a_finished_run_under_resume_auto_is_skipped(tmp_path):
    run_dir = tmp_path / "run"
    _saved_run(run_dir, finished=True)
    opened = open_run(compose_config(run_dir, ["resume=auto"]), None)
    assert (opened.status, opened.settings, opened.config) == ("finished", None, None)


def test_bad_input_is_one_config_error(tmp_path):
    with pytest.raises(ConfigError, match="run_dir must be set"):
        open_run(compose_config(None), None)
    with pytest.raises(ConfigError, match="no checkpointed run there"):
        open_run(compose_config(None, [f"resume={tmp_path / 'nothing'}"]), None)
    run_dir = tmp_path / "run"
    _saved_run(run_dir)
    (run_dir / rundir.STATE_FILE).rename(tmp_path / "state.json")  # killed before a commit
    with pytest.raises(ConfigError, match=f"start it again with run_dir={run_dir} resume=auto"):
        open_run(compose_config(None, [f"resume={run_dir}"]), None)
    (tmp_path / "state.json").rename(run_dir / rundir.STATE_FILE)
    saved = yaml.safe_load((run_dir / rundir.CONFIG_FILE).read_text())
    saved["agent"]["batch_size"] = -1  # a saved config that no longer validates
    (run_dir / rundir.CONFIG_FILE).write_text(yaml.safe_dump(saved))
    with pytest.raises(ConfigError, match="batch_size"):
        open_run(compose_config(None, [f"resume={run_dir}"]), None)
