"""``python -m frl.plot RUN_DIR [RUN_DIR ...]``: a picture of how runs trained and tested.

    python -m frl.plot outputs/fedavg/2026-11-27_08-00-00            # one run
    python -m frl.plot outputs/budget/fedavg-seed{0,1,2} outputs/default/fedavg-seed{0,1,2}
    python -m frl.plot RUN_DIR ... --out comparison.png

The top panel is training: each vehicle's mean return over its last 100 episodes against
its environment steps (Fig. 4's curve), the paper's benchmark of 6, and the per-round
tested return where the run has one. The bottom panels are the test, per task and on
average: return, collisions and arrivals, beside the yardsticks tested on the same
episodes (full throttle, the gap-acceptance rule, the oracle).

Several runs of one setting (runs whose configs differ in the seed alone) are drawn as
their mean, the training curve with a band from the lowest to the highest seed and the
test bars with the seeds' range; different settings are drawn side by side, labelled by
the config keys that tell them apart. Run directories and the report's exported data
directories (``docs/results/data/...``) both read.

Every finished ``python -m frl.train`` run draws its own: ``RUN_DIR/figure.png``
(:func:`draw_run_figure`).
"""

from __future__ import annotations

import argparse
import io
import logging
import sys
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from frl.agents.learn import EPISODE_WINDOW
from frl.fileio import write_bytes_atomic
from frl.report.plots import pyplot
from frl.report.runs import RunDataError, RunRecord, load_run
from frl.run_directory import FIGURE_FILE
from frl.train_config import ConfigError, complete_saved_config

BENCHMARK_RETURN = 6.0
"""The paper's benchmark return in Fig. 4 (Section IV.B)."""
CURVE_POINTS = 400
TASK_ORDER = ("left", "straight", "right", "average")
YARDSTICKS = {
    "full_throttle": "full throttle",
    "gap_acceptance": "the rule",
    "committed_gap_acceptance": "the committed rule",
    "oracle": "oracle",
}
YARDSTICK_COLORS = {
    "full_throttle": "0.55",
    "gap_acceptance": "tab:orange",
    "committed_gap_acceptance": "tab:brown",
    "oracle": "tab:purple",
}
TEST_METRICS = (
    ("average_reward", "test return", 1.0),
    ("collision_rate", "collisions (%)", 100.0),
    ("arrival_rate", "arrivals (%)", 100.0),
)
IGNORED_KEYS = frozenset({"seed", "run_dir", "resume", "progress", "cores", "device"})
"""Config keys that do not make another setting (how and where a run ran, not what)."""


@dataclass(frozen=True)
class Setting:
    """Runs whose configs differ in the seed (and where they ran) alone."""

    label: str
    runs: tuple[RunRecord, ...]


def vehicle_curve(episodes: Any, steps: np.ndarray) -> np.ndarray:
    """A vehicle's mean return over its last :data:`EPISODE_WINDOW` episodes at each of
    ``steps`` (NaN before its first episode ended)."""
    returns = np.asarray(episodes.returns, float)
    if returns.size == 0:
        return np.full(len(steps), np.nan)
    sums = np.cumsum(returns)
    counts = np.arange(1, returns.size + 1)
    window = np.minimum(counts, EPISODE_WINDOW)
    previous = np.concatenate([[0.0], sums])[counts - window]
    means = (sums - previous) / window
    index = np.searchsorted(np.asarray(episodes.end_step), steps, side="right") - 1
    return np.where(index >= 0, means[np.maximum(index, 0)], np.nan)


def training_curves(run: RunRecord) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Steps and each vehicle's curve of :func:`vehicle_curve` on them."""
    steps = np.linspace(0, run.total_steps, CURVE_POINTS)
    return steps, {name: vehicle_curve(e, steps) for name, e in sorted(run.episodes.items())}


def settings_of(runs: Sequence[RunRecord]) -> list[Setting]:
    """The runs grouped by what they trained, in the order first seen, each labelled by
    the config keys that tell the settings apart (its directory's name where one)."""
    flat = [_flat(_comparable(run.config)) for run in runs]
    keys: list[tuple[Any, ...]] = []
    members: dict[tuple[Any, ...], list[RunRecord]] = {}
    for run, config in zip(runs, flat, strict=True):
        key = tuple(sorted((k, repr(v)) for k, v in config.items() if k not in IGNORED_KEYS))
        if key not in members:
            keys.append(key)
        members.setdefault(key, []).append(run)
    differing = sorted({k for c in flat for k in c if k not in IGNORED_KEYS and
                        len({repr(other.get(k)) for other in flat}) > 1})  # fmt: skip
    grouped = []
    for key in keys:
        group = members[key]
        config = dict(key)
        label = ", ".join(f"{k}={config.get(k, 'unset')}" for k in differing)
        seeds = sorted(run.seed for run in group)
        seed_text = f"seed {seeds[0]}" if len(seeds) == 1 else f"seeds {_seed_list(seeds)}"
        name = label or (group[0].path.parent.name if len(group) > 1 else group[0].name)
        grouped.append(Setting(f"{name} ({seed_text})", tuple(group)))
    return grouped


