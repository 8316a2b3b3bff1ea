"""The report's PNG figures (matplotlib, non-interactive), one function per paper figure."""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Any

import numpy as np

from frl.fileio import write_bytes_atomic
from frl.report.aggregate import (
    SCHEME_LABELS,
    TASKS,
    TESTED_CURVE_METRICS,
    CurveSettings,
    EvalSummary,
    IntervalPoint,
    RewardPoint,
    SchemeCurves,
    TestedCurve,
)
from frl.report.stats import Estimate

COLORS = {"central": "tab:red", "separate": "tab:blue", "fedavg": "tab:green"}
YARDSTICK_STYLES = {
    "full_throttle": {"color": "black", "linestyle": "--"},
    "oracle": {"color": "tab:purple", "linestyle": "-"},
    "gap_acceptance": {"color": "tab:orange", "linestyle": "-."},
    "committed_gap_acceptance": {"color": "tab:brown", "linestyle": (0, (3, 1, 1, 1))},
    "always_brake": {"color": "gray", "linestyle": ":"},
}


def pyplot() -> Any:
    """matplotlib's pyplot on the Agg backend: files only, never a window."""
    import matplotlib

    matplotlib.use("Agg")  # files only; never opens a window
    import matplotlib.pyplot as plt

    return plt


def _save(figure, path: Path) -> Path:  # type: ignore[no-untyped-def]
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=120, bbox_inches="tight")
    pyplot().close(figure)
    write_bytes_atomic(path, buffer.getvalue())
    return path


def _err(estimate: Estimate | None) -> float:
    return estimate.half_width if estimate and estimate.half_width is not None else 0.0


def _val(estimate: Estimate | None) -> float:
    return estimate.mean if estimate else np.nan


def _yardstick_lines(  # type: ignore[no-untyped-def]
    axis, yardsticks: dict[str, EvalSummary] | None, metric: str, where: str = "tested"
) -> None:
    """Each yardstick's test average over tasks and seeds as a horizontal line."""
    for name, summary in (yardsticks or {}).items():
        value = _val(summary.metrics.get("average", {}).get(metric))
        if np.isfinite(value):
            style = YARDSTICK_STYLES.get(name, {"color": "black", "linestyle": ":"})
            label = f"{name.replace('_', ' ')}, {where} (n={len(summary.seeds)})"
            axis.axhline(value, linewidth=1.2, label=label, **style)


def plot_fig4(
    curves: dict[str, SchemeCurves],
    settings: CurveSettings,
    path: Path,
    yardsticks: dict[str, EvalSummary] | None = None,
) -> Path:
    """Average training reward per scheme, mean and 95% band over seeds; each yardstick's
    average test return (same seeds) as a reference line."""
    plt = pyplot()
    figure, (left, right) = plt.subplots(1, 2, figsize=(12, 4.2))
    for scheme, c in curves.items():
        label = f"{SCHEME_LABELS[scheme]} (n={len(c.seeds)})"
        for axis, mean, half in (
            (left, c.reward_mean, c.reward_half),
            (right, c.step_mean, c.step_half),
        ):
            axis.plot(c.steps, mean, color=COLORS[scheme], label=label, linewidth=1.2)
            if np.isfinite(half).any():
                axis.fill_between(
                    c.steps, mean - half, mean + half, color=COLORS[scheme], alpha=0.2
                )
    left.axhline(settings.threshold, color="gray", linestyle="--", linewidth=0.8)
    _yardstick_lines(left, yardsticks, "average_reward")
    left.set(
        xlabel="training step (per agent)",
        ylabel=f"average reward (last {settings.episode_window} episodes' return)",
        title="Fig. 4: episode return, mean and 95% CI over seeds",
    )
    right.set(
        xlabel="training step (per agent)",
        ylabel=f"train/step_reward, {settings.step_window}-step moving average",
        title="per-step reward",
    )
    for axis in (left, right):
        axis.grid(alpha=0.3)
        axis.legend(loc="lower right")
    return _save(figure, path)


