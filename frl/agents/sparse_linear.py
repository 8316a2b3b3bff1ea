"""A first layer that computes ``nn.Linear`` on mostly-zero inputs by gathering non-zeros.

The paper's 26 x 18 x 3 grid holds a handful of vehicles in 468 cells, so a dense first
layer spends almost all of its 1404 x 512 multiply-adds on zeros. ``InputLinear`` keeps
``nn.Linear``'s parameters (``weight`` [out, in], ``bias`` [out]) and state-dict names, so
sparse and dense agents exchange and average parameters freely, and accepts either a dense
batch or a :class:`SparseRows` batch of the same numbers.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

if TYPE_CHECKING:
    from frl.agents.grid_vehicles import GridVehicles


class SparseRows(NamedTuple):
    """A batch of flat feature vectors in compressed-row form.

    Row ``i`` holds ``values[offsets[i]:offsets[i + 1]]`` at feature positions
    ``indices[offsets[i]:offsets[i + 1]]``; every other feature is zero. This is exactly the
    ``input``/``offsets``/``per_sample_weights`` triple of ``F.embedding_bag``.
    """

    indices: Tensor
    """int64 [nnz]: feature positions of the non-zeros, row after row."""
    values: Tensor
    """float32 [nnz]: the non-zero values."""
    offsets: Tensor
    """int64 [batch]: where each row starts in ``indices``/``values``."""
    num_features: int
    """Length of each dense row."""
    by_feature: SparseRows | None = None
    """The transpose in the same form (one row per feature, its entries the batch rows
    that hold it, in row order), which the weight gradient needs; :meth:`transposed`
    computes it when absent. The replay buffer attaches it, computed in NumPy, to the
    observations that a gradient flows through."""
    vehicles: GridVehicles | None = None
    """The vehicles these rows show, for the vehicles encoder; the replay buffer attaches
    them, found in NumPy once per batch, so the networks that read a batch share them."""

    @property
    def batch_size(self) -> int:
        return int(self.offsets.shape[0])

    def to(self, device: torch.device | str, non_blocking: bool = True) -> SparseRows:
        """The same rows on ``device`` (``Tensor.to``'s signature, so a batch moves alike)."""
        return SparseRows(
            self.indices.to(device, non_blocking=non_blocking),
            self.values.to(device, non_blocking=non_blocking),
            self.offsets.to(device, non_blocking=non_blocking),
            self.num_features,
            None if self.by_feature is None else self.by_feature.to(device),
            None if self.vehicles is None else self.vehicles.to(device, non_blocking),
        )

    def row_ids(self) -> Tensor:
        """int64 [nnz]: the row each non-zero belongs to."""
        counts = torch.diff(
            self.offsets, append=torch.tensor([self.indices.numel()], device=self.offsets.device)
        )
        return torch.repeat_interleave(torch.arange(self.batch_size, device=counts.device), counts)

    def transposed(self) -> SparseRows:
        """:attr:`by_feature`, computed here if the rows do not carry it."""
        if self.by_feature is not None:
            return self.by_feature
        order = torch.argsort(self.indices, stable=True)  # stable: a fixed summation order
        per_feature = torch.bincount(self.indices, minlength=self.num_features)
        return SparseRows(
            self.row_ids()[order],
            self.values[order],
            torch.cumsum(per_feature, 0) - per_feature,
            self.batch_size,
        )

    def to_dense(self) -> Tensor:
        """The dense [batch, num_features] float32 tensor these rows encode."""
        dense = torch.zeros(
            self.batch_size, self.num_features, dtype=self.values.dtype, device=self.values.device
        )
        dense.index_put_((self.row_ids(), self.indices), self.values, accumulate=True)
        return dense

    @classmethod
    def from_dense(cls, dense: Tensor) -> SparseRows:
        """Compress a [batch, features] tensor, keeping every entry that is not zero."""
        rows, cols = dense.nonzero(as_tuple=True)
        counts = torch.bincount(rows, minlength=dense.shape[0])
        offsets = torch.cumsum(counts, 0) - counts
        return cls(cols, dense[rows, cols].float(), offsets, int(dense.shape[1]))

    @classmethod
    def from_numpy_row(cls, row: np.ndarray) -> SparseRows:
        """One flat observation as a batch of one row, on the CPU as its NumPy source is
        (for acting: no torch ops to build)."""
        flat = np.asarray(row, dtype=np.float32).reshape(-1)
        nonzero = np.flatnonzero(flat)
        return cls(
            torch.from_numpy(nonzero),
            torch.from_numpy(flat[nonzero]),
            torch.zeros(1, dtype=torch.int64, device="cpu"),
            int(flat.size),
        )


class _SparseMatmul(torch.autograd.Function):
    """``rows @ weight_t`` for compressed rows; differentiable in ``weight_t`` only.

    Forward is ``F.embedding_bag`` (mode ``sum`` with per-sample weights). The weight
    gradient ``rows^T @ grad_out`` is the same kind of gather-and-sum seen from the other
    side: feature ``f``'s gradient row sums ``value * grad_out[row]`` over the non-zeros at
    ``f``. So backward runs one more forward ``embedding_bag`` over the rows of
    ``grad_out``, driven by the transposed rows (:meth:`SparseRows.transposed`), which
    needs no per-non-zero intermediate. Measured alone on the idle 2-core machine
    (1404 x 512 table, batch 256, ~18 non-zeros a row, 2 threads): 0.27 ms against
    0.56 ms for ``index_select`` + ``index_add_`` (a 9.6 MB intermediate), and faster than
    ``embedding_bag``'s own backward and a COO ``torch.sparse.mm``. Input values get no
    gradient (observations never need one).
    """

    @staticmethod
    def forward(
        ctx: Any,
        indices: Tensor,
        values: Tensor,
        offsets: Tensor,
        weight_t: Tensor,
        transposed: SparseRows,
    ) -> Tensor:
        ctx.transposed = transposed
        return F.embedding_bag(indices, weight_t, offsets, mode="sum", per_sample_weights=values)

    @staticmethod
    def backward(ctx: Any, grad_out: Tensor) -> tuple[Tensor | None, ...]:
        if not ctx.needs_input_grad[3]:
            return None, None, None, None, None
        by_feature: SparseRows = ctx.transposed
        # Features no row holds form empty bags, which embedding_bag sums to zero rows.
        grad_table = F.embedding_bag(
            by_feature.indices,
            grad_out.contiguous(),
            by_feature.offsets,
            mode="sum",
            per_sample_weights=by_feature.values,
        )
        return None, None, None, grad_table, None


class InputLinear(nn.Module):
    """``nn.Linear`` whose input may be dense or :class:`SparseRows`, plus an optional dense part.

    ``y = x @ weight.T + bias (+ extra @ extra_weight.T)``. With ``extra_features > 0`` it is
    ``nn.Linear(in_features + extra_features, out_features)`` applied to ``cat([x, extra])``,
    split in two so the large ``x`` part can stay sparse: the critic feeds the action as
    ``extra`` (a rank-``action_dim`` dense term added to the pre-activation).

    The weight is held transposed, as the contiguous [in, out] parameter ``weight_t``, because
    ``F.embedding_bag`` gathers rows of an [in, out] table: a row-major [out, in] weight would
    cost a 2.9 MB transposed copy per forward pass, and a transposed view of it as the
    parameter makes the fused Adam kernel copy it every step (measured: 3.8 ms against
    0.8 ms per step). State dicts still show ``nn.Linear``'s ``weight`` [out, in] (state-dict
    hooks transpose on the way out and in), so agents with sparse and dense inputs, and plain
    ``nn.Linear`` layers, exchange parameters by name. ``.weight`` is an [out, in] view.
    """

    def __init__(self, in_features: int, out_features: int, extra_features: int = 0) -> None:
        super().__init__()
        self.in_features = in_features
        self.out_features = out_features
        self.extra_features = extra_features
        self.weight_t = nn.Parameter(torch.empty(in_features, out_features))
        self.bias = nn.Parameter(torch.empty(out_features))
        if extra_features > 0:
            self.extra_weight = nn.Parameter(torch.empty(out_features, extra_features))
        else:
            self.register_parameter("extra_weight", None)
        self.reset_parameters()
        # The public post-hook appeared in torch 2.5; the private one has the same signature.
        register = getattr(self, "register_state_dict_post_hook", None)
        (register or self._register_state_dict_hook)(_export_linear_weight)
        self.register_load_state_dict_pre_hook(_import_linear_weight)

    @property
    def weight(self) -> Tensor:
        """The weight in ``nn.Linear``'s [out, in] layout (a view of ``weight_t``)."""
        return self.weight_t.t()

    @property
    def fan_in(self) -> int:
        return self.in_features + self.extra_features

    def reset_parameters(self, generator: torch.Generator | None = None) -> None:
        """``nn.Linear``'s default init, U(-1/sqrt(fan_in), 1/sqrt(fan_in)), from ``generator``."""
        bound = 1.0 / math.sqrt(self.fan_in)
        with torch.no_grad():
            for param in self.parameters():
                param.uniform_(-bound, bound, generator=generator)

    def forward(self, x: Tensor | SparseRows, extra: Tensor | None = None) -> Tensor:
        if isinstance(x, SparseRows):
            if x.num_features != self.in_features:
                raise ValueError(f"expected {self.in_features} features, got {x.num_features}")
            if torch.is_grad_enabled() and self.weight_t.requires_grad:
                out = _SparseMatmul.apply(
                    x.indices, x.values, x.offsets, self.weight_t, x.transposed()
                )
            else:  # no autograd.Function overhead when nothing needs a gradient
                out = F.embedding_bag(
                    x.indices, self.weight_t, x.offsets, mode="sum", per_sample_weights=x.values
                )
            out = out + self.bias
        else:
            out = torch.addmm(self.bias, x, self.weight_t)
        if self.extra_weight is not None:
            if extra is None:
                raise ValueError("this layer needs the extra (action) input")
            # A rank-``extra_features`` update: float32 costs nothing here, and under
            # autocast it saves casting ``out`` and both factors to bf16 and back.
            with torch.autocast(out.device.type, enabled=False):
                out = torch.addmm(out.float(), extra.float(), self.extra_weight.t())
        return out

    def extra_repr(self) -> str:
        return (
            f"in_features={self.in_features}, out_features={self.out_features}, "
            f"extra_features={self.extra_features}"
        )


def _export_linear_weight(
    module: InputLinear, state_dict: dict[str, Any], prefix: str, local_metadata: Any
) -> None:
    # Rename weight_t -> weight [out, in]; this module's entries are the last ones so far,
    # so re-inserting them keeps nn.Linear's order (weight, bias, ...).
    own = {
        key: state_dict.pop(key)
        for key in list(state_dict)
        if key.startswith(prefix) and "." not in key[len(prefix) :]
    }
    for key, value in own.items():
        if key == prefix + "weight_t":
            state_dict[prefix + "weight"] = value.t()
    for key, value in own.items():
        if key != prefix + "weight_t":
            state_dict[key] = value


def _import_linear_weight(
    module: InputLinear,
    state_dict: dict[str, Any],
    prefix: str,
    local_metadata: Any,
    strict: bool,
    missing_keys: list[str],
    unexpected_keys: list[str],
    error_msgs: list[str],
) -> None:
    weight = state_dict.pop(prefix + "weight", None)
    if weight is not None:
        state_dict[prefix + "weight_t"] = weight.t() if weight.dim() == 2 else weight
