"""Traffic by round (``federation.round_arrival_period_factors``): each vehicle drives the
traffic of the round an episode starts in, is tested in its own, resumes in the traffic it
was in, and bad schedules are refused before anything runs."""

from __future__ import annotations

import dataclasses
import json

import pytest
from train_helpers import compose_config, load_script, tiny_spec

from frl.federation import VehicleClient
from frl.federation.assembly import client_specs
from frl.federation.codec import spec_from_json, spec_to_json
from frl.federation.traffic_schedule import describe_schedule, scheduled_env
from frl.train_config import ConfigError, validate
from frl.training import train

# One xdist worker runs this module: libsumo holds one simulation per process.
pytestmark = pytest.mark.xdist_group("client")

OWN_PERIOD = 25.0
BUSY_FACTOR = 0.4  # a car every 10 steps per flow


def _scheduled_spec(round_steps: int = 40):
    spec = tiny_spec(0, "left")
    return dataclasses.replace(
        spec, round_arrival_period_factors=(BUSY_FACTOR, 1.0), round_steps=round_steps
    )


def _period(vehicle: VehicleClient) -> float:
    return vehicle.env.config.scenario.human_arrival_period_steps


def test_the_schedule_holds_its_last_entry_and_leaves_the_rest_of_the_traffic():
    env = tiny_spec(0, "left").env
    periods = [
        scheduled_env(env, (0.6, 0.8), 100, steps).scenario.human_arrival_period_steps
        for steps in (0, 99, 100, 199, 200, 10_000)
    ]
    assert periods == [15.0, 15.0, 20.0, 20.0, 20.0, 20.0]
    busy = scheduled_env(env, (0.6,), 100, 0)
    assert dataclasses.replace(busy, scenario=env.scenario) == env
    assert scheduled_env(env, (), 0, 500) is env
    assert scheduled_env(env, (1.0,), 100, 0) is env
    assert describe_schedule((0.6, 0.6, 0.6, 1.0), 5) == (
        "rounds 1-3 at 0.6 times the humans' arrival period, rounds 4-5 at the run's"
    )


def test_each_episode_drives_the_traffic_of_the_round_it_starts_in():
    vehicle = VehicleClient(_scheduled_spec())
    starts = []  # (own step of the episode's first step, the traffic it drives)
    for step in range(1, 111):
        vehicle.train(1, upload=False)
        if vehicle._observation is not None and len(vehicle._episode_rewards) == 1:
            starts.append((step - 1, _period(vehicle)))
        elif vehicle._observation is not None:
            assert _period(vehicle) == starts[-1][1]  # an episode keeps its traffic
    assert {period for step, period in starts if step < 40} == {OWN_PERIOD * BUSY_FACTOR}
    assert {period for step, period in starts if step >= 40} == {OWN_PERIOD}
    vehicle.close()


def test_a_vehicle_is_tested_in_its_own_traffic_and_then_trains_on_in_its_round():
    vehicle = VehicleClient(_scheduled_spec())
    vehicle.train(10, upload=False)
    assert _period(vehicle) == OWN_PERIOD * BUSY_FACTOR
    assert len(vehicle.evaluate("left", [1])) == 1
    assert _period(vehicle) == OWN_PERIOD
    vehicle.train(1, upload=False)
    assert _period(vehicle) == OWN_PERIOD * BUSY_FACTOR
    vehicle.close()


