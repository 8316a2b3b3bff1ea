"""What a training budget buys each vehicle: the updates due in its environment steps.

Torch-free, so the report can count a saved run's updates without importing the agent.
"""

from __future__ import annotations


def updates_due(total_steps: int, train_freq: int, learning_starts: int) -> int:
    """The updates :meth:`frl.agents.DDPG.update` finds due in ``total_steps`` steps: one at
    every step count that is a multiple of ``train_freq`` from ``learning_starts`` on. (The
    first also waits for a batch in the buffer, which this count does not see.)"""
    first = max(learning_starts, 1)
    return max(total_steps // train_freq - (first - 1) // train_freq, 0)
