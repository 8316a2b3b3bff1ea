"""Replay buffer: ring semantics, batch shapes, exact compact storage, stored flags."""

import itertools
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import torch

from frl.agents import ReplayBuffer, SparseRows

GRID = (26, 18, 3)


def sparse_grid(rng: np.random.Generator, vehicles: int) -> np.ndarray:
    grid = np.zeros(GRID, dtype=np.float32)
    cells = rng.choice(26 * 18, size=vehicles, replace=False)
    for cell in cells:
        i, j = divmod(int(cell), 18)
        grid[i, j] = (rng.uniform(0, 1), rng.uniform(-2, 2), 1.0)
    return grid


def test_wraps_around_overwriting_the_oldest() -> None:
    buffer = ReplayBuffer(3, (2,), 1, np.random.default_rng(0))
    for i in range(5):
        buffer.add(np.full(2, i), np.array([i / 10]), float(i), np.full(2, i + 1), False)
    assert len(buffer) == 3 and buffer.pos == 2
    stored = sorted(buffer.rewards.tolist())
    assert stored == [2.0, 3.0, 4.0]
    batch = buffer.gather(np.arange(3))
    # Slot 0 holds transition 3, slot 1 transition 4, slot 2 transition 2.
    assert batch.rewards.tolist() == [3.0, 4.0, 2.0]
    assert torch.equal(batch.obs[:, 0], torch.tensor([3.0, 4.0, 2.0]))
    assert torch.equal(batch.next_obs[:, 0], torch.tensor([4.0, 5.0, 3.0]))


def test_batch_shapes_and_dtypes_dense() -> None:
    buffer = ReplayBuffer(10, (3,), 2, np.random.default_rng(0))
    for _ in range(4):
        buffer.add(np.ones(3), np.zeros(2), 1.0, np.ones(3), False)
    batch = buffer.sample(6)
    assert batch.obs.shape == (6, 3) and batch.next_obs.shape == (6, 3)
    assert batch.actions.shape == (6, 2) and batch.rewards.shape == (6,)
    assert batch.terminated.shape == (6,)
    assert all(t.dtype == torch.float32 for t in batch if t is not None)
    assert batch.guide_actions is None  # no teacher


def test_sample_only_from_filled_slots_and_empty_raises() -> None:
    buffer = ReplayBuffer(100, (1,), 1, np.random.default_rng(0))
    with pytest.raises(ValueError, match="empty"):
        buffer.sample(1)
    for i in range(5):
        buffer.add(np.array([i]), np.zeros(1), float(i), np.array([i]), False)
    assert set(buffer.sample(200).rewards.tolist()) <= {0.0, 1.0, 2.0, 3.0, 4.0}


def test_terminated_is_stored_as_given_not_merged_with_truncation() -> None:
    buffer = ReplayBuffer(4, (1,), 1, np.random.default_rng(0))
    # A time-limit cut-off arrives as terminated=False and must stay 0.
    buffer.add(np.zeros(1), np.zeros(1), 0.0, np.zeros(1), terminated=False)
    buffer.add(np.zeros(1), np.zeros(1), 0.0, np.zeros(1), terminated=True)
    assert buffer.gather(np.array([0, 1])).terminated.tolist() == [0.0, 1.0]


def test_compact_grid_round_trip_is_exact_dense_and_sparse() -> None:
    rng = np.random.default_rng(0)
    buffer = ReplayBuffer(50, GRID, 1, np.random.default_rng(1), sparse=True, sparse_width=64)
    observations = [sparse_grid(rng, int(rng.integers(0, 12))) for _ in range(31)]
    for obs, next_obs in itertools.pairwise(observations):
        buffer.add(obs, np.zeros(1), 0.0, next_obs, False)
    slots = np.array([0, 5, 29, 5, 17])
    batch = buffer.gather(slots)
    expected = torch.from_numpy(np.stack([observations[s].reshape(-1) for s in slots]))
    expected_next = torch.from_numpy(np.stack([observations[s + 1].reshape(-1) for s in slots]))
    assert torch.equal(batch.obs, expected)
    assert torch.equal(batch.next_obs, expected_next)
    sparse_batch = buffer.gather(slots, sparse=True)
    assert isinstance(sparse_batch.obs, SparseRows)
    assert sparse_batch.obs.batch_size == 5 and sparse_batch.obs.num_features == 1404
    assert torch.equal(sparse_batch.obs.to_dense(), expected)
    assert torch.equal(sparse_batch.next_obs.to_dense(), expected_next)


