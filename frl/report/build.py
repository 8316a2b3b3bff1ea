"""Build the report: collect runs, aggregate per figure, write PNGs and the markdown."""

from __future__ import annotations

import importlib.util
import logging
import os
from pathlib import Path

from frl.fileio import write_bytes_atomic
from frl.report import aggregate, markdown, plots
from frl.report.aggregate import CurveSettings
from frl.report.collect import collect

log = logging.getLogger("frl.report")

DEFAULT_OUT = Path("docs/results.md")


class MissingDependency(RuntimeError):
    """matplotlib is not installed."""


def require_matplotlib() -> None:
    if importlib.util.find_spec("matplotlib") is None:
        raise MissingDependency(
            "frl.report needs matplotlib: pip install -c constraints.txt -e '.[report]'"
        )


def build_report(
    root: str | os.PathLike[str],
    out: str | os.PathLike[str] = DEFAULT_OUT,
    figures_dir: str | os.PathLike[str] | None = None,
    settings: CurveSettings | None = None,
) -> dict[str, Path]:
    """Write ``out`` (blocks merged into an existing file) and its figures; return the
    written paths by name (``report``, ``fig3`` ... ``fig6``; figures without data are
    not drawn).

    Raises:
        MissingDependency: without matplotlib.
        frl.report.runs.RunDataError: ``root`` is missing or holds no finished run.
    """
    settings = settings or CurveSettings()
    require_matplotlib()
    collection = collect(root)
    out = Path(out)
    figures_dir = Path(figures_dir) if figures_dir is not None else out.with_suffix("")
    written: dict[str, Path] = {}

    def image(name: str, draw) -> str | None:  # type: ignore[no-untyped-def]
        path = draw(figures_dir / f"{name}.png")
        written[name] = path
        return plots.relative(path, out.parent)

    curves = aggregate.fig4(collection, settings)
    summaries = aggregate.fig5(collection)
    yardsticks = aggregate.fig5_yardsticks(collection)
    intervals = aggregate.fig6(collection, settings)
    rewards = aggregate.fig3(collection)
    blocks = {
        "method": markdown.method_block(collection, settings),
        "fig3": markdown.fig3_block(
            rewards, image("fig3", lambda p: plots.plot_fig3(rewards, p)) if rewards else None
        ),
        "fig4": markdown.fig4_block(
            curves,
            settings,
            image("fig4", lambda p: plots.plot_fig4(curves, settings, p)) if curves else None,
        ),
        "fig5": markdown.fig5_block(
            summaries,
            image("fig5", lambda p: plots.plot_fig5(summaries, p, yardsticks))
            if summaries
            else None,
            yardsticks,
        ),
        "fig6": markdown.fig6_block(
            intervals,
            settings,
            image("fig6", lambda p: plots.plot_fig6(intervals, settings, p)) if intervals else None,
        ),
        "runs": markdown.runs_block(collection),
    }
    existing = out.read_text() if out.exists() else None
    write_bytes_atomic(out, markdown.merge(existing, blocks).encode())
    written["report"] = out
    log.info("wrote %s (%d runs)", out, collection.count)
    return written
