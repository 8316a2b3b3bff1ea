"""Worker processes: results in order, and failures that name the client and leave no orphans."""

import multiprocessing
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from worker_helpers import BrokenAtStart, DenormalProbe, Echo

from frl.federation import ClientFailure, WorkerPool, threads_per_worker
from frl.federation.workers import flush_denormals


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # A zombie still answers kill(0); read its state.
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _assert_all_gone(pids):
    assert multiprocessing.active_children() == []
    assert not any(_alive(pid) for pid in pids)


def _pool(names=("client0_left", "client1_straight"), factory=Echo, **kwargs):
    return WorkerPool([(name, factory) for name in names], num_threads=1, **kwargs)


def test_calls_run_in_every_worker_and_come_back_in_order():
    progress = []
    with _pool() as pool:
        pids = pool.pids
        assert sorted(pool.call("pid")) == sorted(pids)
        assert pool.call("add", args=[(1, 2), (10, 20)]) == [3, 30]
        assert pool.call("add", args=[(5, 5)], workers=[1]) == [10]
        assert pool.call("chatty", args=[(3,), (2,)], on_progress=lambda i, p: progress.append(i))
    assert sorted(progress) == [0, 0, 0, 1, 1]
    _assert_all_gone(pids)


def test_an_exception_in_a_worker_names_the_client_and_stops_all():
    with (
        pytest.raises(ClientFailure, match="client client1_straight failed: SumoError") as info,
        _pool() as pool,
    ):
        pids = pool.pids
        pool.call("fail", workers=[1])
    assert "SUMO lost its connection" in str(info.value)
    assert "traceback in the worker of client1_straight" in str(info.value)
    _assert_all_gone(pids)


def test_a_failing_constructor_names_the_client():
    expected = "client client0_left failed: SumoError: could not"
    with (
        pytest.raises(ClientFailure, match=expected),
        WorkerPool([("client0_left", BrokenAtStart)], num_threads=1),
    ):
        pass
    assert multiprocessing.active_children() == []


def test_a_killed_worker_stops_the_run_naming_the_client():
    with pytest.raises(ClientFailure) as info, _pool(poll_s=0.1) as pool:
        pids = pool.pids
        victim = pids[0]
        threading.Timer(0.5, os.kill, (victim, signal.SIGKILL)).start()
        started = time.monotonic()
        pool.call("sleep", args=[(30.0,), (30.0,)])
    assert time.monotonic() - started < 10  # noticed long before the call would end
    message = str(info.value)
    assert "client client0_left failed" in message
    assert "SIGKILL" in message
    assert info.value.client == "client0_left"
    _assert_all_gone(pids)


def test_a_worker_that_exits_is_reported_with_its_exit_code():
    with (
        pytest.raises(ClientFailure, match=r"client1_straight failed: .*exit code 7"),
        _pool() as pool,
    ):
        pids = pool.pids
        pool.call("exit_hard", workers=[1])
    _assert_all_gone(pids)


def test_a_call_past_the_timeout_raises():
    with (
        pytest.raises(ClientFailure, match="client0_left failed: no answer within"),
        _pool(names=("client0_left",), timeout_s=0.5, poll_s=0.1) as pool,
    ):
        pids = pool.pids
        pool.call("sleep", args=[(30.0,)])
    _assert_all_gone(pids)


def test_keyboard_interrupt_in_the_parent_stops_the_workers():
    with pytest.raises(KeyboardInterrupt), _pool() as pool:
        pids = pool.pids
        raise KeyboardInterrupt
    _assert_all_gone(pids)


def _can_flush_denormals() -> bool:
    import torch

    supported = flush_denormals()
    torch.set_flush_denormal(False)  # this process's default again
    return supported


@pytest.mark.skipif(not _can_flush_denormals(), reason="this CPU cannot flush denormals")
def test_workers_flush_denormals_on_every_thread():
    # Adam's decayed running means are denormal, and slow to compute on; workers flush them.
    with WorkerPool([("client0_left", DenormalProbe)], num_threads=2) as pool:
        [(alone, many)] = pool.call("products")
    assert (alone, many) == (0.0, 0.0)


def test_threads_split_the_cores():
    assert threads_per_worker(3, cores=2) == 1
    assert threads_per_worker(1, cores=2) == 2
    assert threads_per_worker(2, cores=16) == 8


def test_workers_exit_when_the_coordinator_is_killed(tmp_path):
    script = tmp_path / "coordinator.py"
    script.write_text(
        "import sys, time\n"
        "from worker_helpers import Echo\n"
        "from frl.federation import WorkerPool\n"
        "if __name__ == '__main__':\n"
        "    pool = WorkerPool([('client0_left', Echo)], num_threads=1)\n"
        "    pool.start()\n"
        "    print(pool.pids[0], flush=True)\n"
        "    pool.call('sleep', args=[(60.0,)])\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).parent), *sys.path])}
    coordinator = subprocess.Popen(
        [sys.executable, str(script)], stdout=subprocess.PIPE, text=True, env=env
    )
    worker_pid = int(coordinator.stdout.readline())
    coordinator.kill()
    coordinator.wait(timeout=10)
    deadline = time.monotonic() + 10
    while _alive(worker_pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(worker_pid), "the worker outlived its coordinator"