def plot_fig4_tested(
    curves: dict[str, TestedCurve],
    settings: CurveSettings,
    path: Path,
    yardsticks: dict[str, EvalSummary] | None = None,
    on_curve_seeds: bool = False,
) -> Path:
    """The per-round test curve per scheme: tested return, collisions and arrivals, mean
    and 95% band over seeds; each yardstick as a reference line, tested on the curve's
    own seeds where ``on_curve_seeds``, else on the final test's."""
    plt = pyplot()
    titles = ("tested return", "collision rate", "arrival rate")
    figure, axes = plt.subplots(1, 3, figsize=(15, 4))
    for axis, metric, title in zip(axes, TESTED_CURVE_METRICS, titles, strict=True):
        for scheme, c in curves.items():
            mean = np.array([_val(e) for e in c.metrics[metric]])
            half = np.array([_err(e) for e in c.metrics[metric]])
            label = f"{SCHEME_LABELS[scheme]} (n={len(c.seeds)})"
            axis.plot(c.steps, mean, marker="o", color=COLORS[scheme], label=label, linewidth=1.2)
            axis.fill_between(c.steps, mean - half, mean + half, color=COLORS[scheme], alpha=0.2)
        where = "same episodes" if on_curve_seeds else "final test"
        _yardstick_lines(axis, yardsticks, metric, where)
        axis.set(xlabel="training step (per agent)", ylabel=title, title=f"{title}, every round")
        axis.grid(alpha=0.3)
    axes[0].axhline(settings.threshold, color="gray", linestyle="--", linewidth=0.8)
    axes[0].legend(loc="best", fontsize="small")
    return _save(figure, path)


def plot_fig5(
    summaries: dict[str, EvalSummary],
    path: Path,
    yardsticks: dict[str, EvalSummary] | None = None,
) -> Path:
    """Test reward, collision rate and travel time per task and scheme, with 95% CIs;
    each yardstick (same seeds) as a horizontal mark across its task's bars."""
    plt = pyplot()
    panels = (
        ("average_reward", "average reward"),
        ("collision_rate", "collision rate"),
        ("average_episode_steps", "travel time (steps, all episodes)"),
    )
    figure, axes = plt.subplots(1, 3, figsize=(14, 4))
    x = np.arange(len(TASKS))
    width = 0.8 / max(1, len(summaries))
    for axis, (metric, title) in zip(axes, panels, strict=True):
        for i, (scheme, summary) in enumerate(summaries.items()):
            values = [summary.metrics.get(t, {}).get(metric) for t in TASKS]
            axis.bar(
                x + (i - (len(summaries) - 1) / 2) * width,
                [_val(v) for v in values],
                width,
                yerr=[_err(v) for v in values],
                capsize=3,
                color=COLORS[scheme],
                label=f"{SCHEME_LABELS[scheme]} (n={len(summary.seeds)})",
            )
        for name, summary in (yardsticks or {}).items():
            style = YARDSTICK_STYLES.get(name, {"color": "black", "linestyle": ":"})
            for i, task in enumerate(TASKS):
                value = _val(summary.metrics.get(task, {}).get(metric))
                axis.hlines(
                    value,
                    x[i] - 0.45,
                    x[i] + 0.45,
                    linewidth=1.6,
                    label=f"{name.replace('_', ' ')} (same seeds)" if i == 0 else None,
                    **style,
                )
        axis.set_xticks(x, TASKS)
        axis.set_title(title)
        axis.grid(axis="y", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    # Below the panels: inside, it would hide the yardstick marks.
    figure.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.02), ncol=5)
    figure.suptitle("Fig. 5: test performance per task, mean and 95% CI over seeds")
    return _save(figure, path)


