"""The inner loop of agent changes: variants on one task, seed by seed beside the yardsticks.

    python benchmarks/agent_study.py --variant base \\
        --variant "vehicles agent.encoder=vehicles" [--variant "NAME OVERRIDE ..."] \\
        [--task left] [--seeds 0,1,2] [--jobs 2] [--out runs/study] \\
        [--data-dir docs/results/data/study-left] [-- OVERRIDES FOR EVERY RUN]

Each variant is a name and Hydra overrides. Every (variant, seed) trains one vehicle on
``--task`` (Sep-DDPG with that task alone: the left turn is the hardest task, about
3.5 min a run at the paper's budget in float32) and tests it on the task's 100 test
episodes, where full throttle, the gap-acceptance driver and the oracle drive the very
same traffic. Runs go ``--jobs`` at a time, each on its share of the cores, and are
resumable (``resume=auto``: a finished run is read back). With ``--data-dir`` each
finished run's small result files are kept there.

Prints, per variant: each seed's test return, collisions and arrivals; their means with
95% t intervals over seeds; and the differences paired seed by seed against the first
variant, the gap-acceptance driver and full throttle.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from frl.report.measures import PerSeed, paired, per_seed, test_metric, yardstick_metric
from frl.report.runs import export_run, has_complete_results, load_run
from frl.report.stats import Estimate, mean_ci
from frl.side_by_side import cores_per_job, run_side_by_side, with_cores

METRICS = (("average_reward", "return", 1.0, ""), ("collision_rate", "collisions", 100.0, "%"),
           ("arrival_rate", "arrivals", 100.0, "%"))  # fmt: skip


def parse_variant(text: str) -> tuple[str, list[str]]:
    name, *overrides = text.split()
    if "=" in name:
        raise argparse.ArgumentTypeError(f"a variant starts with its name, got {text!r}")
    return name, overrides


def fmt(estimate: Estimate | None, scale: float, unit: str) -> str:
    if estimate is None:
        return "–"
    text = f"{estimate.mean * scale:+.2f}{unit}"
    if estimate.half_width is None:
        return f"{text} (n=1)"
    return f"{text} ± {estimate.half_width * scale:.2f}"


def mean_text(values: PerSeed, scale: float, unit: str) -> str:
    estimate = mean_ci(list(values.values()))
    text = f"{estimate.mean * scale:.2f}{unit}"
    return text if estimate.half_width is None else f"{text} ± {estimate.half_width * scale:.2f}"


def main() -> None:
    argv = sys.argv[1:]
    common = argv[argv.index("--") + 1 :] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", action="append", type=parse_variant, required=True)
    parser.add_argument("--task", default="left")
    parser.add_argument("--scheme", default="separate", help="separate (one vehicle) or fedavg")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("runs/study"))
    parser.add_argument("--data-dir", type=Path, default=None)
    args = parser.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    names = [name for name, _ in args.variant]
    if len(set(names)) != len(names):
        parser.error("variant names must differ")
    try:
        cores = cores_per_job(args.jobs)
    except ValueError as error:
        parser.error(str(error))
    tasks = "" if args.scheme == "fedavg" else f"federation.tasks=[{args.task}]"

    jobs, labels = [], []
    for name, overrides in args.variant:
        for seed in seeds:
            run_dir = args.out / f"{name}-seed{seed}"
            if has_complete_results(run_dir):
                continue
            command = [
                sys.executable, "-m", "frl.train", f"federation={args.scheme}",
                *([tasks] if tasks else []), f"seed={seed}", f"run_dir={run_dir}",
                "resume=auto", "progress=false", *common, *overrides,
            ]  # fmt: skip
            jobs.append(with_cores(command, cores))
            labels.append(f"{name}-seed{seed}")
    if jobs:
        outcomes = run_side_by_side(jobs, args.jobs, args.out / "logs", labels)
        for outcome in outcomes:
            status = "ok" if outcome.returncode == 0 else f"FAILED, see {outcome.log_path}"
            print(f"{outcome.label}: {outcome.wall_s / 60:.1f} min, {status}", file=sys.stderr)

    runs = {}
    for name in names:
        records = []
        for seed in seeds:
            run_dir = args.out / f"{name}-seed{seed}"
            if has_complete_results(run_dir):
                records.append(load_run(run_dir))
                if args.data_dir is not None:
                    export_run(run_dir, args.data_dir / run_dir.name)
        runs[name] = records

    print(f"{args.scheme}, task {args.task if tasks else 'all'}, seeds {args.seeds}; common "
          f"overrides: {' '.join(common) or '(none)'}")  # fmt: skip
    task = args.task if tasks else "average"
    print("\n| variant | seed | return | collisions | arrivals | travel time | wall min |")
    print("|---|---|---|---|---|---|---|")
    for name in names:
        for run in runs[name]:
            m = (run.evaluation or {}).get("per_task", {}).get(task) or run.evaluation["average"]
            travel = "-" if m["average_travel_time"] is None else f"{m['average_travel_time']:.1f}"
            wall = (run.results.get("job_wall_time_s") or 0) / 60
            print(
                f"| {name} | {run.seed} | {m['average_reward']:.2f} | {m['collision_rate']:.1%} "
                f"| {m['arrival_rate']:.1%} | {travel} | {wall:.1f} |"
            )

    base = names[0]
    header = ["variant", "seeds"] + [label for _, label, _, _ in METRICS]
    header += [f"{label} - {other}" for other in (base, "gap acceptance", "full throttle")
               for _, label, _, _ in METRICS[:2]]  # fmt: skip
    print("\n| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for name in names:
        records = runs[name]
        if not records:
            print(f"| {name} | 0 | not run |")
            continue
        cells = [name, str(len(records))]
        for key, _, scale, unit in METRICS:
            cells.append(mean_text(per_seed(records, test_metric(key, task)), scale, unit))
        for other in (base, "gap_acceptance", "full_throttle"):
            for key, _, scale, unit in METRICS[:2]:
                mine = per_seed(records, test_metric(key, task))
                if other == base:
                    theirs = per_seed(runs[base], test_metric(key, task))
                else:
                    theirs = per_seed(records, yardstick_task_metric(other, key, task))
                cells.append("–" if other == name else fmt(paired(mine, theirs), scale, unit))
        print("| " + " | ".join(cells) + " |")
    print("\nIntervals: 95% t over seeds; differences are paired seed by seed (same traffic).")


def yardstick_task_metric(yardstick: str, name: str, task: str):  # type: ignore[no-untyped-def]
    if task == "average":
        return yardstick_metric(yardstick, name)

    def read(run):  # type: ignore[no-untyped-def]
        table = ((run.evaluation or {}).get("yardsticks") or {}).get(yardstick) or {}
        return ((table.get("per_task") or {}).get(task) or {}).get(name)

    return read


if __name__ == "__main__":
    main()
