"""Find the runs of each figure under a reproduction root (run or data directories).

The layout, made by ``python -m frl.reproduce`` (run directories) and by its export
(data directories), is the same for both::

    ROOT/fig4/{central,separate,fedavg}-seed{k}/    Figs. 4 and 5
    ROOT/fig6/interval{N}-seed{k}/                  Fig. 6 (interval 2000: fig4's fedavg runs)
    ROOT/fig3/{reward}-seed{k}/                     Fig. 3 (the paper reward: fig4's runs of
                                                    the tuning scheme)
    ROOT/{panel}/fig4/{scheme}-seed{k}/             Figs. 4 and 5 of another agent or
                                                    budget, a panel of its own (AGENT_PANELS)

Runs are grouped by what their ``results.json`` and ``config.yaml`` say, not by their
directory names, so a user's own sweep laid out this way is read the same way.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from frl.report.runs import RunDataError, RunRecord, has_complete_results, load_run
from frl.run_directory import CONFIG_FILE, RESULTS_FILE, STATE_FILE

FIGURE_DIRS: tuple[str, ...] = ("fig4", "fig6", "fig3")
"""Sweep directories; Fig. 5 is read from fig4's runs."""
FIGURES: tuple[str, ...] = ("fig3", "fig4", "fig5", "fig6")
AGENT_PANELS: dict[str, str] = {
    "data-budget": "python -m frl.reproduce --figures fig4 --seeds 0,1,2,3,4 --runs-dir "
    "outputs/repro/runs/data-budget --data-dir outputs/repro/data/data-budget -- budget=data "
    "agent.collision_budget=null agent.critic_lr=0.0001",
    "collision-budget": "python -m frl.reproduce --figures fig4 --seeds 0,1,2,3,4 --runs-dir "
    "outputs/repro/runs/collision-budget --data-dir outputs/repro/data/collision-budget -- "
    "budget=data agent.precision=float32 agent.cost_critic=separate agent.cost_target=n_step "
    "agent.critic_lr=0.0001",
    "costs-to-go": "python -m frl.reproduce --figures fig4 --seeds 0,1,2,3,4 --runs-dir "
    "outputs/repro/runs/costs-to-go --data-dir outputs/repro/data/costs-to-go -- budget=data "
    "agent.critic_lr=0.0001",
    "faster-critics": "python -m frl.reproduce --figures fig4 --seeds 0,1,2,3,4 --runs-dir "
    "outputs/repro/runs/faster-critics --data-dir outputs/repro/data/faster-critics -- "
    "budget=data",
    "guided": "python -m frl.reproduce --figures fig4-guided",
    "paper-agent": "python -m frl.reproduce --figures fig4 --runs-dir outputs/repro/runs/"
    "paper-agent --data-dir outputs/repro/data/paper-agent -- agent=ddpg-paper",
}
"""Optional second roots under a reproduction root, each laid out like it, with Figs. 4
and 5 trained on another agent or budget, and the command that makes each:
``data-budget`` (the default agent at the main command's budget, 80,000 steps and an
update every 8, where the editions train the paper's 10,000 and an update a step, without
the collision budget), ``collision-budget`` (the same with it, as it was first measured:
float32, a separate cost critic on n-step targets), ``costs-to-go`` (the cost head on
each episode's costs to go, in the CPU's precision), ``faster-critics`` (the main
command's agent: the same with its critics at 3e-4), ``guided`` (``agent=ddpg-guided``,
which learns from the gap-acceptance rule) and ``paper-agent`` (the paper's Table II
agent). The first three ran with the critics at Table II's 1e-4, which their commands
keep. Each is reported as a panel of its own, never mixed with the editions' runs."""


@dataclass
class Collection:
    """Finished runs per sweep directory, and the unfinished ones seen (by path)."""

    root: Path
    runs: dict[str, list[RunRecord]] = field(default_factory=dict)
    unfinished: dict[str, list[Path]] = field(default_factory=dict)

    def of(self, sweep: str) -> list[RunRecord]:
        return self.runs.get(sweep, [])

    @property
    def count(self) -> int:
        return sum(len(runs) for runs in self.runs.values())


def check_root(root: str | os.PathLike[str]) -> Path:
    """``root`` as a Path if it holds at least one run; :class:`RunDataError` otherwise."""
    root = Path(root)
    if not root.is_dir():
        raise RunDataError(f"{root}: no such directory")
    found = [d for sweep in FIGURE_DIRS for d in _run_dirs(root / sweep)]
    if not found:
        raise RunDataError(
            f"{root}: no runs found; expected run or data directories under "
            f"{', '.join(f'{root}/{s}/' for s in FIGURE_DIRS)} (each with {RESULTS_FILE} "
            f"or {STATE_FILE})"
        )
    return root


def collect(root: str | os.PathLike[str]) -> Collection:
    """Load every finished run under ``root``'s sweep directories."""
    root = check_root(root)
    collection = Collection(root)
    for sweep in FIGURE_DIRS:
        for run_dir in _run_dirs(root / sweep):
            if _is_data_dir(run_dir) or has_complete_results(run_dir):
                collection.runs.setdefault(sweep, []).append(load_run(run_dir))
            else:
                collection.unfinished.setdefault(sweep, []).append(run_dir)
    if collection.count == 0:
        names = ", ".join(str(p) for paths in collection.unfinished.values() for p in paths)
        raise RunDataError(f"{root}: no finished run yet (unfinished: {names})")
    return collection


def _run_dirs(sweep_dir: Path) -> list[Path]:
    if not sweep_dir.is_dir():
        return []
    return sorted(
        d
        for d in sweep_dir.iterdir()
        if d.is_dir() and any((d / f).exists() for f in (RESULTS_FILE, STATE_FILE, CONFIG_FILE))
    )


def _is_data_dir(path: Path) -> bool:
    try:
        return (
            (path / RESULTS_FILE).exists()
            and not (path / "tb").exists()
            and (path / "step_rewards.csv").exists()
        )
    except OSError as error:  # pragma: no cover - unreadable directory
        raise RunDataError(f"{path}: {error}") from error
