"""A vehicle's drive at a checkpoint: where its simulation stands and the episode in progress.

Each vehicle writes it beside its agent in every committed round (``{name}.drive.npz``),
so a resume puts the environment back exactly where it was at the commit
(:meth:`frl.envs.IntersectionEnv.restore` replays the SUMO seed and the commands since
SUMO last started) and the episode that was running goes on: a run killed and resumed
ends as the run never killed. One ``.npz`` read with ``allow_pickle=False``: the fields
as JSON text, the speed commands and the running episode as arrays.
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from frl.envs import EnvSnapshot
from frl.fileio import write_bytes_atomic

SNAPSHOT_SUFFIX = ".drive.npz"


@dataclass
class VehicleSnapshot:
    """What :class:`frl.federation.VehicleClient` needs to go on driving after a resume."""

    snapshot: EnvSnapshot | None
    """The environment; None where no simulation runs (before the first step, or after a
    test drive): SUMO then starts afresh at the next step, as it would have."""
    observation: np.ndarray | None
    """The observation the next step acts on (flattened), None at an episode's end."""
    episode_observations: np.ndarray
    """float32 (steps, observation size): the running episode's observations, flattened."""
    episode_actions: np.ndarray
    """(steps, action size): its actions, in the dtype the environment was given them."""
    episode_rewards: list[float]
    episode_speeds: list[float]


def snapshot_path(directory: str | os.PathLike[str], client_name: str) -> Path:
    """Where ``client_name`` writes its drive in a round's checkpoint ``directory``."""
    return Path(directory) / f"{client_name}{SNAPSHOT_SUFFIX}"


def write_vehicle_snapshot(path: str | os.PathLike[str], drive: VehicleSnapshot) -> None:
    """Write ``drive`` to ``path`` atomically."""
    fields: dict[str, Any] = {
        "episode_rewards": drive.episode_rewards,  # JSON floats read back bit for bit
        "episode_speeds": drive.episode_speeds,
        "environment": None,
    }
    arrays = {
        "episode_observations": drive.episode_observations,
        "episode_actions": drive.episode_actions,
    }
    if drive.snapshot is not None:
        fields["environment"], arrays["speed_commands"] = drive.snapshot.to_record()
    if drive.observation is not None:
        arrays["observation"] = drive.observation
    buffer = io.BytesIO()
    np.savez_compressed(buffer, fields=np.array(json.dumps(fields)), **arrays)
    write_bytes_atomic(path, buffer.getvalue())


def read_vehicle_snapshot(path: str | os.PathLike[str]) -> VehicleSnapshot:
    """The drive :func:`write_vehicle_snapshot` wrote to ``path``."""
    with np.load(path, allow_pickle=False) as data:
        fields = json.loads(str(data["fields"]))
        environment = fields["environment"]
        return VehicleSnapshot(
            snapshot=(
                None
                if environment is None
                else EnvSnapshot.from_record(environment, data["speed_commands"])
            ),
            observation=data.get("observation"),
            episode_observations=data["episode_observations"],
            episode_actions=data["episode_actions"],
            episode_rewards=[float(r) for r in fields["episode_rewards"]],
            episode_speeds=[float(v) for v in fields["episode_speeds"]],
        )
