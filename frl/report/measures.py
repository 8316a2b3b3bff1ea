"""What a run measured, read per seed, and differences paired over seeds.

The runs of one seed share its traffic, so a difference is taken seed by seed
(:func:`paired`). Used by the claims table and by the figures that set a run beside
its yardsticks.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from frl.report.runs import RunRecord
from frl.report.stats import Estimate, mean_ci

PerSeed = dict[int, float]
Metric = Callable[[RunRecord], float | None]


def task_metrics(evaluation: dict[str, Any], task: str) -> dict[str, Any] | None:
    if task == "average":
        return evaluation.get("average")
    return evaluation.get("per_task", {}).get(task)


def per_seed(runs: list[RunRecord], metric: Metric) -> PerSeed:
    values = {run.seed: metric(run) for run in runs}
    return {seed: float(v) for seed, v in values.items() if v is not None and math.isfinite(v)}


def paired(a: PerSeed, b: PerSeed) -> Estimate | None:
    """Mean and 95% interval of ``a - b`` over the seeds both hold; None if none."""
    seeds = sorted(set(a) & set(b))
    return mean_ci([a[s] - b[s] for s in seeds]) if seeds else None


def test_metric(name: str, task: str = "average") -> Metric:
    def read(run: RunRecord) -> float | None:
        row = task_metrics(run.evaluation or {}, task)
        return None if row is None else row.get(name)

    return read


def yardstick_metric(yardstick: str, name: str) -> Metric:
    def read(run: RunRecord) -> float | None:
        table = ((run.evaluation or {}).get("yardsticks") or {}).get(yardstick) or {}
        return (table.get("average") or {}).get(name)

    return read
