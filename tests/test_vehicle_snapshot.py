"""A vehicle saved mid-episode and loaded into a new vehicle drives on exactly."""

import dataclasses

import numpy as np
import pytest
from train_helpers import tiny_spec

from frl.federation import VehicleClient
from frl.federation.vehicle_snapshot import read_vehicle_snapshot, snapshot_path

# One xdist worker runs this module: libsumo holds one simulation per process.
pytestmark = pytest.mark.xdist_group("client")


def _same_updates(a, b) -> None:
    assert np.array_equal(a.step_rewards, b.step_rewards)
    for name in a.actions:
        assert np.array_equal(a.actions[name], b.actions[name]), name
    for name in a.losses:
        assert np.array_equal(a.losses[name], b.losses[name], equal_nan=True), name
    assert [dataclasses.asdict(e) for e in a.episodes] == [
        dataclasses.asdict(e) for e in b.episodes
    ]


@pytest.mark.parametrize(
    ("task", "route_observation"),
    [("left", False), ("random", True)],
    ids=["grid", "route-central"],
)
def test_a_vehicle_loaded_mid_episode_drives_on_as_if_never_stopped(
    tmp_path, task, route_observation
):
    spec = tiny_spec(0, task)
    spec = dataclasses.replace(
        spec, env=dataclasses.replace(spec.env, route_observation=route_observation)
    )
    driving = VehicleClient(spec)
    driving.train(45)  # past one 30-step episode, into the next
    assert driving._observation is not None and driving._episode_rewards  # mid-episode
    driving.save(tmp_path)
    went_on = driving.train(60)  # two episode ends, the critic bias of the saved one among them
    driving.close()  # libsumo: one simulation per process

    drive = read_vehicle_snapshot(snapshot_path(tmp_path, spec.name))
    assert drive.snapshot is not None and len(drive.episode_rewards) == 15

    resumed = VehicleClient(spec)
    assert resumed.load(tmp_path)
    _same_updates(went_on, resumed.train(60))
    assert resumed._restarts == 1  # the same simulation, never restarted
    resumed.close()


def test_a_checkpoint_without_a_drive_drops_the_episode(tmp_path):
    spec = tiny_spec(0, "left")
    vehicle = VehicleClient(spec)
    vehicle.train(45)
    vehicle.save(tmp_path)
    vehicle.close()
    snapshot_path(tmp_path, spec.name).unlink()  # as checkpoints were written before drives

    resumed = VehicleClient(spec)
    assert not resumed.load(tmp_path)
    update = resumed.train(10)
    assert resumed._restarts == 2  # a new simulation, on the next seed
    assert update.num_steps == 10
    resumed.close()
