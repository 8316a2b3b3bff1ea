"""``python -m frl.report.compare RUN [RUN ...]``: runs side by side, for studies the
figures do not cover (a learning-rate or noise variant, a new reward).

One markdown row per run: the settings in which the runs differ, the final and best
training reward (the Fig. 4 curve) and the test metrics averaged over the tasks.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from frl.cli import OneLineParser
from frl.report.aggregate import CurveSettings, reward_curve
from frl.report.markdown import table
from frl.report.runs import RunDataError, RunRecord, load_run

IGNORED_SETTINGS = frozenset({"seed", "run_dir", "resume", "progress", "device"})
"""Keys that differ between runs without changing what is being compared."""


def flat_settings(config: dict[str, Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    """``(dotted.key, value)`` for every leaf of a run's config."""
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            yield from flat_settings(value, f"{name}.")
        else:
            yield name, value


def differing_settings(per_run: Sequence[dict[str, Any]]) -> list[str]:
    """The keys of the runs' flattened configs (see ``flat_settings``) with different values
    in the runs that have them, in config order. A key an older run's config lacks is not a
    difference: that run predates the option."""
    keys = dict.fromkeys(key for settings in per_run for key in settings)
    return [
        key
        for key in keys
        if key not in IGNORED_SETTINGS
        and len({repr(settings[key]) for settings in per_run if key in settings}) > 1
    ]


def training_rewards(run: RunRecord, episode_window: int) -> tuple[float, float]:
    """Final and best value of the Fig. 4 reward curve; the best counts only after the
    warm-up, whose actions are random."""
    curve = reward_curve(run, episode_window)
    learned = curve[run.learning_starts :]
    best = float(np.nanmax(learned)) if np.isfinite(learned).any() else math.nan
    return float(curve[-1]), best


def compare_table(runs: Sequence[RunRecord], episode_window: int = 100) -> str:
    """A markdown table with one row per run."""
    per_run = [dict(flat_settings(run.config)) for run in runs]
    varied = differing_settings(per_run)
    header = [
        "run",
        "seed",
        *varied,
        "final training reward",
        "best training reward",
        "test reward",
        "collisions",
        "arrivals",
        "travel time",
    ]
    rows = []
    for run, settings in zip(runs, per_run, strict=True):
        final, best = training_rewards(run, episode_window)
        test = (run.evaluation or {}).get("average") or {}
        rows.append(
            [
                run.name,
                run.seed,
                *(settings.get(key, "–") for key in varied),
                _number(final),
                _number(best),
                _number(test.get("average_reward")),
                _percent(test.get("collision_rate")),
                _percent(test.get("arrival_rate")),
                _number(test.get("average_travel_time"), digits=1),
            ]
        )
    return table(header, rows)


def _number(value: float | None, digits: int = 2) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _percent(value: float | None) -> str:
    return "–" if value is None else f"{100 * value:.1f}%"


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(
        prog="python -m frl.report.compare",
        description="Compare finished runs (run or exported data directories) side by side.",
    )
    parser.add_argument("runs", nargs="+", help="run directories or exported data directories")
    parser.add_argument(
        "--episode-window",
        type=int,
        default=CurveSettings().episode_window,
        help="episodes in the training-reward mean (%(default)s)",
    )
    args = parser.parse_args(argv)
    if args.episode_window < 1:
        parser.error("--episode-window must be >= 1")
    try:
        runs = [load_run(path) for path in args.runs]
    except RunDataError as error:
        print(f"frl.report.compare: {error}", file=sys.stderr)
        return 2
    print(compare_table(runs, args.episode_window))
    return 0


if __name__ == "__main__":
    sys.exit(main())
