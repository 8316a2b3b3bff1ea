"""The vehicles encoder: the grid read as a set of vehicles, in front of DDPG's MLPs."""

from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium import spaces

from frl.agents import DDPG, DDPGConfig, SparseRows
from frl.agents.vehicle_encoder import VehicleSetEncoder

GRID = spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
ACCEL = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
SMALL = DDPGConfig(
    hidden_sizes=(32, 16),
    buffer_size=500,
    learning_starts=20,
    batch_size=8,
    encoder="vehicles",
    encoder_width=16,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def encoder(width: int = 8, seed: int = 0) -> VehicleSetEncoder:
    module = VehicleSetEncoder((26, 18, 3), width)
    module.reset_parameters(torch.Generator().manual_seed(seed))
    return module


def grid_with(*vehicles: tuple[int, int, float, float]) -> torch.Tensor:
    """A flat grid holding each (row, column, speed, heading) as an occupied cell."""
    grid = torch.zeros(26, 18, 3)
    for row, column, speed, heading in vehicles:
        grid[row, column] = torch.tensor([speed, heading, 1.0])
    return grid.reshape(1, -1)


def test_one_vehicle_is_the_shared_mlp_of_its_position_and_channels() -> None:
    module = encoder()
    out = module(grid_with((3, 5, 0.4, -1.0)))
    features = torch.tensor([[-1 + 2 * 3 / 25, -1 + 2 * 5 / 17, 0.4, -1.0]])
    hidden = features
    for layer in module.layers:
        hidden = torch.relu(layer(hidden))
    torch.testing.assert_close(out, torch.cat([hidden, hidden], dim=1))


def test_vehicles_are_pooled_by_sum_and_max_whatever_their_order() -> None:
    module = encoder()
    a, b = (2, 4, 0.5, 1.0), (20, 9, 0.1, -1.0)
    both = module(grid_with(a, b))
    torch.testing.assert_close(both, module(grid_with(b, a)))
    one_a, one_b = module(grid_with(a)), module(grid_with(b))
    width = module.width
    torch.testing.assert_close(both[:, :width], one_a[:, :width] + one_b[:, :width])
    torch.testing.assert_close(both[:, width:], torch.maximum(one_a[:, width:], one_b[:, width:]))


def test_an_empty_grid_encodes_to_zero_and_a_batch_keeps_its_rows_apart() -> None:
    module = encoder()
    batch = torch.cat([grid_with(), grid_with((1, 1, 0.2, 0.0)), grid_with()])
    out = module(batch)
    assert out.shape == (3, 16)
    assert torch.equal(out[0], torch.zeros(16)) and torch.equal(out[2], torch.zeros(16))
    torch.testing.assert_close(out[1:2], module(grid_with((1, 1, 0.2, 0.0))))


def test_sparse_rows_give_the_dense_grids_encoding_bit_for_bit() -> None:
    module = encoder(width=16)
    batch = torch.cat(
        [
            grid_with((2, 4, 0.5, 1.0), (20, 9, 0.0, -1.0)),  # a stopped car: speed not stored
            grid_with(),
            grid_with((13, 2, 0.3, 0.0), (25, 17, 0.7, 1.5)),  # heading 0: not stored
            grid_with((0, 0, 0.0, 0.0)),  # only the occupancy channel
        ]
    )
    sparse = SparseRows.from_dense(batch)
    assert torch.equal(module(sparse), module(batch))


def test_a_sampled_batch_carries_its_vehicles_and_they_encode_as_the_grids_do() -> None:
    """The replay buffer finds each batch's vehicles once (NumPy); every network reading
    the batch gets the encoding of the dense grids, and of the rows without them."""
    from frl.agents import ReplayBuffer

    module = encoder(width=16)
    grids = [
        grid_with((2, 4, 0.5, 1.0), (20, 9, 0.0, -1.0)),
        grid_with(),
        grid_with((13, 2, 0.3, 0.0), (25, 17, 0.7, 1.5)),
        grid_with((0, 0, 0.0, 0.0)),
    ]
    buffer = ReplayBuffer(
        8, (26, 18, 3), 1, np.random.default_rng(0), sparse=True, vehicle_geometry=module.geometry
    )
    for grid, next_grid in zip(grids, grids[1:] + grids[:1], strict=True):
        buffer.add(grid.numpy().reshape(26, 18, 3), np.zeros(1), 0.0, next_grid.numpy(), False)
    batch = buffer.gather(np.array([0, 1, 2, 3, 2]), sparse=True)
    dense = torch.cat([grids[i] for i in (0, 1, 2, 3, 2)])
    for rows in (batch.obs, batch.next_obs):
        assert rows.vehicles is not None and rows.vehicles.geometry == module.geometry
    # Each grid's vehicles fill its first slots, in cell order; 8 slots for at most 2.
    found = batch.obs.vehicles
    assert found.present.shape == (5, 8)
    assert found.present.sum(dim=1).tolist() == [2, 0, 2, 1, 2]
    assert found.cell[0, :2].tolist() == [2 * 18 + 4, 20 * 18 + 9]
    assert found.cell[1].tolist() == [0] * 8 and found.channels[1].abs().sum() == 0
    assert torch.equal(module(batch.obs), module(dense))
    assert torch.equal(module(batch.obs), module(batch.obs._replace(vehicles=None)))
    # Vehicles found for another grid are not used: this encoder finds its own.
    other = batch.next_obs._replace(vehicles=batch.obs.vehicles._replace(geometry=(1, 2, 0)))
    assert torch.equal(module(other), module(batch.next_obs))


def test_batches_take_a_fixed_number_of_slots_and_more_only_for_a_fuller_grid() -> None:
    """Every batch whose grids show at most 8 vehicles is laid out in 8 slots, whatever
    its vehicle count; a fuller grid widens that batch to 16 slots and loses no vehicle,
    and the padding changes no encoding."""
    module = encoder(width=16)
    few = torch.cat([grid_with((2, 4, 0.5, 1.0)), grid_with()])
    some = torch.cat([grid_with(*[(row, 3, 0.1 * row, 1.0) for row in range(8)]), grid_with()])
    crowded = grid_with(*[(row, 5, 0.05 * row, -1.0) for row in range(11)])
    for batch, slots in ((few, 8), (some, 8), (torch.cat([crowded, few]), 16)):
        found = SparseRows.from_dense(batch)
        found = module._vehicles_of_rows(found)
        assert found.cell.shape == found.present.shape == (len(batch), slots)
        assert found.channels.shape == (len(batch), slots, 2)
        occupied = batch[:, : module.grid_features].reshape(len(batch), -1, 3)[..., -1] > 0
        assert found.present.sum(dim=1).tolist() == occupied.sum(dim=1).tolist()
    # The crowded grid encodes the same alone as beside others, and as the sum and max of
    # its vehicles encoded one by one.
    alone = module(crowded)
    torch.testing.assert_close(module(torch.cat([crowded, few]))[:1], alone)
    singles = torch.cat([module(grid_with((row, 5, 0.05 * row, -1.0))) for row in range(11)])
    width = module.width
    torch.testing.assert_close(alone[0, :width], singles[:, :width].sum(dim=0))
    torch.testing.assert_close(alone[0, width:], singles[:, width:].amax(dim=0))


def test_a_nearby_position_gives_a_nearby_encoding() -> None:
    """Positions are numbers, not one-hot inputs: the next cell over is close."""
    module = encoder(width=32)
    here = module(grid_with((10, 5, 0.5, 1.0)))
    next_cell = module(grid_with((11, 5, 0.5, 1.0)))
    far = module(grid_with((25, 17, 0.5, 1.0)))
    assert (here - next_cell).norm() < (here - far).norm()


def test_refuses_observations_that_are_no_grid() -> None:
    with pytest.raises(ValueError, match="3-D grid"):
        VehicleSetEncoder((1404,))
    with pytest.raises(ValueError, match="encoder must be one of flat, vehicles"):
        DDPGConfig(encoder="cnn")
    flat = spaces.Box(-1.0, 1.0, (3,), dtype=np.float32)
    with pytest.raises(ValueError, match="3-D grid"):
        DDPG(flat, ACCEL, SMALL)


def run(agent: DDPG, steps: int, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)

    def obs() -> np.ndarray:
        grid = np.zeros(GRID.shape, np.float32)
        for cell in rng.choice(26 * 18, size=int(rng.integers(1, 5)), replace=False):
            grid[divmod(int(cell), 18)] = (rng.uniform(0, 1), rng.choice([-1.0, 1.0]), 1.0)
        return grid

    current = obs()
    agent.episode_start()
    for t in range(steps):
        following = obs()
        agent.observe(current, agent.act(current), float(rng.normal()), following, t % 7 == 6)
        agent.update()
        current = following


def test_an_agent_with_the_encoder_trains_saves_and_averages_by_name(tmp_path: Path) -> None:
    agent = DDPG(GRID, ACCEL, SMALL, seed=1)
    assert agent.sparse and agent.buffer.sparse  # the encoder reads the non-zeros
    state = agent.federated_state()
    assert state["actor.encoder.layers.0.weight"].shape == (16, 4)
    assert state["critic.layers.0.weight"].shape == (32, 32)  # 2 x width in
    assert not any("positions" in key for key in state)
    before = state["critic.encoder.layers.1.weight"].clone()
    run(agent, 40)
    assert not torch.equal(before, agent.federated_state()["critic.encoder.layers.1.weight"])
    agent.save(tmp_path / "a.pt", include_buffer=True)
    restored = DDPG.from_checkpoint(tmp_path / "a.pt", GRID, ACCEL)
    obs = np.zeros(GRID.shape, np.float32)
    obs[13, 2] = (0.3, 0.0, 1.0)
    np.testing.assert_array_equal(restored.act(obs, explore=False), agent.act(obs, explore=False))
    run(agent, 10, seed=3)
    run(restored, 10, seed=3)
    a, b = agent.federated_state(), restored.federated_state()
    assert all(torch.equal(a[key], b[key]) for key in a)
    # Same keys and shapes as any other vehicle of the run: FedAvg averages by name.
    other = DDPG(GRID, ACCEL, SMALL, seed=2)
    other.load_federated_state(a)
