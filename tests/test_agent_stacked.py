"""Many agents in one update (frl.agents.stacked): each learns as it would alone, to the
rounding of a batched matrix product; its state, checkpoints and federated loads stay its
own; a stacked run resumes exactly; what cannot be stacked is refused in one line. The
stacked update through a CUDA graph's data path trains exactly as the eager one (on the
CPU with the capture left out; the tests marked ``cuda`` capture for real)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium import spaces

from frl.agents import DDPG, DDPGConfig
from frl.agents.stacked import STACKED_PACKING, StackedUpdate, stacking_refusal
from frl.agents.update_graph import GraphedUpdate

GRID = spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
ACCEL = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
SEEDS = (4, 5, 6)

pytestmark = pytest.mark.usefixtures("one_torch_thread")
cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


def small_config(**options: object) -> DDPGConfig:
    """The default agent's update (vehicles encoder, inverting gradients, the collision
    budget's cost head) on small networks; one-step targets, so that every agent holds a
    batch at the same step and the agents update as often stacked as alone."""
    fields: dict = {
        "hidden_sizes": (32, 16), "encoder": "vehicles", "actor_update": "inverting_gradients",
        "n_step": 1, "batch_size": 16, "buffer_size": 400, "learning_starts": 24,
        "precision": "float32", "collision_budget": 0.02, "lagrange_window": 5,
    }  # fmt: skip
    fields.update(options)
    if fields["collision_budget"] is None:
        del fields["lagrange_window"]
    return DDPGConfig(**fields)


def observation(rng: np.random.Generator) -> np.ndarray:
    """A grid with 1-7 vehicles, now and then 9-12 (a batch of 16 slots)."""
    grid = np.zeros(GRID.shape, np.float32)
    count = rng.integers(9, 13) if rng.random() < 0.03 else rng.integers(1, 8)
    for cell in rng.choice(26 * 18, size=count, replace=False):
        grid[cell // 18, cell % 18] = (rng.random(), rng.uniform(-1, 1), 1.0)
    return grid


def agents_of(config: DDPGConfig, device: str = "cpu") -> list[DDPG]:
    agents = [DDPG(GRID, ACCEL, config, seed=seed, device=device) for seed in SEEDS]
    for agent in agents:
        agent.set_guide(lambda obs: np.full(1, 0.25, np.float32))
    return agents


def drive(
    agents: list[DDPG], steps: int, update: Callable[[], list[dict]], start: int = 0
) -> list[list[dict]]:
    """Each agent its own transitions (its own generator), in lockstep, ``update`` after
    every step: 10-step episodes, every third of an agent's ending in a collision."""
    losses: list[list[dict]] = []
    for step in range(start, start + steps):
        for k, agent in enumerate(agents):
            rng = np.random.default_rng([k, step])
            terminated = step % 10 == 9
            cost = float(terminated and (step + 10 * k) % 30 == 29)
            action = rng.uniform(-1, 1, 1).astype(np.float32)
            agent.observe(
                observation(rng), action, float(rng.normal()), observation(rng), terminated,
                cost=cost,
            )  # fmt: skip
        losses.append(update())
    return losses


def stacked_updates(stacked: StackedUpdate) -> Callable[[], list[dict]]:
    from frl.agents.learn import read_losses

    return lambda: read_losses(stacked.update_unread())


def one_by_one(agents: list[DDPG]) -> Callable[[], list[dict]]:
    return lambda: [agent.update() for agent in agents]


def states(agent: DDPG) -> dict[str, torch.Tensor]:
    state = dict(agent.federated_state())
    for name in ("actor_optimizer", "critic_optimizer"):
        for index, moments in getattr(agent, name).state_dict()["state"].items():
            for key, value in moments.items():
                state[f"{name}.{index}.{key}"] = value.detach().cpu().clone()
    return state


