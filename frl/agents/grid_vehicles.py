"""The vehicles in a batch of grids stored as compressed rows, found once per batch.

Every network that reads a sampled batch with the vehicles encoder
(:class:`frl.agents.vehicle_encoder.VehicleSetEncoder`) needs the same list of occupied
cells; the replay buffer finds it in NumPy when it samples the batch, where the compact
storage already holds each row's non-zeros, and attaches it to the batch's
:class:`frl.agents.sparse_linear.SparseRows`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor


class GridVehicles(NamedTuple):
    """The vehicles of a batch of grids, found once for every network that reads the batch
    (the replay buffer attaches them to the :class:`SparseRows` it samples)."""

    geometry: tuple[int, int, int]
    """``(grid features, channels per cell, features after the grid)`` they were found for."""
    sample: Tensor
    """int64 [n]: each vehicle's row in the batch, in increasing order."""
    cell: Tensor
    """int64 [n]: its cell (row * columns + column)."""
    channels: Tensor
    """float32 [n, channels - 1]: its cell's other channels (speed, heading)."""
    extra: Tensor | None
    """float32 [batch, extra]: the features after the grid; None without any."""

    def to(self, device: torch.device | str, non_blocking: bool = True) -> GridVehicles:
        extra = None if self.extra is None else self.extra.to(device, non_blocking=non_blocking)
        return GridVehicles(
            self.geometry,
            self.sample.to(device, non_blocking=non_blocking),
            self.cell.to(device, non_blocking=non_blocking),
            self.channels.to(device, non_blocking=non_blocking),
            extra,
        )


def find_vehicles(
    indices: np.ndarray,
    values: np.ndarray,
    counts: np.ndarray,
    num_features: int,
    geometry: tuple[int, int, int],
) -> GridVehicles:
    """The vehicles of compressed rows (``counts[i]`` non-zeros of row ``i``, their
    ``indices`` increasing along each row, and ``values``), in the order of the dense
    path: by row, then cell. A cell's channels that are zero are not stored; each is looked
    up by its key (row * features + index), which increases along the rows."""
    grid_features, width, extra_features = geometry
    row_ids = np.repeat(np.arange(len(counts), dtype=np.int64), counts)
    indices = indices.astype(np.int64, copy=False)
    keys = row_ids * num_features + indices
    occupied = (indices % width == width - 1) & (values > 0) & (indices < grid_features)
    occupied = np.flatnonzero(occupied)
    wanted = keys[occupied, None] - (width - 1) + np.arange(width - 1)
    found = np.minimum(np.searchsorted(keys, wanted), max(keys.size - 1, 0))
    channels = np.where(keys[found] == wanted, values[found], np.float32(0.0))
    extra = None
    if extra_features:
        stored = np.flatnonzero(indices >= grid_features)
        extra = np.zeros((len(counts), extra_features), np.float32)
        extra[row_ids[stored], indices[stored] - grid_features] = values[stored]
    return GridVehicles(
        geometry,
        torch.from_numpy(row_ids[occupied]),
        torch.from_numpy(indices[occupied] // width),
        torch.from_numpy(np.ascontiguousarray(channels, dtype=np.float32)),
        None if extra is None else torch.from_numpy(extra),
    )
