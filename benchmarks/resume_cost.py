"""What a vehicle's drive costs a checkpoint and a resume: bytes written, seconds to restore.

    python benchmarks/resume_cost.py [--steps 64000] [--task left] [--backend traci]
        [--checkpoint ROUND_DIR]

Drives one vehicle's simulation for ``--steps`` environment steps with the
gap-acceptance rule (one SUMO start, as a training vehicle without per-round restarts
drives it; 64,000 is the default budget's last committed round), writes its drive as a
checkpoint does, then restores it in a fresh environment, times the restore and checks
that both environments then give the same observations. With ``--checkpoint`` (a run's
``checkpoints/round_NNNN``), the drive's size is also given as a share of the vehicle
files already there.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from frl.envs import EnvConfig, IntersectionEnv
from frl.federation.vehicle_snapshot import (
    VehicleSnapshot,
    read_vehicle_snapshot,
    snapshot_path,
    write_vehicle_snapshot,
)
from frl.policies import GapAcceptancePolicy


def drive_steps(env: IntersectionEnv, steps: int, seed: int) -> VehicleSnapshot:
    """``steps`` steps of the rule across episodes in one simulation; the drive then, with
    the running episode as a vehicle saves it."""
    policy = GapAcceptancePolicy(env.config)
    observation, _ = env.reset(seed=seed)
    observations, actions = [], []
    for _ in range(steps):
        action = policy(observation)
        observations.append(observation.reshape(-1))
        actions.append(action)
        observation, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            observation, _ = env.reset()
            observations, actions = [], []
    return VehicleSnapshot(
        snapshot=env.snapshot(),
        observation=observation.reshape(-1),
        episode_observations=np.stack(observations) if observations else np.empty((0, 1)),
        episode_actions=np.stack(actions) if actions else np.empty((0, 1)),
        episode_rewards=[0.0] * len(observations),
        episode_speeds=[0.0] * len(observations),
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=64_000)
    parser.add_argument("--task", default="left")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--checkpoint", type=Path, default=None)
    parser.add_argument(
        "--backend", choices=("libsumo", "traci"), default="libsumo",
        help="traci: as a worker's second vehicle drives (a fleet larger than the cores)",
    )  # fmt: skip
    args = parser.parse_args(argv)
    if args.steps <= 0:
        parser.error(f"--steps must be positive, got {args.steps}")
    if args.checkpoint is not None and not args.checkpoint.is_dir():
        parser.error(f"--checkpoint {args.checkpoint} is not a directory")

    config = EnvConfig(task=args.task, backend=args.backend)
    driven = IntersectionEnv(config)
    began = time.perf_counter()
    drive = drive_steps(driven, args.steps, args.seed)
    driving_s = time.perf_counter() - began
    expected = drive_steps_on(driven)
    driven.close()  # libsumo: one simulation per process
    with tempfile.TemporaryDirectory() as tmp:
        path = snapshot_path(tmp, "vehicle")
        began = time.perf_counter()
        write_vehicle_snapshot(path, drive)
        write_s = time.perf_counter() - began
        size = path.stat().st_size
        began = time.perf_counter()
        restored = IntersectionEnv(config)
        restored.restore(read_vehicle_snapshot(path).snapshot)  # type: ignore[arg-type]
        restore_s = time.perf_counter() - began
    after = drive_steps_on(restored)
    same = all(np.array_equal(a, b) for a, b in zip(expected, after, strict=True))
    restored.close()
    print(
        f"{args.steps:,} steps driven in {driving_s:.1f} s "
        f"({args.task}, seed {args.seed}, {args.backend})"
    )
    print(
        f"drive: {size / 1e6:.2f} MB ({len(drive.episode_rewards)} steps of the running "
        f"episode), written in {write_s * 1e3:.0f} ms"
    )
    print(f"restore: {restore_s:.2f} s (a fresh SUMO start and the replay of every step)")
    print(f"after the restore, the next 200 steps: {'identical' if same else 'DIFFERENT'}")
    if args.checkpoint is not None:
        vehicle_files = sum(
            p.stat().st_size for p in args.checkpoint.iterdir() if p.suffix in (".pt", ".json")
        )
        vehicles = len(list(args.checkpoint.glob("*.json")))
        per_vehicle = vehicle_files / max(vehicles, 1)
        print(
            f"a vehicle's checkpoint in {args.checkpoint}: {per_vehicle / 1e6:.1f} MB; "
            f"the drive adds {100 * size / per_vehicle:.1f}%"
        )
    return 0 if same else 1


def drive_steps_on(env: IntersectionEnv, steps: int = 200) -> list[np.ndarray]:
    """The observations of ``steps`` more steps of full throttle from where ``env`` stands."""
    observations = []
    for _ in range(steps):
        observation, _, terminated, truncated, _ = env.step(np.ones(1, np.float32))
        if terminated or truncated:  # a new ego in the flowing traffic, as training does
            observation, _ = env.reset()
        observations.append(observation)
    return observations


if __name__ == "__main__":
    sys.exit(main())