@pytest.mark.parametrize(
    "options",
    [
        {},  # the default update
        {"actor_update": "tanh", "collision_budget": None},
        {"guide": "gap_acceptance", "guide_weight": 0.5, "n_step": 3},
        {"critic": {"kind": "quantile", "quantiles": 8}},
        {"cost_target": "n_step"},
    ],
)
def test_each_stacked_agent_learns_as_it_would_alone(options: dict) -> None:
    alone, together = agents_of(small_config(**options)), agents_of(small_config(**options))
    stacked = StackedUpdate(together)
    losses_alone = drive(alone, 60, one_by_one(alone))
    losses_together = drive(together, 60, stacked_updates(stacked))
    assert [a.num_updates for a in alone] == [a.num_updates for a in together] == [37] * 3
    for a, b in zip(alone, together, strict=True):
        state_b = states(b)
        for key, value in states(a).items():
            gap = (value - state_b[key]).abs().max().item()
            assert gap < 2e-5, f"{key} differs by {gap:.3g}"
    for step_a, step_b in zip(losses_alone, losses_together, strict=True):
        for a, b in zip(step_a, step_b, strict=True):
            assert a.keys() == b.keys()
            for name in a:
                assert b[name] == pytest.approx(a[name], rel=1e-4, abs=1e-5), name
    # The agents learned apart: their rows differ.
    first = together[0].federated_state()
    assert any(not torch.equal(v, together[1].federated_state()[k]) for k, v in first.items())


def test_an_agent_s_tensors_are_views_of_its_rows_and_in_place_loads_reach_the_update() -> None:
    agents = agents_of(small_config())
    stacked = StackedUpdate(agents)
    drive(agents, 30, stacked_updates(stacked))
    name = "critic.layers.1.weight"
    for k, agent in enumerate(agents):
        held = dict(agent.networks.named_parameters())[name]
        assert held.data_ptr() == stacked.stacked[name][k].data_ptr()
    # FedAvg's download writes into the agent's tensors: the stacked rows see it.
    agents[2].load_federated_state(agents[0].federated_state())
    assert torch.equal(stacked.stacked[name][2], stacked.stacked[name][0])
    assert stacked.stackings == 1


def test_a_stacked_agent_s_checkpoint_is_its_own_and_a_stacked_run_resumes_exactly(
    tmp_path: Path,
) -> None:
    config = small_config()
    lone = agents_of(config)
    drive(lone, 40, one_by_one(lone))
    lone_size = None
    agents = agents_of(config)
    stacked = StackedUpdate(agents)
    drive(agents, 40, stacked_updates(stacked))
    for k, agent in enumerate(agents):
        agent.save(tmp_path / f"agent{k}.pt", include_buffer=True)
    lone[0].save(tmp_path / "lone.pt", include_buffer=True)
    lone_size = (tmp_path / "lone.pt").stat().st_size
    # Not three agents' rows in one file: the same size as a lone agent's, to 1%.
    assert abs((tmp_path / "agent0.pt").stat().st_size - lone_size) < 0.01 * lone_size
    # A checkpoint loads into a lone agent as that agent's state.
    alone = DDPG(GRID, ACCEL, config, seed=0)
    alone.restore(tmp_path / "agent1.pt")
    for key, value in states(agents[1]).items():
        assert torch.equal(value, states(alone)[key]), key
    # Killed here: fresh agents restored from the checkpoints, stacked afresh, go on
    # exactly as the run that was not stopped.
    resumed = agents_of(config)
    for k, agent in enumerate(resumed):
        agent.restore(tmp_path / f"agent{k}.pt")
    drive(agents, 30, stacked_updates(stacked), start=40)
    drive(resumed, 30, stacked_updates(StackedUpdate(resumed)), start=40)
    for a, b in zip(agents, resumed, strict=True):
        state_b = states(b)
        for key, value in states(a).items():
            assert torch.equal(value, state_b[key]), key


def test_restoring_a_stacked_agent_in_place_restacks_and_goes_on_exactly(tmp_path: Path) -> None:
    config = small_config()
    agents, twins = agents_of(config), agents_of(config)
    stacked, twin_stack = StackedUpdate(agents), StackedUpdate(twins)
    drive(agents, 40, stacked_updates(stacked))
    drive(twins, 40, stacked_updates(twin_stack))
    for k, agent in enumerate(agents):
        agent.save(tmp_path / f"agent{k}.pt", include_buffer=True)
    drive(agents, 10, stacked_updates(stacked), start=40)  # steps the checkpoint undoes
    for k, agent in enumerate(agents):
        agent.restore(tmp_path / f"agent{k}.pt")  # replaces the optimizers' moments
    drive(agents, 20, stacked_updates(stacked), start=40)
    drive(twins, 20, stacked_updates(twin_stack), start=40)
    assert stacked.stackings == 2 and twin_stack.stackings == 1
    for a, b in zip(agents, twins, strict=True):
        state_b = states(b)
        for key, value in states(a).items():
            assert torch.equal(value, state_b[key]), key


