"""Runs of frl.train, several at once, and their test tables beside the yardsticks.

Shared by benchmarks/learning.py (schemes x seeds) and benchmarks/agent_study.py (agent
variants x seeds): each run is a name (a group: a scheme, a variant) and a seed, and
every difference is taken seed by seed, where a model and the yardsticks tested beside
it met the same traffic. The intervals need SciPy: ``pip install -c constraints.txt -e
'.[report]'`` (in ``.[dev]`` too).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from frl.launchers import LAUNCHERS, launcher_overrides
from frl.launchers import cores_per_job as launcher_cores
from frl.report.measures import PerSeed, paired, per_seed
from frl.report.runs import RunRecord, export_run, has_complete_results, load_run
from frl.report.stats import Estimate, mean_ci
from frl.side_by_side import cores_per_job, run_side_by_side, with_cores

YARDSTICKS = ("full_throttle", "gap_acceptance", "oracle")
LABELS = {"full_throttle": "full throttle", "gap_acceptance": "gap acceptance",
          "oracle": "oracle"}  # fmt: skip
METRICS = (
    ("average_reward", "return", 1.0, ""),
    ("collision_rate", "collisions", 100.0, "%"),
    ("arrival_rate", "arrivals", 100.0, "%"),
)
"""(results key, label, scale, unit) of the metrics every table shows."""


@dataclass(frozen=True)
class Run:
    group: str
    seed: int
    run_dir: Path
    overrides: tuple[str, ...]


def train_all(
    runs: Sequence[Run], jobs: int, log_dir: Path, launcher: list[str] | None = None
) -> None:
    """Train (and test) every run not finished yet; resumable (``resume=auto``).

    On this machine ``jobs`` at a time, each on its share of the cores. With ``launcher``
    (:func:`launcher_argument`'s overrides) each group's unfinished seeds are one Hydra
    multirun whose jobs the launcher places (a SLURM job or Ray task per run, in the same
    run directories); the groups' multiruns are submitted together."""
    todo = [run for run in runs if not has_complete_results(run.run_dir)]
    if not todo:
        return
    if launcher:
        _train_through_launcher(todo, log_dir, launcher)
        return
    cores = cores_per_job(jobs)
    commands = []
    for run in todo:
        command = [sys.executable, "-m", "frl.train", f"seed={run.seed}", f"run_dir={run.run_dir}",
                   "resume=auto", "progress=false", *run.overrides]  # fmt: skip
        commands.append(with_cores(command, cores))
    labels = [f"{run.group}-seed{run.seed}" for run in todo]
    _report(run_side_by_side(commands, jobs, log_dir, labels))


def _train_through_launcher(todo: Sequence[Run], log_dir: Path, launcher: list[str]) -> None:
    groups: dict[tuple[str, Path, tuple[str, ...]], list[int]] = {}
    for run in todo:
        if run.run_dir.name != f"{run.group}-seed{run.seed}":
            raise ValueError(f"{run.run_dir}: a launcher's sweep names its runs GROUP-seedN")
        groups.setdefault((run.group, run.run_dir.parent, run.overrides), []).append(run.seed)
    commands, labels = [], []
    for (group, out, overrides), seeds in groups.items():
        commands.append([
            sys.executable, "-m", "frl.train", "-m", *launcher,
            f"seed={','.join(map(str, seeds))}", f"hydra.sweep.dir={out}",
            f"hydra.sweep.subdir={group}-seed${{seed}}", "resume=auto", "progress=false",
            *overrides,
        ])  # fmt: skip
        labels.append(group)
    _report(run_side_by_side(commands, len(commands), log_dir, labels))


def _report(outcomes: Sequence[object]) -> None:
    for outcome in outcomes:
        status = "ok" if outcome.returncode == 0 else f"FAILED, see {outcome.log_path}"
        print(f"{outcome.label}: {outcome.wall_s / 60:.1f} min, {status}", file=sys.stderr)


def add_launcher_arguments(parser: argparse.ArgumentParser) -> None:
    """``--launcher NAME`` and ``--cores-per-job N``, as ``frl.reproduce`` has them."""
    parser.add_argument("--launcher", default=None,
                        help=f"train through a Hydra launcher: {', '.join(LAUNCHERS)} "
                        "(pip install -c constraints.txt -e '.[cluster]')")  # fmt: skip
    parser.add_argument(
        "--cores-per-job",
        type=int,
        default=None,
        help=f"CPUs each launcher job asks for and uses ({launcher_cores()})",
    )


def launcher_argument(args: argparse.Namespace, parser: argparse.ArgumentParser) -> list[str]:
    """The launcher overrides the arguments ask for ([] for this machine), or a usage error."""
    if args.launcher is None:
        if args.cores_per_job is not None:
            parser.error("--cores-per-job is for --launcher; on this machine --jobs shares cores")
        return []
    if args.jobs not in (None, 1):
        parser.error("--jobs shares this machine's cores; with --launcher leave it out")
    try:
        return launcher_overrides(args.launcher, args.cores_per_job or launcher_cores())
    except ValueError as error:
        parser.error(str(error))
    return []


def load_groups(runs: Sequence[Run], data_dir: Path | None = None) -> dict[str, list[RunRecord]]:
    """The finished runs by group (exported to ``data_dir`` when given)."""
    groups: dict[str, list[RunRecord]] = {}
    for run in runs:
        records = groups.setdefault(run.group, [])
        if has_complete_results(run.run_dir):
            records.append(load_run(run.run_dir))
            if data_dir is not None:
                export_run(run.run_dir, data_dir / run.run_dir.name)
    return groups


def model_metric(name: str, task: str):  # type: ignore[no-untyped-def]
    """A run's test metric on ``task`` (``average``: over its tasks)."""

    def read(run: RunRecord) -> float | None:
        evaluation = run.evaluation or {}
        row = evaluation.get("average") if task == "average" else (
            evaluation.get("per_task", {}).get(task))  # fmt: skip
        return None if row is None else row.get(name)

    return read


def yardstick_metric(yardstick: str, name: str, task: str):  # type: ignore[no-untyped-def]
    """The same metric of the yardstick tested beside a run, on the same seeds."""

    def read(run: RunRecord) -> float | None:
        table = ((run.evaluation or {}).get("yardsticks") or {}).get(yardstick) or {}
        row = table.get("average") if task == "average" else (
            (table.get("per_task") or {}).get(task))  # fmt: skip
        return None if row is None else row.get(name)

    return read


def estimate_text(estimate: Estimate | None, scale: float, unit: str, signed: bool) -> str:
    """``4.36 ± 1.11``, ``20.0 ± 4.3%`` or, for a difference of rates, ``+12.3 ± 5.2 pp``."""
    if estimate is None:
        return "–"
    digits = 1 if unit else 2
    sign = "+" if signed else ""
    number = f"{estimate.mean * scale:{sign}.{digits}f}"
    suffix = (" pp" if signed else "%") if unit else ""
    if estimate.half_width is None:
        return f"{number}{suffix} (n=1)"
    return f"{number} ± {estimate.half_width * scale:.{digits}f}{suffix}"


def print_runs(groups: dict[str, list[RunRecord]], task: str) -> None:
    """One row per run: the model's test figures and each yardstick's on its seeds."""
    heads = ["return", "collisions", "arrivals", "travel time"]
    heads += [LABELS[y] for y in YARDSTICKS] + ["wall min"]
    print("| group | seed | " + " | ".join(heads) + " |")
    print("|---|---|" + "---|" * len(heads))
    for group, records in groups.items():
        for run in records:
            values = [model_metric(key, task)(run) for key, *_ in METRICS]
            travel = model_metric("average_travel_time", task)(run)
            cells = [f"{values[0]:.2f}", f"{values[1]:.1%}", f"{values[2]:.1%}"]
            cells.append("-" if travel is None else f"{travel:.1f}")
            for yardstick in YARDSTICKS:
                ret = yardstick_metric(yardstick, "average_reward", task)(run)
                hit = yardstick_metric(yardstick, "collision_rate", task)(run)
                cells.append("–" if ret is None else f"{ret:.2f}, {hit:.1%}")
            cells.append(f"{(run.results.get('job_wall_time_s') or 0) / 60:.1f}")
            print(f"| {group} | {run.seed} | " + " | ".join(cells) + " |")


def print_summary(
    groups: dict[str, list[RunRecord]], task: str, baseline: str | None = None
) -> None:
    """Per group: means with 95% t intervals over seeds, and differences paired seed by
    seed against ``baseline`` (a group), full throttle and the gap-acceptance driver."""
    others = ([baseline] if baseline else []) + ["full_throttle", "gap_acceptance"]
    heads = [label for _, label, _, _ in METRICS]
    heads += [f"{label} - {LABELS.get(other, other)}" for other in others
              for _, label, _, _ in METRICS]  # fmt: skip
    print("| group | seeds | " + " | ".join(heads) + " |")
    print("|---|---|" + "---|" * len(heads))
    for group, records in groups.items():
        if not records:
            print(f"| {group} | 0 | not run |")
            continue
        cells = []
        mine: dict[str, PerSeed] = {}
        for key, _, scale, unit in METRICS:
            mine[key] = per_seed(records, model_metric(key, task))
            cells.append(estimate_text(mean_ci(list(mine[key].values())), scale, unit, False))
        for other in others:
            for key, _, scale, unit in METRICS:
                if other == baseline:
                    if group == baseline:
                        cells.append("–")
                        continue
                    theirs = per_seed(groups.get(baseline, []), model_metric(key, task))
                else:
                    theirs = per_seed(records, yardstick_metric(other, key, task))
                cells.append(estimate_text(paired(mine[key], theirs), scale, unit, True))
        seeds = ", ".join(str(run.seed) for run in records)
        print(f"| {group} | {len(records)} ({seeds}) | " + " | ".join(cells) + " |")
    print("\nIntervals: 95% t over seeds; differences paired seed by seed (same test traffic).")
