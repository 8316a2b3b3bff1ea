"""The learned driver's study tables: groups of runs side by side, per task and on average,
paired seed by seed against a baseline group and the yardsticks, with the bar and the goal.

    python benchmarks/driver_study.py docs/results/data/study-driver \\
        --groups default,guided,clone [--baseline default] [--seeds 0,1,2,3,4]

Reads ``DATA/{group}-seed{seed}/results.json`` (a run's exported small files, or the
cloned driver's, ``benchmarks/clone_driver.py``) from every DATA directory given, first
found first. Prints every run, then per group and per task (left, straight, right,
average) the means with 95% t intervals over seeds and the differences paired seed by
seed against the baseline group, full throttle and the gap-acceptance driver; a compact
table of the same (one row per group and task, against the rule and the baseline); then, per
group, the bar of an agent that learns from its own driving (mean return >= 6.0,
collisions <= 9%, arrivals >= 90%, no seed below 5.5) and the goal (return at least the
rule's and collisions at most the rule's, paired means over the seeds; arrivals >= 95%;
no task whose collisions exceed the rule's by more than 3 points).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from paired_runs import (
    METRICS,
    estimate_text,
    model_metric,
    print_runs,
    print_summary,
    yardstick_metric,
)

from frl.envs import TASKS
from frl.fileio import read_json
from frl.report.measures import paired, per_seed
from frl.report.runs import RESULTS_FILE, RunRecord
from frl.report.stats import mean_ci

BAR = {"return": 6.0, "collisions": 0.09, "arrivals": 0.90, "worst seed": 5.5}
GOAL = {"arrivals": 0.95, "task collisions over the rule": 0.03}


def load_groups(
    data_dirs: list[Path], names: list[str], seeds: list[int]
) -> dict[str, list[RunRecord]]:
    """Each group's runs that have a test table, by seed."""
    groups: dict[str, list[RunRecord]] = {}
    for name in names:
        records = groups.setdefault(name, [])
        for seed in seeds:
            for data_dir in data_dirs:
                path = data_dir / f"{name}-seed{seed}"
                if (path / RESULTS_FILE).exists():
                    results = read_json(path / RESULTS_FILE)
                    if results.get("evaluation"):
                        records.append(RunRecord(path, results, {}, np.empty(0)))
                    break
    return groups


def verdicts(records: list[RunRecord]) -> list[str]:
    """The bar's and the goal's marks for one group, each with its figure."""
    if not records:
        return ["not run"]
    mean = {
        key: float(np.mean(list(per_seed(records, model_metric(key, "average")).values())))
        for key in ("average_reward", "collision_rate", "arrival_rate")
    }
    worst = min(per_seed(records, model_metric("average_reward", "average")).values())
    bar = [
        ("return >= 6.0", mean["average_reward"] >= BAR["return"], f"{mean['average_reward']:.2f}"),
        ("collisions <= 9%", mean["collision_rate"] <= BAR["collisions"],
         f"{mean['collision_rate']:.1%}"),
        ("arrivals >= 90%", mean["arrival_rate"] >= BAR["arrivals"], f"{mean['arrival_rate']:.1%}"),
        ("no seed below 5.5", worst >= BAR["worst seed"], f"worst {worst:.2f}"),
    ]  # fmt: skip
    rule = {
        key: paired(
            per_seed(records, model_metric(key, "average")),
            per_seed(records, yardstick_metric("gap_acceptance", key, "average")),
        )
        for key in ("average_reward", "collision_rate")
    }
    task_gaps = {}
    for task in TASKS:
        gap = paired(
            per_seed(records, model_metric("collision_rate", task)),
            per_seed(records, yardstick_metric("gap_acceptance", "collision_rate", task)),
        )
        task_gaps[task] = None if gap is None else gap.mean
    worst_task = max(task_gaps, key=lambda t: -1 if task_gaps[t] is None else task_gaps[t])
    worst_gap = task_gaps[worst_task] or 0.0
    goal = [
        ("return >= the rule's", rule["average_reward"].mean >= 0,
         f"{rule['average_reward'].mean:+.2f}"),
        ("collisions <= the rule's", rule["collision_rate"].mean <= 0,
         f"{100 * rule['collision_rate'].mean:+.1f} pp"),
        ("arrivals >= 95%", mean["arrival_rate"] >= GOAL["arrivals"],
         f"{mean['arrival_rate']:.1%}"),
        ("no task > rule + 3 pp", worst_gap <= GOAL["task collisions over the rule"],
         f"{worst_task} {100 * worst_gap:+.1f} pp"),
    ]  # fmt: skip
    lines = []
    for title, marks in (("bar", bar), ("goal", goal)):
        met = all(ok for _, ok, _ in marks)
        detail = "; ".join(
            f"{name}: {'yes' if ok else 'no'} ({value})" for name, ok, value in marks
        )
        lines.append(f"{title}: {'MET' if met else 'not met'} - {detail}")
    return lines


