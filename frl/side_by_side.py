"""Run the jobs of Hydra multiruns side by side, each on its share of the cores.

Hydra's basic launcher runs a multirun's jobs one after another, each free to use every
core. Started side by side, such jobs ask for more torch threads than there are cores
and each slows several-fold (two Central-DDPG runs on two cores: 366-626 s a round
against 60-72 s alone). Here each job of a multirun becomes its own one-job multirun
(same preset, same run directory, same export), and at most ``jobs`` of them run at
once, each with ``cores=<available cores // jobs>``::

    jobs = expand_jobs(sweeper_params("fig6"), ["seed=0,1,2"])   # [["seed=0", "interval=250"], ...]
    commands = [[python, "-m", "frl.train", "-m", "+experiment=fig6", *with_cores(job, 1)]
                for job in jobs]
    run_side_by_side(commands, jobs=2, log_dir=Path("outputs/repro/runs/logs"))
"""

from __future__ import annotations

import itertools
import logging
import re
import subprocess
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from frl.federation.workers import available_cores, stop_processes

log = logging.getLogger("frl.side_by_side")

POLL_S = 1.0
"""How often finished jobs are looked for."""


def sweeper_params(experiment: str) -> dict[str, str]:
    """The ``hydra.sweeper.params`` an experiment preset sets (``{"seed": "0,1,2", ...}``)."""
    from hydra import compose, initialize_config_module

    from frl.train_config import register_configs

    register_configs()
    with initialize_config_module("frl.conf", version_base="1.3"):
        cfg = compose("config", overrides=[f"+experiment={experiment}"], return_hydra_config=True)
    params = cfg.hydra.sweeper.get("params") or {}
    return {str(key): str(value) for key, value in params.items()}


def expand_jobs(params: dict[str, str], overrides: Sequence[str]) -> list[list[str]]:
    """Every job of a multirun as plain overrides, in Hydra's order (first key slowest).

    ``params`` are the preset's sweeper params, ``overrides`` the command line's; as in
    Hydra, a key given on the command line replaces the preset's sweep of that key.
    """
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parser = OverridesParser.create()
    by_key: dict[str, list[str]] = {}
    for override in parser.parse_overrides([f"{k}={v}" for k, v in params.items()]):
        by_key[override.key_or_group] = _values(override)
    for override in parser.parse_overrides(list(overrides)):
        by_key[override.key_or_group] = _values(override)
    return [list(job) for job in itertools.product(*by_key.values())]


def _values(override: object) -> list[str]:
    """``key=value`` for each value of a (sweep) override."""
    key = override.get_key_element()  # type: ignore[attr-defined]
    if override.is_sweep_override():  # type: ignore[attr-defined]
        return [f"{key}={value}" for value in override.sweep_string_iterator()]  # type: ignore[attr-defined]
    return [override.input_line]  # type: ignore[attr-defined]


def cores_per_job(jobs: int, cores: int | None = None) -> int:
    """Each job's share of the cores; ValueError if there are more jobs than cores."""
    cores = available_cores() if cores is None else cores
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    if jobs > cores:
        raise ValueError(f"{jobs} jobs side by side need at least {jobs} cores; {cores} available")
    return cores // jobs


def with_cores(overrides: Sequence[str], cores: int) -> list[str]:
    """``overrides`` plus ``cores=N``, unless they set ``cores`` themselves."""
    if any(re.match(r"^\+*cores=", o) for o in overrides):
        return list(overrides)
    return [*overrides, f"cores={cores}"]


@dataclass
class JobOutcome:
    label: str
    returncode: int
    wall_s: float
    log_path: Path


def run_side_by_side(
    commands: Sequence[list[str]],
    jobs: int,
    log_dir: Path,
    labels: Sequence[str] | None = None,
    env: dict[str, str] | None = None,
) -> list[JobOutcome]:
    """Run ``commands``, at most ``jobs`` at once, in order; each one's output goes to
    ``log_dir/<label>.log``. A failed command does not stop the others. Interrupted
    (Ctrl-C), every running command is stopped with its children and the interrupt
    raised again."""
    labels = list(labels) if labels is not None else [f"job{i}" for i in range(len(commands))]
    log_dir.mkdir(parents=True, exist_ok=True)
    waiting = list(zip(labels, commands, strict=True))
    running: list[tuple[str, subprocess.Popen[bytes], float, Path]] = []
    outcomes: list[JobOutcome] = []
    try:
        while waiting or running:
            while waiting and len(running) < jobs:
                label, command = waiting.pop(0)
                log_path = log_dir / f"{_file_name(label)}.log"
                with log_path.open("ab") as out:
                    process = subprocess.Popen(
                        command, stdout=out, stderr=subprocess.STDOUT, env=env,
                        start_new_session=True,  # stopped with its workers as one group
                    )  # fmt: skip
                log.info("started %s (log: %s)", label, log_path)
                running.append((label, process, time.perf_counter(), log_path))
            time.sleep(POLL_S)
            for entry in [e for e in running if e[1].poll() is not None]:
                running.remove(entry)
                label, process, began, log_path = entry
                wall = time.perf_counter() - began
                outcome = JobOutcome(label, process.returncode, wall, log_path)
                outcomes.append(outcome)
                code = outcome.returncode
                how = "finished" if code == 0 else f"FAILED (exit {code})"
                log.info("%s %s in %.1f min", label, how, outcome.wall_s / 60)
    except BaseException:
        stop_processes([entry[1] for entry in running])
        raise
    return outcomes


def _file_name(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.=-]+", "_", label).strip("_") or "job"
