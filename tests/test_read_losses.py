"""Losses read once per window are the values a read per loss and update gave."""

import torch

from frl.agents.learn import read_losses


def test_a_window_read_at_once_equals_each_loss_read_alone():
    generator = torch.Generator().manual_seed(0)
    steps = [
        {
            "critic_loss": torch.rand((), generator=generator),
            "imitation_loss": torch.rand((), generator=generator).to(torch.bfloat16),
            "lagrange_multiplier": 3.25,
        }
        for _ in range(7)
    ]
    read = read_losses(steps)
    assert read == [{name: float(v) for name, v in step.items()} for step in steps]
    assert all(isinstance(value, float) for step in read for value in step.values())


def test_steps_without_tensors_and_no_steps_read_too():
    assert read_losses([]) == []
    assert read_losses([{}, {"collision_rate": 0.5}]) == [{}, {"collision_rate": 0.5}]
