"""Process-wide CPU settings that benchmarks/agent_speed.py applies before timing the agent."""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

import torch

# glibc mallopt parameters (malloc.h).
_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3


def set_torch_threads(num_threads: int | None = None) -> int:
    """Use ``num_threads`` intra-op threads (default: the CPUs this process may use).

    Torch's default can exceed the cores a container grants, and oversubscribed OpenMP
    threads spin against each other; one thread per core is fastest for these MLPs.
    """
    if num_threads is None:
        try:
            num_threads = len(os.sched_getaffinity(0))
        except AttributeError:  # not on Linux
            num_threads = os.cpu_count() or 1
    torch.set_num_threads(num_threads)
    return num_threads


def retain_freed_memory() -> bool:
    """Ask glibc to keep freed memory for reuse instead of returning it to the kernel.

    Every DDPG step allocates and frees the same few dozen 0.1-3 MB tensors. By default
    glibc serves those with fresh ``mmap`` pages and hands them back on free, so each step
    pays hundreds of page faults (measured: ~330 per step, 1-2 ms of kernel time on the
    2-core VM). Raising the mmap and trim thresholds lets the heap keep and reuse them.
    Returns False (doing nothing) where glibc is not the allocator.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    ok = mallopt(_M_MMAP_THRESHOLD, 32 * 1024 * 1024)  # glibc's maximum on 64-bit
    ok &= mallopt(_M_TRIM_THRESHOLD, 1024 * 1024 * 1024)
    ok &= mallopt(_M_TOP_PAD, 64 * 1024 * 1024)
    return bool(ok)


def configure_cpu_training(num_threads: int | None = None) -> int:
    """:func:`set_torch_threads` and :func:`retain_freed_memory`; returns the thread count."""
    retain_freed_memory()
    return set_torch_threads(num_threads)
