"""An encoder that reads the occupancy grid as the set of vehicles it shows.

The paper's grid is one-hot in space: a car one cell over lights other inputs, so an MLP
on the flat grid must learn what each cell means separately, from the few dozen
conflicts a vehicle meets in 10,000 steps. This encoder turns every occupied cell into
one vehicle, ``[row, column, channels...]`` with the cell's position as two numbers in
[-1, 1], runs one small MLP shared by all vehicles, and pools over the vehicles of each
observation (sum and max). Positions become continuous inputs that the network can
interpolate between, as in highway-env's ``Kinematics`` observation with a
permutation-invariant encoder, while the observation stays the paper's grid: nothing is
read that the grid does not hold. Features after the grid (the route of the env's
``route_observation``) pass through to the MLP beside the pooled vehicles.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from frl.agents.grid_vehicles import GridVehicles, find_vehicles, slots_for
from frl.agents.sparse_linear import SparseRows


class VehicleSetEncoder(nn.Module):
    """Flat grids ``[batch, H * W * C (+ extra)]`` -> ``[batch, 2 * width (+ extra)]``:
    the vehicles' sum and max pooling, then the extra features as they are.

    Reads dense batches or :class:`SparseRows` (the replay buffer's compact form, whose
    rows list their non-zeros in increasing feature order): the same vehicles, in the
    same order, from either. A sampled batch carries its vehicles, found once in NumPy by
    the replay buffer (:mod:`frl.agents.grid_vehicles`), so the five networks that read it
    in an update do not each find them again. Each grid's vehicles sit in a fixed number of
    slots with a mask, so the shapes stay the same from batch to batch.

    Args:
        grid_shape: ``(H, W, C)``; the last channel is 1 in occupied cells, 0 elsewhere
            (the Eq. (1) grid's third channel). The other ``C - 1`` channels are the
            vehicle's features (speed and relative heading).
        width: output width of the per-vehicle MLP (two layers, ReLU).
        extra_features: features that follow the grid in each row (0: the grid alone).
    """

    def __init__(self, grid_shape: Sequence[int], width: int = 64, extra_features: int = 0) -> None:
        super().__init__()
        if len(grid_shape) != 3 or min(grid_shape) < 1 or grid_shape[2] < 2:
            raise ValueError(
                "the vehicles encoder reads a 3-D grid (rows, columns, channels) whose last "
                f"channel marks occupied cells; got an observation of shape {tuple(grid_shape)}"
            )
        rows, columns, channels = (int(n) for n in grid_shape)
        self.grid_shape = (rows, columns, channels)
        self.width = width
        self.grid_features = rows * columns * channels
        self.extra_features = int(extra_features)
        self.out_features = 2 * width + self.extra_features
        self.geometry = (self.grid_features, channels, self.extra_features)
        """What :func:`find_vehicles` needs to find this encoder's vehicles."""
        self.layers = nn.ModuleList([nn.Linear(2 + channels - 1, width), nn.Linear(width, width)])
        # Each cell's (row, column) in [-1, 1]; filled by reset_parameters. Not in the
        # state dict: a function of the shape, not a parameter to average.
        self.register_buffer("positions", torch.empty(rows * columns, 2), persistent=False)

    def reset_parameters(self, generator: torch.Generator) -> None:
        """``nn.Linear``'s default init, drawn from ``generator`` only, and the cell
        positions (a module built on the meta device gets them here)."""
        rows, columns, _ = self.grid_shape
        with torch.no_grad():
            row = torch.linspace(-1.0, 1.0, rows) if rows > 1 else torch.zeros(1)
            column = torch.linspace(-1.0, 1.0, columns) if columns > 1 else torch.zeros(1)
            grid = torch.stack(torch.meshgrid(row, column, indexing="ij"), dim=-1)
            self.positions.copy_(grid.reshape(rows * columns, 2))
            for layer in self.layers:
                bound = layer.in_features**-0.5
                layer.weight.uniform_(-bound, bound, generator=generator)
                layer.bias.uniform_(-bound, bound, generator=generator)

    def forward(self, flat: Tensor | SparseRows) -> Tensor:
        if isinstance(flat, SparseRows):
            found = flat.vehicles
            if found is None or found.geometry != self.geometry:
                found = self._vehicles_of_rows(flat)
            return self.encode(found.cell, found.channels, found.present, found.extra)
        batch = flat.shape[0]
        grid = flat[:, : self.grid_features].reshape(batch, -1, self.grid_shape[2])
        extra = flat[:, self.grid_features :] if self.extra_features else None
        return self.encode(*self._vehicles_of_grids(grid), extra)

    def embed(self, vehicles: Tensor) -> Tensor:
        """The shared per-vehicle MLP: ``[..., 2 + C - 1]`` -> ``[..., width]``, each >= 0."""
        hidden = vehicles
        for layer in self.layers:
            hidden = torch.relu(F.linear(hidden, layer.weight, layer.bias))
        return hidden

    def encode(
        self, cell: Tensor, channels: Tensor, present: Tensor, extra: Tensor | None
    ) -> Tensor:
        """The encoding of a batch from its vehicles in slots (:class:`GridVehicles`'
        ``cell`` [batch, slots], ``channels`` [batch, slots, C - 1] and ``present``
        [batch, slots]) and the features after the grid (``extra``, or None)."""
        return self.pool(
            self.embed(torch.cat([self.positions[cell], channels], dim=-1)), present, extra
        )

    def pool(self, hidden: Tensor, present: Tensor, extra: Tensor | None) -> Tensor:
        """The sum and the max of the embedded vehicles ``hidden`` [batch, slots, width]
        over the slots that ``present`` marks, then ``extra``."""
        # ReLU outputs are >= 0, so zeroing the padding leaves the vehicles' sum and max
        # (and 0 for an observation without any vehicle).
        hidden = hidden * present.unsqueeze(-1).to(hidden.dtype)
        pooled = [hidden.sum(dim=1), hidden.amax(dim=1)]
        return torch.cat(pooled if extra is None else [*pooled, extra], dim=1)

    def _vehicles_of_grids(self, grid: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """``(cell, channels, present)`` of dense grids ``[batch, cells, C]``, as
        :func:`find_vehicles` lays them out."""
        occupied = grid[..., -1] > 0
        counts = occupied.sum(dim=1)
        slots = slots_for(int(counts.max()) if counts.numel() else 0)
        # A stable sort puts each grid's occupied cells first, in cell order.
        order = torch.argsort((~occupied).to(torch.uint8), dim=1, stable=True)[:, :slots]
        present = torch.arange(slots, device=grid.device) < counts[:, None]
        cell = F.pad(order, (0, slots - order.shape[1])) * present
        channels = torch.gather(
            grid[..., :-1], 1, cell.unsqueeze(-1).expand(-1, -1, grid.shape[2] - 1)
        )
        return cell, channels * present.unsqueeze(-1), present.to(grid.dtype)

    def _vehicles_of_rows(self, rows: SparseRows) -> GridVehicles:
        """The vehicles of rows that do not carry them (found on the CPU, as the replay
        buffer finds them, then moved to the rows' device)."""
        counts = torch.diff(rows.offsets, append=rows.offsets.new_tensor([rows.indices.numel()]))
        found = find_vehicles(
            rows.indices.cpu().numpy(),
            rows.values.detach().cpu().numpy(),
            counts.cpu().numpy(),
            rows.num_features,
            self.geometry,
        )
        return found if rows.values.device.type == "cpu" else found.to(rows.values.device)
