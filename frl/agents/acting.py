"""The actor on one observation: the forward pass behind every environment step.

Collection runs the actor once per step, at batch 1. The update's machinery does not
suit that: building compressed rows and finding the vehicles in them takes a dozen small
torch calls, and bf16 autocast, the update's precision, costs more than it saves on one
row. Measured at one thread (``benchmarks/collection.py``): 0.75 ms per action that way,
against about 0.1 ms for the arithmetic of the actor's layers. So acting here finds the
grid's vehicles in NumPy, runs the actor's own layers on them in float32 and, on the CPU,
pools the vehicles in NumPy, with nothing else in between (0.33 ms a forward pass in a
training step, measured the same way). What is left is mostly reading the 1.9 MB of
weights, which SUMO and the updates push out of the cache: the 512 x 512 layer takes
31 us at batch 1 with its weights in cache and 112 us without. :class:`ActionScale`
maps the actor's [-1, 1] to the action space; :func:`policy_actions` acts on a batch.
Many agents' actors act on one observation each in one batched pass
(:meth:`frl.agents.stacked.StackedUpdate.policy_actions`) through
:func:`stacked_actor_inputs` and :func:`action_on_inputs`.

In float32 the numbers are exactly :meth:`frl.agents.Actor.forward`'s on the same
observation: the same layers and kernels on tensors of the same shapes. An agent whose
updates run in bf16 acts in float32 all the same: acting never uses autocast.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from gymnasium import spaces
from torch import Tensor

from frl.agents.grid_vehicles import GridVehicles, slots_for
from frl.agents.networks import Actor
from frl.agents.sparse_linear import SparseRows
from frl.agents.vehicle_encoder import VehicleSetEncoder


def actor_action(actor: Actor, flat_observation: np.ndarray, sparse: bool) -> np.ndarray:
    """The actor's action, in [-1, 1] (float64 ``[action_dim]``), on one flat observation.

    Args:
        actor: the network, on any device.
        flat_observation: float32 ``[features]``, as the agent stores it.
        sparse: whether a flat (encoder-less) actor reads compressed rows
            (``DDPGConfig.use_sparse``); the vehicles encoder reads the grid either way.
    """
    device = actor.layers[-1].weight.device
    with torch.inference_mode():
        x = _actor_input(actor, flat_observation, sparse, device)
        first, *hidden, last = actor.layers
        x = torch.relu_(first(x))
        for layer in hidden:
            x = torch.relu_(F.linear(x, layer.weight, layer.bias))
        preactivation = F.linear(x, last.weight, last.bias)
        if actor.output == "clip":
            action = preactivation.clamp(-1.0, 1.0)
        else:
            action = torch.tanh(preactivation)
        return action[0].to("cpu", torch.float64).numpy()


def policy_actions(actor: Actor, flat_batch: np.ndarray, sparse: bool) -> np.ndarray:
    """The actor's actions in [-1, 1] (float64 ``[batch, action_dim]``) on a batch of flat
    observations, in float32 as acting on one."""
    flat = torch.from_numpy(flat_batch).to(actor.layers[-1].weight.device)
    with torch.no_grad():
        actions = actor(SparseRows.from_dense(flat) if sparse else flat)
    return actions.double().cpu().numpy()


def stacked_actor_inputs(
    actor: Actor, flats: Sequence[np.ndarray], device: torch.device
) -> list[Tensor]:
    """What each of several actors of ``actor``'s shape reads for its one flat observation,
    stacked (one row each, a batch of one in every row): for the vehicles encoder, each
    grid's vehicles found in NumPy (:func:`vehicles_of_one`) in as many slots as the
    fullest grid needs, and the features after the grid; else the dense row."""
    encoder = actor.encoder
    if not isinstance(encoder, VehicleSetEncoder):
        return [torch.from_numpy(np.stack([flat.reshape(1, -1) for flat in flats])).to(device)]
    found = [vehicles_of_one(encoder, flat) for flat in flats]
    slots = max(cell.shape[1] for cell, _, _ in found)
    cells = np.zeros((len(flats), 1, slots), np.int64)
    channels = np.zeros((len(flats), 1, slots, encoder.grid_shape[2] - 1), np.float32)
    present = np.zeros((len(flats), 1, slots), np.float32)
    for k, (cell, found_channels, found_present) in enumerate(found):
        width = cell.shape[1]
        cells[k, :, :width], channels[k, :, :width] = cell, found_channels
        present[k, :, :width] = found_present
    arrays = [cells, channels, present]
    if encoder.extra_features:
        arrays.append(np.stack([flat[None, encoder.grid_features :] for flat in flats]))
    return [torch.from_numpy(array).to(device) for array in arrays]


def action_on_inputs(actor: Actor, *inputs: Tensor) -> Tensor:
    """The actor's action ([1, action_dim]) on one row of :func:`stacked_actor_inputs`:
    what ``torch.func.vmap`` maps over many actors' parameters."""
    encoder = actor.encoder
    if not isinstance(encoder, VehicleSetEncoder):
        return actor(inputs[0])
    cell, channels, present, *extra = inputs
    device = cell.device
    rows = SparseRows(
        torch.empty(0, dtype=torch.int64, device=device),
        torch.empty(0, dtype=torch.float32, device=device),
        torch.zeros(1, dtype=torch.int64, device=device),
        encoder.grid_features + encoder.extra_features,
        vehicles=GridVehicles(
            encoder.geometry, cell, channels, present, extra[0] if extra else None
        ),
    )
    return actor(rows)


