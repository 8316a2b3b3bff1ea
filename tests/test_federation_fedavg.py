"""FedAvg (Eq. (3)) against hand-computed means; plan and seed rules. Milliseconds, no SUMO."""

import pytest
import torch

from frl.federation import FederationPlan, evaluation_seeds, fedavg, state_nbytes
from frl.federation.client import training_sumo_seed
from frl.federation.plan import client_seeds


def test_equal_weights_give_the_plain_mean():
    a = {"w": torch.tensor([[1.0, 2.0], [3.0, 4.0]]), "b": torch.tensor([0.0])}
    b = {"w": torch.tensor([[3.0, 6.0], [5.0, 0.0]]), "b": torch.tensor([1.0])}
    c = {"w": torch.tensor([[2.0, 1.0], [1.0, 2.0]]), "b": torch.tensor([-4.0])}

    result = fedavg([a, b, c])

    torch.testing.assert_close(result["w"], torch.tensor([[2.0, 3.0], [3.0, 2.0]]))
    torch.testing.assert_close(result["b"], torch.tensor([-1.0]))


def test_weights_are_normalised():
    a = {"w": torch.tensor([0.0, 10.0])}
    b = {"w": torch.tensor([4.0, 2.0])}

    result = fedavg([a, b], weights=[1, 3])  # 1/4 a + 3/4 b

    torch.testing.assert_close(result["w"], torch.tensor([3.0, 4.0]))


def test_single_client_is_identity_and_inputs_are_untouched():
    a = {"w": torch.tensor([1.5, -2.0])}
    before = a["w"].clone()

    result = fedavg([a])

    torch.testing.assert_close(result["w"], before)
    assert result["w"] is not a["w"]
    torch.testing.assert_close(a["w"], before)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64, torch.float16, torch.bfloat16])
def test_dtypes_are_kept(dtype):
    a = {"w": torch.tensor([1.0, 2.0], dtype=dtype)}
    b = {"w": torch.tensor([2.0, 4.0], dtype=dtype)}

    result = fedavg([a, b])

    assert result["w"].dtype == dtype
    torch.testing.assert_close(result["w"].float(), torch.tensor([1.5, 3.0]))


def test_integer_tensors_are_not_averaged():
    a = {"w": torch.tensor([1.0]), "count": torch.tensor(7)}
    b = {"w": torch.tensor([3.0]), "count": torch.tensor(9)}

    result = fedavg([a, b])

    assert result["count"].dtype == torch.int64
    assert result["count"].item() == 7


def test_keys_are_matched_by_name_not_position():
    a = {"x": torch.tensor([1.0]), "y": torch.tensor([10.0])}
    b = {"y": torch.tensor([30.0]), "x": torch.tensor([3.0])}

    result = fedavg([a, b])

    assert result["x"].item() == 2.0
    assert result["y"].item() == 20.0


def test_missing_or_extra_keys_raise():
    a = {"x": torch.zeros(2), "y": torch.zeros(2)}
    with pytest.raises(ValueError, match="client 1 lacks 'y'"):
        fedavg([a, {"x": torch.zeros(2)}])
    with pytest.raises(ValueError, match="client 1 has unexpected 'z'"):
        fedavg([a, {**a, "z": torch.zeros(1)}])


def test_shape_and_dtype_mismatches_raise():
    a = {"x": torch.zeros(2, 3)}
    with pytest.raises(ValueError, match=r"'x': client 1 has shape \(3, 2\)"):
        fedavg([a, {"x": torch.zeros(3, 2)}])
    with pytest.raises(ValueError, match="dtype"):
        fedavg([a, {"x": torch.zeros(2, 3, dtype=torch.float64)}])


def test_bad_weights_raise():
    a = {"x": torch.zeros(1)}
    with pytest.raises(ValueError, match="at least one"):
        fedavg([])
    with pytest.raises(ValueError, match="2 weights for 1"):
        fedavg([a], weights=[1, 2])
    with pytest.raises(ValueError, match="non-negative"):
        fedavg([a, a], weights=[1, -1])
    with pytest.raises(ValueError, match="all be zero"):
        fedavg([a, a], weights=[0, 0])


def test_state_nbytes_counts_tensor_data():
    state = {"a": torch.zeros(10, dtype=torch.float32), "b": torch.zeros(3, dtype=torch.float64)}
    assert state_nbytes(state) == 10 * 4 + 3 * 8


def test_plan_rounds_cover_the_budget():
    plan = FederationPlan(scheme="fedavg", total_steps=10_000, interval=3_000)
    assert plan.num_rounds == 4
    assert [plan.round_steps(r) for r in range(4)] == [3000, 3000, 3000, 1000]
    assert plan.round_end_step(3) == 10_000
    assert FederationPlan(scheme="central").client_tasks == ("random",)
    assert FederationPlan(scheme="separate").client_tasks == ("left", "straight", "right")


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"scheme": "fedsgd"}, "unknown federation scheme 'fedsgd'"),
        ({"interval": 0}, "interval must be"),
        ({"interval": 20_000}, "interval must be"),
        ({"tasks": ("left", "uturn")}, "unknown task 'uturn'"),
        ({"targets": "copy"}, "federation.targets"),
        ({"weighting": "loss"}, "federation.weighting"),
    ],
)
def test_plan_rejects_bad_values(kwargs, message):
    with pytest.raises(ValueError, match=message):
        FederationPlan(**kwargs)


def test_training_and_evaluation_seeds_are_disjoint_and_reproducible():
    train = {
        training_sumo_seed(env_seed, restart)
        for _, env_seed in client_seeds(0, 3)
        for restart in range(5)
    }
    test = {s for task in ("left", "straight", "right") for s in evaluation_seeds(0, task, 100)}
    assert all(s % 2 == 0 for s in train)
    assert all(s % 2 == 1 for s in test)
    assert len(test) == 300
    assert evaluation_seeds(0, "left", 5) == evaluation_seeds(0, "left", 5)
    assert evaluation_seeds(0, "left", 5) != evaluation_seeds(1, "left", 5)
    assert client_seeds(0, 3) == client_seeds(0, 3)
    assert all(0 <= s < 2**31 for s in train | test)
