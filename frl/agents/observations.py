"""How the agent reads its observation space: a Box, or a Dict of Boxes (a grid and more).

Networks and the replay buffer work on one flat float32 vector per observation. A Box
observation is flattened as it always was. A Dict observation (for example the
intersection's ``route_observation``: ``{"grid": ..., "route": ...}``) becomes its parts'
flat values one after the other, in the Dict's key order, and the part named ``grid``,
which comes first, is what the vehicles encoder reads as the grid; the other parts reach
the networks as plain features. A teacher (:attr:`frl.agents.DDPGConfig.guide`) is
asked on the observation as the environment gave it, rebuilt from the flat vector.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces

GRID_KEY = "grid"
"""The Dict part that the vehicles encoder reads as the grid."""


class ObservationLayout:
    """The flat layout of a Box or Dict-of-Boxes observation space.

    Raises:
        TypeError: another kind of space, or a Dict with a part that is not a Box.
        ValueError: a Dict whose ``grid`` part is not its first.
    """

    def __init__(self, space: spaces.Space[Any]) -> None:
        if isinstance(space, spaces.Box):
            self.parts: dict[str, tuple[int, ...]] | None = None
            self.shape: tuple[int, ...] = tuple(space.shape)
            self.grid_shape = self.shape
        elif isinstance(space, spaces.Dict):
            parts = {}
            for key, part in space.spaces.items():
                if not isinstance(part, spaces.Box):
                    raise TypeError(f"observation part {key!r} must be a gymnasium Box, got {part}")
                parts[key] = tuple(part.shape)
            if GRID_KEY in parts and next(iter(parts)) != GRID_KEY:
                raise ValueError(f"the observation's {GRID_KEY!r} part must come first")
            self.parts = parts
            sizes = [int(np.prod(shape, dtype=np.int64)) for shape in parts.values()]
            self.shape = (sum(sizes),)
            self.grid_shape = parts.get(GRID_KEY, self.shape)
        else:
            raise TypeError(f"observation_space must be a gymnasium Box or Dict, got {space}")
        self.num_features = int(np.prod(self.shape, dtype=np.int64))
        self.grid_features = int(np.prod(self.grid_shape, dtype=np.int64))

    @property
    def extra_features(self) -> int:
        """Features after the grid (a Dict's other parts); 0 for a Box."""
        return self.num_features - self.grid_features

    def flat(self, observation: Any) -> Any:
        """One observation as the agent stores it: a Box's as it is (flattened where it
        is stored), a Dict's as one flat float32 vector."""
        if self.parts is None:
            return observation
        if not isinstance(observation, Mapping) or set(observation) != set(self.parts):
            raise ValueError(f"expected an observation with the parts {sorted(self.parts)}")
        values = []
        for key, shape in self.parts.items():
            value = np.asarray(observation[key], dtype=np.float32)
            if value.shape != shape:
                raise ValueError(
                    f"observation part {key!r}: expected shape {shape}, got {value.shape}"
                )
            values.append(value.reshape(-1))
        return np.concatenate(values)

    def flat_batch(self, observation: Any) -> tuple[np.ndarray, bool]:
        """``(rows, batched)``: one observation or a batch of them as float32 rows
        ``(N, num_features)``, and whether a batch was given.

        Raises:
            ValueError: neither one observation of the space nor a batch of them.
        """
        if self.parts is None:
            obs = np.asarray(observation, dtype=np.float32)
            if obs.shape == self.shape:
                return obs.reshape(1, self.num_features), False
            if obs.ndim == len(self.shape) + 1 and obs.shape[1:] == self.shape:
                return obs.reshape(len(obs), self.num_features), True
            raise ValueError(
                f"expected an observation of shape {self.shape} or a batch of them "
                f"(N, {', '.join(map(str, self.shape))}), got {obs.shape}"
            )
        if not isinstance(observation, Mapping) or set(observation) != set(self.parts):
            raise ValueError(f"expected an observation with the parts {sorted(self.parts)}")
        arrays = {key: np.asarray(observation[key], np.float32) for key in self.parts}
        first_key, first_shape = next(iter(self.parts.items()))
        batched = arrays[first_key].shape != first_shape
        rows = []
        for key, shape in self.parts.items():
            value = arrays[key]
            expected = (value.shape[0], *shape) if batched and value.ndim else shape
            if value.shape != expected:
                raise ValueError(
                    f"observation part {key!r}: expected shape {shape} or a batch of them, "
                    f"got {value.shape}"
                )
            rows.append(value.reshape(len(value) if batched else 1, -1))
        if len({len(r) for r in rows}) != 1:
            raise ValueError("the observation's parts hold batches of different lengths")
        return np.concatenate(rows, axis=1), batched

    def unflat(self, flat: Any) -> Any:
        """The observation as the environment gave it, from :meth:`flat`'s form."""
        if self.parts is None:
            return flat
        vector = np.asarray(flat, dtype=np.float32).reshape(-1)
        observation, start = {}, 0
        for key, shape in self.parts.items():
            size = int(np.prod(shape, dtype=np.int64))
            observation[key] = vector[start : start + size].reshape(shape)
            start += size
        return observation

    def record(self) -> dict[str, list[int]] | None:
        """The Dict's parts and their shapes, for a checkpoint (None for a Box)."""
        return None if self.parts is None else {k: list(v) for k, v in self.parts.items()}


def space_from_record(shape: list[int], parts: Mapping[str, list[int]] | None) -> spaces.Space[Any]:
    """An unbounded observation space with a checkpoint's shape (a Box) or parts (a Dict)."""
    if parts is None:
        return spaces.Box(-np.inf, np.inf, tuple(shape), dtype=np.float32)
    return spaces.Dict(
        {
            key: spaces.Box(-np.inf, np.inf, tuple(part), dtype=np.float32)
            for key, part in parts.items()
        }
    )
