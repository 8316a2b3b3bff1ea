"""Checkpoints of an agent: what they hold, atomic writes, ``weights_only`` loads, and the
checks that refuse a file of another agent before anything is changed."""

from __future__ import annotations

import io
import os
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any, Self

import numpy as np
import torch
from gymnasium import spaces

from frl.agents.config import EXECUTION_FIELDS, DDPGConfig
from frl.agents.noise import generator_state, set_generator_state
from frl.agents.observations import space_from_record
from frl.agents.retired import RetiredOptionError
from frl.fileio import atomic_write

CHECKPOINT_FORMAT = "frl.agents.ddpg"
CHECKPOINT_VERSION = 1


class CheckpointError(ValueError):
    """A file is not a readable checkpoint of this format and version."""


def _tagged(payload: dict[str, Any]) -> dict[str, Any]:
    return {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, **payload}


def checkpoint_bytes(payload: dict[str, Any]) -> bytes:
    """The bytes :func:`write_checkpoint` writes for ``payload`` (a file sent elsewhere)."""
    buffer = io.BytesIO()
    torch.save(_tagged(payload), buffer)
    return buffer.getvalue()


def write_checkpoint(payload: dict[str, Any], path: str | os.PathLike[str]) -> None:
    """Save ``payload`` tagged with format and version, atomically: a crash leaves the old
    file or the new one, never a torn one (:func:`frl.fileio.atomic_write`)."""
    with atomic_write(path) as f:
        torch.save(_tagged(payload), f)


def read_checkpoint(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Load and validate a checkpoint with ``torch.load(weights_only=True)`` on the CPU.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        CheckpointError: truncated, corrupt or foreign file, or another format version.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(path)
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises RuntimeError, UnpicklingError, EOFError, ...
        raise CheckpointError(f"{path} is not a readable checkpoint: {error}") from error
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path} is not an {CHECKPOINT_FORMAT!r} checkpoint")
    if data.get("version") != CHECKPOINT_VERSION:
        raise CheckpointError(
            f"{path} has checkpoint version {data.get('version')!r}; "
            f"this frl reads version {CHECKPOINT_VERSION}"
        )
    return data


def spaces_record(agent: Any) -> dict[str, Any]:
    """The observation and action spaces of ``agent``, as a checkpoint keeps them."""
    return {
        "obs_shape": list(agent.obs_shape),
        "obs_parts": agent.layout.record(),
        "action_shape": list(agent.scale.shape),
        "action_low": torch.from_numpy(agent.scale.low.copy()),
        "action_high": torch.from_numpy(agent.scale.high.copy()),
    }


def agent_payload(agent: Any, include_buffer: bool) -> dict[str, Any]:
    """Everything :meth:`frl.agents.DDPG.restore` needs to go on exactly: config, spaces,
    networks, optimizers, the explorer's noise and generators, the pending n-step steps,
    counters, a collision budget's multiplier and running episode (and the replay
    buffer)."""
    explorer = agent.explorer
    held = explorer.held_action
    optimizers = {
        "actor": _own_storage(agent.actor_optimizer.state_dict()),
        "critic": _own_storage(agent.critic_optimizer.state_dict()),
    }
    budget = None
    if agent.constraint is not None:
        optimizers["cost_critic"] = _own_storage(agent.constraint.optimizer.state_dict())
        budget = agent.constraint.state_dict()
    return {
        "config": agent.config.to_dict(),
        "seed": agent.seed,
        "spaces": spaces_record(agent),
        "networks": {
            name: {
                key: _own_storage(value.detach().cpu()) for key, value in net.state_dict().items()
            }
            for name, net in agent.networks.networks().items()
        },
        "optimizers": optimizers,
        "collision_budget": budget,
        "noise": explorer.noise.state_dict(),
        "driver": explorer.state_dict(),
        "n_step": agent.writer.pending.state_dict(),
        "rngs": {
            "explore": generator_state(explorer.warmup_rng),
            "buffer": generator_state(agent.buffer.rng),
        },
        "counters": {"num_env_steps": agent.num_env_steps, "num_updates": agent.num_updates},
        "warmup_action": None if held is None else torch.from_numpy(held.copy()),
        "buffer": agent.buffer.state_dict() if include_buffer else None,
    }