def draw(runs: Sequence[RunRecord], path: Path) -> Path:
    """The figure of ``runs`` (one run, several seeds, several settings), written
    atomically to ``path`` as a PNG."""
    if not runs:
        raise ValueError("no runs to draw")
    plt = pyplot()
    settings = settings_of(runs)
    figure = plt.figure(figsize=(13, 8.5))
    grid = figure.add_gridspec(2, 3, height_ratios=(1.1, 1.0), hspace=0.35, wspace=0.28)
    _training_panel(figure.add_subplot(grid[0, :]), settings)
    tested = [s for s in settings if all(r.evaluation for r in s.runs)]
    for column, (metric, label, scale) in enumerate(TEST_METRICS):
        axis = figure.add_subplot(grid[1, column])
        if tested:
            _test_panel(axis, tested, metric, label, scale)
        else:
            axis.text(0.5, 0.5, "not tested (eval_episodes=0)", ha="center", va="center")
            axis.set_axis_off()
    figure.suptitle(_title(settings), fontsize=11, x=0.45, y=0.94)
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=100, bbox_inches="tight")
    plt.close(figure)
    write_bytes_atomic(path, buffer.getvalue())
    return path


def draw_run_figure(run_dir: str | Path) -> Path:
    """``RUN_DIR/figure.png`` of one finished run (what ``frl.train`` draws at its end)."""
    run_dir = Path(run_dir)
    return draw([read_run(run_dir)], run_dir / FIGURE_FILE)


def read_run(path: Path) -> RunRecord:
    """:func:`frl.report.runs.load_run`, without TensorBoard's reader logging each of the
    run's event files into the command's output."""
    reader_log = logging.getLogger("tensorboard")
    level = reader_log.level
    reader_log.setLevel(logging.WARNING)
    try:
        return load_run(path)
    finally:
        reader_log.setLevel(level)


# ------------------------------------------------------------------ the panels
def _training_panel(axis: Any, settings: list[Setting]) -> None:
    colors = _colors(len(settings))
    for setting, color in zip(settings, colors, strict=True):
        per_run = []
        steps = np.zeros(0)
        for run in setting.runs:
            steps, curves = training_curves(run)
            if len(settings) == 1 and len(setting.runs) == 1:
                for name, curve in curves.items():
                    axis.plot(steps, curve, linewidth=0.9, alpha=0.7, label=name)
            if curves:
                per_run.append(_nanmean(np.stack(list(curves.values()))))
        if per_run:
            stacked = np.stack(per_run)
            mean = _nanmean(stacked)
            name = "mean of the vehicles" if len(settings) == 1 else setting.label
            axis.plot(steps, mean, color=color, linewidth=2.2, label=name)
            if len(per_run) > 1:
                with warnings.catch_warnings():  # before every seed's first episode
                    warnings.simplefilter("ignore", RuntimeWarning)
                    low, high = np.nanmin(stacked, axis=0), np.nanmax(stacked, axis=0)
                axis.fill_between(steps, low, high, color=color, alpha=0.18, linewidth=0)
        _tested_curve(axis, setting, color)
    axis.axhline(BENCHMARK_RETURN, color="black", linestyle=":", linewidth=1.2,
                 label="the paper's benchmark (6)")  # fmt: skip
    axis.set_xlabel("environment steps per vehicle")
    axis.set_ylabel(f"training return (last {EPISODE_WINDOW} episodes)")
    axis.grid(alpha=0.3)
    axis.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)


def _tested_curve(axis: Any, setting: Setting, color: Any) -> None:
    curves = [run.round_test_curve for run in setting.runs]
    if not curves or any(curve is None for curve in curves):
        return
    steps = curves[0][0]
    if any(curve[0] != steps for curve in curves):
        return
    values = np.nanmean(np.array([curve[1] for curve in curves], float), axis=0)
    axis.plot(steps, values, color=color, marker="o", linestyle="--", linewidth=1.2,
              label="tested each round" if len(setting.runs) == 1 else
              f"{setting.label}: tested each round")  # fmt: skip


