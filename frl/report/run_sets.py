"""The studies' run sets: one table per study directory, the home of every study's numbers.

A run set is one setting's seeds: the runs ``ROOT/study-*/.../NAME-seed{k}/`` grouped by
their directory and ``NAME``. Each row says what the runs trained (environment steps and
updates per vehicle, precision, commits) and what they tested, averaged over the seeds
with 95% t intervals, beside the gap-acceptance rule on the same test episodes and the
difference paired seed by seed. docs/studies.md reads these rows; it does not re-quote them.

Only ``results.json`` and ``config.yaml`` are read, so runs exported without curves (the
behaviour clones) have rows too.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from frl.fileio import read_json
from frl.report.aggregate import COMMITTED_RULE, RULE
from frl.report.markdown import fmt, table
from frl.report.measures import test_metric, yardstick_metric
from frl.report.runs import RunDataError, read_config
from frl.report.stats import Estimate, mean_ci
from frl.run_directory import RESULTS_FILE
from frl.update_count import updates_due

STUDY_PREFIX = "study-"
TASK_COLUMNS = ("left", "straight", "right")
_SEEDED = re.compile(r"^(?P<name>.+)-seed(?P<seed>\d+)$")


@dataclass(frozen=True)
class StudyRun:
    """What a run set's row needs of one run."""

    seed: int
    results: dict[str, Any]
    config: dict[str, Any]

    @property
    def evaluation(self) -> dict[str, Any]:
        return self.results.get("evaluation") or {}

    def tested(self, name: str, task: str = "average") -> float | None:
        return test_metric(name, task)(self)  # type: ignore[arg-type]

    def rule(self, name: str, yardstick: str = RULE) -> float | None:
        return yardstick_metric(yardstick, name)(self)  # type: ignore[arg-type]


@dataclass(frozen=True)
class RunSet:
    """One setting's runs, by seed: ``label`` is its path under the study directory."""

    study: str
    label: str
    runs: tuple[StudyRun, ...]


def study_run_sets(root: str | os.PathLike[str]) -> dict[str, list[RunSet]]:
    """Every run set under ``root``'s ``study-*`` directories, by study, in path order."""
    root = Path(root)
    found: dict[tuple[str, str], list[StudyRun]] = {}
    for study_dir in sorted(p for p in root.glob(f"{STUDY_PREFIX}*") if p.is_dir()):
        for results_path in sorted(study_dir.rglob(RESULTS_FILE)):
            run_dir = results_path.parent
            match = _SEEDED.match(run_dir.name)
            if match is None:
                continue
            label = str(run_dir.parent.relative_to(study_dir) / match["name"])
            run = StudyRun(int(match["seed"]), *_read(run_dir))
            if run.evaluation.get("average") is not None:
                found.setdefault((study_dir.name, label), []).append(run)
    studies: dict[str, list[RunSet]] = {}
    for (study, label), runs in found.items():
        runs.sort(key=lambda r: r.seed)
        studies.setdefault(study, []).append(RunSet(study, label, tuple(runs)))
    return studies


