"""Fleets: many vehicles per task, rounds that draw a part of them, per-vehicle traffic,
strategies and FedProx, vehicles sharing worker processes; and their bad input."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from train_helpers import compose_config, tiny_spec

from frl.federation import FederationPlan, ProcessClientPool
from frl.federation.assembly import client_specs
from frl.federation.client import ClientSpec
from frl.federation.frames import encode_frame
from frl.federation.plan import round_sample
from frl.report.runs import load_run
from frl.run_directory import RESULTS_FILE
from frl.train_config import ConfigError, validate
from frl.training import train


def test_a_fleet_repeats_the_tasks_interleaved_and_keeps_the_first_vehicles():
    plan = FederationPlan(vehicles_per_task=2)
    assert plan.client_tasks == ("left", "straight", "right") * 2
    assert (plan.fleet_size, plan.test_tasks, plan.vehicles_drawn) == (6, plan.tasks, 6)
    repeated = FederationPlan(tasks=("left", "left", "right"))
    assert (repeated.fleet_size, repeated.test_tasks) == (3, ("left", "right"))
    separate = FederationPlan(scheme="separate", vehicles_per_task=2)
    names = [f"client{i}_{t}" for i, t in enumerate(separate.client_tasks)]
    assert separate.model_files(names)["left"] == ["client0_left.pt", "client3_left.pt"]
    assert FederationPlan(scheme="central", vehicles_per_task=4).fleet_size == 1
    # Vehicle i's seeds do not depend on the fleet's size.
    small = client_specs(validate(compose_config(None)))
    large = client_specs(validate(compose_config(None, ["federation.vehicles_per_task=3"])))
    assert [(s.agent_seed, s.env_seed, s.task) for s in small] == [
        (s.agent_seed, s.env_seed, s.task) for s in large[:3]
    ]


def test_rounds_draw_from_the_run_seed():
    plan = FederationPlan(vehicles_per_task=4, fraction_train=0.25)
    assert plan.vehicles_drawn == 3 and plan.samples
    draws = [round_sample(7, r, range(12), 3) for r in range(20)]
    assert draws == [round_sample(7, r, range(12), 3) for r in range(20)]
    assert all(len(set(d)) == 3 and d == sorted(d) for d in draws)
    assert len({tuple(d) for d in draws}) > 10
    assert (
        round_sample(8, 0, range(12), 3) != draws[0] or round_sample(8, 1, range(12), 3) != draws[1]
    )
    assert FederationPlan(vehicles_per_task=2, vehicles_per_round=2).vehicles_drawn == 2


@pytest.mark.parametrize(
    ("overrides", "match"),
    [
        (["federation.fraction_train=0"], r"fraction_train must be in \(0, 1\], got 0"),
        (["federation.fraction_train=1.5"], r"fraction_train must be in \(0, 1\], got 1.5"),
        (
            ["federation.vehicles_per_round=4"],
            "vehicles_per_round=4 exceeds the fleet's 3 vehicles",
        ),
        (["federation.vehicles_per_round=2", "federation.fraction_train=0.5"], "not both"),
        (["federation.vehicles_per_task=0"], "vehicles_per_task must be a positive integer"),
        (["federation.strategy=fedsgd"], "unknown federation.strategy 'fedsgd'"),
        (
            ["federation.strategy=fedavgm", "+federation.strategy_params={eta: 0.1}"],
            "fedavgm takes server_learning_rate, server_momentum; got 'eta'",
        ),
        (
            ["federation.vehicle_traffic=[paper,dense]"],
            "vehicle_traffic has 2 entries for a fleet of 3 vehicles",
        ),
        (
            ["federation.vehicle_arrival_period_steps=[25,10,5,5]"],
            "vehicle_arrival_period_steps has 4 entries for a fleet of 3",
        ),
        (["federation.vehicle_traffic=[paper,dense,busy]"], "unknown traffic preset 'busy'"),
        (
            ["federation.strategy=fedadam", "federation.initial_model=independent"],
            "fedadam steps from one global model; it needs federation.initial_model=shared",
        ),
        (["federation.workers=-1"], "federation.workers must be >= 0"),
    ],
)
def test_bad_fleet_settings_are_refused_before_anything_runs(overrides, match):
    with pytest.raises(ConfigError, match=match):
        validate(compose_config(None, overrides))


def test_per_vehicle_traffic_and_proximal_weight_reach_the_vehicles():
    settings = validate(
        compose_config(
            None,
            [
                "federation.vehicle_traffic=[paper,dense,paper]",
                "federation.vehicle_arrival_period_steps=[25,10,50]",
                "federation.strategy=fedprox",
                "+federation.strategy_params={proximal_mu: 0.01}",
            ],
        )
    )
    specs = client_specs(settings)
    periods = [s.env.scenario.human_arrival_period_steps for s in specs]
    assert periods == [25.0, 10.0, 50.0]
    assert specs[1].env.scenario.lane_width == 3.2  # the dense preset's
    assert all(s.proximal_mu == 0.01 for s in specs)
    assert settings.env.scenario.human_arrival_period_steps == 25.0  # tests stay on it


def test_vehicles_sharing_a_worker_drive_as_they_would_alone():
    specs = [tiny_spec(0, "left"), tiny_spec(1, "straight"), tiny_spec(2, "right")]
    results = []
    for workers in (3, 1):
        with ProcessClientPool(specs, num_threads=1, num_workers=workers) as pool:
            updates = pool.train(60, upload=True, include_targets=True)
            later = pool.train(20, upload=False, include_targets=True, vehicles=[2])
        results.append((updates, later))
    (alone, alone_later), (shared, shared_later) = results
    for a, b in zip(alone, shared, strict=True):
        assert a.client == b.client
        np.testing.assert_array_equal(a.step_rewards, b.step_rewards)
        for key in a.parameters:
            assert torch.equal(a.parameters[key], b.parameters[key]), key
    assert [u.client for u in shared_later] == ["client2_right"]
    assert shared_later[0].total_steps == 80
    np.testing.assert_array_equal(alone_later[0].step_rewards, shared_later[0].step_rewards)


def test_vehicles_sent_the_same_message_share_one_frame(monkeypatch):
    from frl.federation import client_pool

    encoded = []

    def counting_encode(header, arrays=None):
        encoded.append(header["op"])
        return encode_frame(header, arrays)

    specs = [tiny_spec(0, "left"), tiny_spec(1, "straight"), tiny_spec(2, "right")]
    with ProcessClientPool(specs, num_threads=1, num_workers=2) as pool:
        monkeypatch.setattr(client_pool, "encode_frame", counting_encode)
        model = pool.get_model(0)
        pool.set_parameters(model, sync_targets=False)
        held = pool.get_parameters()

    # One frame for the three vehicles' global model, however many workers host them.
    assert encoded.count("sync") == 1
    for state in held:
        for key, tensor in model.items():
            assert torch.equal(state[key], tensor), key


def test_proximal_term_pulls_towards_the_global_model():
    from train_helpers import TINY_AGENT, TINY_ENV

    from frl.agents import DDPG
    from frl.envs import IntersectionEnv

    env = IntersectionEnv(TINY_ENV)
    try:
        agent = DDPG(env.observation_space, env.action_space, TINY_AGENT, seed=0)
    finally:
        env.close()
    agent.set_proximal_anchor(0.5)
    with torch.no_grad():
        for p in agent.actor.parameters():
            p.add_(1.0)
    pairs = agent.proximal.anchors[agent.actor_optimizer]
    for param, _ in pairs:
        param.grad = None
    agent.proximal.add_gradient(agent.actor_optimizer)
    assert len(pairs) == len(list(agent.actor.parameters()))
    assert len(agent.proximal.anchors[agent.critic_optimizer]) == len(
        list(agent.critic.parameters())
    )
    for param, pinned in pairs:
        torch.testing.assert_close(pinned, param.detach() - 1.0)  # the anchor did not move
        torch.testing.assert_close(param.grad, torch.full_like(param, 0.5))  # mu (w - anchor)
    agent.set_proximal_anchor(0.0)
    assert all(pairs == [] for pairs in agent.proximal.anchors.values())


class _Killed(Exception):
    pass


FLEET = [
    "federation.vehicles_per_task=2",
    "federation.tasks=[left,right]",
    "federation.fraction_train=0.5",
    "federation.strategy=fedadam",
    "+federation.strategy_params={eta: 0.001}",
    "federation.vehicle_arrival_period_steps=[25,50,25,50]",
    "eval_episodes=1",
    "yardsticks=[]",
    "cores=1",
]


def _server_state(run_dir: Path, completed_rounds: int) -> dict:
    return torch.load(
        run_dir / "checkpoints" / f"round_{completed_rounds:04d}" / "server.pt", weights_only=True
    )


@pytest.mark.slow
def test_a_sampled_fleet_with_a_server_optimiser_resumes_exactly(tmp_path):
    """The roadside unit's global model and Adam moments, and the draws, survive a kill.

    (As for every run, the episode running at the kill is dropped, so the resumed run's
    later steps are not those of an uninterrupted one.)"""
    saved = {}

    def keep_round_two(state):
        if state.completed_rounds == 2:
            saved["straight"] = _server_state(tmp_path / "straight", 2)

    straight = train(compose_config(tmp_path / "straight", FLEET), on_round_end=keep_round_two)

    def kill_after_round(state):
        if state.completed_rounds == 2:
            saved["killed"] = _server_state(tmp_path / "killed", 2)
            raise _Killed

    with pytest.raises(_Killed):
        train(compose_config(tmp_path / "killed", FLEET), on_round_end=kill_after_round)
    resumed = train(compose_config(tmp_path / "killed", [*FLEET, "resume=true"]))

    for part in ("global_model", "strategy"):
        a, b = saved["straight"][part], saved["killed"][part]
        assert set(a) == set(b) and a
        assert all(torch.equal(a[k], b[k]) for k in a)
    assert {k.split("/")[0] for k in saved["straight"]["strategy"]} == {"m", "v"}
    fleet = straight["fleet"]
    assert fleet["vehicles"] == 4 and fleet["vehicles_per_round"] == 2
    assert [len(p) for p in fleet["participants"]] == [2, 2, 2]
    assert sum(fleet["vehicle_steps"].values()) == 2 * 240
    for key in ("participants", "vehicle_steps"):
        assert resumed["fleet"][key] == fleet[key]
    assert straight["communication"]["total_bytes"] == resumed["communication"]["total_bytes"]
    # The drawn vehicles fetch the global model at the start of each round.
    assert straight["communication"]["downloads"] == 3 * 2


def test_a_separate_fleet_is_tested_per_task_over_its_vehicles(tmp_path):
    results = train(
        compose_config(
            tmp_path / "run",
            [
                "federation=separate",
                "federation.tasks=[left,right]",
                "federation.vehicles_per_task=2",
                "eval_episodes=2",
                "yardsticks=[]",
                "cores=1",
            ],
        )
    )
    index = json.loads((tmp_path / "run" / "models" / "index.json").read_text())
    assert index == {
        "left": ["client0_left.pt", "client2_left.pt"],
        "right": ["client1_right.pt", "client3_right.pt"],
    }
    per_task = json.loads((tmp_path / "run" / RESULTS_FILE).read_text())["evaluation"]["per_task"]
    assert per_task["left"]["episodes"] == 4  # 2 seeds x 2 vehicles
    assert results["evaluation"]["models"] == index
    tb = tmp_path / "run" / "tb" / "vehicles"
    vehicles = ["client0_left", "client1_right", "client2_left", "client3_right"]
    assert sorted(p.name for p in tb.iterdir()) == vehicles
    # The report reads each vehicle's episodes from its own TensorBoard run.
    record = load_run(tmp_path / "run")
    assert sorted(record.episodes) == vehicles
    counted = json.loads((tmp_path / "run" / RESULTS_FILE).read_text())["training"]["episodes"]
    assert {name: len(e.returns) for name, e in record.episodes.items()} == counted


def stackable_spec(index: int, task: str) -> ClientSpec:
    """A tiny vehicle whose agent can be stacked: the vehicles encoder, a collision budget."""
    spec = tiny_spec(index, task)
    agent = dataclasses.replace(spec.agent, encoder="vehicles", collision_budget=0.02)
    return dataclasses.replace(spec, agent=agent)


def test_vehicles_sharing_a_worker_can_learn_in_one_stacked_update(tmp_path):
    specs = [stackable_spec(0, "left"), stackable_spec(1, "straight"), stackable_spec(2, "right")]
    runs = []
    for workers, stacked in ((3, False), (1, True), (1, True)):
        state = tmp_path / f"run{len(runs)}"
        state.mkdir()
        with ProcessClientPool(
            specs, num_threads=1, num_workers=workers, stack_updates=stacked, state_dir=state
        ) as pool:
            first = pool.train(60, upload=True, include_targets=True)
            pool.save(state / "round_0001")
            second = pool.train(40, upload=True, include_targets=True)
            alone = pool.train(20, upload=True, include_targets=True, vehicles=[2])
        runs.append((first, second, alone))
    (one_by_one, _, _), (stacked, stacked_second, stacked_alone), (again, again_second, _) = runs
    for a, b in zip(one_by_one, stacked, strict=True):
        assert a.client == b.client and a.losses["critic_loss"].shape == (60,)
        # The same vehicles, their batched products rounded otherwise.
        np.testing.assert_allclose(a.step_rewards, b.step_rewards, atol=1e-3)
        for key in a.parameters:
            np.testing.assert_allclose(a.parameters[key], b.parameters[key], atol=1e-3)
        assert any(not torch.equal(a.parameters[k], b.parameters[k]) for k in a.parameters)
    # One seed, one stacked run; a vehicle drawn alone trains on its own after it.
    for a, b in zip(stacked + stacked_second, again + again_second, strict=True):
        np.testing.assert_array_equal(a.step_rewards, b.step_rewards)
        for key in a.parameters:
            assert torch.equal(a.parameters[key], b.parameters[key]), key
    assert stacked_alone[0].total_steps == 120
    # Killed after round 1: restored from its checkpoints, the stacked run goes on exactly.
    state = tmp_path / "run1"
    with ProcessClientPool(
        specs, num_threads=1, num_workers=1, stack_updates=True, state_dir=state
    ) as pool:
        pool.load(state / "round_0001")
        resumed = pool.train(40, upload=True, include_targets=True)
    for a, b in zip(stacked_second, resumed, strict=True):
        np.testing.assert_array_equal(a.step_rewards, b.step_rewards)
        for key in a.parameters:
            assert torch.equal(a.parameters[key], b.parameters[key]), key


@pytest.mark.parametrize(
    ("overrides", "match"),
    [
        (["federation.stack_updates=maybe"], "stack_updates must be true, false or auto"),
        (
            ["federation.stack_updates=true", "agent.encoder=flat"],
            "stack_updates=true: the vehicles cannot be stacked: their batches change shape",
        ),
        (
            [
                "federation.stack_updates=true", "federation.strategy=fedprox",
                "+federation.strategy_params={proximal_mu: 0.01}",
            ],
            r"FedProx's pull \(federation.strategy=fedprox\) is not stacked",
        ),
        (
            ["federation.stack_updates=true", "federation.backend=flower"],
            "federation.backend=flower runs each vehicle in a process of its own",
        ),
    ],
)  # fmt: skip
def test_stacking_vehicles_that_cannot_be_stacked_is_refused_before_anything_runs(overrides, match):
    with pytest.raises(ConfigError, match=match):
        validate(compose_config(None, overrides, tiny=False))


def test_vehicles_stack_where_asked_or_on_a_gpu_and_never_by_default_on_a_cpu():
    assert validate(compose_config(None, [], tiny=False)).stack_updates is False
    assert validate(compose_config(None, ["federation.stack_updates=true"], tiny=False))
    flat = ["agent.encoder=flat"]  # auto leaves what cannot be stacked alone
    assert validate(compose_config(None, flat, tiny=False)).stack_updates is False
