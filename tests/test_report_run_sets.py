"""The studies' run sets: rows grouped by directory and name, paired with the rule per seed."""

from __future__ import annotations

import json

import pytest
import yaml

from frl.report.run_sets import studies_block, study_run_sets
from frl.report.runs import RunDataError


def _table(reward: float, collisions: float, tasks: tuple[str, ...]) -> dict:
    row = {"average_reward": reward, "collision_rate": collisions,
           "arrival_rate": 1 - collisions, "average_travel_time": 50.0}  # fmt: skip
    return {"average": row, "per_task": {task: row for task in tasks}}


def _write_run(directory, reward, collisions, rule=None, tasks=("left", "straight", "right"),
               train_freq=1, total_steps=10_000, precision="float32", clone=False,
               committed=None):  # fmt: skip
    directory.mkdir(parents=True)
    evaluation = _table(reward, collisions, tasks)
    if rule is not None:
        evaluation["yardsticks"] = {"gap_acceptance": _table(*rule, tasks)}
    if committed is not None:
        evaluation["yardsticks"]["committed_gap_acceptance"] = _table(*committed, tasks)
    results = {"evaluation": evaluation, "versions": {"git_commit": "abcdef0123"}}
    if clone:
        results["clone"] = {"steps_per_task": 30_000, "updates": 9_000}
    else:
        results["agent_precision"] = {"used": precision}
        config = {"total_steps": total_steps,
                  "agent": {"train_freq": train_freq, "learning_starts": 1000}}  # fmt: skip
        (directory / "config.yaml").write_text(yaml.safe_dump(config))
    (directory / "results.json").write_text(json.dumps(results))


@pytest.fixture
def root(tmp_path):
    study = tmp_path / "study-ratio"
    _write_run(study / "tf8" / "fedavg-seed0", 6.0, 0.10, rule=(6.5, 0.04), train_freq=8,
               total_steps=80_000, committed=(7.0, 0.0))  # fmt: skip
    _write_run(study / "tf8" / "fedavg-seed1", 5.0, 0.20, rule=(6.7, 0.02), train_freq=8,
               total_steps=80_000, committed=(7.1, 0.01))  # fmt: skip
    _write_run(study / "left-seed0", 4.0, 0.30, tasks=("left",), precision="bf16")
    _write_run(tmp_path / "study-clone" / "clone-seed3", 6.6, 0.03, rule=(6.6, 0.03), clone=True)
    _write_run(tmp_path / "fig4" / "fedavg-seed0", 1.0, 0.5)  # an edition's: not a study
    (study / "notes-seed9").mkdir()  # no results.json: not a run
    return tmp_path


def test_runs_group_by_directory_and_name_over_their_seeds(root):
    studies = study_run_sets(root)
    assert list(studies) == ["study-clone", "study-ratio"]
    sets = {run_set.label: [run.seed for run in run_set.runs] for run_set in studies["study-ratio"]}
    assert sets == {"left": [0], "tf8/fedavg": [0, 1]}


def test_a_row_gives_budget_precision_means_and_the_rule_paired_seed_by_seed(root):
    text = studies_block(study_run_sets(root))
    row = next(line for line in text.splitlines() if line.startswith("| `tf8/fedavg`"))
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    # 80,000 steps, one update every 8 after the first 1,000: 10,000 - 124 = 9,876.
    assert cells[1:4] == ["0, 1", "80,000 / 9,876", "float32 · abcdef0"]
    # mean 5.5, t(0.975, 1) * s / sqrt(2) = 12.706 * 0.7071 / 1.4142 = 6.35
    assert cells[4] == "5.50 ± 6.35"
    assert cells[5] == "15.0 ± 63.5%"
    assert cells[8] == "15.0% / 15.0% / 15.0%"
    assert cells[9] == "6.60 / 3.0% / 97.0% / 50.0"
    # paired returns -0.5 and -1.7: mean -1.1, half 12.706 * 0.8485 / 1.4142 = 7.62;
    # collisions +6 and +18 pp: mean 12, half 12.706 * 8.485 / 1.4142 = 76.2
    assert cells[10] == "-1.10 ± 7.62 / 12.0 ± 76.2 pp"
    # The committed rule beside it: paired -1.0 and -2.1, +10 and +19 pp.
    assert cells[11] == "7.05 / 0.5% / 99.5% / 50.0"
    # mean -1.55, half 12.706 * 0.7778 / 1.4142 = 6.99; 14.5 pp, half 12.706 * 6.364 / 1.4142
    assert cells[12] == "-1.55 ± 6.99 / 14.5 ± 57.2 pp"


def test_rows_without_the_rule_or_a_task_say_so_and_a_clone_gives_its_fitting(root):
    lines = studies_block(study_run_sets(root)).splitlines()
    left = next(line for line in lines if line.startswith("| `left`"))
    assert "bf16 · abcdef0" in left and "30.0% / – / –" in left
    assert left.rstrip(" |").endswith("– | – | – | –")
    clone = next(line for line in lines if line.startswith("| `clone`"))
    assert "30,000 / 9,000 (cloned)" in clone and "6.60 (n=1)" in clone


def test_a_root_without_studies_says_so(tmp_path):
    assert study_run_sets(tmp_path) == {}
    assert "No study runs" in studies_block({})


def test_an_unreadable_run_is_named_in_one_error(root):
    broken = root / "study-ratio" / "tf8" / "fedavg-seed2"
    broken.mkdir()
    (broken / "results.json").write_text("{not json")
    with pytest.raises(RunDataError, match="fedavg-seed2: unreadable run files"):
        study_run_sets(root)
