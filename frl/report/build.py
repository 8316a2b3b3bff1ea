"""Build the report: collect runs, aggregate per figure, write PNGs and the markdown."""

from __future__ import annotations

import importlib.util
import logging
import os
from collections.abc import Callable
from pathlib import Path

from frl.fileio import write_bytes_atomic
from frl.report import aggregate, claims, markdown, plots, run_sets
from frl.report.aggregate import CurveSettings
from frl.report.collect import AGENT_PANELS, Collection, collect

log = logging.getLogger("frl.report")

DEFAULT_OUT = Path("outputs/results.md")
"""Where ``python -m frl.report`` writes unless ``--out`` says (``docs/results.md``: the
published report)."""


class MissingDependency(RuntimeError):
    """matplotlib or SciPy (the report extra) is not installed."""


def require_matplotlib() -> None:
    """Raise :class:`MissingDependency` unless the report extra (matplotlib, SciPy) is there."""
    missing = [name for name in ("matplotlib", "scipy") if importlib.util.find_spec(name) is None]
    if missing:
        raise MissingDependency(
            f"frl.report needs {' and '.join(missing)}: "
            "pip install -c constraints.txt -e '.[report]'"
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
        MissingDependency: without matplotlib or SciPy.
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

    intervals = aggregate.fig6(collection, settings)
    fig6_yardsticks = aggregate.fig6_yardsticks(collection)
    rewards = aggregate.fig3(collection)
    fig3_yardsticks = aggregate.fig3_yardsticks(collection)
    blocks = {
        "claims": markdown.claims_block(claims.all_claims(collection, settings)),
        "method": markdown.method_block(collection, settings),
        "fig3": markdown.fig3_block(
            rewards,
            image("fig3", lambda p: plots.plot_fig3(rewards, p, fig3_yardsticks))
            if rewards
            else None,
            fig3_yardsticks,
        ),
        **_fig4_fig5_blocks(collection, settings, image, suffix=""),
        "fig6": markdown.fig6_block(
            intervals,
            settings,
            image("fig6", lambda p: plots.plot_fig6(intervals, settings, p, fig6_yardsticks))
            if intervals
            else None,
            fig6_yardsticks,
        ),
        "runs": markdown.runs_block(collection),
        "studies": run_sets.studies_block(run_sets.study_run_sets(collection.root)),
    }
    existing = out.read_text() if out.exists() else None
    for panel, command in AGENT_PANELS.items():
        if (collection.root / panel).is_dir():
            blocks.update(_panel_blocks(collect(collection.root / panel), settings, image, panel))
        elif _asks_for(existing, f"claims-{panel}"):
            # The file asks for the panel: say it is not run rather than keep stale blocks.
            missing = f"_{markdown.NOT_RUN}_ (needs `{panel}/fig4/` runs: `{command}`)."
            blocks.update({f"{name}-{panel}": missing for name in PANEL_BLOCKS})
    write_bytes_atomic(out, markdown.merge(existing, blocks).encode())
    written["report"] = out
    log.info("wrote %s (%d runs)", out, collection.count)
    return written


def _asks_for(existing: str | None, name: str) -> bool:
    """Whether the report being merged into (the template for a new one) has block ``name``."""
    if existing is None:
        return f"{{{name}}}" in markdown.TEMPLATE
    return f"<!-- frl.report:begin {name} -->" in existing


PANEL_BLOCKS = ("claims", "fig4", "fig4-tested", "fig5", "runs")
"""The blocks of an agent panel, each named ``NAME-PANEL`` in the report."""


def _panel_blocks(
    panel: Collection,
    settings: CurveSettings,
    image: Callable[[str, Callable[[Path], Path]], str | None],
    name: str,
) -> dict[str, str]:
    """An agent panel's blocks: its claims, Figs. 4 and 5 and its runs, named ``-name``."""
    return {
        **_fig4_fig5_blocks(panel, settings, image, suffix=f"-{name}"),
        f"claims-{name}": markdown.claims_block(
            claims.fig4_panel_claims(panel.of("fig4"), settings)
        ),
        f"runs-{name}": markdown.runs_block(panel),
    }


def _fig4_fig5_blocks(
    collection: Collection,
    settings: CurveSettings,
    image: Callable[[str, Callable[[Path], Path]], str | None],
    suffix: str,
) -> dict[str, str]:
    """Figs. 4 and 5 of one collection's ``fig4/`` runs, blocks and images named with
    ``suffix``."""
    curves = aggregate.fig4(collection, settings)
    tested = aggregate.tested_curves(collection, settings)
    summaries = aggregate.fig5(collection)
    yardsticks = aggregate.fig5_yardsticks(collection)
    on_curve_seeds = aggregate.tested_curve_yardsticks(collection)
    curve_references = on_curve_seeds or yardsticks
    return {
        f"fig4-tested{suffix}": markdown.fig4_tested_block(
            tested,
            settings,
            image(
                f"fig4-tested{suffix}",
                lambda p: plots.plot_fig4_tested(
                    tested, settings, p, curve_references, bool(on_curve_seeds)
                ),
            )
            if tested
            else None,
            curve_references,
            bool(on_curve_seeds),
        ),
        f"fig4{suffix}": markdown.fig4_block(
            curves,
            settings,
            image(f"fig4{suffix}", lambda p: plots.plot_fig4(curves, settings, p, yardsticks))
            if curves
            else None,
            yardsticks,
        ),
        f"fig5{suffix}": markdown.fig5_block(
            summaries,
            image(f"fig5{suffix}", lambda p: plots.plot_fig5(summaries, p, yardsticks))
            if summaries
            else None,
            yardsticks,
        ),
    }
