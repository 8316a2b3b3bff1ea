"""Do the trained agents drive well? The three schemes beside the yardsticks, seed by seed.

    python benchmarks/learning.py [--schemes central,separate,fedavg] [--seeds 0,1,2,3,4]
        [--jobs 1] [--out runs/learning] [--data-dir DIR] [-- HYDRA_OVERRIDES...]
    python benchmarks/learning.py --launcher submitit_slurm -- hydra.launcher.partition=cpu

Trains each scheme at each seed with ``python -m frl.train`` (default config: the default
budget, 80,000 steps and an update every 8, and the paper's traffic; overrides after ``--``
go to every run, ``-- budget=paper`` for the editions' budget), ``--jobs`` at a time, each
resumable (``resume=auto``: a finished run is read back, a killed one continues); with
``--launcher`` through a Hydra launcher instead (a SLURM job or Ray task per run,
``--cores-per-job`` CPUs each; docs/reproduction.md, "On a cluster"). Then
prints each run's test table averaged over the tasks beside full throttle, the
gap-acceptance driver and the oracle on the same seeds; per scheme the means with 95% t
intervals over seeds and the differences paired seed by seed against FedAvg-DDPG, full
throttle and the gap-acceptance driver; and whether FedAvg-DDPG clears the bar of
docs/studies.md (mean return >= 6.0, collisions <= 9%, arrivals >= 90%, no seed below 5.5).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

# The helpers beside this script, also under PYTHONSAFEPATH=1 (docs/reproduction.md).
sys.path.insert(0, str(Path(__file__).resolve().parent))
from paired_runs import (
    Run,
    add_launcher_arguments,
    launcher_argument,
    load_groups,
    model_metric,
    print_runs,
    print_summary,
    train_all,
)

SCHEMES = ("central", "separate", "fedavg")
BAR = {"average_reward": 6.0, "collision_rate": 0.09, "arrival_rate": 0.90, "worst_seed": 5.5}


def main() -> None:
    argv = sys.argv[1:]
    overrides = argv[argv.index("--") + 1 :] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--schemes", default=",".join(SCHEMES))
    parser.add_argument("--seeds", default="0,1,2,3,4")
    parser.add_argument("--jobs", type=int, default=None, help="runs at a time here (1)")
    parser.add_argument("--out", type=Path, default=Path("runs/learning"))
    parser.add_argument("--data-dir", type=Path, default=None)
    add_launcher_arguments(parser)
    args = parser.parse_args(argv)
    launcher = launcher_argument(args, parser)
    schemes = args.schemes.split(",")
    unknown = [s for s in schemes if s not in SCHEMES]
    if unknown:
        parser.error(f"unknown scheme {unknown[0]!r}; choose from {', '.join(SCHEMES)}")
    seeds = [int(s) for s in args.seeds.split(",")]

    began = time.perf_counter()
    runs = [
        Run(scheme, seed, args.out / f"{scheme}-seed{seed}", (f"federation={scheme}", *overrides))
        for scheme in schemes
        for seed in seeds
    ]
    try:
        train_all(runs, args.jobs or 1, args.out / "logs", launcher)
    except ValueError as error:
        parser.error(str(error))
    groups = load_groups(runs, args.data_dir)
    print(f"overrides: {' '.join(overrides) or '(none)'}; test figures averaged over the tasks\n")
    print_runs(groups, "average")
    print()
    print_summary(groups, "average", baseline="fedavg" if "fedavg" in groups else None)
    fedavg = groups.get("fedavg")
    if fedavg:
        returns = [model_metric("average_reward", "average")(run) for run in fedavg]
        collisions = [model_metric("collision_rate", "average")(run) for run in fedavg]
        arrivals = [model_metric("arrival_rate", "average")(run) for run in fedavg]
        mean = {key: sum(v) / len(v) for key, v in
                (("average_reward", returns), ("collision_rate", collisions),
                 ("arrival_rate", arrivals))}  # fmt: skip
        checks = [
            f"mean return {mean['average_reward']:.2f} (>= {BAR['average_reward']})",
            f"collisions {mean['collision_rate']:.1%} (<= {BAR['collision_rate']:.0%})",
            f"arrivals {mean['arrival_rate']:.1%} (>= {BAR['arrival_rate']:.0%})",
            f"worst seed {min(returns):.2f} (>= {BAR['worst_seed']})",
        ]
        met = (
            mean["average_reward"] >= BAR["average_reward"]
            and mean["collision_rate"] <= BAR["collision_rate"]
            and mean["arrival_rate"] >= BAR["arrival_rate"]
            and min(returns) >= BAR["worst_seed"]
        )
        print(f"\nFedAvg-DDPG over {len(fedavg)} seeds: " + "; ".join(checks))
        print(f"the bar: {'met' if met else 'NOT met'}")
    print(f"\ntotal wall time: {time.perf_counter() - began:.0f} s (finished runs read back)")


if __name__ == "__main__":
    main()
