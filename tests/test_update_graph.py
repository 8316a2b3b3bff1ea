"""The update captured as a CUDA graph (frl.agents.update_graph).

A machine without CUDA cannot capture, so the tests on it run the graph's data path with
the capture left out (``replay_as_graph=False``: each sampled batch copied into static
tensors, the sparse rows rebuilt from their vehicles alone, the losses stacked, the
graphs dropped when a tensor they read is replaced) and require it to train exactly as
the eager update does. The tests marked ``cuda`` capture for real where a GPU is present.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium import spaces

from frl.agents import DDPG, DDPGConfig
from frl.agents.networks import DeviceAdam
from frl.agents.update_graph import (
    GraphedUpdate,
    batch_layout,
    batch_tensors,
    keeps_one_layout,
    rebuild_batch,
)

GRID = spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
ACCEL = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def small_config(**options: object) -> DDPGConfig:
    """The default agent's update (vehicles encoder, 5-step targets, inverting gradients,
    the collision budget's cost head) on small networks."""
    fields: dict = {
        "hidden_sizes": (32, 16), "encoder": "vehicles", "actor_update": "inverting_gradients",
        "n_step": 5, "batch_size": 16, "buffer_size": 400, "learning_starts": 24,
        "precision": "float32", "collision_budget": 0.02, "lagrange_window": 5,
    }  # fmt: skip
    return DDPGConfig(**{**fields, **options})


