"""Are two finished runs the same, bit for bit? Their test tables, models and step rewards.

    python scripts/same_run.py RUN_A RUN_B [--denormals-as-zero]

Compares ``results.json``'s evaluation (per-task tables, averages, yardsticks), every
tensor of every final model under ``models/`` and ``step_rewards.npy``. Used to show
that a refactoring left a run unchanged: train the same quick config at the same seed
before and after, then compare. Exit code 0 when everything is equal, 1 otherwise.

``--denormals-as-zero`` compares a run made before training processes flushed denormals
to zero (``frl.federation.workers.flush_denormals``) with one made since. Only Adam's
moments can tell them apart, and only where they are far below anything that moves a
parameter: running means that decayed past float32's smallest normal number (0 in the
later run), and running squares fed such values (the last bits of numbers near 1e-33).
Adam divides by sqrt(v) + 1e-8, so moments below :data:`TINY_MOMENT` move no parameter;
they are read as 0 on both sides. Networks, tables and step rewards must still be equal.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from frl import run_directory as rundir

RETIRED_TENSORS = frozenset({"rngs.target_noise"})
"""Tensors that model files written before an option's retirement carry and later ones do
not (TD3's target-smoothing generator, unused while the option was off): not a difference
in the run."""


def tensors(value: Any, prefix: str = "") -> dict[str, torch.Tensor]:
    """Every tensor inside a checkpoint's nested dicts, by dotted key."""
    if isinstance(value, torch.Tensor):
        return {prefix: value}
    if isinstance(value, dict):
        found: dict[str, torch.Tensor] = {}
        for key, item in value.items():
            found.update(tensors(item, f"{prefix}.{key}" if prefix else str(key)))
        return found
    return {}


TINY_MOMENT = 1e-30
"""Adam moments below this read as 0 under ``--denormals-as-zero``: a step of at most
lr * 1e-30 / 1e-8 moves no float32 parameter above 1e-14."""


def as_flushed(key: str, tensor: torch.Tensor) -> torch.Tensor:
    """An optimizer moment (``exp_avg``, ``exp_avg_sq``) with its entries below
    :data:`TINY_MOMENT` read as 0; any other tensor as it is."""
    if not key.rsplit(".", 1)[-1].startswith("exp_avg") or not tensor.is_floating_point():
        return tensor
    return torch.where(tensor.abs() < TINY_MOMENT, torch.zeros_like(tensor), tensor)


def differences(a: Path, b: Path, denormals_as_zero: bool = False) -> list[str]:
    found = []
    results_a, results_b = rundir.read_results(a) or {}, rundir.read_results(b) or {}
    for key in ("per_task", "average", "yardsticks"):
        left = results_a.get("evaluation", {}).get(key)
        right = results_b.get("evaluation", {}).get(key)
        if left is None or left != right:
            found.append(f"evaluation.{key} differs")
    models_a = sorted(p.name for p in (a / rundir.MODELS_DIR).glob("*.pt"))
    models_b = sorted(p.name for p in (b / rundir.MODELS_DIR).glob("*.pt"))
    if not models_a or models_a != models_b:
        found.append(f"model files differ: {models_a} vs {models_b}")
    for name in set(models_a) & set(models_b):
        left = tensors(torch.load(a / rundir.MODELS_DIR / name, weights_only=True))
        right = tensors(torch.load(b / rundir.MODELS_DIR / name, weights_only=True))
        if left.keys() - RETIRED_TENSORS != right.keys() - RETIRED_TENSORS:
            found.append(f"{name}: different tensors")
        if denormals_as_zero:
            left = {k: as_flushed(k, v) for k, v in left.items()}
            right = {k: as_flushed(k, v) for k, v in right.items()}
        found += [
            f"{name}: {k} differs"
            for k in left
            if k in right and not torch.equal(left[k], right[k])
        ]
    if not np.array_equal(rundir.read_step_rewards(a), rundir.read_step_rewards(b)):
        found.append("step rewards differ")
    return found


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_a", type=Path)
    parser.add_argument("run_b", type=Path)
    parser.add_argument(
        "--denormals-as-zero",
        action="store_true",
        help="read Adam's moments below 1e-30 as 0 (a run from before denormals were flushed)",
    )
    args = parser.parse_args()
    for run in (args.run_a, args.run_b):
        if rundir.read_results(run) is None:
            parser.error(f"{run} holds no finished run (no {rundir.RESULTS_FILE})")
    found = differences(args.run_a, args.run_b, args.denormals_as_zero)
    for line in found:
        print(line)
    if not found:
        models = len(list((args.run_a / rundir.MODELS_DIR).glob("*.pt")))
        flushed = " (Adam's moments below 1e-30 read as 0)" if args.denormals_as_zero else ""
        print(f"identical: evaluation tables, {models} model(s){flushed}, step rewards")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
