"""benchmarks/stacked_update.py: the stacked update is each vehicle's own update."""

from __future__ import annotations

import copy
import importlib.util
import sys
from pathlib import Path

import pytest
import torch

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def stacked_update():
    spec = importlib.util.spec_from_file_location(
        "_stacked_update_under_test", BENCHMARKS / "stacked_update.py"
    )
    module = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(BENCHMARKS))  # it imports cpu_settings beside it
    try:
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(BENCHMARKS))
    return module


def test_three_vehicles_stacked_take_each_its_own_steps(stacked_update):
    torch.manual_seed(0)
    networks = [stacked_update.TrunkAndEncoder() for _ in range(3)]
    looped = stacked_update.LoopedUpdates(copy.deepcopy(networks), torch.device("cpu"), "float32")
    stacked = stacked_update.StackedUpdate(networks, torch.device("cpu"), "float32")
    slots, targets = stacked_update.make_inputs(3, torch.device("cpu"), seed=1)
    for _ in range(3):  # the second and third steps read Adam's state of the first
        loop_outputs = torch.stack(looped.step(slots, targets))
        stacked_outputs = stacked.step(slots, targets)
        torch.testing.assert_close(stacked_outputs, loop_outputs, rtol=1e-5, atol=1e-6)
    # Adam steps by about lr wherever a gradient is nonzero, so a gradient near 0 whose
    # rounding differs (another kernel) can move a parameter by up to lr a step.
    three_steps = 3 * 1e-4
    for vehicle, network in enumerate(looped.networks):
        for name, parameter in network.named_parameters():
            torch.testing.assert_close(
                stacked.params[name][vehicle], parameter, rtol=0, atol=three_steps
            )
    # And the vehicles did learn apart: their parameters differ.
    first = stacked.params["trunk.0.weight"]
    assert not torch.allclose(first[0], first[1])
