"""scripts/cost_separability.py: the ranking measure its verdict rests on."""

import numpy as np
import pytest
from train_helpers import load_script

cost_separability = load_script("cost_separability")


def test_auc_counts_the_pairs_a_score_orders_rightly_and_ties_as_half():
    scores = np.array([0.1, 0.4, 0.35, 0.8, 0.4])
    labels = np.array([False, False, True, True, True])
    # pairs (positive, negative): 0.35>0.1 yes, 0.35>0.4 no, 0.8 beats both, 0.4 vs 0.1 yes,
    # 0.4 vs 0.4 a tie: (1 + 0 + 2 + 1 + 0.5) / 6
    assert cost_separability.roc_auc(scores, labels) == pytest.approx(4.5 / 6)
    assert cost_separability.roc_auc(-scores, labels) == pytest.approx(1.5 / 6)


def test_auc_of_scores_that_separate_is_one_and_of_one_class_undefined():
    labels = np.array([True, False, True, False])
    assert cost_separability.roc_auc(np.array([3.0, 1.0, 2.0, 0.0]), labels) == 1.0
    assert np.isnan(cost_separability.roc_auc(np.ones(3), np.zeros(3, dtype=bool)))
