"""``python -m frl.report RUNS_OR_DATA_DIR``: figures and the markdown report from saved
runs (``outputs/results.md`` unless ``--out`` names another, such as ``docs/results.md``)."""

from __future__ import annotations

import sys

from frl.cli import OneLineParser
from frl.report.aggregate import CurveSettings
from frl.report.build import DEFAULT_OUT, MissingDependency, build_report
from frl.report.runs import RunDataError


def main(argv: list[str] | None = None) -> int:
    defaults = CurveSettings()
    parser = OneLineParser(
        prog="python -m frl.report",
        description="Plot the paper's Figs. 3-6 and write the markdown report from runs "
        "(ROOT/fig4, fig6, fig3: run directories or exported data directories).",
    )
    parser.add_argument("root", help="e.g. outputs/repro/runs or docs/results/data")
    parser.add_argument("--out", default=str(DEFAULT_OUT), help="markdown report (%(default)s)")
    parser.add_argument(
        "--figures-dir", default=None, help="PNG directory (default: OUT without .md)"
    )
    parser.add_argument(
        "--episode-window",
        type=int,
        default=defaults.episode_window,
        help="episodes in the training-reward mean (%(default)s)",
    )
    parser.add_argument(
        "--step-window",
        type=int,
        default=defaults.step_window,
        help="steps in the step-reward moving average (%(default)s)",
    )
    parser.add_argument(
        "--threshold",
        type=float,
        default=defaults.threshold,
        help="Fig. 4 benchmark reward (%(default)s)",
    )
    args = parser.parse_args(argv)
    if args.episode_window < 1 or args.step_window < 1:
        parser.error("windows must be >= 1")
    settings = CurveSettings(args.episode_window, args.step_window, args.threshold)
    try:
        written = build_report(args.root, args.out, args.figures_dir, settings)
    except (MissingDependency, RunDataError) as error:
        print(f"frl.report: {error}", file=sys.stderr)
        return 2
    for name, path in written.items():
        print(f"{name}: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