def test_a_vehicle_loaded_mid_episode_drives_on_in_the_traffic_it_was_in(tmp_path):
    spec = _scheduled_spec()
    driving = VehicleClient(spec)
    driving.train(45, upload=False)  # in round 2, the busy round's last episode running
    assert driving._observation is not None and _period(driving) == OWN_PERIOD * BUSY_FACTOR
    at = driving.agent.num_env_steps
    driving.save(tmp_path)
    went_on = driving.train(60, upload=False)
    driving.close()
    assert json.loads((tmp_path / f"{spec.name}.json").read_text())[
        "arrival_period_steps"
    ] == pytest.approx(OWN_PERIOD * BUSY_FACTOR)

    resumed = VehicleClient(spec)
    assert resumed.load(tmp_path)
    assert resumed.agent.num_env_steps == at and _period(resumed) == OWN_PERIOD * BUSY_FACTOR
    again = resumed.train(60, upload=False)
    assert (again.step_rewards == went_on.step_rewards).all()
    assert [dataclasses.asdict(e) for e in again.episodes] == [
        dataclasses.asdict(e) for e in went_on.episodes
    ]
    assert _period(resumed) == OWN_PERIOD
    resumed.close()


def test_the_schedule_reaches_every_vehicle_and_survives_the_wire():
    settings = validate(
        compose_config(
            None,
            [
                "federation.round_arrival_period_factors=[0.6,1]",
                "federation.vehicle_arrival_period_steps=[25,50,25]",
            ],
        )
    )
    specs = client_specs(settings)
    assert all(s.round_arrival_period_factors == (0.6, 1.0) for s in specs)
    assert all(s.round_steps == 80 for s in specs)  # 40 updates, one every 2 steps
    assert spec_from_json(spec_to_json(specs[1])) == specs[1]
    busy = scheduled_env(specs[1].env, specs[1].round_arrival_period_factors, 80, 0)
    assert busy.scenario.human_arrival_period_steps == 30.0  # the vehicle's own, scaled
    assert settings.env.scenario.human_arrival_period_steps == 25.0  # tests stay on it
    unscheduled = client_specs(validate(compose_config(None)))
    assert all(s.round_arrival_period_factors == () and s.round_steps == 0 for s in unscheduled)


@pytest.mark.parametrize(
    ("factors", "match"),
    [
        ("[0.6,0.6,1,1]", r"round_arrival_period_factors has 4 entries for a run of 3 rounds"),
        ("[0.6,0]", r"round_arrival_period_factors must hold positive numbers, got 0"),
        ("[-1]", r"round_arrival_period_factors must hold positive numbers, got -1"),
        ("[nan]", r"round_arrival_period_factors must hold positive numbers, got nan"),
        ("[0.05]", r"round_arrival_period_factors: scenario.human_arrival_process=bernoulli"),
    ],
)
def test_bad_schedules_are_refused_before_anything_runs(tmp_path, factors, match):
    run_dir = tmp_path / "run"
    config = compose_config(run_dir, [f"federation.round_arrival_period_factors={factors}"])
    with pytest.raises(ConfigError, match=match):
        train(config)
    assert not run_dir.exists()


same_run = load_script("same_run")


class _Killed(Exception):
    pass


@pytest.mark.slow
def test_a_scheduled_run_killed_after_a_busy_round_resumes_to_the_same_run(tmp_path):
    overrides = [
        "federation.round_arrival_period_factors=[0.4,1]",
        "federation.tasks=[left,right]",
        "eval_episodes=1",
        "yardsticks=[]",
        "cores=1",
    ]
    straight = train(compose_config(tmp_path / "straight", overrides))
    assert straight["fleet"]["round_arrival_period_factors"] == [0.4, 1.0]

    def kill_after_the_busy_round(state):
        if state.completed_rounds == 1:
            raise _Killed

    with pytest.raises(_Killed):
        train(
            compose_config(tmp_path / "killed", overrides), on_round_end=kill_after_the_busy_round
        )
    checkpoint = tmp_path / "killed" / "checkpoints" / "round_0001"
    periods = [
        json.loads(p.read_text())["arrival_period_steps"] for p in checkpoint.glob("client*.json")
    ]
    assert periods == [10.0, 10.0]
    train(compose_config(tmp_path / "killed", [*overrides, "resume=true"]))
    assert same_run.differences(tmp_path / "straight", tmp_path / "killed") == []
