"""Uniform replay buffer with exact compact storage for mostly-zero observations.

Dense storage keeps float32 observations as they are (fine for Pendulum's 3 numbers). Sparse
storage keeps, per observation, its non-zero float32 values and their flat positions (int16
when the observation has at most 32767 features) in a fixed-width row of ``capacity_nnz``
slots. Storage is exact: values are kept as float32, the dtype the networks consume. When an
observation has more non-zeros than the row width, every row is widened (copied into larger
arrays) rather than truncated, so a full buffer holds ``2 * buffer_size * capacity_nnz * 6``
bytes plus the scalars: 77 MB for the paper's 100,000 transitions at the default width 64 (up
to 21 vehicles x 3 channels), against 1.1 GB for dense float32 observations. The storage takes
memory only as rows are written (about 0.8 MB per 1,000 transitions).

``terminated`` is stored as given. Pass ``terminated`` (not ``terminated or truncated``)
so that time-limit cut-offs still bootstrap from the next observation.
"""

from __future__ import annotations

import mmap
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import Tensor

from frl.agents.grid_vehicles import find_vehicles
from frl.agents.noise import generator_state, set_generator_state
from frl.agents.sparse_linear import SparseRows


class Batch(NamedTuple):
    """Sampled transitions as tensors; observations flat, dense or :class:`SparseRows`."""

    obs: Tensor | SparseRows
    actions: Tensor
    rewards: Tensor
    next_obs: Tensor | SparseRows
    terminated: Tensor
    horizons: Tensor
    """Steps from ``obs`` to ``next_obs`` (n-step transitions; 1 for one-step ones)."""
    guide_actions: Tensor | None = None
    """A teacher's actions at ``obs`` (normalised), where the buffer stores them."""
    costs: Tensor | None = None
    """The discounted cost sums (collisions), where the buffer stores them."""
    costs_final: Tensor | None = None
    """1 where ``costs`` is the discounted cost to the end of the transition's episode
    (the cost critic's whole target), 0 where the cost critic bootstraps; where the
    buffer keeps costs to go."""

    def to(self, device: Any) -> Batch:
        """The same batch on ``device`` (copies from the host do not wait)."""
        return Batch(*(None if t is None else t.to(device, non_blocking=True) for t in self))


def committed_when_written(shape: tuple[int, ...], dtype: Any) -> np.ndarray:
    """Zeros in an anonymous memory map, whose pages take memory only once written.

    ``np.zeros`` of a large block costs no memory until written only while malloc serves it
    with ``mmap``; a vehicle process raises glibc's mmap threshold to 32 MB
    (:func:`frl.federation.workers.retain_freed_memory`), and calloc then serves it from the
    heap and clears it, touching every page: a buffer sized for the paper's 100,000
    transitions would hold about 65 MB per vehicle from the start, when a 10,000-step run
    writes 8 MB of it.
    """
    dtype = np.dtype(dtype)
    count = int(np.prod(shape, dtype=np.int64))
    if count == 0:
        return np.zeros(shape, dtype=dtype)
    return np.frombuffer(mmap.mmap(-1, count * dtype.itemsize), dtype, count).reshape(shape)