def _own_storage(value: Any) -> Any:
    """``value`` with every tensor that is a view into a larger block (an agent in a
    stacked update, :mod:`frl.agents.stacked`) copied out: ``torch.save`` writes a
    tensor's whole storage, which would be every vehicle's rows."""
    if isinstance(value, torch.Tensor):
        whole = value.untyped_storage().nbytes()
        return value.clone() if whole != value.numel() * value.element_size() else value
    if isinstance(value, dict):
        return {key: _own_storage(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_own_storage(item) for item in value]
    return value


def restore_agent(agent: Any, path: str | os.PathLike[str]) -> None:
    """Load a :func:`agent_payload` file into ``agent``, checked before anything changes.

    Raises:
        CheckpointError: unreadable, foreign or malformed file, or one from an agent with
            another config, other spaces or other network shapes.
    """
    data = read_checkpoint(path)
    try:
        _check_compatible(agent, data, path)
        networks = {
            f"{name}.{key}": value
            for name, saved in data["networks"].items()
            for key, value in saved.items()
        }
        agent.networks.check_state(networks)
    except (KeyError, TypeError, AttributeError, ValueError) as error:
        raise CheckpointError(f"{path}: malformed checkpoint ({error})") from error
    try:
        agent.networks.load_state_dict(networks)
        agent.actor_optimizer.load_state_dict(data["optimizers"]["actor"])
        agent.critic_optimizer.load_state_dict(data["optimizers"]["critic"])
        if agent.constraint is not None:
            agent.constraint.optimizer.load_state_dict(data["optimizers"]["cost_critic"])
            agent.constraint.load_state_dict(data["collision_budget"])
        explorer = agent.explorer
        explorer.noise.load_state_dict(data["noise"])
        explorer.load_state_dict(data.get("driver"))
        agent.writer.pending.load_state_dict(data.get("n_step", {}))
        held = data.get("warmup_action")
        explorer.held_action = None if held is None else held.numpy().astype(np.float64)
        if data["buffer"] is not None:
            agent.buffer.load_state_dict(data["buffer"])
        else:
            agent.buffer.pos = agent.buffer.size = 0
        set_generator_state(explorer.warmup_rng, data["rngs"]["explore"])
        set_generator_state(agent.buffer.rng, data["rngs"]["buffer"])
        agent.num_env_steps = int(data["counters"]["num_env_steps"])
        agent.num_updates = int(data["counters"]["num_updates"])
    except (KeyError, TypeError, AttributeError, ValueError, RuntimeError) as error:
        raise CheckpointError(f"{path}: malformed checkpoint ({error!r})") from error


def load_agent(
    cls: Any, path: str | os.PathLike[str], observation_space: Any, action_space: Any,
    device: Any,
) -> Any:  # fmt: skip
    """``cls`` (the agent class) built with the checkpoint's config and seed, then restored;
    spaces left out (None) are rebuilt from the file (the observation bounds unbounded)."""
    data = read_checkpoint(path)
    config = saved_config(data, path)
    try:
        seed = int(data["seed"])
    except (KeyError, TypeError, ValueError) as error:
        raise CheckpointError(f"{path}: malformed checkpoint ({error!r})") from error
    if observation_space is None or action_space is None:
        saved_observation, saved_action = spaces_of(data, path)
        observation_space = observation_space or saved_observation
        action_space = action_space or saved_action
    agent = cls(observation_space, action_space, config, seed=seed, device=device)
    restore_agent(agent, path)
    return agent


def saved_config(data: dict[str, Any], path: str | os.PathLike[str]) -> DDPGConfig:
    """The config a checkpoint was written with (retired options refused in one line)."""
    try:
        return DDPGConfig.from_dict(data["config"])
    except RetiredOptionError as error:
        raise CheckpointError(f"{path}: {error}") from None
    except (KeyError, TypeError, ValueError) as error:
        raise CheckpointError(f"{path}: malformed checkpoint config ({error!r})") from error


def _check_compatible(agent: Any, data: dict[str, Any], path: str | os.PathLike[str]) -> None:
    # Keys added to DDPGConfig since a checkpoint was written read as what it ran with.
    saved = saved_config(data, path).to_dict()
    mine = agent.config.to_dict()
    differing = sorted(
        k
        for k in set(saved) | set(mine)
        if saved.get(k) != mine.get(k) and k not in EXECUTION_FIELDS
    )
    if differing:
        raise CheckpointError(f"checkpoint config differs from this agent's in {differing}")
    spaces_saved, spaces_mine = data["spaces"], spaces_record(agent)
    if spaces_saved.get("obs_parts") != spaces_mine["obs_parts"]:
        raise CheckpointError(
            f"checkpoint observation parts {spaces_saved.get('obs_parts')} != "
            f"{spaces_mine['obs_parts']}"
        )
    for key in ("obs_shape", "action_shape"):
        if list(spaces_saved[key]) != spaces_mine[key]:
            raise CheckpointError(f"checkpoint {key} {spaces_saved[key]} != {spaces_mine[key]}")
    for key in ("action_low", "action_high"):
        if not torch.equal(spaces_saved[key], spaces_mine[key]):
            raise CheckpointError(f"checkpoint {key} differs from this agent's action space")


def spaces_of(
    data: dict[str, Any], path: str | os.PathLike[str]
) -> tuple[spaces.Box | spaces.Dict, spaces.Box]:
    """The observation and action spaces a checkpoint records."""
    try:
        record = data["spaces"]
        observation = space_from_record(record["obs_shape"], record.get("obs_parts"))
        shape = tuple(record["action_shape"])
        low = record["action_low"].numpy().astype(np.float32).reshape(shape)
        high = record["action_high"].numpy().astype(np.float32).reshape(shape)
        return observation, spaces.Box(low, high, shape, dtype=np.float32)
    except (KeyError, TypeError, AttributeError, ValueError) as error:
        raise CheckpointError(f"{path}: malformed checkpoint spaces ({error!r})") from error


class class_only:
    """A classmethod that refuses to be called on an instance: ``agent.load(path)`` would
    return a new agent and leave ``agent`` as it was, silently."""

    def __init__(self, method: Callable[..., Any]) -> None:
        self.method = method
        self.__doc__ = method.__doc__

    def __get__(self, instance: object, owner: type) -> Callable[..., Any]:
        if instance is not None:
            name = self.method.__name__
            raise TypeError(
                f"{owner.__name__}.{name} is a class method that returns a new agent: "
                f"agent = {owner.__name__}.{name}(path); to load a file into this agent, "
                "agent.restore(path)"
            )
        return types.MethodType(self.method, owner)


FilePath = str | os.PathLike[str]


class Checkpointing:
    """An agent's files: :meth:`save`, :meth:`restore`, ``from_checkpoint`` and ``load``
    (Stable-Baselines3's names), for :class:`frl.agents.DDPG`."""

    def save(self, path: FilePath, include_buffer: bool = False) -> None:
        """Write networks, optimizers, noise, counters and generators (and the buffer),
        atomically; the file loads with ``torch.load(weights_only=True)``."""
        write_checkpoint(agent_payload(self, include_buffer), path)

    def save_bytes(self) -> bytes:
        """What :meth:`save` writes without the buffer, as bytes (a model file made on
        another host)."""
        return checkpoint_bytes(agent_payload(self, include_buffer=False))

    def restore(self, path: FilePath) -> None:
        """Load a :meth:`save` file into this agent (same config and spaces): exact resume,
        with an empty buffer if none was saved. Raises ``CheckpointError``, changing
        nothing, for an unreadable or foreign file or one of another config or shapes."""
        restore_agent(self, path)

    @classmethod
    def from_checkpoint(  # a new agent with the file's config and seed, restored
        cls, path: FilePath, observation_space: spaces.Box | spaces.Dict | None = None,
        action_space: spaces.Box | None = None, device: str | torch.device = "cpu",
    ) -> Self:  # fmt: skip
        """Spaces left out are rebuilt from the file (the observation bounds unbounded)."""
        return load_agent(cls, path, observation_space, action_space, device)

    @class_only
    def load(cls, path: FilePath, device: str | torch.device = "cpu") -> Self:
        """A new agent from a :meth:`save` file or a run's ``models/*.pt``, as in SB3.
        Raises ``CheckpointError`` for an unreadable, foreign or malformed file."""
        return cls.from_checkpoint(path, device=device)
