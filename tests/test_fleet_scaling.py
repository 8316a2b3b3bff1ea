"""The fleet benchmark's memory sampler: a process tree's PSS counts shared pages once."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import time
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"

pytestmark = pytest.mark.skipif(
    not Path("/proc/self/smaps_rollup").exists(), reason="needs Linux's /proc smaps_rollup"
)

# A parent that writes 64 MB, then forks a child that only reads it: the pages are shared.
SHARING_TREE = """
import os, sys, time
block = bytearray(64 * 1024 * 1024)
for i in range(0, len(block), 4096):
    block[i] = 1
child = os.fork()
if child == 0:
    total = sum(block[i] for i in range(0, len(block), 4096))
    time.sleep(3)
    os._exit(0)
print("ready", flush=True)
time.sleep(3)
os.waitpid(child, 0)
"""


def fleet_scaling():
    spec = importlib.util.spec_from_file_location(
        "_fleet_scaling_under_test", BENCHMARKS / "fleet_scaling.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_forked_child_sharing_its_parent_memory_is_counted_once():
    PeakMemory = fleet_scaling().PeakMemory
    mb = 1024 * 1024
    process = subprocess.Popen([sys.executable, "-c", SHARING_TREE], stdout=subprocess.PIPE)
    try:
        assert process.stdout is not None and process.stdout.readline().strip() == b"ready"
        memory = PeakMemory(process.pid, every_s=0.2)
        time.sleep(1.5)
        memory.stop()
    finally:
        process.wait(timeout=30)

    # RSS counts the 64 MB in both processes; PSS splits it between them.
    assert memory.peak_rss >= 128 * mb
    assert 64 * mb <= memory.peak_pss <= memory.peak_rss - 48 * mb
    roles = memory.roles_at_peak
    assert roles["coordinator"][0] == 1 and roles["workers"][0] == 1
    assert sum(size for _, size in roles.values()) == memory.peak_pss