def _actor_input(
    actor: Actor, flat: np.ndarray, sparse: bool, device: torch.device
) -> Tensor | SparseRows:
    """What the actor's first layer reads: the encoding, compressed rows or a dense row."""
    if isinstance(actor.encoder, VehicleSetEncoder):
        return encode_one(actor.encoder, flat, device)
    if sparse:
        return SparseRows.from_numpy_row(flat).to(device)
    return torch.from_numpy(flat.reshape(1, -1)).to(device)


def vehicles_of_one(
    encoder: VehicleSetEncoder, flat: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The vehicles of one flat observation as the encoder lays out a batch of one:
    ``cell`` int64 [1, slots] (in cell order), ``channels`` float32 [1, slots, C - 1] and
    ``present`` float32 [1, slots], found in NumPy."""
    rows, columns, channels = encoder.grid_shape
    grid = flat[: encoder.grid_features].reshape(rows * columns, channels)
    cells = np.flatnonzero(grid[:, -1] > 0)
    slots = slots_for(cells.size)
    cell = np.zeros((1, slots), np.int64)
    cell[0, : cells.size] = cells
    found = np.zeros((1, slots, channels - 1), np.float32)
    # + 0 turns a stored -0.0 into 0.0, as the compressed rows (which drop it) would.
    found[0, : cells.size] = grid[cells, :-1] + np.float32(0.0)
    present = np.zeros((1, slots), np.float32)
    present[0, : cells.size] = 1.0
    return cell, found, present


def encode_one(encoder: VehicleSetEncoder, flat: np.ndarray, device: torch.device) -> Tensor:
    """``encoder(flat[None])`` for one flat observation, its vehicles found in NumPy; on
    the CPU they are pooled in NumPy too."""
    cell, found, present = vehicles_of_one(encoder, flat)
    if encoder.positions.device.type != "cpu":
        # On a GPU the slots go over as they are: finding the vehicles there would read
        # their count back to the host in the middle of the forward pass.
        extra = flat[None, encoder.grid_features :] if encoder.extra_features else None
        tensors = [torch.from_numpy(a).to(device) for a in (cell, found, present)]
        return encoder.encode(
            *tensors, None if extra is None else torch.from_numpy(extra).to(device)
        )
    # On the CPU the vehicles go through the encoder's own MLP and the pooling is done in
    # NumPy: a dozen torch calls fewer. The vehicles sit in slots, as the encoder lays out a
    # batch of one (a matrix product gives the same numbers only on the same shape); a sum
    # over axis 0 from zero adds them in order, as the encoder's sum over a grid's slots
    # does, and a max is exact.
    count = int(present.sum())
    vehicles = np.zeros((cell.shape[1], 2 + found.shape[2]), np.float32)
    vehicles[:count, :2] = encoder.positions.numpy()[cell[0, :count]]
    vehicles[:count, 2:] = found[0, :count]
    vehicles_out = encoder.embed(torch.from_numpy(vehicles)).detach().numpy()[:count]
    pooled = [
        np.add.reduce(vehicles_out, axis=0, initial=0.0),
        np.maximum.reduce(vehicles_out, axis=0, initial=0.0),
    ]
    if encoder.extra_features:
        pooled.append(flat[encoder.grid_features :])
    return torch.from_numpy(np.concatenate(pooled)[None])


class ActionScale:
    """Between a Box action space's bounds and the actor's [-1, 1]."""

    def __init__(self, space: spaces.Box) -> None:
        if not isinstance(space, spaces.Box):
            raise TypeError(f"action_space must be a gymnasium Box, got {space}")
        if not (np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))):
            raise ValueError("action_space bounds must be finite")
        self.shape: tuple[int, ...] = tuple(space.shape)
        self.low = space.low.astype(np.float64).reshape(-1)
        self.high = space.high.astype(np.float64).reshape(-1)

    def to_unit(self, action: Any, batch: bool = False) -> np.ndarray:
        """An env action as the actor's, clipped to [-1, 1] (float64, flat); with ``batch``
        a batch of them, one flat row each."""
        action = np.asarray(action, dtype=np.float64)
        action = action.reshape(len(action), -1) if batch else action.reshape(-1)
        return np.clip(2.0 * (action - self.low) / (self.high - self.low) - 1.0, -1.0, 1.0)

    def from_unit(self, action: np.ndarray) -> np.ndarray:
        """The actor's action in the env's units, float32 within the bounds."""
        env_action = self.low + (action + 1.0) * 0.5 * (self.high - self.low)
        low, high = self.low.astype(np.float32), self.high.astype(np.float32)
        return np.clip(env_action.astype(np.float32), low, high).reshape(self.shape)


class Acting:
    """An agent's actions, exploring (the explorer's) and deterministic, on one observation
    or a batch, for :class:`frl.agents.DDPG`."""

    actor: Actor
    explorer: Any
    teacher: Any
    layout: Any
    scale: ActionScale
    obs_dim: int
    obs_shape: tuple[int, ...]
    action_dim: int
    sparse: bool
    num_env_steps: int
    last_policy_action: np.ndarray

    def _policy_action(self, flat: Any) -> np.ndarray:
        """The deterministic policy's normalised action on one flat observation."""
        flat = np.asarray(flat, dtype=np.float32).reshape(-1)
        if flat.size != self.obs_dim:
            raise ValueError(f"expected an observation of shape {self.obs_shape}")
        return actor_action(self.actor, flat, self.sparse)

    def act(
        self, obs: Any, explore: bool = True, policy_action: np.ndarray | None = None
    ) -> np.ndarray:
        """Action for one observation, float32 within the bounds: with ``explore`` the
        explorer's (held uniform warm-up actions, then the policy's plus noise), without
        it the deterministic policy's. In an episode the teacher drives
        (``DDPGConfig.guide_drives``), exploring takes the teacher's action plus the noise.
        ``policy_action``: the policy's normalised action on ``obs``, already computed
        (with other agents', :meth:`frl.agents.stacked.StackedUpdate.policy_actions`);
        None: the actor computes it here."""
        if explore and self.explorer.in_warmup(self.num_env_steps):
            self.last_policy_action = np.full(self.action_dim, np.nan)
            return self.scale.from_unit(self.explorer.warmup_action())
        if explore and self.explorer.teacher_at_wheel():
            self.last_policy_action = np.full(self.action_dim, np.nan)
            flat = np.asarray(self.layout.flat(obs), dtype=np.float32).reshape(-1)
            return self.scale.from_unit(self.explorer.noisy(self.teacher(flat)))
        if policy_action is None:
            action = self._policy_action(self.layout.flat(obs))
        else:
            action = np.asarray(policy_action, dtype=np.float64).reshape(-1)
            if action.size != self.action_dim:
                raise ValueError(
                    f"policy_action has {action.size} values; this agent's actions have "
                    f"{self.action_dim}"
                )
        self.last_policy_action = action
        return self.scale.from_unit(self.explorer.noisy(action) if explore else action)

    def predict(
        self, observation: Any, state: Any = None, episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:  # fmt: skip
        """``(action, None)`` for one observation or a batch (Stable-Baselines3's
        signature; no recurrent state). ``deterministic=False`` adds what the exploration
        noise would add next, drawn from a copy: ``predict`` never changes the agent. A
        ``ValueError`` names an observation of neither the space's shape nor a batch's."""
        batch, batched = self.layout.flat_batch(observation)
        if batched:
            actions = policy_actions(self.actor, batch, self.sparse)
        else:
            actions = self._policy_action(batch[0])[None]
        if not deterministic:
            actions = self.explorer.noisy_copies(actions)
        env_actions = np.stack([self.scale.from_unit(action) for action in actions])
        return (env_actions if batched else env_actions[0]), None
