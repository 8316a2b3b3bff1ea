"""Process-wide CPU settings that benchmarks/agent_speed.py applies before timing the agent:
the same as frl's training workers get (frl.federation.workers.prepare_worker_process)."""

from __future__ import annotations

import torch

from frl.federation.workers import available_cores, flush_denormals, retain_freed_memory


def set_torch_threads(num_threads: int | None = None) -> int:
    """Use ``num_threads`` intra-op threads (default: the CPUs this process may use).

    Torch's default can exceed the cores a container grants, and oversubscribed OpenMP
    threads spin against each other; one thread per core is fastest for these MLPs.
    """
    num_threads = num_threads or available_cores()
    torch.set_num_threads(num_threads)
    return num_threads


def configure_cpu_training(num_threads: int | None = None) -> int:
    """:func:`retain_freed_memory`, :func:`flush_denormals` and :func:`set_torch_threads`;
    returns the thread count."""
    retain_freed_memory()
    flush_denormals()
    return set_torch_threads(num_threads)
