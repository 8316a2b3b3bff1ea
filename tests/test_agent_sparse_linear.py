"""The sparse-input first layer computes nn.Linear exactly, in outputs and in gradients."""

import pytest
import torch

from frl.agents import InputLinear, SparseRows


def random_sparse(batch: int, features: int, density: float, seed: int) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    values = torch.randn(batch, features, generator=gen)
    mask = torch.rand(batch, features, generator=gen) < density
    dense = values * mask
    dense[0] = 0.0  # an all-zero row (empty bag)
    return dense


@pytest.mark.parametrize(("density", "seed"), [(0.02, 0), (0.2, 1), (1.0, 2)])
def test_matches_linear_in_output_and_gradients(density: float, seed: int) -> None:
    torch.manual_seed(seed)
    linear = torch.nn.Linear(300, 40)
    layer = InputLinear(300, 40)
    layer.load_state_dict(linear.state_dict())
    x = random_sparse(16, 300, density, seed)
    grad_out = torch.randn(16, 40, generator=torch.Generator().manual_seed(seed + 10))

    expected = linear(x)
    expected.backward(grad_out)
    out_sparse = layer(SparseRows.from_dense(x))
    out_sparse.backward(grad_out)
    torch.testing.assert_close(out_sparse, expected, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(layer.weight_t.grad.t(), linear.weight.grad, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(layer.bias.grad, linear.bias.grad, rtol=1e-5, atol=1e-5)

    layer.zero_grad()
    out_dense = layer(x)  # the dense path of the same layer
    out_dense.backward(grad_out)
    torch.testing.assert_close(out_dense, expected, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(layer.weight_t.grad.t(), linear.weight.grad, rtol=1e-5, atol=1e-5)


def test_extra_input_equals_linear_on_concatenation() -> None:
    torch.manual_seed(3)
    linear = torch.nn.Linear(50 + 2, 8)
    layer = InputLinear(50, 8, extra_features=2)
    with torch.no_grad():
        layer.weight.copy_(linear.weight[:, :50])
        layer.extra_weight.copy_(linear.weight[:, 50:])
        layer.bias.copy_(linear.bias)
    x = random_sparse(6, 50, 0.1, 3)
    action = torch.randn(6, 2, requires_grad=True)
    action_ref = action.detach().clone().requires_grad_(True)
    out = layer(SparseRows.from_dense(x), action)
    expected = linear(torch.cat([x, action_ref], dim=1))
    torch.testing.assert_close(out, expected, rtol=1e-5, atol=1e-5)
    out.sum().backward()
    expected.sum().backward()
    torch.testing.assert_close(action.grad, action_ref.grad)
    torch.testing.assert_close(layer.extra_weight.grad, linear.weight.grad[:, 50:])


def test_state_dict_has_linear_names_shapes_and_order() -> None:
    layer, linear = InputLinear(7, 3), torch.nn.Linear(7, 3)
    state = layer.state_dict()
    assert list(state) == list(linear.state_dict()) == ["weight", "bias"]
    assert state["weight"].shape == (3, 7)
    torch.testing.assert_close(state["weight"], layer.weight)
    linear.load_state_dict(state)  # and back into a plain Linear
    torch.testing.assert_close(linear.weight, layer.weight)


def test_sparse_rows_dense_round_trip_and_feature_check() -> None:
    x = random_sparse(5, 20, 0.3, 4)
    rows = SparseRows.from_dense(x)
    assert torch.equal(rows.to_dense(), x)
    with pytest.raises(ValueError, match="features"):
        InputLinear(21, 2)(rows)