class _SparseStore:
    """Fixed-width compressed rows: ``values[i, :count[i]]`` at ``indices[i, :count[i]]``."""

    def __init__(self, capacity: int, num_features: int, width: int) -> None:
        self.num_features = num_features
        self.index_dtype = np.int16 if num_features <= np.iinfo(np.int16).max else np.int32
        self.counts = committed_when_written((capacity,), np.int32)
        self.indices = committed_when_written((capacity, width), self.index_dtype)
        self.values = committed_when_written((capacity, width), np.float32)

    @property
    def width(self) -> int:
        return self.indices.shape[1]

    @property
    def nbytes(self) -> int:
        return self.counts.nbytes + self.indices.nbytes + self.values.nbytes

    def _widen(self, needed: int) -> None:
        width = max(needed, 2 * self.width)
        indices = committed_when_written((len(self.counts), width), self.index_dtype)
        values = committed_when_written((len(self.counts), width), np.float32)
        # Rows never written hold zeros and a count of 0: copying only the others keeps the
        # untouched part of the capacity free.
        written = np.flatnonzero(self.counts)
        indices[written, : self.width] = self.indices[written]
        values[written, : self.width] = self.values[written]
        self.indices, self.values = indices, values

    def put(self, slot: int, flat: np.ndarray) -> None:
        nz = np.flatnonzero(flat)
        if nz.size > self.width:
            self._widen(nz.size)
        n = nz.size
        self.counts[slot] = n
        self.indices[slot, :n] = nz
        self.values[slot, :n] = flat[nz]
        # Stale entries past ``n`` are masked out by ``counts`` when sampling.

    def get(self, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        counts = self.counts[slots]
        mask = np.arange(self.width) < counts[:, None]
        indices = self.indices[slots][mask]
        values = self.values[slots][mask]
        offsets = np.cumsum(counts, dtype=np.int64) - counts
        return indices, values, offsets

    def rows(
        self, slots: np.ndarray, transposed: bool, vehicles: tuple[int, int, int] | None = None
    ) -> SparseRows:
        """The observations at ``slots`` as :class:`SparseRows`, with their transpose
        (the weight gradient's layout) when ``transposed``, and their vehicles where
        ``vehicles`` gives the grid's geometry
        (:func:`frl.agents.grid_vehicles.find_vehicles`)."""
        indices, values, offsets = self.get(slots)
        by_feature = None
        if transposed:
            # NumPy's stable sort of 16-bit keys is a radix sort: about 20 us here against
            # 50-130 us for torch.argsort on the int64 indices inside backward.
            order = np.argsort(indices, kind="stable")
            row_ids = np.repeat(np.arange(len(slots), dtype=np.int64), self.counts[slots])
            per_feature = np.bincount(indices, minlength=self.num_features)
            by_feature = SparseRows(
                torch.from_numpy(row_ids[order]),
                torch.from_numpy(values[order]),
                torch.from_numpy(np.cumsum(per_feature) - per_feature),
                len(slots),
            )
        wide_indices = indices.astype(np.int64)
        found = None
        if vehicles is not None:
            found = find_vehicles(
                wide_indices, values, self.counts[slots], self.num_features, vehicles
            )
        return SparseRows(
            torch.from_numpy(wide_indices),
            torch.from_numpy(values),
            torch.from_numpy(offsets),
            self.num_features,
            by_feature,
            found,
        )

    def dense(self, slots: np.ndarray) -> np.ndarray:
        indices, values, _ = self.get(slots)
        rows = np.repeat(np.arange(len(slots)), self.counts[slots])
        out = np.zeros((len(slots), self.num_features), dtype=np.float32)
        out[rows, indices] = values
        return out


class ReplayBuffer:
    """Ring buffer of ``(obs, action, reward, next_obs, terminated)`` transitions.

    Args:
        capacity: transitions kept; the oldest is overwritten first.
        obs_shape: observation shape; observations are stored flattened.
        action_dim: flat action size; actions are stored as float32.
        rng: the generator that draws sample indices (never the global RNG).
        sparse: store observations compactly (exact); see the module docstring.
        sparse_width: initial non-zeros per stored observation (grows on demand).
        guided: store a teacher's action at ``obs`` with every transition
            (:attr:`frl.agents.DDPGConfig.guide`).
        costed: store each transition's cost (a collision budget's cost critic learns it).
        costs_to_go: a costed buffer whose transitions may carry, in place of their
            n-step cost, the discounted cost to their episode's end, marked as such
            (``Batch.costs_final``).
        vehicle_geometry: a vehicles encoder's ``geometry``
            (:class:`frl.agents.vehicle_encoder.VehicleSetEncoder`): compact batches come
            with their vehicles, found once per batch in NumPy.
    """

    def __init__(
        self,
        capacity: int,
        obs_shape: tuple[int, ...],
        action_dim: int,
        rng: np.random.Generator,
        sparse: bool = False,
        sparse_width: int = 64,
        guided: bool = False,
        costed: bool = False,
        vehicle_geometry: tuple[int, int, int] | None = None,
        costs_to_go: bool = False,
    ) -> None:
        if capacity <= 0:
            raise ValueError(f"capacity must be positive, got {capacity}")
        if costs_to_go and not costed:
            raise ValueError("a buffer keeps costs to go only where it keeps costs (costed)")
        self.capacity = capacity
        self.obs_shape = tuple(obs_shape)
        self.num_features = int(np.prod(self.obs_shape, dtype=np.int64))
        self.action_dim = action_dim
        self.rng = rng
        self.vehicle_geometry = vehicle_geometry
        self.sparse = sparse
        if sparse:
            self._obs: Any = _SparseStore(capacity, self.num_features, sparse_width)
            self._next_obs: Any = _SparseStore(capacity, self.num_features, sparse_width)
        else:
            self._obs = committed_when_written((capacity, self.num_features), np.float32)
            self._next_obs = committed_when_written((capacity, self.num_features), np.float32)
        self.actions = committed_when_written((capacity, action_dim), np.float32)
        self.rewards = committed_when_written((capacity,), np.float32)
        self.terminated = committed_when_written((capacity,), np.float32)
        self.horizons = np.ones(capacity, dtype=np.float32)
        self.guided = guided
        self.guide_actions = committed_when_written(
            (capacity if guided else 0, action_dim), np.float32
        )
        self.costed = costed
        self.costs = committed_when_written((capacity if costed else 0,), np.float32)
        self.costs_to_go = costs_to_go
        self.costs_final = committed_when_written((capacity if costs_to_go else 0,), np.float32)
        self.pos = 0
        self.size = 0

    def __len__(self) -> int:
        return self.size

    @property
    def nbytes(self) -> int:
        """Bytes held by the storage arrays (allocated for the full capacity)."""
        obs_bytes = self._obs.nbytes + self._next_obs.nbytes
        scalars = self.actions.nbytes + self.rewards.nbytes + self.terminated.nbytes
        costs = self.costs.nbytes + self.costs_final.nbytes
        return obs_bytes + scalars + self.guide_actions.nbytes + costs

    def add(
        self,
        obs: np.ndarray,
        action: np.ndarray,
        reward: float,
        next_obs: np.ndarray,
        terminated: bool,
        horizon: int = 1,
        guide_action: np.ndarray | None = None,
        cost: float = 0.0,
        cost_final: bool = False,
    ) -> None:
        """Store one transition; ``terminated`` must exclude time-limit truncation.
        ``horizon``: steps from ``obs`` to ``next_obs`` (an n-step transition's k).
        A ``guided`` buffer needs the teacher's action at ``obs``; a ``costed`` one keeps
        ``cost``, which with ``cost_final`` is the discounted cost to the episode's end (a
        buffer that keeps ``costs_to_go`` only)."""
        if cost_final and not self.costs_to_go:
            raise ValueError("this buffer does not keep costs to go (costs_to_go=False)")
        flat_obs = np.asarray(obs, dtype=np.float32).reshape(-1)
        flat_next = np.asarray(next_obs, dtype=np.float32).reshape(-1)
        if flat_obs.size != self.num_features or flat_next.size != self.num_features:
            raise ValueError(
                f"observations must have {self.num_features} values, "
                f"got {flat_obs.size} and {flat_next.size}"
            )
        slot = self.pos
        if self.sparse:
            self._obs.put(slot, flat_obs)
            self._next_obs.put(slot, flat_next)
        else:
            self._obs[slot] = flat_obs
            self._next_obs[slot] = flat_next
        self.actions[slot] = np.asarray(action, dtype=np.float32).reshape(-1)
        self.rewards[slot] = reward
        self.terminated[slot] = float(terminated)
        self.horizons[slot] = horizon
        if self.guided:
            if guide_action is None:
                raise ValueError("a guided buffer needs the teacher's action of every transition")
            self.guide_actions[slot] = np.asarray(guide_action, np.float32).reshape(-1)
        if self.costed:
            self.costs[slot] = cost
        if self.costs_to_go:
            self.costs_final[slot] = float(cost_final)
        self.pos = (slot + 1) % self.capacity
        self.size = min(self.size + 1, self.capacity)

    def _observations(
        self, store: Any, slots: np.ndarray, as_sparse: bool, transposed: bool = False
    ) -> Tensor | SparseRows:
        if not self.sparse:
            dense = torch.from_numpy(store[slots])
            return SparseRows.from_dense(dense) if as_sparse else dense
        if as_sparse:
            return store.rows(slots, transposed, self.vehicle_geometry)
        return torch.from_numpy(store.dense(slots))

    def sample_slots(self, batch_size: int) -> np.ndarray:
        """Uniform slot indices (with replacement, as SB3 and CleanRL sample)."""
        if self.size == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        return self.rng.integers(0, self.size, size=batch_size)

    def sample(self, batch_size: int, sparse: bool = False, device: Any = "cpu") -> Batch:
        """Draw ``batch_size`` transitions; observations as :class:`SparseRows` if ``sparse``."""
        slots = self.sample_slots(batch_size)
        return self.gather(slots, sparse=sparse, device=device)

    def gather(
        self, slots: np.ndarray, sparse: bool = False, device: Any = "cpu", transposed: bool = True
    ) -> Batch:
        """The transitions at ``slots`` as a :class:`Batch`. Sparse observations come with
        their transpose where ``transposed`` (a sparse first layer's weight gradient flows
        through it; the vehicles encoder never reads it); next observations only ever meet
        the target networks, without gradients."""
        obs = self._observations(self._obs, slots, sparse, transposed=transposed)
        next_obs = self._observations(self._next_obs, slots, sparse)
        batch = Batch(
            obs,
            torch.from_numpy(self.actions[slots]),
            torch.from_numpy(self.rewards[slots]),
            next_obs,
            torch.from_numpy(self.terminated[slots]),
            torch.from_numpy(self.horizons[slots]),
            torch.from_numpy(self.guide_actions[slots]) if self.guided else None,
            torch.from_numpy(self.costs[slots]) if self.costed else None,
            torch.from_numpy(self.costs_final[slots]) if self.costs_to_go else None,
        )
        return batch if torch.device(device).type == "cpu" else batch.to(device)

    def _per_transition(self) -> tuple[str, ...]:
        """The arrays with one row per transition besides the observations."""
        return (
            ("actions", "rewards", "terminated", "horizons")
            + (("guide_actions",) if self.guided else ())
            + (("costs",) if self.costed else ())
            + (("costs_final",) if self.costs_to_go else ())
        )

    def state_dict(self) -> dict[str, Any]:
        """The filled part as tensors, the write position and the sampling generator."""
        n = self.size
        state: dict[str, Any] = {"pos": self.pos, "size": n, "rng": generator_state(self.rng)}
        for name in self._per_transition():
            state[name] = torch.from_numpy(getattr(self, name)[:n].copy())
        for name in ("_obs", "_next_obs"):
            store = getattr(self, name)
            if self.sparse:
                parts = ("counts", "indices", "values")
                state[name] = {p: torch.from_numpy(getattr(store, p)[:n].copy()) for p in parts}
            else:
                state[name] = torch.from_numpy(store[:n].copy())
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a :meth:`state_dict` of a buffer with the same capacity and shapes."""
        n = int(state["size"])
        if not 0 <= n <= self.capacity or not 0 <= int(state["pos"]) < self.capacity:
            raise ValueError("buffer state does not fit this buffer's capacity")
        for name in ("_obs", "_next_obs"):
            saved = state[name]
            store = getattr(self, name)
            if self.sparse:
                width = saved["indices"].shape[1]
                if width > store.width:
                    store._widen(width)
                store.counts[:n] = saved["counts"].numpy()
                store.indices[:n, :width] = saved["indices"].numpy()
                store.values[:n, :width] = saved["values"].numpy()
            else:
                store[:n] = saved.numpy()
        # Buffers saved before n-step returns hold one-step transitions only.
        state = {"horizons": torch.ones(n), **state}
        for name in self._per_transition():
            getattr(self, name)[:n] = state[name].numpy()
        self.pos, self.size = int(state["pos"]), n
        set_generator_state(self.rng, state["rng"])
