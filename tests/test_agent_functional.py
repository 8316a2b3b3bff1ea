"""Pure maths: TD target and target-network updates against hand-computed numbers."""

import numpy as np
import pytest
import torch

from frl.agents import discounted_returns, hard_update, soft_update, td_target


def test_soft_update_matches_hand_computed_polyak_average() -> None:
    target = [torch.tensor([0.0, 10.0]), torch.tensor([[1.0]])]
    online = [torch.tensor([1.0, 20.0]), torch.tensor([[3.0]])]
    soft_update(target, online, tau=0.1)
    # (1 - 0.1) * t + 0.1 * s
    assert torch.allclose(target[0], torch.tensor([0.1, 11.0]))
    assert torch.allclose(target[1], torch.tensor([[1.2]]))
    assert torch.equal(online[0], torch.tensor([1.0, 20.0]))  # sources untouched


def test_soft_update_with_tau_one_copies() -> None:
    target, online = [torch.zeros(3)], [torch.tensor([1.0, 2.0, 3.0])]
    soft_update(target, online, tau=1.0)
    assert torch.equal(target[0], online[0])


def test_soft_update_works_on_parameters_and_rejects_mismatched_lists() -> None:
    target = torch.nn.Parameter(torch.zeros(2))
    soft_update([target], [torch.ones(2)], tau=0.25)
    assert torch.allclose(target.detach(), torch.full((2,), 0.25))
    with pytest.raises(ValueError):
        soft_update([torch.zeros(1)], [], tau=0.5)


def test_hard_update_copies() -> None:
    target = [torch.zeros(2, 2)]
    hard_update(target, [torch.eye(2)])
    assert torch.equal(target[0], torch.eye(2))


def test_td_target_cuts_bootstrap_only_on_termination() -> None:
    rewards = torch.tensor([1.0, 1.0])
    terminated = torch.tensor([0.0, 1.0])
    next_q = torch.tensor([10.0, 10.0])
    # 1 + 0.9 * 10 = 10; terminal: just the reward.
    assert torch.allclose(td_target(rewards, terminated, next_q, 0.9), torch.tensor([10.0, 1.0]))


def test_discounted_returns_match_hand_computed_values() -> None:
    # G2 = 3; G1 = 2 + 0.5 * 3 = 3.5; G0 = 1 + 0.5 * 3.5 = 2.75
    np.testing.assert_allclose(discounted_returns([1.0, 2.0, 3.0], 0.5), [2.75, 3.5, 3.0])
    assert discounted_returns([], 0.99).shape == (0,)
