"""Reproduce Section IV: run the figure sweeps in order, export each run, build the report.

    python -m frl.reproduce                 # fig4 (= fig5), fig3, fig6, fig4-guided; seeds 0,1,2
    python -m frl.reproduce --figures fig4 --seeds 0,1,2,3,4   # more seeds for Figs. 4, 5
    python -m frl.reproduce --dry-run                  # print the commands only
    python -m frl.reproduce --export-only              # export finished runs, rebuild report
    python -m frl.reproduce --jobs 2                   # two runs at a time, a core each
    python -m frl.reproduce --launcher submitit_slurm -- hydra.launcher.partition=cpu
    python -m frl.reproduce --launcher ray -- hydra.launcher.ray.init.address=auto

Each figure is one Hydra multirun, ``python -m frl.train -m +experiment=figN``, whose
preset (frl/conf/experiment/) fixes the sweep, a deterministic directory per job
(``outputs/repro/runs/fig4/fedavg-seed0``) and ``resume=auto``: running the same command
again skips finished jobs and continues a killed one from its last round. With
``--jobs N`` each job runs as its own one-job multirun, N at a time, each on its share of
the cores (``cores=<cores // N>``, frl.side_by_side), its output in ``RUNS_DIR/logs/``.
The preset's :class:`ExportRun` callback copies each finished run's small result files
to ``DATA_DIR/<figure>/<run>/`` as soon as it ends, and the report is built from those
files. Everything goes under ``outputs/repro/`` unless told otherwise; the published
results are rebuilt with ``--data-dir docs/results/data --report docs/results.md``.
Ctrl-C stops the sweep; the next call picks up where it was. With ``--launcher`` each
figure's multirun hands its jobs to a Hydra launcher (SLURM, Ray; ``frl.launchers``),
every job on ``--cores-per-job`` CPUs, and the same command resumes it.
"""

from __future__ import annotations

import logging
import os
import shlex
import subprocess
import sys
import traceback
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback

from frl.cli import OneLineParser
from frl.fileio import read_json
from frl.launchers import LAUNCHERS, launcher_overrides
from frl.launchers import cores_per_job as launcher_cores
from frl.report.collect import AGENT_PANELS, FIGURE_DIRS
from frl.report.runs import RunDataError, export_run, exported_results, has_complete_results
from frl.run_directory import RESULTS_FILE
from frl.side_by_side import (
    cores_per_job,
    expand_jobs,
    run_side_by_side,
    sweeper_params,
    with_cores,
)

log = logging.getLogger("frl.reproduce")

DEFAULT_FIGURES = ("fig4", "fig3", "fig6", "fig4-guided")
"""Fig. 4 first (the paper's central claims), then the cheap Fig. 3, then Fig. 6 (the
costliest), then the guided agent's panel of Figs. 4 and 5."""
SWEEP_OF = {
    "fig3": "fig3", "fig4": "fig4", "fig5": "fig4", "fig6": "fig6",
    "fig4-guided": "fig4-guided", "fig5-guided": "fig4-guided",
}  # fmt: skip
"""Fig. 5 is tested on Fig. 4's runs (the guided panel's likewise)."""
SWEEP_DIRS = {"fig4-guided": Path("guided", "fig4")}
"""Where a sweep's runs go under the runs and data directories, where not its own name:
the guided panel in the layout ``frl.report`` reads (``AGENT_PANELS``)."""
DEFAULT_RUNS_DIR = Path("outputs/repro/runs")
DEFAULT_DATA_DIR = Path("outputs/repro/data")
DEFAULT_REPORT = Path("outputs/repro/results.md")
"""Everything a reproduction writes goes under ``outputs/`` unless told otherwise: the
published results (``--data-dir docs/results/data --report docs/results.md``) change only
when asked."""


class ExportRun(Callback):
    """Hydra callback: export a job's run once it has finished (``hydra.callbacks``)."""

    def __init__(self, data_dir: str) -> None:
        self.data_dir = Path(data_dir)

    def on_job_end(self, config: Any, job_return: Any, **kwargs: Any) -> None:
        from hydra.core.utils import JobStatus

        run_dir = Path(config.get("run_dir") or config.hydra.runtime.output_dir)
        if job_return.status != JobStatus.COMPLETED:
            # Hydra raises a failed job's error only once the whole sweep has ended.
            error = getattr(job_return, "_return_value", None)
            log.error("%s failed: %s", run_dir, "".join(_format(error)).rstrip())
            return
        try:
            if export_if_stale(run_dir, self.data_dir / run_dir.name):
                log.info("exported %s to %s", run_dir, self.data_dir / run_dir.name)
        except (OSError, RunDataError) as error:  # keep the sweep going; --export-only retries
            log.error("could not export %s: %s", run_dir, error)


