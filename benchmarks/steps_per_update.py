"""Environment steps per update: FedAvg-DDPG at the paper's 10,000 updates per vehicle,
each update on 1, 2, 4 or 8 steps' worth of new data, beside the yardsticks.

    python benchmarks/steps_per_update.py [--ratios 1,2,4,8] [--seeds 0,1,2] [--jobs 2]
        [--out runs/steps-per-update] [--data-dir DIR] [--baseline DIR] [--read-only]
        [-- OVERRIDES...]

Ratio k trains ``agent.train_freq=k total_steps=10000k interval=2000``: every vehicle
takes 10,000 k environment steps and about 10,000 updates, 2,000 a round, as the
paper's budget has them at k = 1 (docs/training.md, "Steps and updates"). Each run is
resumable and tested on 100 episodes per task beside full throttle, the rule and the
oracle on the same seeds. ``--baseline DIR`` reads ratio 1 from exported runs
(``DIR/fedavg-seedN``: ``docs/results/data/fig4``, the third edition, float32) instead of
training it; pair only runs of one precision. ``--read-only --out DIR`` reads finished or
exported runs (``DIR/tfK/fedavg-seedN``) and trains nothing.

Prints, per task and over the tasks: each run's figures with travel time; per ratio the
means with 95% t intervals over seeds and the differences paired seed by seed against
ratio 1, full throttle and the rule; and whether each ratio clears the bar (mean return
>= 6.0, collisions <= 9%, arrivals >= 90%, no seed below 5.5) and the goal (the rule's
collisions, arrivals within 1 pp, travel time, return within 0.1, no task worse than the
rule's collisions by more than 3 pp).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from paired_runs import (
    Run,
    load_groups,
    model_metric,
    print_runs,
    print_summary,
    train_all,
    yardstick_metric,
)

from frl.report.runs import RunRecord, has_complete_results, load_run

UPDATES = 10_000
ROUND_UPDATES = 2_000
TASKS = ("left", "straight", "right")
BAR = {"average_reward": 6.0, "collision_rate": 0.09, "arrival_rate": 0.90, "worst_seed": 5.5}


def overrides_for(ratio: int) -> tuple[str, ...]:
    return (
        "federation=fedavg",
        f"agent.train_freq={ratio}",
        f"total_steps={UPDATES * ratio}",
        f"interval={ROUND_UPDATES}",  # updates: rounds of 2,000 k steps
    )


def mean(values: list[float]) -> float:
    return sum(values) / len(values)


def verdicts(records: list[RunRecord]) -> str:
    """The bar's and the goal's verdicts over ``records`` (means over seeds)."""

    def model(key: str, task: str = "average") -> list[float]:
        return [model_metric(key, task)(run) for run in records]

    def rule(key: str, task: str = "average") -> list[float]:
        return [yardstick_metric("gap_acceptance", key, task)(run) for run in records]

    returns = model("average_reward")
    bar = (
        mean(returns) >= BAR["average_reward"]
        and mean(model("collision_rate")) <= BAR["collision_rate"]
        and mean(model("arrival_rate")) >= BAR["arrival_rate"]
        and min(returns) >= BAR["worst_seed"]
    )
    travel, rule_travel = model("average_travel_time"), rule("average_travel_time")
    goal_parts = {
        "collisions": mean(model("collision_rate")) <= mean(rule("collision_rate")),
        "arrivals": mean(model("arrival_rate")) >= mean(rule("arrival_rate")) - 0.01,
        "travel time": mean(travel) <= mean(rule_travel),
        "return": mean(returns) >= mean(rule("average_reward")) - 0.1,
        "every task": all(
            mean(model("collision_rate", task)) <= mean(rule("collision_rate", task)) + 0.03
            for task in TASKS
        ),
    }
    missed = [name for name, ok in goal_parts.items() if not ok]
    goal = "met" if not missed else f"not met ({', '.join(missed)})"
    return f"the bar {'met' if bar else 'not met'}; the goal {goal}"


def main() -> None:
    argv = sys.argv[1:]
    extra = argv[argv.index("--") + 1 :] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ratios", default="1,2,4,8", help="environment steps per update")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--jobs", type=int, default=1, help="runs at a time (a core share each)")
    parser.add_argument("--out", type=Path, default=Path("runs/steps-per-update"))
    parser.add_argument("--data-dir", type=Path, default=None, help="export finished runs here")
    parser.add_argument("--read-only", action="store_true",
                        help="train nothing: read the runs that have finished")  # fmt: skip
    parser.add_argument("--baseline", type=Path, default=None,
                        help="ratio 1 read from DIR/fedavg-seedN instead of trained")  # fmt: skip
    args = parser.parse_args(argv)
    try:
        ratios = [int(r) for r in args.ratios.split(",")]
        seeds = [int(s) for s in args.seeds.split(",")]
    except ValueError:
        parser.error("--ratios and --seeds take comma-separated integers")
    if not ratios or min(ratios) < 1 or not seeds or min(seeds) < 0:
        parser.error("ratios must be >= 1 and seeds >= 0")
    if args.baseline is not None and not args.baseline.is_dir():
        parser.error(f"--baseline {args.baseline} is not a directory")

    runs, baseline_runs = [], []
    for ratio in ratios:
        for seed in seeds:
            if ratio == 1 and args.baseline is not None:
                baseline_runs.append(Run("1", seed, args.baseline / f"fedavg-seed{seed}", ()))
                continue
            run_dir = args.out / f"tf{ratio}" / f"fedavg-seed{seed}"
            runs.append(Run(str(ratio), seed, run_dir, (*overrides_for(ratio), *extra)))
    if not args.read_only:
        train_all(runs, args.jobs, args.out / "logs")
    groups = load_groups(runs, None)
    if args.data_dir is not None:
        for run in runs:
            if has_complete_results(run.run_dir):
                from frl.report.runs import export_run

                export_run(run.run_dir, args.data_dir / f"tf{run.group}" / run.run_dir.name)
    if baseline_runs:
        found = [load_run(r.run_dir) for r in baseline_runs if has_complete_results(r.run_dir)]
        groups = {"1": found, **groups}
    groups = {f"{ratio} steps/update": records for ratio, records in groups.items()}
    base = next(iter(groups)) if ratios[0] == 1 else None
    for task in (*TASKS, "average"):
        print(f"\n### {task}\n")
        print_runs(groups, task)
        print()
        print_summary(groups, task, baseline=base)
    print()
    for name, records in groups.items():
        if records:
            print(f"{name}, {len(records)} seeds: {verdicts(records)}")


if __name__ == "__main__":
    main()
