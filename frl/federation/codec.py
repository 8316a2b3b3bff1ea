"""What crosses the wire between a vehicle and the roadside unit, without pickle.

A vehicle's specification, its updates and model parameters as plain parts: JSON-able
headers and numpy arrays. Two carriers move the same parts:

- frames (:mod:`frl.federation.frames`) between the roadside unit's side and a vehicle
  process: over a worker pipe (``federation.backend=processes``) or a Flower vehicle's
  Unix socket;
- Flower messages (:mod:`frl.flower.messages`) between a ServerApp and its ClientApps.

Nothing here imports Flower, so the vehicle process does not need it.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
from torch import Tensor

from frl.agents import DDPGConfig
from frl.envs import EnvConfig, RewardConfig
from frl.episodes import EpisodeRecord
from frl.federation.client import ClientSpec, LocalUpdate
from frl.federation.frames import Arrays, prefixed, unprefixed

PARAMETER_PREFIX = "param/"
LOSS_PREFIX = "loss/"
ACTION_PREFIX = "action/"
STEP_REWARDS = "step_rewards"


# ------------------------------------------------------------------ client specs
def spec_to_json(spec: ClientSpec) -> str:
    """A :class:`ClientSpec` as JSON text (the vehicle builds its env and agent from it)."""
    data = dataclasses.asdict(spec)
    data["agent"] = spec.agent.to_dict()
    return json.dumps(data, sort_keys=True)


def spec_from_json(text: str) -> ClientSpec:
    """Inverse of :func:`spec_to_json`; unknown or missing fields raise ``TypeError``."""
    data = json.loads(text)
    return ClientSpec(
        env=EnvConfig.from_dict(data.pop("env")),
        reward=RewardConfig.from_dict(data.pop("reward")),
        agent=DDPGConfig.from_dict(data.pop("agent")),
        **data,
    )


# ------------------------------------------------------------------ parameters
def tensors_to_arrays(parameters: Mapping[str, Tensor]) -> Arrays:
    """CPU numpy copies of a parameter dict, keys unchanged."""
    return {key: value.detach().cpu().numpy().copy() for key, value in parameters.items()}


def arrays_to_tensors(arrays: Mapping[str, np.ndarray], copy: bool = True) -> dict[str, Tensor]:
    """Tensors of a parameter dict: copies, or with ``copy=False`` tensors that share the
    arrays' memory (for arrays just decoded from a frame, which nothing else holds; a
    read-only array is still copied)."""
    return {
        key: torch.from_numpy(value if not copy and value.flags.writeable else value.copy())
        for key, value in arrays.items()
    }


# ------------------------------------------------------------------ updates
def update_to_parts(update: LocalUpdate) -> tuple[Arrays | None, Arrays, dict[str, Any]]:
    """``(parameters, series, summary)`` of a :class:`LocalUpdate`.

    ``parameters`` is the model upload (or None), ``series`` the per-step rewards,
    losses and actions, ``summary`` the scalars and episode records as plain JSON types.
    """
    parameters = None if update.parameters is None else tensors_to_arrays(update.parameters)
    series = {STEP_REWARDS: np.asarray(update.step_rewards, np.float32)}
    series.update(prefixed(update.losses, LOSS_PREFIX))
    series.update(prefixed(update.actions, ACTION_PREFIX))
    summary = {
        "client": update.client,
        "num_steps": update.num_steps,
        "total_steps": update.total_steps,
        "cpu_time_s": update.cpu_time_s,
        "wall_time_s": update.wall_time_s,
        "episodes": [dataclasses.asdict(e) for e in update.episodes],
    }
    return parameters, series, summary


def update_from_parts(
    parameters: Mapping[str, np.ndarray] | None,
    series: Mapping[str, np.ndarray],
    summary: Mapping[str, Any],
    copy: bool = True,
) -> LocalUpdate:
    """Inverse of :func:`update_to_parts`; with ``copy=False`` the parameters share the
    arrays' memory (:func:`arrays_to_tensors`)."""
    return LocalUpdate(
        client=str(summary["client"]),
        num_steps=int(summary["num_steps"]),
        total_steps=int(summary["total_steps"]),
        step_rewards=np.asarray(series[STEP_REWARDS], np.float32),
        episodes=[EpisodeRecord(**e) for e in summary["episodes"]],
        losses={k: np.asarray(v, np.float32) for k, v in unprefixed(series, LOSS_PREFIX).items()},
        actions={
            k: np.asarray(v, np.float32) for k, v in unprefixed(series, ACTION_PREFIX).items()
        },
        parameters=None if parameters is None else arrays_to_tensors(parameters, copy=copy),
        cpu_time_s=float(summary["cpu_time_s"]),
        wall_time_s=float(summary.get("wall_time_s", 0.0)),
    )