def _format(error: object) -> list[str]:
    if isinstance(error, BaseException):
        return traceback.format_exception(error)
    return [repr(error)]


def export_if_stale(run_dir: Path, target: Path) -> bool:
    """Export a finished run unless ``target`` already holds its current results."""
    if not has_complete_results(run_dir):
        return False
    exported = target / RESULTS_FILE
    if exported.exists() and read_json(exported) == exported_results(run_dir):
        return False
    export_run(run_dir, target)
    return True


def export_finished(runs_dir: Path, data_dir: Path) -> list[Path]:
    """Export every finished run under ``runs_dir/<sweep>/`` not exported as it is now;
    return the targets written."""
    written = []
    for sweep in FIGURE_DIRS:
        for root in ("", *AGENT_PANELS):
            sweep_dir = runs_dir / root / sweep
            if sweep_dir.is_dir():
                for run_dir in sorted(d for d in sweep_dir.iterdir() if d.is_dir()):
                    target = data_dir / root / sweep / run_dir.name
                    if export_if_stale(run_dir, target):
                        written.append(target)
    return written


def sweep_command(
    sweep: str, seeds: str, runs_dir: Path, data_dir: Path, overrides: list[str]
) -> list[str]:
    """The Hydra multirun of one figure's preset."""
    return _multirun(sweep, [f"seed={seeds}"], runs_dir, data_dir, overrides)


def _multirun(
    sweep: str, leading: list[str], runs_dir: Path, data_dir: Path, trailing: list[str]
) -> list[str]:
    """``python -m frl.train -m`` of a figure's preset into its sweep and data
    directories; ``leading`` overrides before those, ``trailing`` after."""
    sweep_dir = SWEEP_DIRS.get(sweep, Path(sweep))
    return [
        sys.executable, "-m", "frl.train", "-m", f"+experiment={sweep}", *leading,
        f"hydra.sweep.dir={runs_dir / sweep_dir}",
        f"hydra.callbacks.export_run.data_dir={data_dir / sweep_dir}",
        *trailing,
    ]  # fmt: skip


def job_commands(
    sweep: str, seeds: str, runs_dir: Path, data_dir: Path, overrides: list[str], cores: int
) -> list[tuple[str, list[str]]]:
    """Each job of a figure's multirun as its own one-job multirun on ``cores`` cores,
    with a label naming what varies between the jobs."""
    jobs = expand_jobs(sweeper_params(sweep), [f"seed={seeds}", *overrides])
    varying = [i for i in range(len(jobs[0])) if len({job[i] for job in jobs}) > 1]
    return [
        (
            " ".join([sweep, *(job[i] for i in varying)]),
            _multirun(sweep, with_cores(job, cores), runs_dir, data_dir, []),
        )
        for job in jobs
    ]


def _parse_figures(text: str) -> list[str]:
    names = [name.strip() for name in text.split(",") if name.strip()]
    unknown = [name for name in names if name not in SWEEP_OF]
    if unknown or not names:
        raise ValueError(
            f"unknown figure {', '.join(unknown) or repr(text)}; choose from {', '.join(SWEEP_OF)}"
        )
    sweeps: list[str] = []
    for name in names:
        if SWEEP_OF[name] not in sweeps:
            sweeps.append(SWEEP_OF[name])
    return sweeps


