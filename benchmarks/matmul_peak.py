"""How close a training step runs to the machine's limit: the matrix products it makes,
their FLOPs, and the time the same products take on their own.

:class:`MatmulLog` watches a step below autograd and autocast (a torch dispatch mode, as
``torch.utils.flop_counter.FlopCounterMode`` does) and counts each matrix product by its
shapes, strides and dtype. :func:`peak_seconds` then times each distinct product alone,
on fresh tensors of the same layout, in the same process and on the same threads: the
time a step's arithmetic takes at this machine's measured speed for exactly these shapes.
A step's share of that peak is ``peak seconds / step seconds``.

Only matrix products count (``mm``, ``addmm``, ``bmm``, ``baddbmm``): the arithmetic of
these MLPs, as FlopCounterMode counts it. A sparse first layer's gather-and-sum
(``embedding_bag``) is no matrix product and is left out of both sides.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from typing import Any, NamedTuple

import torch
from torch.utils._python_dispatch import TorchDispatchMode

aten = torch.ops.aten
MATRIX_PRODUCTS = (aten.mm.default, aten.addmm.default, aten.bmm.default, aten.baddbmm.default)


class TensorLayout(NamedTuple):
    size: tuple[int, ...]
    stride: tuple[int, ...]
    dtype: torch.dtype
    device: torch.device


class MatrixProduct(NamedTuple):
    """One matrix product as the step made it: the op, its arguments' layouts (a
    :class:`TensorLayout` where a tensor was) and its keyword arguments."""

    op: Any
    args: tuple[Any, ...]
    kwargs: tuple[tuple[str, Any], ...]

    @property
    def flops(self) -> int:
        """2 m k n (times the batch): a multiply and an add per term, as FlopCounterMode
        counts; ``addmm``'s bias add is not counted."""
        tensors = [arg for arg in self.args if isinstance(arg, TensorLayout)]
        left, right = tensors[-2].size, tensors[-1].size
        batch = left[0] if len(left) == 3 else 1
        return 2 * batch * left[-2] * left[-1] * right[-1]


def _layout(value: Any) -> Any:
    if isinstance(value, torch.Tensor):
        return TensorLayout(tuple(value.shape), tuple(value.stride()), value.dtype, value.device)
    return value


class MatmulLog(TorchDispatchMode):
    """Counts the matrix products made inside ``with MatmulLog() as log:``."""

    def __init__(self) -> None:
        super().__init__()
        self.products: Counter[MatrixProduct] = Counter()

    def __torch_dispatch__(
        self, func: Any, types: Any, args: tuple = (), kwargs: dict | None = None
    ) -> Any:
        kwargs = kwargs or {}
        if func in MATRIX_PRODUCTS:
            args_layout = tuple(_layout(arg) for arg in args)
            kwargs_layout = tuple(sorted((k, _layout(v)) for k, v in kwargs.items()))
            self.products[MatrixProduct(func, args_layout, kwargs_layout)] += 1
        return func(*args, **kwargs)

    @property
    def flops(self) -> int:
        return sum(product.flops * count for product, count in self.products.items())


def _fresh(value: Any, generator: torch.Generator) -> Any:
    """A tensor of ``value``'s layout with random contents (or ``value`` itself)."""
    if not isinstance(value, TensorLayout):
        return value
    tensor = torch.empty_strided(value.size, value.stride, dtype=value.dtype, device=value.device)
    if tensor.device.type == "cpu":
        return tensor.copy_(torch.randn(value.size, generator=generator))
    return tensor.normal_()


def _synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def peak_seconds(
    products: Counter[MatrixProduct], repeats: int = 20, clock: Callable[[], float] | None = None
) -> float:
    """Seconds that ``products`` (each made as often as counted) take on their own: each
    distinct product timed alone, ``repeats`` calls after one warm-up, at its best."""
    clock = clock or time.perf_counter
    generator = torch.Generator().manual_seed(0)
    total = 0.0
    for product, count in products.items():
        args = [_fresh(arg, generator) for arg in product.args]
        kwargs = {key: _fresh(value, generator) for key, value in product.kwargs}
        devices = [arg.device for arg in args if isinstance(arg, torch.Tensor)]
        product.op(*args, **kwargs)
        best = float("inf")
        for _ in range(repeats):
            _synchronize(devices[0])
            started = clock()
            product.op(*args, **kwargs)
            _synchronize(devices[0])
            best = min(best, clock() - started)
        total += best * count
    return total


class Arithmetic(NamedTuple):
    """A step's matrix products: FLOPs per step and their seconds on their own."""

    flops_per_step: float
    peak_seconds_per_step: float

    def share_of_peak(self, step_seconds: float) -> float:
        """How much of the step the arithmetic alone would take (1.0: at the limit)."""
        return self.peak_seconds_per_step / step_seconds

    @property
    def peak_flops_per_second(self) -> float:
        """This machine's measured speed on exactly these products."""
        return self.flops_per_step / self.peak_seconds_per_step


def measure_arithmetic(run_steps: Callable[[], None], steps: int, repeats: int = 20) -> Arithmetic:
    """Count the matrix products of ``run_steps()`` (which runs ``steps`` steps) and time
    them alone."""
    if steps <= 0:
        raise ValueError(f"steps must be positive, got {steps}")
    with MatmulLog() as log:
        run_steps()
    if not log.products:
        raise ValueError("the steps made no matrix product")
    return Arithmetic(log.flops / steps, peak_seconds(log.products, repeats) / steps)
