"""``federation.backend=flower``: parity with the in-process backend, a vehicle killed
mid-round, the failure policy, and no process left behind. The deployment runtime's
parity is tested where it is killed and resumed (tests/test_flower_kill_and_resume.py):
its finished run must equal the in-process run to the last bit.

Skipped (not failed) where Flower is not installed: ``pip install -e '.[flower]'``.
"""

import json
import multiprocessing
import os
import signal
from pathlib import Path

import numpy as np
import pytest
import torch
from train_helpers import compose_config, load_script

pytest.importorskip("flwr")

from frl.federation import ClientFailure
from frl.train import train
from frl.train_config import ConfigError, validate

# One xdist worker runs this module and test_launchers.py: both start local Ray clusters
# (but for the deployment test below).
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("ray-and-flower")]

same_run = load_script("same_run")

# Four rounds of 40 steps, learning from step 40 on: before the Flower backend averaged
# with frl's arithmetic, its step rewards parted from the in-process run's in round 2.
# One test episode per task beside one yardstick compares the test tables too.
ROUNDS = ["total_steps=160", "interval=20", "eval_episodes=1", "yardsticks=[full_throttle]"]
TWO_ROUNDS = ["total_steps=80", "interval=20", "eval_episodes=0"]
FLOWER = ["federation.backend=flower"]


def _global_model(run_dir: Path) -> dict[str, torch.Tensor]:
    networks = torch.load(run_dir / "models" / "global.pt", weights_only=True)["networks"]
    return {f"{net}.{k}": v for net, state in networks.items() for k, v in state.items()}


def _assert_same_model(a: Path, b: Path) -> None:
    """Bit for bit: a difference in the last bits after two rounds grows over a real run
    into another driver."""
    first, second = _global_model(a), _global_model(b)
    assert first.keys() == second.keys()
    different = [key for key in first if not torch.equal(first[key], second[key])]
    assert different == []
    rewards = [np.load(run / "step_rewards.npy") for run in (a, b)]
    assert np.array_equal(*rewards)  # every step of every round, to the last bit


def _assert_same_run(a: Path, b: Path) -> None:
    """The global model, every vehicle's final model, every step reward and the test
    table, bit for bit (``scripts/same_run.py``)."""
    _assert_same_model(a, b)
    assert same_run.differences(a, b) == []


@pytest.fixture(scope="module")
def in_process_run(tmp_path_factory):
    """The reference: four rounds of FedAvg-DDPG on the in-process backend, then a test."""
    run_dir = tmp_path_factory.mktemp("processes") / "run"
    train(compose_config(run_dir, ROUNDS))
    return run_dir


def test_simulation_matches_the_in_process_backend(in_process_run, tmp_path):
    run_dir = tmp_path / "run"

    results = train(compose_config(run_dir, [*ROUNDS, *FLOWER, "round_test_episodes=1"]))

    _assert_same_run(in_process_run, run_dir)  # the round tests leave the training alone
    reference = json.loads((in_process_run / "results.json").read_text())
    assert results["backend"] == "flower" and reference["backend"] == "processes"
    assert results["communication"] == reference["communication"]
    assert results["training"]["final_step_reward"] == reference["training"]["final_step_reward"]
    assert results["training"]["episodes"] == reference["training"]["episodes"]
    assert set(results) == set(reference)
    assert results["evaluation"]["per_task"]["left"]["episodes"] == 1
    assert [point["step"] for point in results["round_tests"]["points"]] == [40, 80, 120, 160]
    assert sorted(os.listdir(run_dir / "tb")) and (run_dir / "state.json").exists()
    assert multiprocessing.active_children() == []


FLEET = [
    "federation.vehicles_per_task=2",
    "federation.tasks=[left,right]",
    "federation.fraction_train=0.5",
    "federation.strategy=fedavgm",
    "+federation.strategy_params={server_momentum: 0.5}",
    "federation.vehicle_arrival_period_steps=[25,50,25,50]",
    "total_steps=120",
    "interval=20",  # updates: 40 steps a round at the tiny agent's train_freq=2
    "eval_episodes=0",
    "cores=1",
]


