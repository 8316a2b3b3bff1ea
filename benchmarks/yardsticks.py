"""The four yardstick policies on each traffic preset: the table of docs/scenario.md.

    python benchmarks/yardsticks.py [--episodes 300] [--traffic paper,dense] [--seed 0]

Every policy meets the same test seeds (those of a run with ``--seed``, as
``python -m frl.evaluate`` uses). Prints, per preset, task and policy: the average
return with its 95% normal-approximation interval (mean ± 1.96 standard errors over the
episodes), the collision and arrival rates with 95% Wilson intervals (SciPy, the
``report`` extra), the mean travel time of the arrivals, and the wall time; then the
averages over the three tasks (unweighted, as the paper averages). Results are cached
(frl.yardsticks), so a second call prints at once; the wall time shown is then the
cache's.
"""

from __future__ import annotations

import argparse
import math
import time

from frl.envs import TASKS, TRAFFIC_PRESETS
from frl.episodes import average_over_tasks
from frl.evaluate import default_settings, evaluate_policies
from frl.policies import YARDSTICK_LABELS, YARDSTICKS
from frl.report.stats import wilson_interval

Z_95 = 1.96
"""The normal quantile of the return's 95% interval: hundreds of episodes per task, so
the t quantile (1.97 at 299 degrees of freedom) would change no printed digit."""


def rate(summary: dict, key: str) -> str:
    n = summary["episodes"]
    k = round(summary[key] * n)
    low, high = wilson_interval(k, n)
    return f"{k / n:.1%} [{low:.1%}, {high:.1%}]"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=300, help="test episodes per task")
    parser.add_argument("--traffic", default=",".join(TRAFFIC_PRESETS))
    parser.add_argument("--seed", type=int, default=0, help="the run seed whose test seeds to use")
    parser.add_argument("--policies", default=",".join(YARDSTICKS))
    args = parser.parse_args()
    names = args.policies.split(",")
    print(
        "| traffic | task | policy | avg return (95% CI) | collisions (95% CI) "
        "| arrivals (95% CI) | travel time | wall s |"
    )
    print("|---|---|---|---|---|---|---|---|")
    averages = []
    for traffic in args.traffic.split(","):
        settings = default_settings(traffic, args.seed)
        for name in names:
            began = time.perf_counter()
            tables = evaluate_policies(settings, list(TASKS), args.episodes, [name])[name]
            wall = time.perf_counter() - began
            for task in TASKS:
                m = tables[task]
                sd = m["return_std"]
                interval = f" ± {Z_95 * sd / math.sqrt(m['episodes']):.2f}" if sd else ""
                print(
                    f"| {traffic} | {task} | {YARDSTICK_LABELS[name]} | "
                    f"{m['average_reward']:.2f}{interval} | {rate(m, 'collision_rate')} | "
                    f"{rate(m, 'arrival_rate')} | {travel(m)} | {wall:.0f} |",
                    flush=True,
                )
            averages.append((traffic, name, average_over_tasks(tables)))
    print("\n| traffic | policy | avg return | collisions | arrivals | travel time |")
    print("|---|---|---|---|---|---|")
    for traffic, name, m in averages:
        print(
            f"| {traffic} | {YARDSTICK_LABELS[name]} | {m['average_reward']:.2f} | "
            f"{m['collision_rate']:.1%} | {m['arrival_rate']:.1%} | {travel(m)} |"
        )


def travel(metrics: dict) -> str:
    value = metrics["average_travel_time"]
    return "-" if value is None else f"{value:.1f}"


if __name__ == "__main__":
    main()
