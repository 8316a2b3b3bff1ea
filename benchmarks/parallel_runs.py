"""Do runs side by side add up? The same runs one after another and side by side.

    python benchmarks/parallel_runs.py [--runs 2] [--scheme central] [--steps 2000]
        [--oversubscribed] [--out runs/bench-parallel] [-- HYDRA_OVERRIDES...]

Trains ``--runs`` runs (seeds 0, 1, ...; one round of ``--steps`` steps each, no test)
three ways and prints each way's wall time and throughput against the first:

- one after another, each on every core (``cores=0``, the default);
- side by side, each on its share (``cores=<cores // runs>``, what ``frl.reproduce
  --jobs`` does);
- with ``--oversubscribed``, side by side each on every core, as two plain
  ``python -m frl.train`` calls would run (slow: the reason ``cores`` exists).

Run it on an otherwise idle machine: other load makes every figure meaningless.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path

from frl.federation.workers import available_cores
from frl.side_by_side import cores_per_job


def command(seed: int, cores: int, run_dir: Path, args: argparse.Namespace) -> list[str]:
    return [
        sys.executable, "-m", "frl.train", f"federation={args.scheme}", f"seed={seed}",
        "budget=paper", f"total_steps={args.steps}", f"interval={args.steps}", "eval_episodes=0",
        f"cores={cores}", f"run_dir={run_dir}", "progress=false", *args.overrides,
    ]  # fmt: skip


def timed(commands: list[list[str]], side_by_side: bool) -> float:
    """Wall seconds to run ``commands`` one after another or all at once."""
    began = time.perf_counter()
    if side_by_side:
        processes = [subprocess.Popen(c, stdout=subprocess.DEVNULL) for c in commands]
        codes = [p.wait() for p in processes]
    else:
        codes = [subprocess.run(c, stdout=subprocess.DEVNULL, check=False).returncode
                 for c in commands]  # fmt: skip
    if any(codes):
        raise SystemExit(f"a run failed (exit codes {codes}); run one command by hand to see why")
    return time.perf_counter() - began


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=2, help="runs per way (%(default)s)")
    parser.add_argument("--scheme", default="central", choices=("central", "separate", "fedavg"))
    parser.add_argument("--steps", type=int, default=2000, help="steps per agent (%(default)s)")
    parser.add_argument("--oversubscribed", action="store_true",
                        help="also time the runs side by side on every core each")  # fmt: skip
    parser.add_argument("--out", type=Path, default=Path("runs/bench-parallel"))
    parser.add_argument("overrides", nargs="*", help="Hydra overrides after --")
    args = parser.parse_args()
    try:
        share = cores_per_job(args.runs)
    except ValueError as error:
        parser.error(str(error))
    if args.out.exists():
        shutil.rmtree(args.out)  # fresh runs: resume would skip them

    ways = [("one after another", 0, False), (f"side by side, cores={share}", share, True)]
    if args.oversubscribed:
        ways.append(("side by side, cores=0 (every core each)", 0, True))
    print(f"{args.runs} {args.scheme} runs of {args.steps} steps, {available_cores()} cores")
    print("| way | wall time | per run | throughput |")
    print("|---|---|---|---|")
    first = None
    for index, (name, cores, together) in enumerate(ways):
        commands = [command(seed, cores, args.out / f"way{index}-seed{seed}", args)
                    for seed in range(args.runs)]  # fmt: skip
        wall = timed(commands, together)
        first = first or wall
        print(f"| {name} | {wall:.1f} s | {wall / args.runs:.1f} s | {first / wall:.2f}x |",
              flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
