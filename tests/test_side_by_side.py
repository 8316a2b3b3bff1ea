"""Multirun jobs side by side: the job list Hydra would run, the cores each gets, and a
runner that keeps at most N going, logs each and survives a failed one."""

import os
import sys
import time
from types import SimpleNamespace

import pytest
from train_helpers import compose_config

from frl import reproduce, side_by_side
from frl.side_by_side import (
    cores_per_job,
    expand_jobs,
    run_side_by_side,
    sweeper_params,
    with_cores,
)


def test_the_jobs_are_hydras_product_with_the_command_line_winning():
    params = {"seed": "0,1,2", "federation": "fedavg,separate"}
    jobs = expand_jobs(params, ["seed=5,6", "agent=ddpg-paper", "+foo=[a,b]"])
    assert jobs == [
        ["seed=5", "federation=fedavg", "agent=ddpg-paper", "+foo=[a,b]"],
        ["seed=5", "federation=separate", "agent=ddpg-paper", "+foo=[a,b]"],
        ["seed=6", "federation=fedavg", "agent=ddpg-paper", "+foo=[a,b]"],
        ["seed=6", "federation=separate", "agent=ddpg-paper", "+foo=[a,b]"],
    ]


def test_a_presets_sweep_is_read_from_its_config():
    assert sweeper_params("fig6") == {"seed": "0,1,2", "interval": "250,500,1000,2500,5000,10000"}


def test_the_cores_are_shared_and_never_overbooked():
    assert cores_per_job(2, cores=2) == 1
    assert cores_per_job(3, cores=16) == 5
    with pytest.raises(ValueError, match="3 jobs side by side need at least 3 cores; 2"):
        cores_per_job(3, cores=2)
    with pytest.raises(ValueError, match="jobs must be >= 1"):
        cores_per_job(0, cores=2)
    assert with_cores(["seed=0"], 1) == ["seed=0", "cores=1"]
    assert with_cores(["cores=2", "seed=0"], 1) == ["cores=2", "seed=0"]


def _sleeper(tmp_path, name: str, code: int = 0) -> list[str]:
    script = (
        "import sys, time, pathlib; d = pathlib.Path(sys.argv[1]);"
        f"(d / '{name}.start').write_text(str(time.time())); time.sleep(1.5);"
        f"(d / '{name}.end').write_text(str(time.time())); print('{name} done');"
        f"sys.exit({code})"
    )
    return [sys.executable, "-c", script, str(tmp_path)]


def test_at_most_n_run_at_once_and_a_failure_stops_none(tmp_path):
    names = ["a", "b", "c", "d"]
    commands = [_sleeper(tmp_path, n, code=3 if n == "b" else 0) for n in names]
    began = time.time()
    outcomes = run_side_by_side(commands, 2, tmp_path / "logs", names)
    assert sorted((o.label, o.returncode) for o in outcomes) == [
        ("a", 0), ("b", 3), ("c", 0), ("d", 0)
    ]  # fmt: skip
    spans = [
        (float((tmp_path / f"{n}.start").read_text()), float((tmp_path / f"{n}.end").read_text()))
        for n in names
    ]
    for moment in [start + 0.1 for start, _ in spans]:  # never three at once
        assert sum(start <= moment <= end for start, end in spans) <= 2
    assert time.time() - began < 4 * 1.5  # two at a time, not one after another
    assert (tmp_path / "logs" / "c.log").read_text().strip() == "c done"


def test_reproduce_gives_each_job_its_own_multirun_and_share(capsys):
    assert reproduce.main(["--jobs", "2", "--dry-run", "--figures", "fig4", "--seeds", "0,1",
                           "--", "agent=ddpg-paper"]) == 0  # fmt: skip
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 6
    assert "-m +experiment=fig4 seed=1 federation=separate agent=ddpg-paper cores=1" in lines[4]
    assert all("hydra.sweep.dir=outputs/repro/runs/fig4" in line for line in lines)


def test_the_guided_panel_is_fig4_on_the_guided_agent_under_guided(capsys):
    assert reproduce.main(["--jobs", "2", "--dry-run", "--figures", "fig5-guided",
                           "--seeds", "3", "--runs-dir", "r", "--data-dir", "d"]) == 0  # fmt: skip
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 3  # the three schemes; fig5-guided is fig4-guided's runs
    assert all("-m +experiment=fig4-guided seed=3 federation=" in line for line in lines)
    assert all("hydra.sweep.dir=r/guided/fig4 hydra.callbacks.export_run.data_dir=d/guided/fig4"
               in line for line in lines)  # fmt: skip
    assert sweeper_params("fig4-guided") == sweeper_params("fig4")
    guided, default = (compose_config(None, [f"+experiment={name}"])
                       for name in ("fig4-guided", "fig4"))  # fmt: skip
    assert guided.agent.guide == "gap_acceptance" and default.agent.guide == "none"
    assert guided.round_test_episodes == default.round_test_episodes == 20


def test_reproduce_refuses_more_jobs_than_cores(capsys):
    with pytest.raises(SystemExit) as info:
        reproduce.main(["--jobs", "64", "--dry-run"])
    assert info.value.code == 2
    assert "--jobs: 64 jobs side by side need at least 64 cores" in capsys.readouterr().err


def test_an_interrupt_stops_every_running_job(tmp_path, monkeypatch):
    polls = []

    def interrupt_on_the_third_poll(seconds):
        polls.append(seconds)
        if len(list(tmp_path.glob("*.pid"))) == 2:  # both started and running
            raise KeyboardInterrupt
        time.sleep(0.2)

    monkeypatch.setattr(
        side_by_side,
        "time",
        SimpleNamespace(sleep=interrupt_on_the_third_poll, perf_counter=time.perf_counter),
    )
    script = (
        "import os, sys, time, pathlib;"
        "pathlib.Path(sys.argv[1]).write_text(str(os.getpid())); time.sleep(120)"
    )
    commands = [[sys.executable, "-c", script, str(tmp_path / f"{i}.pid")] for i in range(3)]

    with pytest.raises(KeyboardInterrupt):
        run_side_by_side(commands, 2, tmp_path / "logs")

    pids = [int(p.read_text()) for p in sorted(tmp_path.glob("*.pid"))]
    assert len(pids) == 2  # the third never started
    deadline = time.time() + 20
    while time.time() < deadline and any(_alive(pid) for pid in pids):
        time.sleep(0.1)
    assert not any(_alive(pid) for pid in pids)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (ended, not yet reaped) is gone for our purpose
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False
