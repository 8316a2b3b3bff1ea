"""The inner loop of agent changes: variants on one task, seed by seed beside the yardsticks.

    python benchmarks/agent_study.py --variant base \\
        --variant "vehicles agent.encoder=vehicles" [--variant "NAME OVERRIDE ..."] \\
        [--task left] [--scheme separate] [--seeds 0,1,2] [--jobs 2] [--out runs/study] \\
        [--data-dir docs/results/data/study-left] [--launcher ray] [-- OVERRIDES FOR EVERY RUN]

Each variant is a name and Hydra overrides. Every (variant, seed) trains one vehicle on
``--task`` (Sep-DDPG with that task alone: the left turn is the hardest task, about
3.5 min a run at the paper's budget, ``-- budget=paper``, in float32) on the default
budget unless told, and tests it on the task's 100 test
episodes, where full throttle, the gap-acceptance driver and the oracle drive the very
same traffic. ``--scheme fedavg`` trains the three-vehicle FedAvg-DDPG instead, tested on
every task. Runs go ``--jobs`` at a time, each on its share of the cores (or through a
Hydra launcher, ``--launcher``, as in benchmarks/learning.py), and are
resumable (``resume=auto``: a finished run is read back). With ``--data-dir`` each
finished run's small result files are kept there.

Prints each run's test figures beside the yardsticks, then per variant the means with
95% t intervals over seeds and the differences paired seed by seed against the first
variant, full throttle and the gap-acceptance driver.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

# The helpers beside this script, also under PYTHONSAFEPATH=1 (docs/reproduction.md).
sys.path.insert(0, str(Path(__file__).resolve().parent))
from paired_runs import (
    Run,
    add_launcher_arguments,
    launcher_argument,
    load_groups,
    print_runs,
    print_summary,
    train_all,
)


def parse_variant(text: str) -> tuple[str, list[str]]:
    name, *overrides = text.split()
    if "=" in name:
        raise argparse.ArgumentTypeError(f"a variant starts with its name, got {text!r}")
    return name, overrides


def main() -> None:
    argv = sys.argv[1:]
    common = argv[argv.index("--") + 1 :] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", action="append", type=parse_variant, required=True)
    parser.add_argument("--task", default="left")
    parser.add_argument("--scheme", default="separate", choices=("separate", "fedavg"))
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--jobs", type=int, default=None, help="runs at a time here (2)")
    parser.add_argument("--out", type=Path, default=Path("runs/study"))
    parser.add_argument("--data-dir", type=Path, default=None)
    add_launcher_arguments(parser)
    args = parser.parse_args(argv)
    launcher = launcher_argument(args, parser)
    seeds = [int(s) for s in args.seeds.split(",")]
    names = [name for name, _ in args.variant]
    if len(set(names)) != len(names):
        parser.error("variant names must differ")
    one_task = args.scheme == "separate"
    scheme = [f"federation={args.scheme}"]
    scheme += [f"federation.tasks=[{args.task}]"] if one_task else []
    runs = [
        Run(name, seed, args.out / f"{name}-seed{seed}", (*scheme, *common, *overrides))
        for name, overrides in args.variant
        for seed in seeds
    ]
    try:
        train_all(runs, args.jobs or 2, args.out / "logs", launcher)
    except ValueError as error:
        parser.error(str(error))
    groups = load_groups(runs, args.data_dir)
    task = args.task if one_task else "average"
    print(f"{args.scheme}, task {task}, seeds {args.seeds}; every run: {' '.join(common) or '-'}")
    for name, overrides in args.variant:
        print(f"  {name}: {' '.join(overrides) or '(no overrides)'}")
    print()
    print_runs(groups, task)
    print()
    print_summary(groups, task, baseline=names[0])


if __name__ == "__main__":
    main()
