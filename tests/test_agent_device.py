"""Device placement: every tensor that acting or an update makes lives where its inputs do.

CI has no GPU, so a tensor made on torch's default device instead of its input's (the
bug that stopped the first ``device=cuda`` run) is caught here another way: acting and
updating with the default device set to ``meta``. A tensor made without ``device=`` then
lands on ``meta`` and any arithmetic with the agent's CPU tensors fails at once.
"""

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest
import torch
from gymnasium import spaces

from frl.agents import DDPG, DDPGConfig, SparseRows

GRID = spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
ROUTE = spaces.Dict({"grid": GRID, "route": spaces.Box(-np.inf, np.inf, (4,), np.float32)})
ACCEL = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@contextmanager
def default_device_meta() -> Iterator[None]:
    torch.set_default_device("meta")
    try:
        yield
    finally:
        torch.set_default_device(None)


def observation(rng: np.random.Generator, space: spaces.Space) -> object:
    grid = np.zeros(GRID.shape, np.float32)
    for _ in range(rng.integers(1, 8)):
        grid[rng.integers(26), rng.integers(18)] = (rng.random(), rng.uniform(-1, 1), 1.0)
    if isinstance(space, spaces.Dict):
        return {"grid": grid, "route": rng.uniform(-1, 1, 4).astype(np.float32)}
    return grid


@pytest.mark.parametrize(
    ("encoder", "actor_update", "n_step", "space"),
    [
        ("vehicles", "inverting_gradients", 5, GRID),  # the default agent
        ("vehicles", "inverting_gradients", 5, ROUTE),
        ("flat", "tanh", 1, GRID),  # Table II's agent
    ],
)
def test_acting_and_updating_make_no_tensor_on_the_default_device(
    encoder: str, actor_update: str, n_step: int, space: spaces.Space
) -> None:
    config = DDPGConfig(
        hidden_sizes=(32, 16),
        encoder=encoder,
        actor_update=actor_update,
        n_step=n_step,
        batch_size=8,
        buffer_size=200,
        learning_starts=16,
        precision="float32",
    )
    agent = DDPG(space, ACCEL, config, seed=0)
    rng = np.random.default_rng(0)
    obs = observation(rng, space)
    for step in range(30):
        action = agent.act(obs, explore=True)
        next_obs = observation(rng, space)
        agent.observe(obs, action, 0.1, next_obs, step % 10 == 9)
        obs = next_obs
    before = agent.networks.cpu_copy()
    with default_device_meta():
        agent.act(obs, explore=True)
        agent.predict(obs)
        agent.observe(obs, action, 0.1, observation(rng, space), False)
        agent.update()
        agent.critic_values([obs], np.zeros((1, 1), np.float32))
    after = agent.networks.cpu_copy()
    assert all(t.device.type == "cpu" for t in after.values())
    assert any(not torch.equal(before[k], after[k]) for k in before), "no update ran"


def test_sparse_rows_move_with_tensor_to_s_keywords() -> None:
    rows = SparseRows.from_numpy_row(np.array([0.0, 1.5, 0.0, -2.0], np.float32))
    moved = rows.to("cpu", non_blocking=False)
    assert torch.equal(moved.indices, rows.indices) and torch.equal(moved.values, rows.values)
    assert moved.num_features == rows.num_features
