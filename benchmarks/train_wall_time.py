"""Wall time of the main command, `python -m frl.train` (FedAvg-DDPG, the default budget).

    python benchmarks/train_wall_time.py                    # run it (about 16 min on 2 cores)
    python benchmarks/train_wall_time.py --budget paper     # the editions' budget (about 13)
    python benchmarks/train_wall_time.py --from-run RUN_DIR # summarise a finished run
    python benchmarks/train_wall_time.py --total-steps 2000 --interval 500 --eval-episodes 10

Prints the command's wall time, its training and evaluation parts, the seconds per
aggregation round, the coordinator's overhead share (wall time outside local training:
aggregation, transfers, logging and checkpoints) and the clients' CPU seconds, which do
not depend on what else the machine is running.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def summarise(run_dir: Path, command_wall_s: float | None = None) -> None:
    results = json.loads((run_dir / "results.json").read_text())
    training = results["training"]
    communication = results["communication"]
    print(f"run: {run_dir}")
    print(f"scheme {results['scheme']}, {len(results['clients'])} clients x "
          f"{results['total_steps']} steps, interval {results['interval']}, "
          f"{results['rounds']} rounds")  # fmt: skip
    if command_wall_s is not None:
        print(f"command wall time        {command_wall_s:8.1f} s  (start, training, test)")
    job = results.get("job_wall_time_s")
    if job is not None:
        print(f"train() wall time        {job:8.1f} s")
    print(f"training (round loop)    {training['wall_time_s']:8.1f} s")
    print(f"seconds per round        {training['seconds_per_round']:8.1f} s")
    print(f"coordinator overhead     {training['coordinator_overhead_s']:8.2f} s "
          f"({training['coordinator_overhead_share']:.2%} of training wall time)")  # fmt: skip
    for part in ("aggregation_s", "communication_s", "checkpoint_s", "logging_s"):
        print(f"  {part:<22} {training[part]:8.2f} s")
    cpu = training.get("client_cpu_s")
    if cpu:
        print(f"client CPU time          {cpu:8.1f} s  (= {cpu / 2:.0f} s on 2 idle cores)")
    evaluation_s = results.get("evaluation_wall_time_s")
    if evaluation_s is not None:
        print(f"evaluation               {evaluation_s:8.1f} s")
    mib = communication["total_bytes"] / 2**20
    print(f"bytes per upload         {communication['bytes_per_upload']:,} "
          f"(total up + down {mib:.1f} MiB)")  # fmt: skip
    if "evaluation" in results:
        from frl.evaluate import format_table

        print(format_table(results))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--from-run", type=Path, help="summarise this finished run instead")
    parser.add_argument("--budget", choices=("data", "paper"), help="default: the config's")
    parser.add_argument("--total-steps", type=int, help="default: the budget's")
    parser.add_argument("--interval", type=int, help="updates per round; default: the budget's")
    parser.add_argument("--eval-episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.from_run is not None:
        summarise(args.from_run)
        return
    run_dir = REPO / "outputs" / "benchmarks" / time.strftime("train_wall_time_%Y%m%d_%H%M%S")
    budget = [f"budget={args.budget}"] if args.budget else []
    budget += [f"total_steps={args.total_steps}"] if args.total_steps is not None else []
    budget += [f"interval={args.interval}"] if args.interval is not None else []
    command = [
        sys.executable, "-m", "frl.train", "federation=fedavg", *budget,
        f"eval_episodes={args.eval_episodes}", f"seed={args.seed}",
        "progress=false", f"hydra.run.dir={run_dir}",
    ]  # fmt: skip
    print(" ".join(command[1:]), flush=True)
    started = time.perf_counter()
    subprocess.run(command, cwd=REPO, check=True)
    summarise(run_dir, time.perf_counter() - started)


if __name__ == "__main__":
    main()
