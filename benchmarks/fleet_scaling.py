"""How a fleet scales on one machine: wall time, memory and bytes for 3 to 24 vehicles.

    python benchmarks/fleet_scaling.py [--fleets 3,6,12,24] [--total-steps 900]
        [--interval 300] [--out runs/fleet-scaling] [-- HYDRA_OVERRIDES...]

Trains FedAvg-DDPG (default agent and traffic, learning from step 300 instead of 1,000
so that every step of the third round updates the networks) with 1, 2, 4 and 8 vehicles
per task at a small budget, one fleet after the other, each as ``python -m frl.train``
(no test episodes), and samples the memory of the whole process tree (the coordinator,
its worker processes and their SUMO children) every 0.5 s.

Prints per fleet: the worker processes; wall seconds per learning round (from the third
on); the peak memory, in total and per vehicle, as the tree's summed PSS (each shared
page divided among the processes that map it: the memory the run takes), beside the peak
of its summed RSS (shared pages counted once per process: libtorch's code in every
worker), and what each part held at the PSS peak; the bytes up and down per round; the
share of the round loop's wall time outside local training (aggregation, transfers,
logging, checkpoints); the vehicles' CPU seconds, and CPU milliseconds per vehicle step,
which do not depend on what else runs. The replay buffers hold sparse rows (about 1 MB
per 1,000 steps), so a full 10,000-step run adds little to the memory measured here.
Fleets larger than max(cores, 3) share worker processes (``federation.workers``), so the
time per round grows with the fleet while the cores stay busy and not oversubscribed.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

from frl.federation.assembly import worker_processes

REPO = Path(__file__).resolve().parents[1]
MEMORY_TARGET_GB = 3.0
"""Peak memory (summed PSS) allowed for 24 vehicles."""


def process_children() -> dict[int, list[int]]:
    """Each live process's children (Linux /proc)."""
    children: dict[int, list[int]] = {}
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/stat") as f:
                parent = int(f.read().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(parent, []).append(int(entry.name))
    return children


def process_tree(root_pid: int) -> list[int]:
    """``root_pid`` and all its descendants."""
    children, tree, todo = process_children(), [], [root_pid]
    while todo:
        pid = todo.pop()
        tree.append(pid)
        todo.extend(children.get(pid, []))
    return tree


def resident_and_proportional(pid: int) -> tuple[int, int] | None:
    """Resident (RSS) and proportional (PSS) bytes of ``pid``, or None once it is gone.

    RSS counts every page the process maps, shared ones (libtorch's code, the pages a
    forked worker still shares with its parent) in full; PSS divides each shared page among
    the processes that map it, so that a tree's PSS sums to the memory it takes."""
    rss = pss = None
    try:
        with open(f"/proc/{pid}/smaps_rollup") as f:
            for line in f:
                if line.startswith("Rss:"):
                    rss = int(line.split()[1]) * 1024
                elif line.startswith("Pss:"):
                    pss = int(line.split()[1]) * 1024
    except OSError:
        return None
    return None if rss is None or pss is None else (rss, pss)


def process_role(pid: int, root_pid: int) -> str:
    """Which part of a run ``pid`` is: the coordinator (the roadside unit's process), a
    SUMO simulation, or another Python process (the vehicles' workers, their helpers)."""
    if pid == root_pid:
        return "coordinator"
    try:
        with open(f"/proc/{pid}/comm") as f:
            name = f.read().strip()
    except OSError:
        return "gone"
    return "sumo" if name.startswith("sumo") else "workers"


class PeakMemory:
    """Samples a process tree's memory in a thread: the peaks of its summed RSS and of its
    summed PSS (``peak_rss``, ``peak_pss``, bytes), and the PSS of each role at the PSS
    peak (``roles_at_peak``: role -> (processes, bytes))."""

    def __init__(self, pid: int, every_s: float = 0.5) -> None:
        self.pid, self.every_s = pid, every_s
        self.peak_rss = self.peak_pss = 0
        self.roles_at_peak: dict[str, tuple[int, int]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()

    def _sample(self) -> None:
        while not self._stop.is_set():
            rss_total = pss_total = 0
            roles: dict[str, tuple[int, int]] = {}
            for pid in process_tree(self.pid):
                memory = resident_and_proportional(pid)
                if memory is None:
                    continue
                rss_total += memory[0]
                pss_total += memory[1]
                role = process_role(pid, self.pid)
                count, size = roles.get(role, (0, 0))
                roles[role] = (count + 1, size + memory[1])
            self.peak_rss = max(self.peak_rss, rss_total)
            if pss_total > self.peak_pss:
                self.peak_pss, self.roles_at_peak = pss_total, roles
            self._stop.wait(self.every_s)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def run_fleet(vehicles: int, args: argparse.Namespace, overrides: list[str]) -> dict:
    """Train one fleet; its row of the table."""
    if vehicles % 3:
        raise SystemExit(f"fleet sizes must be multiples of 3 (one per task), got {vehicles}")
    run_dir = args.out / f"fleet{vehicles}"
    shutil.rmtree(run_dir, ignore_errors=True)
    command = [
        sys.executable, "-m", "frl.train", f"federation.vehicles_per_task={vehicles // 3}",
        "budget=paper", f"total_steps={args.total_steps}", f"interval={args.interval}",
        "eval_episodes=0",
        f"agent.learning_starts={args.interval}", "progress=false", f"run_dir={run_dir}",
        *overrides,
    ]  # fmt: skip
    began = time.perf_counter()
    with open(args.out / f"fleet{vehicles}.log", "wb") as log:
        process = subprocess.Popen(command, cwd=REPO, stdout=log, stderr=subprocess.STDOUT)
        memory = PeakMemory(process.pid)
        returncode = process.wait()
        memory.stop()
    if returncode != 0:
        raise SystemExit(f"fleet of {vehicles} failed; see {args.out / f'fleet{vehicles}.log'}")
    results = json.loads((run_dir / "results.json").read_text())
    training, communication = results["training"], results["communication"]
    # From the third round on, every step updates (the batch of 256 fills during the second).
    learning_rounds = json.loads((run_dir / "state.json").read_text())["round_times_s"][2:]
    return {
        "vehicles": vehicles,
        "command_s": time.perf_counter() - began,
        "seconds_per_round": sum(learning_rounds) / len(learning_rounds),
        "peak_gb": memory.peak_pss / 1e9,
        "peak_rss_gb": memory.peak_rss / 1e9,
        "per_vehicle_mb": memory.peak_pss / vehicles / 1e6,
        "roles_at_peak": memory.roles_at_peak,
        "mib_per_round": communication["total_bytes"] / results["rounds"] / 2**20,
        # The round loop outside the coordinator's wait for local training: with vehicles
        # taking turns in a worker, the slowest single vehicle is not the round's training.
        "outside_share": training["coordinator_overhead_share"],
        "client_cpu_s": training["client_cpu_s"],
        "cpu_ms_per_step": 1000 * training["client_cpu_s"] / (vehicles * args.total_steps),
    }


def main() -> None:
    argv = sys.argv[1:]
    overrides = argv[argv.index("--") + 1 :] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fleets", default="3,6,12,24")
    parser.add_argument("--total-steps", type=int, default=900)
    parser.add_argument("--interval", type=int, default=300)
    parser.add_argument("--out", type=Path, default=Path("runs/fleet-scaling"))
    args = parser.parse_args(argv)
    fleets = [int(v) for v in args.fleets.split(",")]
    if args.total_steps < 3 * args.interval or args.interval < 256:
        parser.error("need three rounds of at least 256 steps: the first two fill the buffers")
    args.out.mkdir(parents=True, exist_ok=True)

    from frl.federation.workers import available_cores
    from frl.train_config import load_run_config, validate

    print(f"FedAvg-DDPG, default agent and traffic, {args.total_steps} steps per vehicle, "
          f"interval {args.interval}, learning from step {args.interval}, "
          f"{available_cores()} cores; overrides: "
          f"{' '.join(overrides) or '(none)'}")  # fmt: skip
    header = (f"{'vehicles':>8} {'workers':>7} {'s/round':>8} {'peak GB':>8} {'RSS GB':>7} "
              f"{'MB/vehicle':>10} {'MiB/round':>9} {'outside':>8} {'CPU s':>7} "
              f"{'CPU ms/step':>11} {'command s':>9}")  # fmt: skip
    print(header)
    rows = []
    for vehicles in fleets:
        row = run_fleet(vehicles, args, overrides)
        rows.append(row)
        settings = validate(load_run_config(args.out / f"fleet{vehicles}"))
        print(f"{vehicles:>8} {worker_processes(settings):>7} {row['seconds_per_round']:>8.1f} "
              f"{row['peak_gb']:>8.2f} {row['peak_rss_gb']:>7.2f} "
              f"{row['per_vehicle_mb']:>10.0f} {row['mib_per_round']:>9.1f} "
              f"{row['outside_share']:>8.1%} {row['client_cpu_s']:>7.0f} "
              f"{row['cpu_ms_per_step']:>11.1f} {row['command_s']:>9.0f}",
              flush=True)  # fmt: skip
        roles = ", ".join(
            f"{role} {size / 1e9:.2f} GB ({count} processes)"
            for role, (count, size) in sorted(row["roles_at_peak"].items())
        )
        print(f"{'':>8} at the peak: {roles}", flush=True)
    largest = max(rows, key=lambda r: r["vehicles"])
    verdict = "within" if largest["peak_gb"] < MEMORY_TARGET_GB else "ABOVE"
    print(
        f"\npeak memory with {largest['vehicles']} vehicles: {largest['peak_gb']:.2f} GB, "
        f"{verdict} the {MEMORY_TARGET_GB:g} GB target"
    )


if __name__ == "__main__":
    main()
