"""Statistics of the report: confidence intervals over seeds, smoothing, threshold steps.

Pure functions on numpy arrays, tested against hand-computed numbers; the t quantile and
the Wilson interval come from SciPy (the ``report`` extra).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

CONFIDENCE = 0.95


@dataclass(frozen=True)
class Estimate:
    """Mean over seeds with a two-sided t confidence interval (``half_width`` None if n < 2)."""

    mean: float
    half_width: float | None
    n: int

    @property
    def low(self) -> float | None:
        return None if self.half_width is None else self.mean - self.half_width

    @property
    def high(self) -> float | None:
        return None if self.half_width is None else self.mean + self.half_width


def t_quantile(probability: float, df: int) -> float:
    """Quantile of Student's t distribution with ``df`` degrees of freedom (SciPy)."""
    if df < 1:
        raise ValueError(f"degrees of freedom must be >= 1, got {df}")
    if not 0.5 <= probability < 1:
        raise ValueError(f"probability must be in [0.5, 1), got {probability}")
    return float(_scipy_stats().t.ppf(probability, df))


def wilson_interval(
    successes: int, trials: int, confidence: float = CONFIDENCE
) -> tuple[float, float]:
    """The Wilson score interval of a proportion (SciPy's ``binomtest``); NaNs for no trials."""
    if trials == 0:
        return (math.nan, math.nan)
    interval = _scipy_stats().binomtest(successes, trials).proportion_ci(confidence, "wilson")
    return (float(interval.low), float(interval.high))


def _scipy_stats():  # type: ignore[no-untyped-def]
    try:
        from scipy import stats
    except ImportError:  # the report extra brings it
        raise ImportError(
            "frl's statistics need SciPy: pip install -c constraints.txt -e '.[report]'"
        ) from None
    return stats


def mean_ci(values: Sequence[float], confidence: float = CONFIDENCE) -> Estimate:
    """Mean and t-interval half-width ``t_{(1+c)/2, n-1} * s / sqrt(n)`` (s: ddof=1)."""
    data = np.asarray([v for v in values if v is not None], dtype=float)
    if data.size == 0:
        raise ValueError("no values to estimate from")
    if data.size == 1:
        return Estimate(float(data[0]), None, 1)
    half = t_quantile((1 + confidence) / 2, data.size - 1) * data.std(ddof=1) / math.sqrt(data.size)
    return Estimate(float(data.mean()), float(half), int(data.size))


def band(curves: np.ndarray, confidence: float = CONFIDENCE) -> tuple[np.ndarray, np.ndarray]:
    """Per-step mean and t-interval half-width of ``curves`` (seeds x steps); NaN if n < 2."""
    curves = np.asarray(curves, dtype=float)
    mean = curves.mean(axis=0)
    n = curves.shape[0]
    if n < 2:
        return mean, np.full_like(mean, np.nan)
    half = t_quantile((1 + confidence) / 2, n - 1) * curves.std(axis=0, ddof=1) / math.sqrt(n)
    return mean, half


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing mean over the last ``window`` values (fewer at the start)."""
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    values = np.asarray(values, dtype=float)
    sums = np.cumsum(np.concatenate([[0.0], values]))
    ends = np.arange(1, values.size + 1)
    starts = np.maximum(0, ends - window)
    return (sums[ends] - sums[starts]) / (ends - starts)


def episode_return_curve(
    end_steps: np.ndarray, returns: np.ndarray, total_steps: int, window: int
) -> np.ndarray:
    """At each step 1..total_steps, the mean return of the last ``window`` episodes ended
    by then (NaN before the first): Stable-Baselines3's ``rollout/ep_rew_mean``."""
    end_steps = np.asarray(end_steps, dtype=int)
    order = np.argsort(end_steps, kind="stable")
    end_steps, smoothed = end_steps[order], moving_average(np.asarray(returns)[order], window)
    # index of the last episode that ended at or before each step
    last = np.searchsorted(end_steps, np.arange(1, total_steps + 1), side="right") - 1
    curve = np.full(total_steps, np.nan)
    seen = last >= 0
    curve[seen] = smoothed[last[seen]]
    return curve


def first_crossing(curve: np.ndarray, threshold: float, after: int = 0) -> int | None:
    """The first step (1-based) later than step ``after`` at which ``curve`` reaches
    ``threshold``; None if never."""
    hits = np.flatnonzero(np.asarray(curve)[after:] >= threshold)
    return after + int(hits[0]) + 1 if hits.size else None


def first_hold(steps: Sequence[int], values: Sequence[float], threshold: float) -> int | None:
    """The first of ``steps`` from which every later value is at or above ``threshold``
    (the curve *holds* it to the end); None if the last value is below it or NaN."""
    data = np.asarray(values, dtype=float)
    if len(steps) != data.size:
        raise ValueError(f"{len(steps)} steps for {data.size} values")
    below = np.flatnonzero(~(data >= threshold))  # NaN breaks a hold too
    if data.size == 0 or (below.size and below[-1] == data.size - 1):
        return None
    return int(steps[below[-1] + 1]) if below.size else int(steps[0])