def print_task_rates(groups: dict[str, list[RunRecord]]) -> None:
    """Collisions per task beside the rule's on the same seeds, and the paired gap."""
    heads = [f"{task} collisions (rule; model - rule)" for task in TASKS]
    print("| group | seeds | " + " | ".join(heads) + " |")
    print("|---|---|" + "---|" * len(heads))
    for group, records in groups.items():
        if not records:
            continue
        cells = []
        for task in TASKS:
            mine = per_seed(records, model_metric("collision_rate", task))
            rule = per_seed(records, yardstick_metric("gap_acceptance", "collision_rate", task))
            gap = paired(mine, rule)
            own, theirs = mean_ci(list(mine.values())), mean_ci(list(rule.values()))
            gap_text = "–" if gap is None else f"{100 * gap.mean:+.1f}"
            if gap is not None and gap.half_width is not None:
                gap_text += f" ± {100 * gap.half_width:.1f}"
            cells.append(f"{100 * own.mean:.1f}% ({100 * theirs.mean:.1f}%; {gap_text} pp)")
        print(f"| {group} | {len(records)} | " + " | ".join(cells) + " |")


def print_compact(groups: dict[str, list[RunRecord]], baseline: str) -> None:
    """One row per group and task: means, travel time, and paired gaps to the rule and
    to the baseline group, in return and collisions."""
    print("| group | task | seeds | return | collisions | arrivals | travel time | "
          "return - rule | collisions - rule | return - " + baseline + " | collisions - "
          + baseline + " |")  # fmt: skip
    print("|---|---|---|" + "---|" * 8)
    for group, records in groups.items():
        if not records:
            continue
        for task in (*TASKS, "average"):
            mine = {key: per_seed(records, model_metric(key, task)) for key, *_ in METRICS}
            cells = [
                estimate_text(mean_ci(list(mine[key].values())), scale, unit, False)
                for key, _, scale, unit in METRICS
            ]
            travel = per_seed(records, model_metric("average_travel_time", task))
            cells.append(f"{np.mean(list(travel.values())):.1f}" if travel else "–")
            gap_metrics = METRICS[:2]  # return and collisions
            for key, _, scale, unit in gap_metrics:
                rule = per_seed(records, yardstick_metric("gap_acceptance", key, task))
                cells.append(estimate_text(paired(mine[key], rule), scale, unit, True))
            for key, _, scale, unit in gap_metrics:
                theirs = per_seed(groups.get(baseline, []), model_metric(key, task))
                gap = None if group == baseline else paired(mine[key], theirs)
                cells.append(estimate_text(gap, scale, unit, True))
            seeds = ", ".join(str(run.seed) for run in records)
            print(f"| {group} | {task} | {seeds} | " + " | ".join(cells) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, nargs="+")
    parser.add_argument("--groups", required=True)
    parser.add_argument("--baseline", default=None)
    parser.add_argument("--seeds", default="0,1,2,3,4")
    args = parser.parse_args()
    names = [name for name in args.groups.split(",") if name]
    try:
        seeds = [int(s) for s in args.seeds.split(",")]
    except ValueError:
        parser.error(f"--seeds must be integers separated by commas, got {args.seeds!r}")
    missing = [str(d) for d in args.data if not d.is_dir()]
    if missing:
        parser.error(f"no such directory: {missing[0]}")
    baseline = args.baseline or names[0]
    if baseline not in names:
        parser.error(f"--baseline {baseline!r} is not among --groups")
    groups = load_groups(args.data, names, seeds)
    print("## Every run (mean over the three tasks)\n")
    print_runs(groups, "average")
    for task in (*TASKS, "average"):
        print(f"\n## {task}\n")
        print_summary(groups, task, baseline=baseline)
    print("\n## Per task, compact (gaps paired seed by seed)\n")
    print_compact(groups, baseline)
    print("\n## Collisions per task beside the rule\n")
    print_task_rates(groups)
    print("\n## The bar and the goal\n")
    for group, records in groups.items():
        seeds_run = ", ".join(str(run.seed) for run in records) or "-"
        for line in verdicts(records):
            print(f"- {group} (seeds {seeds_run}) {line}")


if __name__ == "__main__":
    main()
