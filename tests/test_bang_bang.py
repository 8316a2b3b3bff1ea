"""scripts/bang_bang.py: the actor's answer executed as full throttle or full brake."""

import numpy as np
from train_helpers import load_script

bang_bang = load_script("bang_bang")


def test_the_action_becomes_full_throttle_above_the_threshold_and_full_brake_elsewhere():
    answers = iter([0.3, -0.2, 0.0, 0.26, 0.25])
    act = bang_bang.bang_bang(lambda _: np.array([next(answers)]), 0.25)
    assert [float(act(None)[0]) for _ in range(5)] == [1.0, -1.0, -1.0, 1.0, -1.0]
    act = bang_bang.bang_bang(lambda _: np.array([[0.01]]), 0.0)  # any shape of one action
    assert act(None).tolist() == [1.0] and act(None).dtype == np.float32
