"""benchmarks/driver_study.py: the study's tables and verdicts, paired seed by seed."""

import subprocess
import sys
from pathlib import Path

from frl.envs import TASKS
from frl.fileio import write_json_atomic

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "driver_study.py"


def _row(reward: float, collisions: float, arrivals: float, travel: float = 60.0) -> dict:
    return {
        "average_reward": reward,
        "collision_rate": collisions,
        "arrival_rate": arrivals,
        "average_travel_time": travel,
    }


def _write_run(data: Path, name: str, seed: int, model: dict, rule: dict) -> None:
    """A run's results.json: the same row on every task, for the model and the rule."""
    evaluation = {
        "per_task": {task: model for task in TASKS},
        "average": model,
        "yardsticks": {
            "gap_acceptance": {"per_task": {task: rule for task in TASKS}, "average": rule},
            "full_throttle": {
                "per_task": {task: _row(3.5, 0.2, 0.8) for task in TASKS},
                "average": _row(3.5, 0.2, 0.8),
            },
        },
    }
    results = {"scheme": "fedavg", "seed": seed, "evaluation": evaluation}
    write_json_atomic(data / f"{name}-seed{seed}" / "results.json", results)


def _study(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=120
    )


def test_the_compact_table_pairs_each_group_with_the_rule_and_the_baseline(tmp_path):
    rule = _row(6.5, 0.04, 0.96)
    for seed, (weak, strong) in enumerate([(5.0, 6.6), (5.4, 6.8)]):
        _write_run(tmp_path, "default", seed, _row(weak, 0.14, 0.84), rule)
        _write_run(tmp_path, "guided", seed, _row(strong, 0.03, 0.97), rule)
    done = _study(str(tmp_path), "--groups", "default,guided", "--seeds", "0,1")
    assert done.returncode == 0, done.stderr
    rows = [line for line in done.stdout.splitlines() if line.startswith("| guided | average")]
    # return 6.7 (6.6, 6.8); the rule: +0.20, -1.0 pp; default: +1.50 (1.6, 1.4), -11 pp
    assert rows == [
        "| guided | average | 0, 1 | 6.70 ± 1.27 | 3.0 ± 0.0% | 97.0 ± 0.0% | 60.0 "
        "| +0.20 ± 1.27 | -1.0 ± 0.0 pp | +1.50 ± 1.27 | -11.0 ± 0.0 pp |"
    ]
    verdicts = [line for line in done.stdout.splitlines() if line.startswith("- guided")]
    assert verdicts[0].startswith("- guided (seeds 0, 1) bar: MET")
    assert verdicts[1].startswith("- guided (seeds 0, 1) goal: MET")
    assert "- default (seeds 0, 1) goal: not met" in done.stdout


def test_bad_arguments_get_one_line_errors(tmp_path):
    missing = _study(str(tmp_path / "nowhere"), "--groups", "default")
    assert missing.returncode == 2 and "no such directory" in missing.stderr
    seeds = _study(str(tmp_path), "--groups", "default", "--seeds", "0,x")
    assert seeds.returncode == 2 and "--seeds must be integers" in seeds.stderr
    baseline = _study(str(tmp_path), "--groups", "default", "--baseline", "clone")
    assert baseline.returncode == 2 and "is not among --groups" in baseline.stderr