def test_a_sampled_fleet_with_flowers_fedavgm_matches_the_processes_backend(tmp_path):
    """Four vehicles, two drawn per round, Flower's own FedAvgM at the roadside unit."""
    reference = train(compose_config(tmp_path / "processes", FLEET))
    results = train(compose_config(tmp_path / "flower", [*FLEET, *FLOWER]))

    assert results["fleet"]["participants"] == reference["fleet"]["participants"]
    assert results["fleet"]["vehicle_steps"] == reference["fleet"]["vehicle_steps"]
    assert results["communication"] == reference["communication"]
    # Flower's FedAvgM is Flower's arithmetic, frl's the processes backend's: to rounding.
    first, second = (_global_model(tmp_path / name) for name in ("processes", "flower"))
    for key in first:
        torch.testing.assert_close(first[key], second[key], rtol=0, atol=1e-6, msg=key)
    assert multiprocessing.active_children() == []


def test_a_vehicle_killed_mid_round_is_dropped_and_the_run_goes_on(tmp_path):
    run_dir = tmp_path / "run"
    cfg = compose_config(run_dir, [*TWO_ROUNDS, *FLOWER, "federation.flower.min_clients=2"])
    victims = []

    def kill_before_round_two(state):  # round 2 then finds the vehicle gone
        if state.completed_rounds == 1:
            victim = next(
                p for p in multiprocessing.active_children() if p.name.endswith("client1_straight")
            )
            victims.append(victim.pid)
            os.kill(victim.pid, signal.SIGKILL)

    results = train(cfg, on_round_end=kill_before_round_two)

    assert victims and results["rounds"] == 2
    dropped = results["training"]["dropped_clients"]
    assert list(dropped) == ["client1_straight"] and dropped["client1_straight"].startswith("train")
    assert results["communication"]["uploads"] == 3 + 2  # round 2 averaged the other two
    assert (run_dir / "models" / "global.pt").exists()
    state = json.loads((run_dir / "state.json").read_text())
    assert list(state["dropped_clients"]) == ["client1_straight"]
    assert multiprocessing.active_children() == []


def test_the_failure_policy_stops_or_drops_as_configured(tmp_path):
    from train_helpers import tiny_spec

    from frl.flower.grid_pool import FlowerClientPool

    specs = [tiny_spec(i, task) for i, task in enumerate(["left", "straight", "right"])]

    def pool(**policy):
        return FlowerClientPool(None, specs, tmp_path, "run", **policy)

    strict = pool(accept_failures=False)
    with pytest.raises(ClientFailure, match=r"client1_straight failed: boom(.|\n)*accept_failures"):
        strict._handle_failures("train", {1: "boom"})

    tolerant = pool(accept_failures=True, min_clients=2)
    tolerant._handle_failures("train", {1: "boom"})
    assert tolerant.names == ["client0_left", "client2_right"]
    assert tolerant.dropped == {"client1_straight": "train: boom"}
    with pytest.raises(ClientFailure, match="only 1 vehicles remain, fewer than min_clients=2"):
        tolerant._handle_failures("train", {2: "gone"})

    separate = pool(accept_failures=True, aggregates=False)
    with pytest.raises(ClientFailure, match="does not aggregate"):
        separate._handle_failures("train", {0: "boom"})


def test_flower_settings_are_checked_before_anything_starts():
    with pytest.raises(ConfigError, match="runtime"):
        validate(compose_config(None, [*FLOWER, "federation.flower.runtime=cloud"]))
    with pytest.raises(ConfigError, match="min_clients=4 exceeds the 3 vehicles that train"):
        validate(compose_config(None, [*FLOWER, "federation.flower.min_clients=4"]))
    with pytest.raises(ConfigError, match="host:port"):
        validate(compose_config(None, [*FLOWER, "federation.flower.superlink=nowhere"]))
    assert validate(compose_config(None, FLOWER)).flower.runtime == "simulation"
