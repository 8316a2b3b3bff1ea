"""Per-round overhead of the Flower backend against the in-process backend, same small run.

    python benchmarks/flower_overhead.py                       # 3 vehicles, 4 rounds of 100 steps
    python benchmarks/flower_overhead.py --total-steps 800 --interval 200 --runtimes simulation

Runs ``python -m frl.train`` once per backend (``processes``; ``flower`` with the
simulation runtime; ``flower`` with the deployment runtime, a SuperLink and one SuperNode
per vehicle on 127.0.0.1), with the same seed and a small network, no evaluation, and
prints from each ``results.json``:

- seconds per round (wall time of the round loop / rounds);
- the slowest vehicle's local training per round (wall), which no transport can save;
- the share of the round loop spent outside that training (transport, aggregation,
  checkpoints, logging, process start-up of Flower's ClientApps).

The load average is printed too: on a busy machine every figure grows.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BACKENDS = {
    "processes": ["federation.backend=processes"],
    "simulation": ["federation.backend=flower", "federation.flower.runtime=simulation"],
    "deployment": ["federation.backend=flower", "federation.flower.runtime=deployment"],
}


def run(name: str, overrides: list[str], run_dir: Path) -> tuple[dict, float]:
    command = [sys.executable, "-m", "frl.train", *overrides, *BACKENDS[name], f"run_dir={run_dir}"]
    began = time.perf_counter()
    subprocess.run(command, cwd=REPO, check=True, stdout=subprocess.DEVNULL)
    return json.loads((run_dir / "results.json").read_text()), time.perf_counter() - began


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--total-steps", type=int, default=400)
    parser.add_argument("--interval", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--runtimes", default="processes,simulation,deployment")
    args = parser.parse_args()
    overrides = [
        "budget=paper",  # an update every step, the budget set below
        f"total_steps={args.total_steps}",
        f"interval={args.interval}",  # updates, here steps: an update every step
        f"seed={args.seed}",
        "eval_episodes=0",
        "progress=false",
        "agent.hidden_sizes=[32,32]",
        "agent.learning_starts=50",
        "agent.batch_size=32",
        "agent.buffer_size=5000",
    ]
    names = [n.strip() for n in args.runtimes.split(",") if n.strip()]
    print(f"3 vehicles x {args.total_steps} steps, interval {args.interval}, seed {args.seed}")
    print(f"load average before: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    header = (
        f"{'backend':<12}{'rounds':>7}{'s/round':>10}{'training':>10}{'outside':>10}"
        f"{'outside %':>11}{'command s':>11}"
    )
    print(header)
    rows = {}
    with tempfile.TemporaryDirectory(prefix="frl-flower-bench-") as tmp:
        for name in names:
            results, command_s = run(name, overrides, Path(tmp) / name)
            training = results["training"]
            rounds = results["rounds"]
            per_round = training["seconds_per_round"]
            local = training["client_training_s"] / rounds
            rows[name] = per_round
            print(
                f"{name:<12}{rounds:>7}{per_round:>10.2f}{local:>10.2f}{per_round - local:>10.2f}"
                f"{training['outside_training_share']:>11.1%}{command_s:>11.1f}",
                flush=True,
            )
    base = rows.get("processes")
    if base:
        for name, per_round in rows.items():
            if name != "processes":
                print(f"{name}: +{per_round - base:.2f} s per round over processes")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    print(
        "s/round: wall time per round; training: the slowest vehicle's local training per "
        "round; outside: the rest (transport, aggregation, checkpoints, logging)"
    )


if __name__ == "__main__":
    main()