def test_a_stacked_agent_refuses_to_learn_alone_until_released() -> None:
    agents = agents_of(small_config())
    stacked = StackedUpdate(agents)
    drive(agents, 30, stacked_updates(stacked))
    before = states(agents[1])
    for agent in agents:
        agent.observe(observation(np.random.default_rng(0)), np.zeros(1, np.float32), 0.0,
                      observation(np.random.default_rng(1)), False)  # fmt: skip
    with pytest.raises(RuntimeError, match="stacked update"):
        agents[1].update()
    stacked.release()
    for key, value in states(agents[1]).items():
        assert torch.equal(value, before[key]), key
    name = "actor.layers.1.weight"
    assert dict(agents[1].networks.named_parameters())[name].untyped_storage().nbytes() == (
        dict(agents[1].networks.named_parameters())[name].numel() * 4
    )
    assert agents[1].update()  # on its own again
    assert not torch.equal(states(agents[1])[name], before[name])


def test_agents_that_cannot_share_an_update_are_refused_in_one_line() -> None:
    agents = agents_of(small_config())
    other = DDPG(GRID, ACCEL, small_config(actor_lr=3e-4), seed=9)
    assert stacking_refusal([*agents, other]) == "their agent configs differ in 'actor_lr'"
    with pytest.raises(ValueError, match="cannot learn in one stacked update"):
        StackedUpdate([*agents, other])
    flat = [DDPG(GRID, ACCEL, small_config(encoder="flat"), seed=s) for s in SEEDS]
    assert "change shape" in str(stacking_refusal(flat))
    # A different execution setting (a CUDA graph) is no obstacle.
    assert stacking_refusal([agents[0], DDPG(GRID, ACCEL, small_config(cuda_graph=False))]) is None
    proximal = agents_of(small_config())
    proximal[0].set_proximal_anchor(0.1)
    assert "FedProx" in str(stacking_refusal(proximal))
    StackedUpdate(agents)
    assert "already" in str(stacking_refusal(agents))


def test_agents_out_of_lockstep_stop_the_stacked_update() -> None:
    agents = agents_of(small_config())
    stacked = StackedUpdate(agents)
    drive(agents, 30, stacked_updates(stacked))
    rng = np.random.default_rng(0)
    agents[0].observe(observation(rng), np.zeros(1, np.float32), 0.0, observation(rng), False)
    with pytest.raises(RuntimeError, match="out of lockstep"):
        stacked.update_unread()


def static_path(stacked: StackedUpdate) -> StackedUpdate:
    """``stacked`` with the graph's data path on the CPU, the capture left out."""
    stacked.update_graph = GraphedUpdate(
        stacked._step, stacked.template.device, stacked._tensors_read, warmup=1,
        replay_as_graph=False, packing=STACKED_PACKING,
    )  # fmt: skip
    return stacked


def assert_same_runs(
    agents_a: list[DDPG], agents_b: list[DDPG], losses_a: list[list[dict]],
    losses_b: list[list[dict]],
) -> None:  # fmt: skip
    assert losses_a == losses_b
    for a, b in zip(agents_a, agents_b, strict=True):
        state_b = states(b)
        for key, value in states(a).items():
            gap = (value - state_b[key]).abs().max().item()
            assert torch.equal(value, state_b[key]), f"{key} differs by up to {gap:.3g}"


def restore_in_place(agents: list[DDPG], directory: Path) -> None:
    """Save and restore every agent: new optimizer moments, so the agents are stacked
    afresh and a graph captured on the old ones must go."""
    for k, agent in enumerate(agents):
        agent.save(directory / f"agent{k}.pt", include_buffer=True)
        agent.restore(directory / f"agent{k}.pt")