def observation(rng: np.random.Generator, crowded: bool = False) -> np.ndarray:
    """A grid with 1-7 vehicles, or 9-12 (more than a batch's first 8 slots)."""
    grid = np.zeros(GRID.shape, np.float32)
    count = rng.integers(9, 13) if crowded else rng.integers(1, 8)
    cells = rng.choice(26 * 18, size=count, replace=False)
    for cell in cells:
        grid[cell // 18, cell % 18] = (rng.random(), rng.uniform(-1, 1), 1.0)
    return grid


def drive(agents: list[DDPG], steps: int, seed: int = 0) -> list[list[dict]]:
    """The same transitions into every agent: 10-step episodes, every third ending in a
    collision (the multiplier rises), a crowded grid now and then (a second layout). Each
    agent's read losses, per step."""
    rng = np.random.default_rng(seed)
    losses: list[list[dict]] = [[] for _ in agents]
    obs = observation(rng)
    for step in range(steps):
        action = rng.uniform(-1, 1, 1).astype(np.float32)
        next_obs = observation(rng, crowded=step % 37 == 0)
        terminated = step % 10 == 9
        cost = float(terminated and step % 30 == 29)
        reward = float(rng.normal())
        for agent, record in zip(agents, losses, strict=True):
            agent.observe(obs, action, reward, next_obs, terminated, cost=cost)
            record.append(agent.update())
        obs = observation(rng) if terminated else next_obs
    return losses


def assert_same_agents(a: DDPG, b: DDPG) -> None:
    state_b = b.federated_state()
    for key, tensor in a.federated_state().items():
        gap = (tensor - state_b[key]).abs().max().item()
        assert torch.equal(tensor, state_b[key]), f"{key} differs by up to {gap:.3g}"
    for name in ("actor_optimizer", "critic_optimizer"):
        state_a, state_b = getattr(a, name).state_dict(), getattr(b, name).state_dict()
        for index, moments in state_a["state"].items():
            for key, value in moments.items():
                assert torch.equal(value.cpu(), state_b["state"][index][key].cpu()), (name, key)


def static_path(agent: DDPG, warmup: int = 1) -> DDPG:
    """``agent`` with the graph's data path on the CPU, the capture left out."""
    agent.update_graph = GraphedUpdate(
        agent._train_step, agent.device, agent._tensors_read, warmup=warmup,
        replay_as_graph=False,
    )  # fmt: skip
    return agent


@pytest.mark.parametrize(
    "options",
    [
        {},  # the default update
        {"guide": "gap_acceptance", "guide_weight": 0.5},  # a teacher's actions in the batch
        {"critic": {"kind": "quantile", "quantiles": 8}},  # quantile levels on the device
    ],
)
def test_the_static_batch_path_trains_exactly_as_the_eager_update(options: dict) -> None:
    eager = DDPG(GRID, ACCEL, small_config(**options), seed=3)
    graphed = static_path(DDPG(GRID, ACCEL, small_config(**options), seed=3))
    for agent in (eager, graphed):
        agent.set_guide(lambda obs: np.full(1, 0.25, np.float32))
    losses = drive([eager, graphed], 160)
    assert losses[0] == losses[1]
    assert_same_agents(eager, graphed)
    assert graphed.update_graph is not None
    assert graphed.update_graph.captures >= 2, "both layouts (8 and 16 slots) captured"
    assert eager.constraint.lagrangian.multiplier > 0, "the price was exercised"
    assert sum(1 for step in losses[0] if step) > 100


def test_a_replaced_tensor_drops_the_graphs_and_training_stays_exact(tmp_path: Path) -> None:
    eager = DDPG(GRID, ACCEL, small_config(), seed=4)
    graphed = static_path(DDPG(GRID, ACCEL, small_config(), seed=4))
    drive([eager, graphed], 80, seed=1)
    graph = graphed.update_graph
    assert graph is not None and graph.captured
    captures = graph.captures
    for agent in (eager, graphed):  # FedProx's anchors: new tensors the update reads
        agent.set_proximal_anchor(0.05)
    drive([eager, graphed], 40, seed=2)
    assert graph.captures > captures
    captures = graph.captures
    for name, agent in (("eager", eager), ("graphed", graphed)):  # new optimizer state
        agent.save(tmp_path / f"{name}.pt")
        agent.restore(tmp_path / f"{name}.pt")
    drive([eager, graphed], 40, seed=3)
    assert graph.captures > captures
    assert_same_agents(eager, graphed)


def test_a_static_batch_keeps_only_the_vehicles_of_sparse_rows() -> None:
    agent = DDPG(GRID, ACCEL, small_config(), seed=0)
    drive([agent], 30)
    batch = agent.buffer.gather(agent.buffer.sample_slots(16), agent.sparse, "cpu", False)
    tensors = batch_tensors(batch)
    assert tensors is not None
    rebuilt = rebuild_batch(batch, iter(tensors))
    assert rebuilt.obs.indices.numel() == 0 and rebuilt.obs.values.numel() == 0
    assert rebuilt.obs.batch_size == 16
    assert rebuilt.obs.vehicles.cell is batch.obs.vehicles.cell
    rebuilt_q = agent.critic(rebuilt.obs, rebuilt.actions)
    assert torch.equal(rebuilt_q, agent.critic(batch.obs, batch.actions))


def test_sparse_rows_without_vehicles_run_eagerly() -> None:
    """Table II's flat encoder reads the non-zeros, whose number changes from batch to
    batch: no layout, no capture, the same training."""
    options = {"encoder": "flat", "actor_update": "tanh", "n_step": 1}
    eager = DDPG(GRID, ACCEL, small_config(**options), seed=5)
    graphed = static_path(DDPG(GRID, ACCEL, small_config(**options), seed=5))
    drive([eager, graphed], 60)
    batch = graphed.buffer.gather(graphed.buffer.sample_slots(16), True, "cpu", True)
    assert batch_layout(batch) is None
    assert graphed.update_graph is not None and graphed.update_graph.captures == 0
    assert_same_agents(eager, graphed)


def test_an_agent_on_a_cpu_updates_eagerly_and_the_option_is_checked() -> None:
    assert DDPG(GRID, ACCEL, small_config(), seed=0).update_graph is None
    with pytest.raises(ValueError, match="cuda_graph"):
        small_config(cuda_graph="yes")


def test_only_agents_whose_batches_keep_their_layout_are_captured() -> None:
    vehicles, flat = small_config(), small_config(encoder="flat", actor_update="tanh")
    assert keeps_one_layout(vehicles, sparse=True) and keeps_one_layout(flat, sparse=False)
    assert not keeps_one_layout(vehicles, sparse=False)  # vehicles found on the device
    assert not keeps_one_layout(flat, sparse=True)  # a changing number of non-zeros
    # On a GPU the flat encoder's first layer stays dense, so that it is captured.
    assert flat.use_sparse(1404, "cpu") and not flat.use_sparse(1404, "cuda")
    assert vehicles.use_sparse(1404, "cuda")
    pinned = small_config(encoder="flat", actor_update="tanh", sparse={"input": True})
    assert pinned.use_sparse(1404, "cuda")


def test_adam_keeps_its_own_capturable_when_a_state_is_loaded() -> None:
    weight = torch.nn.Parameter(torch.ones(3))
    written = DeviceAdam([weight], lr=0.1, capturable=False)
    weight.grad = torch.ones(3)
    written.step()
    state = written.state_dict()
    state["param_groups"][0]["capturable"] = True  # as a GPU run would have saved it
    reader = DeviceAdam([torch.nn.Parameter(torch.ones(3))], lr=0.1, capturable=False)
    reader.load_state_dict(state)
    assert reader.param_groups[0]["capturable"] is False
    capturable = DeviceAdam([torch.nn.Parameter(torch.ones(3))], lr=0.1, capturable=True)
    capturable.load_state_dict(written.state_dict())
    assert capturable.param_groups[0]["capturable"] is True
    (moments,) = capturable.state.values()
    assert moments["step"].dtype == torch.float32


# ---------------------------------------------------------------- on a GPU
@cuda
@pytest.mark.parametrize("precision", ["float32", "bf16"])
def test_a_captured_update_trains_as_the_eager_one_on_a_gpu(precision: str) -> None:
    eager = DDPG(GRID, ACCEL, small_config(precision=precision, cuda_graph=False), 3, "cuda")
    graphed = DDPG(GRID, ACCEL, small_config(precision=precision), seed=3, device="cuda")
    assert eager.update_graph is None and graphed.update_graph is not None
    losses = drive([eager, graphed], 160)
    assert graphed.update_graph.captures >= 2
    assert losses[0] == losses[1]
    assert_same_agents(eager, graphed)


@cuda
def test_a_captured_update_resumes_from_a_cpu_checkpoint(tmp_path: Path) -> None:
    on_cpu = DDPG(GRID, ACCEL, small_config(), seed=6)
    drive([on_cpu], 60)
    on_cpu.save(tmp_path / "agent.pt")
    eager = DDPG(GRID, ACCEL, small_config(cuda_graph=False), seed=6, device="cuda")
    graphed = DDPG(GRID, ACCEL, small_config(), seed=6, device="cuda")
    for agent in (eager, graphed):
        agent.restore(tmp_path / "agent.pt")
    losses = drive([eager, graphed], 80, seed=1)
    assert graphed.update_graph is not None and graphed.update_graph.captures >= 1
    assert losses[0] == losses[1]
    assert_same_agents(eager, graphed)


def test_a_checkpoint_loads_whatever_its_cuda_graph_was(tmp_path: Path) -> None:
    """How an update is launched is no part of what it computes."""
    written = DDPG(GRID, ACCEL, small_config(), seed=7)
    drive([written], 40)
    written.save(tmp_path / "agent.pt")
    reader = DDPG(GRID, ACCEL, small_config(cuda_graph=False), seed=7)
    reader.restore(tmp_path / "agent.pt")
    assert_same_agents(written, reader)
    with pytest.raises(Exception, match="n_step"):  # what an update computes still must match
        DDPG(GRID, ACCEL, small_config(n_step=3), seed=7).restore(tmp_path / "agent.pt")


@cuda
def test_table_ii_s_agent_is_dense_and_captured_on_a_gpu() -> None:
    options = {"encoder": "flat", "actor_update": "tanh", "n_step": 1}
    eager = DDPG(GRID, ACCEL, small_config(cuda_graph=False, **options), seed=8, device="cuda")
    graphed = DDPG(GRID, ACCEL, small_config(**options), seed=8, device="cuda")
    assert not graphed.sparse and graphed.update_graph is not None
    losses = drive([eager, graphed], 120)
    assert graphed.update_graph.captures >= 1
    assert losses[0] == losses[1]
    assert_same_agents(eager, graphed)


def test_anchoring_again_copies_into_the_anchors_the_graph_reads() -> None:
    agent = DDPG(GRID, ACCEL, small_config(), seed=9)
    drive([agent], 30)
    agent.set_proximal_anchor(0.05)
    before = [t.data_ptr() for t in agent._tensors_read()]
    drive([agent], 40, seed=1)  # the networks move away from their anchors
    agent.set_proximal_anchor(0.05)  # the next round's global model
    assert [t.data_ptr() for t in agent._tensors_read()] == before
    for pairs in agent.proximal.anchors.values():
        assert all(torch.equal(param, anchor) for param, anchor in pairs)
    agent.set_proximal_anchor(0.1)  # another pull: new anchors
    assert agent.proximal.mu == 0.1
