"""Copy a training run at chosen budgets while it runs, so each copy can be tested as a
shorter run: one long run gives the test table at every budget on its way.

    python scripts/snapshot_rounds.py RUN_DIR [RUN_DIR ...] --steps 10000,20000,30000
    python -m frl.train resume=RUN_DIR-at-20000 cores=1     # finish and test one copy

Watches each run's ``state.json``. When a run commits the round that ends at one of
``--steps`` (steps per vehicle), the run directory is copied to ``RUN_DIR-at-STEPS``
with that round's checkpoint, its step rewards cut to the budget and its saved config's
``total_steps`` set to the budget. Resuming the copy runs no more rounds: it saves the
round's models and tests them on the run's own test seeds, as a run trained to that budget
would have been. Training does not look at ``total_steps`` before its last round, so the
copy is that run, bit for bit, where the budget is a whole number of rounds (check it
with ``scripts/same_run.py`` against a run trained to the shorter budget).

A round's checkpoint is deleted once the next round commits, so the script must run
beside the training; it polls every ``--poll`` seconds and returns when every run has
finished or has passed all of ``--steps``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path

from omegaconf import OmegaConf

from frl import run_directory as rundir


def snapshot_path(run_dir: Path, steps: int) -> Path:
    return run_dir.with_name(f"{run_dir.name}-at-{steps}")


def copy_round(run_dir: Path, steps: int) -> Path | None:
    """Copy ``run_dir`` as a run of ``steps`` steps; None when the round moved on meanwhile."""
    state = rundir.read_state(run_dir)
    if state is None or state.steps_per_client != steps or state.checkpoint is None:
        return None
    target = snapshot_path(run_dir, steps)
    partial = target.with_name(target.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    skip = {rundir.CHECKPOINT_DIR, rundir.MODELS_DIR, rundir.RESULTS_FILE}
    partial.mkdir(parents=True)
    for item in run_dir.iterdir():
        if item.name in skip:
            continue
        if item.is_dir():
            shutil.copytree(item, partial / item.name)
        else:
            shutil.copy2(item, partial / item.name)
    shutil.copytree(run_dir / state.checkpoint, partial / state.checkpoint)
    # The round may have ended while copying: the copy is good only if it still names it.
    after = rundir.read_state(run_dir)
    if after is None or after.steps_per_client != steps:
        shutil.rmtree(partial, ignore_errors=True)
        return None
    rundir.write_state(partial, state)
    rundir.write_step_rewards(partial, rundir.read_step_rewards(partial, steps))
    # Read and written as frl.train does, so that values keep their types (1e-4 a number).
    config = rundir.read_saved_config(partial)
    config.update(total_steps=steps, run_dir=str(target.resolve()), resume=False)
    OmegaConf.save(OmegaConf.create(config), partial / rundir.CONFIG_FILE)
    shutil.rmtree(target, ignore_errors=True)
    partial.rename(target)
    return target


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+", metavar="RUN_DIR")
    parser.add_argument("--steps", required=True, help="budgets, comma-separated")
    parser.add_argument("--poll", type=float, default=5.0, help="seconds between looks")
    args = parser.parse_args(argv)
    try:
        budgets = sorted({int(text) for text in args.steps.split(",")})
    except ValueError:
        parser.error(f"--steps must be whole numbers separated by commas, got {args.steps!r}")
    if not budgets or budgets[0] <= 0:
        parser.error("--steps must be positive")
    pending = {(run, steps) for run in args.runs for steps in budgets}
    pending -= {(run, steps) for run, steps in pending if snapshot_path(run, steps).exists()}
    while pending:
        for run, steps in sorted(pending):
            state = rundir.read_state(run) if run.exists() else None
            done = state is not None and (state.training_finished or state.steps_per_client > steps)
            if state is not None and state.steps_per_client == steps:
                copied = copy_round(run, steps)
                if copied is not None:
                    print(f"{run} at {steps} steps -> {copied}", flush=True)
                    pending.discard((run, steps))
                    continue
            if done:
                print(f"{run}: missed {steps} steps (already at {state.steps_per_client})")
                pending.discard((run, steps))
        if pending:
            time.sleep(args.poll)
    return 0


if __name__ == "__main__":
    sys.exit(main())