def _read(run_dir: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    try:
        return read_json(run_dir / RESULTS_FILE), read_config(run_dir)
    except (OSError, ValueError, yaml.YAMLError) as error:
        raise RunDataError(f"{run_dir}: unreadable run files ({error})") from error


def studies_block(studies: dict[str, list[RunSet]]) -> str:
    """The markdown of every study's table, one heading per study directory."""
    if not studies:
        return "_No study runs under this root._"
    parts = []
    episodes: set[int] = set()
    for study, run_sets in studies.items():
        rows = [_row(run_set) for run_set in run_sets]
        parts.append(f"#### {study}\n\n{table(HEADER, rows)}")
        episodes |= {
            run.evaluation.get("episodes_per_task", 0)
            for run_set in run_sets
            for run in run_set.runs
        }
    counts = " or ".join(f"{count:,}" for count in sorted(episodes))
    return "\n\n".join(parts) + "\n\n" + LEGEND.format(episodes=counts)


HEADER = (
    "run set",
    "seeds",
    "steps / updates per vehicle",
    "precision · commit",
    "return",
    "collisions",
    "arrivals",
    "travel (steps)",
    "collisions left / straight / right",
    "the rule: return / collisions / arrivals / travel",
    "minus the rule, paired: return / collisions",
    "the committed rule: return / collisions / arrivals / travel",
    "minus the committed rule, paired: return / collisions",
)
LEGEND = (
    "Test figures are means over the seeds with 95% t intervals (n=1: one seed), each run "
    "tested on {episodes} episodes per task and averaged over the tasks it tested. Updates "
    "per vehicle count those due (one every `agent.train_freq` steps after "
    "`agent.learning_starts`). The rule is the gap-acceptance driver on the same "
    "test episodes, the committed rule the same driver told the distance to the stop "
    "line (– where a run predates it as a yardstick: `python -m frl.evaluate RUN_DIR "
    "--policy NAME` adds it); the paired difference is taken seed by seed. Precision is "
    "the one the runs trained in; commit is the code's (`versions.git_commit` of "
    "`results.json`)."
)


def _row(run_set: RunSet) -> list[str]:
    runs = run_set.runs
    return [
        f"`{run_set.label}`",
        ", ".join(str(run.seed) for run in runs),
        _budget(runs),
        _provenance(runs),
        fmt(_mean(runs, lambda r: r.tested("average_reward"))),
        fmt(_mean(runs, lambda r: r.tested("collision_rate")), digits=1, percent=True),
        fmt(_mean(runs, lambda r: r.tested("arrival_rate")), digits=1, percent=True),
        fmt(_mean(runs, lambda r: r.tested("average_travel_time")), digits=1),
        " / ".join(_task_collisions(runs, task) for task in TASK_COLUMNS),
        _rule_row(runs, RULE),
        _minus_rule_row(runs, RULE),
        _rule_row(runs, COMMITTED_RULE),
        _minus_rule_row(runs, COMMITTED_RULE),
    ]


def _budget(runs: Iterable[StudyRun]) -> str:
    return ", ".join(sorted({_steps_and_updates(run) for run in runs}))


def _steps_and_updates(run: StudyRun) -> str:
    """Environment steps and due updates per vehicle (:func:`frl.update_count.updates_due`);
    a behaviour clone's grids and fitting steps per task."""
    clone = run.results.get("clone")
    if clone is not None:
        return f"{clone['steps_per_task']:,} / {clone['updates']:,} (cloned)"
    config = run.config
    agent = config.get("agent") or {}
    steps = int(config.get("total_steps", 0))
    updates = updates_due(
        steps, int(agent.get("train_freq", 1)), int(agent.get("learning_starts", 1))
    )
    return f"{steps:,} / {updates:,}"


def _provenance(runs: Iterable[StudyRun]) -> str:
    precisions: set[str] = set()
    commits: list[str] = []
    for run in runs:
        used = (run.results.get("agent_precision") or {}).get("used")
        precisions.add(used or str((run.config.get("agent") or {}).get("precision", "float32")))
        commit = ((run.results.get("versions") or {}).get("git_commit") or "")[:7]
        if commit and commit not in commits:
            commits.append(commit)
    return f"{', '.join(sorted(precisions))} · {', '.join(commits) or '–'}"


def _task_collisions(runs: Iterable[StudyRun], task: str) -> str:
    estimate = _mean(runs, lambda r: r.tested("collision_rate", task))
    return "–" if estimate is None else f"{100 * estimate.mean:.1f}%"


def _rule_row(runs: Iterable[StudyRun], yardstick: str) -> str:
    """A rule's means on the runs' seeds, compact; – where no run tested it."""
    columns = []
    for name, scale, form in RULE_COLUMNS:
        estimate = _mean(runs, lambda r, n=name: r.rule(n, yardstick))
        if estimate is None:
            return "–"
        columns.append(form.format(scale * estimate.mean))
    return " / ".join(columns)


RULE_COLUMNS = (
    ("average_reward", 1, "{:.2f}"),
    ("collision_rate", 100, "{:.1f}%"),
    ("arrival_rate", 100, "{:.1f}%"),
    ("average_travel_time", 1, "{:.1f}"),
)


def _minus_rule_row(runs: Iterable[StudyRun], yardstick: str) -> str:
    returns = _mean(runs, lambda r: _minus_rule(r, "average_reward", yardstick))
    if returns is None:
        return "–"
    collisions = _mean(runs, lambda r: _minus_rule(r, "collision_rate", yardstick))
    return f"{fmt(returns)} / {fmt(collisions, digits=1, percent=True, unit=' pp')}"


def _minus_rule(run: StudyRun, name: str, yardstick: str) -> float | None:
    own, rule = run.tested(name), run.rule(name, yardstick)
    return None if own is None or rule is None else own - rule


def _mean(runs: Iterable[StudyRun], read: Any) -> Estimate | None:
    values = [v for v in (read(run) for run in runs) if v is not None]
    return mean_ci(values) if values else None