def _test_panel(axis: Any, settings: list[Setting], metric: str, label: str, scale: float) -> None:
    """Grouped bars per task: each setting (mean, whiskers to its seeds' range), then each
    yardstick tested beside every run drawn (mean over those runs' episodes)."""
    runs = [run for setting in settings for run in setting.runs]
    one_run = len(runs) == 1
    groups: list[tuple[str, Any, list[list[float | None]]]] = [
        (
            "the model" if one_run else s.label,
            color,
            [[_tested(r, task, metric) for r in s.runs] for task in TASK_ORDER],
        )
        for s, color in zip(settings, _colors(len(settings)), strict=True)
    ]
    for name, text in YARDSTICKS.items():
        values = [[_yardstick(r, name, task, metric) for r in runs] for task in TASK_ORDER]
        if all(v is not None for task_values in values for v in task_values):
            groups.append((text, YARDSTICK_COLORS[name], values))
    width = 0.8 / len(groups)
    x = np.arange(len(TASK_ORDER))
    for index, (name, color, per_task) in enumerate(groups):
        numbers = [np.array([np.nan if v is None else v for v in values], float) * scale
                   for values in per_task]  # fmt: skip
        means = np.array([np.nanmean(v) if np.isfinite(v).any() else np.nan for v in numbers])
        spread = None
        if max(len(v) for v in numbers) > 1:
            low, high = ([reduce(v) if np.isfinite(v).any() else np.nan for v in numbers]
                         for reduce in (np.nanmin, np.nanmax))  # fmt: skip
            spread = np.clip([means - low, high - means], 0.0, None)  # rounding: never < 0
        axis.bar(x - 0.4 + width * (index + 0.5), means, width, color=color, label=name,
                 yerr=spread, capsize=2)  # fmt: skip
    axis.set_xticks(x, TASK_ORDER)
    axis.set_title(label, fontsize=10)
    axis.grid(axis="y", alpha=0.3)
    if metric == TEST_METRICS[-1][0]:
        axis.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0)


def _tested(run: RunRecord, task: str, metric: str) -> float | None:
    evaluation = run.evaluation or {}
    table = (
        evaluation.get("average") if task == "average" else evaluation.get("per_task", {}).get(task)
    )
    return None if table is None else table.get(metric)


def _yardstick(run: RunRecord, name: str, task: str, metric: str) -> float | None:
    tables = ((run.evaluation or {}).get("yardsticks") or {}).get(name)
    if tables is None:
        return None
    table = tables.get("average") if task == "average" else tables.get("per_task", {}).get(task)
    return None if table is None else table.get(metric)


# -------------------------------------------------------------------- helpers
def _flat(config: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flat(value, f"{name}."))
        else:
            flat[name] = value
    return flat


def _comparable(config: dict[str, Any]) -> dict[str, Any]:
    """The config as today's schema reads it (retired options, keys added since), or as
    saved where it no longer validates."""
    try:
        return complete_saved_config(config)
    except (ConfigError, ValueError, TypeError):
        return config


def _seed_list(seeds: list[int]) -> str:
    if seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}-{seeds[-1]}"
    return ", ".join(map(str, seeds))


def _title(settings: list[Setting]) -> str:
    runs = [run for setting in settings for run in setting.runs]
    schemes = ", ".join(sorted({run.scheme for run in runs}))
    if len(settings) == 1:
        return f"{schemes}: {settings[0].label}"
    return f"{schemes}: {len(runs)} runs, {len(settings)} settings"


def _nanmean(values: np.ndarray) -> np.ndarray:
    counts = np.isfinite(values).sum(axis=0)
    sums = np.nansum(values, axis=0)
    return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)


def _colors(count: int) -> list[Any]:
    palette = ["tab:green", "tab:blue", "tab:red", "tab:cyan", "tab:brown", "tab:pink"]
    return [palette[i % len(palette)] for i in range(count)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m frl.plot", description=__doc__.splitlines()[0])
    parser.add_argument("run_dirs", nargs="+", type=Path, help="run or data directories")
    parser.add_argument(
        "--out",
        type=Path,
        help=f"the PNG to write (one run: RUN_DIR/{FIGURE_FILE}; several: frl-plot.png)",
    )
    args = parser.parse_args(argv)
    out = args.out
    if out is None:
        out = args.run_dirs[0] / FIGURE_FILE if len(args.run_dirs) == 1 else Path("frl-plot.png")
    if out.suffix.lower() != ".png":
        print(f"frl.plot: --out must name a .png file, got {out}", file=sys.stderr)
        return 2
    try:
        runs = [read_run(path) for path in args.run_dirs]
        draw(runs, out)
    except (RunDataError, OSError, ValueError) as error:
        print(f"frl.plot: {error}", file=sys.stderr)
        return 2
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
