"""benchmarks/matmul_peak.py: a step's matrix products counted as FlopCounterMode counts
them, and timed alone."""

from __future__ import annotations

import importlib.util
import itertools
import sys
from pathlib import Path

import pytest
import torch
from torch import nn
from torch.utils.flop_counter import FlopCounterMode

PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "matmul_peak.py"


@pytest.fixture(scope="module")
def matmul_peak():
    spec = importlib.util.spec_from_file_location("_matmul_peak_under_test", PATH)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # NamedTuples look their module up
    spec.loader.exec_module(module)
    yield module
    del sys.modules[spec.name]


def _update_step(dtype: torch.dtype):
    """One forward and backward of a small MLP (an update's shape of work), in ``dtype``."""
    torch.manual_seed(0)
    net = nn.Sequential(nn.Linear(12, 32), nn.ReLU(), nn.Linear(32, 8), nn.ReLU(), nn.Linear(8, 1))
    batch = torch.randn(16, 12)

    def step() -> None:
        with torch.autocast("cpu", dtype=dtype, enabled=dtype != torch.float32):
            loss = net(batch).float().square().mean()
        loss.backward()
        with torch.no_grad():  # acting: one row
            net(batch[:1])

    return step


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
def test_the_flops_are_flop_counter_modes(matmul_peak, dtype):
    step = _update_step(dtype)
    with FlopCounterMode(display=False) as counter:
        step()
    with matmul_peak.MatmulLog() as log:
        step()
    assert log.flops == counter.get_total_flops() > 0
    dtypes = {arg.dtype for p in log.products for arg in p.args if hasattr(arg, "dtype")}
    assert dtype in dtypes  # the products are recorded in the dtype they ran in


def test_a_batched_product_counts_its_batch(matmul_peak):
    left, right = torch.randn(3, 4, 5), torch.randn(3, 5, 6)
    with matmul_peak.MatmulLog() as log:
        torch.bmm(left, right)
        torch.baddbmm(torch.zeros(3, 4, 6), left, right)
    assert log.flops == 2 * (2 * 3 * 4 * 5 * 6)


def test_the_same_products_are_counted_not_stored_again(matmul_peak):
    step = _update_step(torch.float32)
    with matmul_peak.MatmulLog() as once:
        step()
    with matmul_peak.MatmulLog() as twice:
        step()
        step()
    assert set(twice.products) == set(once.products)
    assert all(twice.products[p] == 2 * n for p, n in once.products.items())


def test_the_peak_is_each_product_at_its_best_times_its_count(matmul_peak):
    step = _update_step(torch.float32)
    with matmul_peak.MatmulLog() as log:
        step()
    ticks = itertools.count()
    # A clock that moves one second per reading: every timed call takes exactly 1 s.
    seconds = matmul_peak.peak_seconds(log.products, repeats=3, clock=lambda: float(next(ticks)))
    assert seconds == sum(log.products.values())


def test_measured_arithmetic_gives_a_share_of_the_step(matmul_peak):
    step = _update_step(torch.float32)
    arithmetic = matmul_peak.measure_arithmetic(lambda: [step() for _ in range(4)], steps=4)
    with matmul_peak.MatmulLog() as log:
        step()
    assert arithmetic.flops_per_step == log.flops
    assert arithmetic.peak_seconds_per_step > 0
    assert arithmetic.share_of_peak(2 * arithmetic.peak_seconds_per_step) == pytest.approx(0.5)
    assert arithmetic.peak_flops_per_second == pytest.approx(
        log.flops / arithmetic.peak_seconds_per_step
    )


def test_steps_without_products_or_a_count_are_refused(matmul_peak):
    with pytest.raises(ValueError, match="steps must be positive"):
        matmul_peak.measure_arithmetic(lambda: None, steps=0)
    with pytest.raises(ValueError, match="no matrix product"):
        matmul_peak.measure_arithmetic(lambda: torch.ones(3).sum(), steps=1)
