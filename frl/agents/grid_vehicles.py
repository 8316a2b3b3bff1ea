"""The vehicles in a batch of grids, laid out in a fixed number of slots per grid.

Every network that reads a sampled batch with the vehicles encoder
(:class:`frl.agents.vehicle_encoder.VehicleSetEncoder`) needs the same vehicles; the replay
buffer finds them in NumPy when it samples the batch, where the compact storage already
holds each row's non-zeros, and attaches them to the batch's
:class:`frl.agents.sparse_linear.SparseRows`.

Each grid's vehicles fill the first of ``slots`` places, the rest are padding that a mask
leaves out. ``slots`` is the batch's largest vehicle count rounded up to a multiple of
:data:`SLOT_MULTIPLE`, so the encoder's tensors take one of a few shapes in a whole run
instead of a new one at nearly every batch: the matrix products reuse their compiled
kernels (oneDNN caches up to 1,024 shapes, about 300 MB of a vehicle process's memory
when every batch brought a new one), a captured graph can replay, and the pooling is a
plain masked sum and maximum rather than a scatter.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

SLOT_MULTIPLE = 8
"""Slots per grid are a multiple of this. A grid of the default traffic showed at most 8
vehicles in 9,000 steps (2.8 on average), so a batch nearly always takes 8 slots."""


def slots_for(most_vehicles: int) -> int:
    """The slots per grid of a batch whose fullest grid shows ``most_vehicles``."""
    return max(SLOT_MULTIPLE, -(-most_vehicles // SLOT_MULTIPLE) * SLOT_MULTIPLE)


class GridVehicles(NamedTuple):
    """The vehicles of a batch of grids, ``slots`` places per grid, found once for every
    network that reads the batch (the replay buffer attaches them to the
    :class:`SparseRows` it samples)."""

    geometry: tuple[int, int, int]
    """``(grid features, channels per cell, features after the grid)`` they were found for."""
    cell: Tensor
    """int64 [batch, slots]: each vehicle's cell (row * columns + column), in increasing
    order along a grid; 0 in a padding slot."""
    channels: Tensor
    """float32 [batch, slots, channels - 1]: its cell's other channels (speed, heading);
    0 in a padding slot."""
    present: Tensor
    """float32 [batch, slots]: 1 where a slot holds a vehicle, 0 where it is padding."""
    extra: Tensor | None
    """float32 [batch, extra]: the features after the grid; None without any."""

    def to(self, device: torch.device | str, non_blocking: bool = True) -> GridVehicles:
        extra = None if self.extra is None else self.extra.to(device, non_blocking=non_blocking)
        return GridVehicles(
            self.geometry,
            self.cell.to(device, non_blocking=non_blocking),
            self.channels.to(device, non_blocking=non_blocking),
            self.present.to(device, non_blocking=non_blocking),
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
    ``indices`` increasing along each row, and ``values``), each row's in cell order. A
    cell's channels that are zero are not stored; each is looked up by its key
    (row * features + index), which increases along the rows."""
    grid_features, width, extra_features = geometry
    batch = len(counts)
    row_ids = np.repeat(np.arange(batch, dtype=np.int64), counts)
    indices = indices.astype(np.int64, copy=False)
    keys = row_ids * num_features + indices
    occupied = (indices % width == width - 1) & (values > 0) & (indices < grid_features)
    occupied = np.flatnonzero(occupied)
    wanted = keys[occupied, None] - (width - 1) + np.arange(width - 1)
    found = np.minimum(np.searchsorted(keys, wanted), max(keys.size - 1, 0))
    channels = np.where(keys[found] == wanted, values[found], np.float32(0.0))
    # Each vehicle's slot is its rank within its grid (the rows come sorted).
    vehicle_rows = row_ids[occupied]
    per_row = np.bincount(vehicle_rows, minlength=batch)
    slot = np.arange(occupied.size) - (np.cumsum(per_row) - per_row)[vehicle_rows]
    slots = slots_for(int(per_row.max(initial=0)))
    cell = np.zeros((batch, slots), np.int64)
    cell[vehicle_rows, slot] = indices[occupied] // width
    padded = np.zeros((batch, slots, width - 1), np.float32)
    padded[vehicle_rows, slot] = channels
    present = np.zeros((batch, slots), np.float32)
    present[vehicle_rows, slot] = 1.0
    extra = None
    if extra_features:
        stored = np.flatnonzero(indices >= grid_features)
        extra = np.zeros((batch, extra_features), np.float32)
        extra[row_ids[stored], indices[stored] - grid_features] = values[stored]
    return GridVehicles(
        geometry,
        torch.from_numpy(cell),
        torch.from_numpy(padded),
        torch.from_numpy(present),
        None if extra is None else torch.from_numpy(extra),
    )