def assert_the_graph_trains_as_eager(
    eager: StackedUpdate, graphed: StackedUpdate, steps: int, directory: Path
) -> None:
    """Both stacked updates' agents trained ``steps`` steps, restored in place, then
    ``steps // 2`` more: the same runs, the graph captured again after the restore."""
    assert eager.update_graph is None and graphed.update_graph is not None
    losses = [drive(eager.agents, steps, stacked_updates(eager)),
              drive(graphed.agents, steps, stacked_updates(graphed))]  # fmt: skip
    assert graphed.update_graph.captures >= 1
    assert_same_runs(eager.agents, graphed.agents, *losses)
    restore_in_place(eager.agents, directory / "eager")
    restore_in_place(graphed.agents, directory / "graphed")
    captures = graphed.update_graph.captures
    losses = [drive(eager.agents, steps // 2, stacked_updates(eager), start=steps),
              drive(graphed.agents, steps // 2, stacked_updates(graphed), start=steps)]  # fmt: skip
    assert graphed.stackings == 2 and graphed.update_graph.captures > captures
    assert_same_runs(eager.agents, graphed.agents, *losses)


@pytest.mark.parametrize(
    "options", [{}, {"guide": "gap_acceptance", "guide_weight": 0.5, "n_step": 3}]
)
def test_the_stacked_update_through_a_graph_s_static_batch_trains_as_the_eager_one(
    options: dict, tmp_path: Path
) -> None:
    eager = StackedUpdate(agents_of(small_config(**options)))
    graphed = static_path(StackedUpdate(agents_of(small_config(**options))))
    assert_the_graph_trains_as_eager(eager, graphed, 50, tmp_path)
    graphed.release()
    assert graphed.update_graph is not None and not graphed.update_graph.captured


@cuda
@pytest.mark.parametrize("precision", ["float32", "bf16"])
def test_a_captured_stacked_update_trains_as_the_eager_one_on_a_gpu(
    precision: str, tmp_path: Path
) -> None:
    eager = StackedUpdate(agents_of(small_config(precision=precision, cuda_graph=False), "cuda"))
    graphed = StackedUpdate(agents_of(small_config(precision=precision), "cuda"))
    assert_the_graph_trains_as_eager(eager, graphed, 60, tmp_path)


@pytest.mark.parametrize("options", [{}, {"encoder": "flat", "sparse": {"input": False}}])
def test_the_stacked_actors_act_in_one_pass_as_each_acts_alone(
    options: dict, tmp_path: Path
) -> None:
    agents = agents_of(small_config(**options))
    stacked = StackedUpdate(agents)
    drive(agents, 40, stacked_updates(stacked))  # the actors learned apart
    rng = np.random.default_rng(3)
    observations = [observation(rng) for _ in agents]
    observations[1] = np.zeros(GRID.shape, np.float32)  # a grid without vehicles
    together = stacked.policy_actions(observations)
    assert together.shape == (3, 1) and together.dtype == np.float64
    for agent, obs, action in zip(agents, observations, together, strict=True):
        alone = agent._policy_action(agent.layout.flat(obs))
        assert action == pytest.approx(alone, abs=1e-6)
    assert len({float(a) for a in together[:, 0]}) == 3
    # An agent restored from another's checkpoint acts as that agent, stacked too.
    agents[1].save(tmp_path / "agent1.pt", include_buffer=True)
    agents[0].restore(tmp_path / "agent1.pt")
    restored = stacked.policy_actions(observations)
    own = agents[0]._policy_action(agents[0].layout.flat(observations[0]))
    assert restored[0] == pytest.approx(own, abs=1e-6)
    assert restored[0] != pytest.approx(together[0], abs=1e-6)
    # A parameter replaced rather than written into: the agents are stacked afresh.
    last, optimizer = agents[2].networks.actor.layers[-1], agents[2].actor_optimizer
    held, new = last.bias, torch.nn.Parameter(last.bias.detach() + 0.5)
    group = optimizer.param_groups[0]["params"]
    group[[p is held for p in group].index(True)] = new
    optimizer.state[new] = optimizer.state.pop(held)
    last.bias = new
    replaced = stacked.policy_actions(observations)
    own = agents[2]._policy_action(agents[2].layout.flat(observations[2]))
    assert replaced[2] == pytest.approx(own, abs=1e-6) and stacked.stackings == 2
    with pytest.raises(ValueError, match="one observation per agent"):
        stacked.policy_actions(observations[:2])
    with pytest.raises(ValueError, match="shape"):
        stacked.policy_actions([np.zeros(5, np.float32)] * 3)


def test_an_agent_acting_on_a_policy_action_given_acts_as_on_its_own() -> None:
    config = small_config(learning_starts=0)
    own, given = (DDPG(GRID, ACCEL, config, seed=2) for _ in range(2))
    rng = np.random.default_rng(0)
    for _ in range(5):
        obs = observation(rng)
        action = given._policy_action(given.layout.flat(obs))
        assert np.array_equal(own.act(obs), given.act(obs, policy_action=action))
        assert np.array_equal(own.last_policy_action, given.last_policy_action)
    with pytest.raises(ValueError, match="policy_action has 2 values"):
        given.act(obs, policy_action=np.zeros(2))