def plot_fig6(
    points: list[IntervalPoint],
    settings: CurveSettings,
    path: Path,
    yardsticks: dict[str, EvalSummary] | None = None,
) -> Path:
    """FedAvg reward against the aggregation interval, each yardstick's average test
    return (same seeds) as a reference line; communication on a second axis."""
    plt = pyplot()
    figure, axis = plt.subplots(figsize=(7.5, 4.5))
    intervals = np.array([p.interval for p in points], dtype=float)
    final = np.array([p.final_reward.mean for p in points])
    half = np.array([_err(p.final_reward) for p in points])
    axis.errorbar(
        intervals,
        final,
        yerr=half,
        marker="o",
        capsize=3,
        color="tab:green",
        label=f"training reward at the end (last {settings.episode_window} episodes)",
    )
    axis.fill_between(intervals, final - half, final + half, color="tab:green", alpha=0.15)
    test = np.array([_val(p.test_reward) for p in points])
    if np.isfinite(test).any():
        axis.errorbar(
            intervals,
            test,
            yerr=[_err(p.test_reward) for p in points],
            marker="s",
            capsize=3,
            linestyle="--",
            color="tab:olive",
            label="test reward",
        )
    _yardstick_lines(axis, yardsticks, "average_reward")
    axis.set(xscale="log", xlabel="aggregation interval (steps)", ylabel="average reward")
    # Slanted: on a log axis 2,000 and 2,500 sit too close for upright labels.
    axis.set_xticks(intervals, [f"{int(i):,}" for i in intervals], rotation=45, ha="right")
    axis.minorticks_off()
    axis.grid(alpha=0.3)
    second = axis.twinx()
    cost = np.array([_val(p.total_bytes) for p in points])
    second.plot(
        intervals,
        cost / 1e6,
        marker="^",
        color="tab:brown",
        linestyle=":",
        label="communication (MB, up + down)",
    )
    second.set(ylabel="communication cost (MB)", yscale="log")
    lines = axis.get_legend_handles_labels()
    more = second.get_legend_handles_labels()
    # Below the axes: inside, it hides points wherever the curves happen to fall.
    axis.legend(
        lines[0] + more[0],
        lines[1] + more[1],
        loc="upper center",
        bbox_to_anchor=(0.5, -0.3),
        ncol=2,
        fontsize=8,
    )
    axis.set_title("Fig. 6: FedAvg-DDPG vs aggregation interval (mean, 95% CI)")
    return _save(figure, path)


def plot_fig3(
    points: list[RewardPoint], path: Path, yardsticks: dict[str, EvalSummary] | None = None
) -> Path:
    """Test travel time and collision rate per reward setting, with 95% CIs; each
    yardstick (same seeds and traffic) as a horizontal mark."""
    plt = pyplot()
    figure, axes = plt.subplots(1, 2, figsize=(12, 4))
    labels = [f"{p.label}\n(n={len(p.seeds)})" for p in points]
    x = np.arange(len(points))
    for axis, metric, title in (
        (axes[0], "average_episode_steps", "travel time (steps, all episodes)"),
        (axes[1], "collision_rate", "collision rate"),
    ):
        values = [
            (p.summary.metrics.get("average", {}) if p.summary else {}).get(metric) for p in points
        ]
        axis.bar(
            x,
            [_val(v) for v in values],
            yerr=[_err(v) for v in values],
            capsize=3,
            color="tab:cyan",
        )
        _yardstick_lines(axis, yardsticks, metric)
        axis.set_xticks(x, labels, fontsize=8)
        axis.set_title(title)
        axis.grid(axis="y", alpha=0.3)
    if yardsticks:
        axes[1].legend(loc="upper right", fontsize=8)
    figure.suptitle("Fig. 3: reward tuning, test average over tasks, mean and 95% CI")
    return _save(figure, path)


def relative(path: Path, start: Path) -> str:
    return Path(os.path.relpath(path, start)).as_posix()
