"""scripts/snapshot_rounds.py: a copy taken at a round, resumed, is the shorter run."""

import pytest
from train_helpers import compose_config, load_script

from frl.train import train

snapshot_rounds = load_script("snapshot_rounds")
pytestmark = pytest.mark.slow

same_run = load_script("same_run")

OVERRIDES = ["federation=fedavg", "federation.tasks=[left,right]", "cores=1"]


def test_a_copy_at_a_round_finishes_as_the_run_trained_to_that_budget(tmp_path):
    long_run, copies = tmp_path / "long", []

    def copy_at_160(state):
        copies.append(snapshot_rounds.copy_round(long_run, 160))
        if state.completed_rounds == 2:  # an earlier budget is not the committed round
            assert snapshot_rounds.copy_round(long_run, 80) is None

    train(compose_config(long_run, OVERRIDES), on_round_end=copy_at_160)
    copy = snapshot_rounds.snapshot_path(long_run, 160)
    assert copies == [None, copy, None]
    assert not (copy / "models").exists() and (copy / "checkpoints" / "round_0002").is_dir()

    rounds_run = []
    results = train(
        compose_config(copy, [*OVERRIDES, "resume=true"]),
        on_round_end=lambda state: rounds_run.append(state.completed_rounds),
    )
    assert rounds_run == [] and results["training"]["steps_per_client"] == 160

    short_run = tmp_path / "short"
    train(compose_config(short_run, [*OVERRIDES, "total_steps=160"]))
    assert same_run.differences(copy, short_run) == []
    # the long run went on to its own budget, and is not the short one
    assert same_run.differences(long_run, short_run) != []


def test_bad_budgets_are_refused_before_watching(tmp_path, capsys):
    for steps in ("10k", "0", ""):
        with pytest.raises(SystemExit) as exit_info:
            snapshot_rounds.main([str(tmp_path / "run"), "--steps", steps])
        assert exit_info.value.code == 2
    assert "--steps" in capsys.readouterr().err
