"""scripts/config_walk.py: what counts as a climb back up the layers, and the walk it
records (a profile of first calls, in order)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def walk_tool():
    spec = importlib.util.spec_from_file_location("config_walk", ROOT / "scripts/config_walk.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["config_walk"] = module
    spec.loader.exec_module(module)
    yield module
    del sys.modules["config_walk"]


def test_a_climb_is_a_step_to_a_higher_layer(walk_tool):
    layers = {"frl.training": 6, "frl.federation.plan": 3, "frl.fileio": 0, "frl.envs": 1}
    walk = [
        ("frl.training", "train"),
        ("frl.federation.plan", "FederationPlan.fleet_size"),  # down
        ("frl.fileio", "read_json"),  # down
        ("frl.envs", "EnvConfig.__post_init__"),  # up: 1
        ("frl.training", "schedule_line"),  # up: 2
        ("frl.training", "train_rounds"),  # same layer
    ]
    assert walk_tool.climbs(walk, layers.__getitem__) == [3, 4]
    assert walk_tool.climbs(walk[:3], layers.__getitem__) == []


def test_the_walk_lists_frl_functions_once_in_order_of_first_call(walk_tool, tmp_path):
    from frl.fileio import read_json, write_json_atomic

    def entry(path: Path) -> None:
        write_json_atomic(path, {"a": 1})
        read_json(path)
        read_json(path)

    walk = walk_tool.first_calls(entry, tmp_path / "x.json")
    functions = [function for module, function in walk if module == "frl.fileio"]
    assert functions.index("write_json_atomic") < functions.index("read_json")
    assert functions.count("read_json") == 1
    assert all(module.startswith("frl") for module, _ in walk)  # the entry here is no frl's
    assert walk_tool.module_of(__file__) is None


def test_the_way_from_the_command_to_the_run_climbs_back_at_most_15_times(walk_tool, tmp_path):
    # A newcomer following ``cfg`` from ``training.train`` reads down the layers, coming
    # back up at most 15 times; ``open_run``, the model of it, 4 times (docs/layout.md).
    from frl.run_opening import open_run
    from frl.training import train

    layer_of = walk_tool.layering().layer_of
    cfg = walk_tool.tiny_config(tmp_path / "run")
    assert len(walk_tool.climbs(walk_tool.first_calls(open_run, cfg, None), layer_of)) <= 4
    walk = walk_tool.first_calls(train, cfg)
    assert len(walk) > 150  # the whole run was walked, not a refusal
    assert len(walk_tool.climbs(walk, layer_of)) <= 15
