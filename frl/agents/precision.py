"""Mixed precision: bf16 matmuls where the hardware has them, float32 everywhere else.

``DDPGConfig.precision`` names what the agent computes its forward and backward passes
in. Under ``bf16`` the hidden layers run under ``torch.autocast`` (bf16 matmul inputs,
float32 accumulation); weights, optimizer state, target networks, the output layers and
the losses stay float32, so FedAvg still averages float32 weights and checkpoints hold
float32 tensors only.

bf16 pays only where the hardware multiplies it natively (AVX-512 BF16 or AMX on x86,
the BF16 extension on Arm, Ampere or newer NVIDIA GPUs); elsewhere PyTorch emulates it
through float32 and it is slower than float32 itself. ``auto`` therefore picks bf16
only where it is native.
"""

from __future__ import annotations

import contextlib
import functools
import platform
import subprocess
import sys
import warnings
from collections.abc import Callable
from contextlib import AbstractContextManager

import torch

PRECISIONS: tuple[str, ...] = ("float32", "bf16", "auto")
"""Values of ``DDPGConfig.precision``."""

_X86_BF16_FLAGS = frozenset({"avx512_bf16", "amx_bf16"})


@functools.cache
def _cpu_flags() -> frozenset[str]:
    """The CPU's feature flags as Linux lists them (x86 ``flags``, Arm ``Features``)."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as cpuinfo:
            for line in cpuinfo:
                key, _, value = line.partition(":")
                if key.strip() in ("flags", "Features"):
                    return frozenset(value.split())
    except OSError:
        pass
    return frozenset()


@functools.cache
def _darwin_has_bf16() -> bool:
    """Apple silicon M2 and newer report ``hw.optional.arm.FEAT_BF16`` = 1."""
    try:
        answer = subprocess.run(
            ["sysctl", "-n", "hw.optional.arm.FEAT_BF16"],
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return False
    return answer.stdout.strip() == "1"


def cpu_has_native_bf16() -> bool:
    """Whether this CPU multiplies bf16 in hardware (not through float32 emulation)."""
    if sys.platform.startswith("linux"):
        flags = _cpu_flags()
        if platform.machine().lower() in ("aarch64", "arm64"):
            return "bf16" in flags
        return bool(flags & _X86_BF16_FLAGS)
    if sys.platform == "darwin" and platform.machine() == "arm64":
        return _darwin_has_bf16()
    return False


def has_native_bf16(device: torch.device | str) -> bool:
    """Whether ``device`` computes bf16 matmuls natively."""
    device = torch.device(device)
    if device.type == "cpu":
        return cpu_has_native_bf16()
    if device.type == "cuda":
        return torch.cuda.is_available() and torch.cuda.is_bf16_supported(including_emulation=False)
    return False


_warned_emulated: set[str] = set()


def resolve_precision(
    precision: str,
    device: torch.device | str,
    native: Callable[[torch.device | str], bool] | None = None,
) -> str:
    """What an agent on ``device`` computes in: ``"float32"`` or ``"bf16"``.

    ``auto`` is bf16 where ``device`` has it natively, else float32. An explicit ``bf16``
    where it would be emulated is honoured with a warning (once per device type): it
    runs, slower than float32. ``native`` replaces :func:`has_native_bf16` (for tests).
    """
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    if precision == "float32":
        return "float32"
    is_native = (native or has_native_bf16)(device)
    if precision == "auto":
        return "bf16" if is_native else "float32"
    device_type = torch.device(device).type
    if not is_native and device_type not in _warned_emulated:
        _warned_emulated.add(device_type)
        warnings.warn(
            f"agent.precision=bf16: this {device_type.upper()} has no native bf16, so "
            "PyTorch emulates it and training runs slower than in float32; "
            "precision=auto picks float32 here",
            RuntimeWarning,
            stacklevel=2,
        )
    return "bf16"


def autocast(device: torch.device, precision: str) -> AbstractContextManager[object]:
    """The context the agent's forward passes run in: bf16 autocast, or nothing. On a GPU
    without the cache of weight casts, which a captured update (``DDPGConfig.cuda_graph``)
    may not keep across replays; the casts' values are the same either way."""
    if precision == "bf16":
        return torch.autocast(
            device.type, dtype=torch.bfloat16, cache_enabled=device.type != "cuda"
        )
    return contextlib.nullcontext()


def float32_layer(layer: torch.nn.Module, x: torch.Tensor) -> torch.Tensor:
    """``layer(x)`` in float32 even under autocast.

    The output layers (an action before tanh, a Q-value) keep float32's resolution: in
    bf16 a Q-value of 6 would move in steps of 0.03, about a step's reward, and the TD
    error that trains the critic would drown in that rounding. The layer is 64 inputs
    wide, so float32 costs nothing here.
    """
    with torch.autocast(x.device.type, enabled=False):
        return layer(x.float())


def precision_report(precision: str, device: torch.device | str) -> dict[str, object]:
    """What a run records about its precision: the setting, what it resolved to on this
    machine, and whether the device has native bf16 (results.json's ``agent_precision``)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the agents warn for themselves
        used = resolve_precision(precision, device)
    return {
        "configured": precision,
        "used": used,
        "native_bf16": has_native_bf16(device),
        "device": str(torch.device(device)),
    }
