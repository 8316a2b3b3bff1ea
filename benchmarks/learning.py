"""Do the trained agents beat the blind driver? The three schemes beside the yardsticks.

    python benchmarks/learning.py [--schemes central,separate,fedavg] [--seeds 0,1,2]
        [--out runs/learning] [-- HYDRA_OVERRIDES...]

Trains each scheme at each seed with ``python -m frl.train`` (default config: the paper's
budget and traffic; overrides after ``--`` go to every run), one run after another,
each resumable (``resume=auto``: a finished run is read back, a killed one continues).
Then prints, per run, the model's test table averaged over the tasks beside full
throttle and the oracle on the same seeds, whether the model beats full throttle on
return and on collisions, and the wall time; then per scheme the mean over seeds with a
95% t interval.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from frl.report.stats import mean_ci

SCHEMES = ("central", "separate", "fedavg")


def train(scheme: str, seed: int, run_dir: Path, overrides: list[str]) -> dict:
    command = [
        sys.executable, "-m", "frl.train", f"federation={scheme}", f"seed={seed}",
        f"run_dir={run_dir}", "resume=auto", "progress=false", *overrides,
    ]  # fmt: skip
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return json.loads((run_dir / "results.json").read_text())


def row(scheme: str, seed: int, results: dict) -> dict:
    evaluation = results["evaluation"]
    model = evaluation["average"]
    blind = evaluation["yardsticks"]["full_throttle"]["average"]
    oracle = evaluation["yardsticks"].get("oracle", {}).get("average")
    return {
        "scheme": scheme,
        "seed": seed,
        "reward": model["average_reward"],
        "collisions": model["collision_rate"],
        "arrivals": model["arrival_rate"],
        "travel": model["average_travel_time"],
        "blind_reward": blind["average_reward"],
        "blind_collisions": blind["collision_rate"],
        "oracle_reward": oracle["average_reward"] if oracle else float("nan"),
        "beats_reward": model["average_reward"] > blind["average_reward"],
        "beats_collisions": model["collision_rate"] < blind["collision_rate"],
        "wall_s": results.get("job_wall_time_s", float("nan")),
    }


def main() -> None:
    argv = sys.argv[1:]
    overrides = argv[argv.index("--") + 1 :] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--schemes", default=",".join(SCHEMES))
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--out", type=Path, default=Path("runs/learning"))
    args = parser.parse_args(argv)
    schemes = args.schemes.split(",")
    unknown = [s for s in schemes if s not in SCHEMES]
    if unknown:
        parser.error(f"unknown scheme {unknown[0]!r}; choose from {', '.join(SCHEMES)}")
    seeds = [int(s) for s in args.seeds.split(",")]

    began = time.perf_counter()
    rows = []
    for scheme in schemes:
        for seed in seeds:
            results = train(scheme, seed, args.out / f"{scheme}-seed{seed}", overrides)
            rows.append(row(scheme, seed, results))
            print(f"finished {scheme} seed {seed}", file=sys.stderr, flush=True)
    print(f"overrides: {' '.join(overrides) or '(none)'}")
    print(
        "| scheme | seed | test reward | collisions | arrivals | travel time "
        "| full throttle (same seeds) | oracle reward | beats full throttle | wall s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        verdict = {(True, True): "yes", (True, False): "reward only",
                   (False, True): "collisions only", (False, False): "no"}[
            (r["beats_reward"], r["beats_collisions"])
        ]  # fmt: skip
        travel = "-" if r["travel"] is None else f"{r['travel']:.1f}"
        print(
            f"| {r['scheme']} | {r['seed']} | {r['reward']:.2f} | {r['collisions']:.1%} | "
            f"{r['arrivals']:.1%} | {travel} | {r['blind_reward']:.2f}, "
            f"{r['blind_collisions']:.1%} | {r['oracle_reward']:.2f} | {verdict} | "
            f"{r['wall_s']:.0f} |"
        )
    print("\n| scheme | seeds | test reward (95% CI) | collisions (95% CI) | beat full throttle |")
    print("|---|---|---|---|---|")
    for scheme in schemes:
        mine = [r for r in rows if r["scheme"] == scheme]
        reward = mean_ci([r["reward"] for r in mine])
        collisions = mean_ci([r["collisions"] for r in mine])
        wins = sum(r["beats_reward"] and r["beats_collisions"] for r in mine)
        print(
            f"| {scheme} | {len(mine)} | {_fmt(reward)} | {_fmt(collisions, percent=True)} | "
            f"{wins} of {len(mine)} |"
        )
    print(f"\ntotal wall time: {time.perf_counter() - began:.0f} s (finished runs read back)")


def _fmt(estimate, percent: bool = False) -> str:  # type: ignore[no-untyped-def]
    scale, unit = (100.0, "%") if percent else (1.0, "")
    half = estimate.half_width
    text = f"{estimate.mean * scale:.2f}{unit}"
    return text if half is None else f"{text} ± {half * scale:.2f}{unit}"


if __name__ == "__main__":
    main()