def test_compact_rows_widen_instead_of_truncating() -> None:
    rng = np.random.default_rng(2)
    buffer = ReplayBuffer(8, GRID, 1, np.random.default_rng(3), sparse=True, sparse_width=4)
    small, crowded = sparse_grid(rng, 1), sparse_grid(rng, 30)  # 90 non-zeros > 4
    buffer.add(small, np.zeros(1), 0.0, small, False)
    buffer.add(crowded, np.zeros(1), 0.0, crowded, False)
    assert buffer._obs.width >= 90
    batch = buffer.gather(np.array([0, 1]))
    assert torch.equal(batch.obs, torch.from_numpy(np.stack([small, crowded]).reshape(2, -1)))


def test_widening_a_wrapped_buffer_keeps_every_row() -> None:
    rng = np.random.default_rng(6)
    buffer = ReplayBuffer(6, GRID, 1, np.random.default_rng(7), sparse=True, sparse_width=8)
    added = [sparse_grid(rng, int(n)) for n in rng.integers(0, 3, 9)]  # up to 6 non-zeros
    added.append(sparse_grid(rng, 12))  # 36 non-zeros: widens after the ring wrapped
    for observation in added:
        buffer.add(observation, np.zeros(1), 0.0, observation, False)
    kept = added[-6:]
    slots = (np.arange(6) + 10) % 6  # slot of added[4 + i]
    batch = buffer.gather(slots)
    assert torch.equal(batch.obs, torch.from_numpy(np.stack(kept).reshape(6, -1)))


LINUX_ONLY = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


@LINUX_ONLY
def test_storage_takes_memory_only_as_rows_are_written() -> None:
    # In a process set up as a vehicle worker (glibc keeps freed memory for reuse), a
    # buffer sized for the paper's 100,000 transitions must not hold its 77 MB up front.
    probe = textwrap.dedent(
        """
        import numpy as np
        from frl.agents import ReplayBuffer
        from frl.federation.workers import retain_freed_memory

        def anon_mb():
            for line in open("/proc/self/status"):
                if line.startswith("RssAnon"):
                    return int(line.split()[1]) / 1024

        retain_freed_memory()
        before = anon_mb()
        buffer = ReplayBuffer(100_000, (26, 18, 3), 1, np.random.default_rng(0), sparse=True)
        grid = np.zeros((26, 18, 3), np.float32)
        grid[3, 4] = 1.0
        for _ in range(1000):
            buffer.add(grid, np.zeros(1), 0.0, grid, False)
        print(anon_mb() - before)
        """
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert float(result.stdout) < 10.0, f"{float(result.stdout):.0f} MB for 1,000 transitions"


def test_all_zero_observation_round_trips() -> None:
    buffer = ReplayBuffer(2, GRID, 1, np.random.default_rng(0), sparse=True)
    zeros = np.zeros(GRID, dtype=np.float32)
    buffer.add(zeros, np.zeros(1), 0.0, zeros, False)
    batch = buffer.gather(np.array([0, 0]), sparse=True)
    assert batch.obs.indices.numel() == 0
    assert torch.equal(batch.obs.to_dense(), torch.zeros(2, 1404))


def test_paper_sized_compact_buffer_fits_in_100_mb() -> None:
    buffer = ReplayBuffer(100_000, GRID, 1, np.random.default_rng(0), sparse=True)
    assert buffer.nbytes <= 100e6
    dense = ReplayBuffer(1000, GRID, 1, np.random.default_rng(0))
    assert dense.nbytes * 100 > 1e9  # what the compact form avoids


@pytest.mark.parametrize("guided", [False, True])
def test_state_dict_round_trip_resumes_identical_sampling(guided: bool) -> None:
    rng = np.random.default_rng(4)
    options = {"sparse": True, "sparse_width": 8, "guided": guided}
    buffer = ReplayBuffer(16, GRID, 2, np.random.default_rng(5), **options)
    for _ in range(20):
        teacher = (rng.uniform(-1, 1, 2),) if guided else ()
        buffer.add(
            sparse_grid(rng, 2), rng.uniform(-1, 1, 2), 1.0, sparse_grid(rng, 5), True, 1, *teacher
        )
    copy = ReplayBuffer(16, GRID, 2, np.random.default_rng(99), **options)
    copy.load_state_dict(buffer.state_dict())
    a, b = buffer.sample(8), copy.sample(8)
    assert all(x is y is None or torch.equal(x, y) for x, y in zip(a, b, strict=True))
    assert (a.guide_actions is not None) == guided
    assert (copy.pos, len(copy)) == (buffer.pos, len(buffer))


def test_wrong_observation_size_raises() -> None:
    buffer = ReplayBuffer(2, (3,), 1, np.random.default_rng(0))
    with pytest.raises(ValueError, match="3 values"):
        buffer.add(np.zeros(4), np.zeros(1), 0.0, np.zeros(3), False)
