"""Acting on one observation (frl.agents.acting): the actor's own function, in float32."""

import warnings

import numpy as np
import pytest
import torch
from gymnasium import spaces

from frl.agents import DDPG, DDPGConfig, SparseRows
from frl.agents.acting import actor_action, encode_one, vehicles_of_one

GRID = spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
ROUTE = spaces.Dict({"grid": GRID, "route": spaces.Box(-np.inf, np.inf, (4,), np.float32)})
ACCEL = spaces.Box(-3.0, 2.0, (1,), dtype=np.float32)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def grids(count: int, seed: int = 0) -> np.ndarray:
    """Flat grids with 0-12 vehicles each, some with a zero speed or heading channel and
    one with a -0.0 heading (which compressed rows drop as a zero)."""
    rng = np.random.default_rng(seed)
    batch = np.zeros((count, 26 * 18, 3), np.float32)
    for grid in batch:
        cells = rng.choice(26 * 18, size=rng.integers(0, 13), replace=False)
        grid[cells, 0] = rng.uniform(0, 1, cells.size) * (rng.random(cells.size) > 0.2)
        grid[cells, 1] = rng.uniform(-2, 2, cells.size) * (rng.random(cells.size) > 0.2)
        grid[cells, 2] = 1.0
    batch[1, np.flatnonzero(batch[1, :, 2])[:1], 1] = -0.0
    return batch.reshape(count, -1)


def network_actions(agent: DDPG, flat: np.ndarray) -> np.ndarray:
    """The actor's forward pass on each observation alone, as the update runs it."""
    actions = []
    with torch.no_grad():
        for row in flat:
            rows = SparseRows.from_numpy_row(row) if agent.sparse else torch.from_numpy(row[None])
            actions.append(agent.actor(rows)[0].double().numpy())
    return np.stack(actions)


@pytest.mark.parametrize(
    ("encoder", "actor_update", "space"),
    [
        ("vehicles", "inverting_gradients", GRID),
        ("vehicles", "tanh", ROUTE),
        ("flat", "tanh", GRID),
        ("flat", "inverting_gradients", ROUTE),
    ],
)
def test_one_observation_gets_exactly_the_networks_action(
    encoder: str, actor_update: str, space: spaces.Space
) -> None:
    config = DDPGConfig(
        hidden_sizes=(64, 32), encoder=encoder, actor_update=actor_update, precision="float32"
    )
    agent = DDPG(space, ACCEL, config, seed=5)
    flat = grids(40)
    if space is ROUTE:
        route = np.random.default_rng(1).uniform(0, 2, (len(flat), 4)).astype(np.float32)
        route[::3, :3] = 0.0
        flat = np.concatenate([flat, route], axis=1)
    fast = np.stack([actor_action(agent.actor, row, agent.sparse) for row in flat])
    assert np.array_equal(fast, network_actions(agent, flat))
    assert np.all(np.abs(fast) <= 1.0) and fast.std() > 0


def test_the_numpy_pooling_equals_the_encoder_that_acting_runs_on_a_device() -> None:
    """Off the CPU, acting hands the vehicles it found in NumPy to the encoder; on the CPU
    it pools them in NumPy. Both give the encoder's own numbers on the dense row, up to 12
    vehicles (16 slots) and a -0.0."""
    config = DDPGConfig(hidden_sizes=(64, 32), encoder="vehicles", precision="float32")
    encoder = DDPG(ROUTE, ACCEL, config, seed=5).actor.encoder
    flat = np.concatenate([grids(40), np.ones((40, 4), np.float32)], axis=1)
    with torch.no_grad():
        for row in flat:
            dense = encoder(torch.from_numpy(row[None] + np.float32(0.0)))
            assert torch.equal(encode_one(encoder, row, torch.device("cpu")), dense)
            slots = [torch.from_numpy(a) for a in vehicles_of_one(encoder, row)]
            as_on_a_device = encoder.encode(*slots, torch.from_numpy(row[None, -4:]))
            assert torch.equal(as_on_a_device, dense)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_acting_on_a_gpu_gets_exactly_the_networks_action() -> None:
    config = DDPGConfig(hidden_sizes=(64, 32), encoder="vehicles", precision="float32")
    agent = DDPG(ROUTE, ACCEL, config, seed=5, device="cuda")
    flat = np.concatenate([grids(40), np.ones((40, 4), np.float32)], axis=1)
    acted = np.stack([actor_action(agent.actor, row, agent.sparse) for row in flat])
    with torch.no_grad():
        dense = torch.from_numpy(flat + np.float32(0.0)).to("cuda")
        whole = np.stack(
            [agent.actor(dense[i : i + 1])[0].double().cpu().numpy() for i in range(40)]
        )
    assert np.array_equal(acted, whole)


def test_act_and_predict_use_it_and_scale_to_the_bounds() -> None:
    agent = DDPG(GRID, ACCEL, DDPGConfig(hidden_sizes=(64, 32), encoder="vehicles"), seed=2)
    flat = grids(5)
    normalised = network_actions(agent, flat)
    expected = (-3.0 + (normalised + 1.0) * 0.5 * 5.0).astype(np.float32)
    for row, action, policy in zip(flat, expected, normalised, strict=True):
        observation = row.reshape(GRID.shape)
        assert np.array_equal(agent.act(observation, explore=False), action)
        assert np.array_equal(agent.last_policy_action, policy)
        assert np.array_equal(agent.predict(observation)[0], action)


def test_a_bf16_agent_acts_in_float32() -> None:
    """Acting never runs under autocast: a bf16 agent acts as its float32 twin."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # bf16 emulated on this CPU
        mixed = DDPG(GRID, ACCEL, DDPGConfig(hidden_sizes=(64, 32), precision="bf16"), seed=3)
    exact = DDPG(GRID, ACCEL, DDPGConfig(hidden_sizes=(64, 32), precision="float32"), seed=3)
    for row in grids(10):
        observation = row.reshape(GRID.shape)
        assert np.array_equal(
            mixed.act(observation, explore=False), exact.act(observation, explore=False)
        )
