"""Each traffic preset builds the traffic it claims, read back from SUMO."""

import math

import numpy as np
import pytest

from frl.envs import TRAFFIC_PRESETS, ScenarioConfig, traffic_name, traffic_preset
from frl.envs.scenario import build_scenario
from frl.envs.sumo_backend import SumoSimulation

SIMULATED_S = 1200.0


def _departures(scenario: ScenarioConfig, seed: int) -> tuple[dict[str, int], list[float], float]:
    """Departures per flow and the humans' speed factors over SIMULATED_S, and a lane width."""
    import libsumo  # the simulation below owns libsumo; reads go through the same module

    simulation = SumoSimulation(build_scenario(scenario), scenario, backend="libsumo", gui=False)
    simulation.start(seed)
    counts = {"human_we": 0, "human_ew": 0}
    factors = []
    try:
        for _ in range(round(SIMULATED_S / scenario.step_length)):
            for vehicle in simulation.step().departed:
                counts[vehicle.split(".")[0]] += 1
                factors.append(libsumo.vehicle.getSpeedFactor(vehicle))
        width = libsumo.lane.getWidth("W2C_0")
    finally:
        simulation.close()
    return counts, factors, width


@pytest.mark.parametrize("name", list(TRAFFIC_PRESETS))
def test_each_preset_departs_at_its_rate_with_its_lanes_and_speed_spread(name):
    scenario = traffic_preset(name)
    counts, factors, width = _departures(scenario, seed=11)
    expected = SIMULATED_S / scenario.human_period_seconds  # per flow
    for flow, count in counts.items():
        # Departures are Poisson-like: 4.5 standard deviations keep a false alarm below
        # 1e-5, while the other preset's rate (2.5x apart) lies far outside.
        assert abs(count - expected) < 4.5 * math.sqrt(expected), (flow, count, expected)
    assert width == pytest.approx(scenario.lane_width)
    spread = float(np.std(factors))
    assert spread == pytest.approx(scenario.human_speed_dev, abs=0.025)


def test_presets_are_what_the_docs_say():
    paper, dense = traffic_preset("paper"), traffic_preset("dense")
    assert paper == ScenarioConfig()  # the calibrated traffic is the default
    assert paper.human_period_seconds == pytest.approx(10.0)  # one car per 10 s per flow
    assert (paper.lane_width, paper.human_speed_dev) == (4.0, 0.1)
    assert dense.human_period_seconds == pytest.approx(4.0)
    assert (dense.lane_width, dense.human_speed_dev) == (3.2, 0.0)
    assert traffic_name(paper) == "paper" and traffic_name(dense) == "dense"
    assert traffic_name(traffic_preset("paper", lane_width=3.5)) == "custom"


def test_bad_traffic_settings_fail_clearly():
    with pytest.raises(ValueError, match=r"unknown traffic preset 'rush'.*paper, dense"):
        traffic_preset("rush")
    with pytest.raises(ValueError, match="human_speed_dev"):
        ScenarioConfig(human_speed_dev=-0.1)
    # SUMO's per-second probability cannot exceed 1: one car per 0.8 s per flow.
    with pytest.raises(ValueError, match="bernoulli needs at most one departure per second"):
        ScenarioConfig(human_arrival_process="bernoulli", human_arrival_period_steps=2)
    with pytest.raises(ValueError, match="human_arrival_process"):
        ScenarioConfig(human_arrival_process="uniform")