def _parse_seeds(text: str) -> str:
    try:
        seeds = [int(s) for s in text.split(",")]
    except ValueError:
        raise ValueError(f"--seeds must be comma-separated integers, got {text!r}") from None
    if not seeds or any(s < 0 for s in seeds) or len(set(seeds)) != len(seeds):
        raise ValueError(f"--seeds must be distinct non-negative integers, got {text!r}")
    return ",".join(str(s) for s in seeds)


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(
        prog="python -m frl.reproduce",
        description="Run the paper's Section IV sweeps (resumable), export each finished run "
        "and build the report (all under outputs/repro/ unless told otherwise). Arguments "
        "after -- are passed to every sweep as Hydra overrides.",
    )
    parser.add_argument("--figures", default=",".join(DEFAULT_FIGURES),
                        help="comma-separated, in order, from fig3, fig4, fig5 (= fig4), fig6, "
                        "fig4-guided (= fig5-guided: the guided agent's panel) "
                        "(default %(default)s)")  # fmt: skip
    parser.add_argument("--seeds", default="0,1,2", help="default %(default)s")
    parser.add_argument("--runs-dir", type=Path, default=DEFAULT_RUNS_DIR,
                        help="run directories (%(default)s)")  # fmt: skip
    parser.add_argument("--data-dir", type=Path, default=DEFAULT_DATA_DIR,
                        help="exported result files (%(default)s)")  # fmt: skip
    parser.add_argument("--report", type=Path, default=DEFAULT_REPORT,
                        help="markdown report built from --data-dir (%(default)s)")  # fmt: skip
    parser.add_argument("--no-report", action="store_true", help="skip building the report")
    parser.add_argument("--jobs", type=int, default=1,
                        help="runs at a time, each on its share of the cores "
                        "(%(default)s)")  # fmt: skip
    parser.add_argument("--launcher", default=None,
                        help=f"run each figure's jobs through a Hydra launcher: "
                        f"{', '.join(LAUNCHERS)} (pip install '.[cluster]')")  # fmt: skip
    parser.add_argument("--cores-per-job", type=int, default=None,
                        help="CPUs each launcher job asks for and uses (default: one per "
                        f"vehicle plus one, {launcher_cores()})")  # fmt: skip
    parser.add_argument("--dry-run", action="store_true", help="print the commands and stop")
    parser.add_argument("--export-only", action="store_true",
                        help="run nothing: export finished runs, build the report")  # fmt: skip
    parser.add_argument("overrides", nargs="*", help="Hydra overrides after --")
    args = parser.parse_args(argv)
    try:
        sweeps = _parse_figures(args.figures)
        seeds = _parse_seeds(args.seeds)
    except ValueError as error:
        parser.error(str(error))
    try:
        cores = cores_per_job(args.jobs)
    except ValueError as error:
        parser.error(f"--jobs: {error}")
    launcher: list[str] = []
    if args.launcher is not None:
        if args.jobs != 1:
            parser.error("--jobs runs jobs side by side on this machine; with --launcher the "
                         "launcher places them: leave --jobs out")  # fmt: skip
        try:
            launcher = launcher_overrides(args.launcher, args.cores_per_job or launcher_cores())
        except ValueError as error:
            parser.error(str(error))
    elif args.cores_per_job is not None:
        parser.error("--cores-per-job is for --launcher; side by side, --jobs shares the cores")
    if args.runs_dir.exists() and not args.runs_dir.is_dir():
        parser.error(f"--runs-dir {args.runs_dir} is not a directory")
    if not args.no_report and not args.dry_run:
        from frl.report.build import MissingDependency, require_matplotlib

        try:
            require_matplotlib()  # fail now, not after hours of training
        except MissingDependency as error:
            parser.error(f"{error} (or pass --no-report)")

    if args.jobs > 1:
        labelled = [job for s in sweeps
                    for job in job_commands(s, seeds, args.runs_dir, args.data_dir,
                                            args.overrides, cores)]  # fmt: skip
        commands = [command for _, command in labelled]
    else:
        commands = [sweep_command(s, seeds, args.runs_dir, args.data_dir,
                                  [*launcher, *args.overrides])
                    for s in sweeps]  # fmt: skip
    if args.dry_run:
        for command in commands:
            print(shlex.join(command))
        return 0
    logging.basicConfig(level=logging.INFO, format="[frl.reproduce] %(message)s")
    env = {**os.environ, "HYDRA_FULL_ERROR": "1"}
    status = 0
    if not args.export_only and args.jobs > 1:
        try:
            outcomes = run_side_by_side(
                commands, args.jobs, args.runs_dir / "logs", [label for label, _ in labelled], env
            )
        except KeyboardInterrupt:
            log.error("interrupted: every running job was stopped; rerun to continue")
            return 130
        failed = [o for o in outcomes if o.returncode != 0]
        for outcome in failed:
            log.error("%s stopped with exit code %d (log: %s); rerun to continue",
                      outcome.label, outcome.returncode, outcome.log_path)  # fmt: skip
        status = failed[0].returncode if failed else 0
    elif not args.export_only:
        for sweep, command in zip(sweeps, commands, strict=True):
            log.info("%s: %s", sweep, shlex.join(command))
            done = subprocess.run(command, env=env, check=False)
            if done.returncode != 0:
                log.error("%s stopped with exit code %d; rerun to continue", sweep, done.returncode)
                status = done.returncode
                break
    for target in export_finished(args.runs_dir, args.data_dir):
        log.info("exported %s", target)
    if not args.no_report:
        from frl.report.build import build_report

        try:
            written = build_report(args.data_dir, args.report)
            log.info("report: %s", written["report"])
        except RunDataError as error:
            log.warning("no report yet: %s", error)
    return status


if __name__ == "__main__":
    sys.exit(main())
