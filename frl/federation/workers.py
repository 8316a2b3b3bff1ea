"""Worker processes: one process per client, each hosting one object, called over a pipe.

libsumo holds one simulation per process, so every vehicle lives in its own process. A
worker is forked from a server that has imported torch and frl once
(:func:`worker_context`), so starting one costs a fork, not a fresh interpreter's imports.
The pool is a small remote-call layer: the parent asks worker ``i`` to run
``method(*args)`` on its object and waits for the results of all workers at once.

Messages are plain pickles (``pickle.dumps``, not multiprocessing's ForkingPickler,
which would move tensors through shared memory): what crosses the pipe is a copy, as
it would be over a network, and :meth:`WorkerPool.call` can record it.

Failure handling, the reason this module exists:

- An exception in a worker comes back with its traceback and raises
  :class:`ClientFailure` naming the client.
- A worker that dies (killed, segfault in SUMO) is noticed through its process
  sentinel within ``poll_s`` and raises :class:`ClientFailure` with its exit code.
- A call running past ``timeout_s`` raises :class:`ClientFailure` too.
- Leaving the ``with`` block, by return, exception or Ctrl-C, stops every worker:
  a polite ``close`` message when all is well, otherwise SIGTERM, then SIGKILL.
  Workers ignore SIGINT (the parent handles Ctrl-C), SIGTERM themselves when the
  parent dies (a thread watches its sentinel) and exit when the parent's end of the pipe
  closes, so a killed parent leaves no orphans behind either.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import pickle
import signal
import subprocess
import sys
import threading
import time
import traceback
import types
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any

_PROTOCOL = pickle.HIGHEST_PROTOCOL
_THREAD_ENV_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")

MessageHook = Callable[[str, str, Any], None]
"""``hook(client_name, kind, payload)`` sees every message a worker sends."""


class ClientFailure(RuntimeError):
    """A client's worker raised, died or timed out; the run cannot continue."""

    def __init__(
        self,
        client: str,
        reason: str,
        exitcode: int | None = None,
        remote_traceback: str | None = None,
    ) -> None:
        message = f"client {client} failed: {reason}"
        if remote_traceback:
            message += f"\n--- traceback in the worker of {client} ---\n{remote_traceback}"
        super().__init__(message)
        self.client = client
        self.reason = reason
        self.exitcode = exitcode
        self.remote_traceback = remote_traceback
        self.run_dir: Path | None = None
        """The run it stopped, set by :func:`frl.training.train`."""
        self.completed_rounds: int | None = None
        """Rounds committed to the run directory before it stopped (what resume keeps)."""


def available_cores() -> int:
    """CPUs this process may run on (the container's share, not the host's)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def threads_per_worker(num_workers: int, cores: int | None = None) -> int:
    """Torch threads per worker so that the workers together use every core once."""
    cores = available_cores() if cores is None else cores
    return max(1, cores // max(1, num_workers))


Stoppable = mp.process.BaseProcess | subprocess.Popen[Any]
"""A worker process, or a command started with ``start_new_session=True``."""


def stop_processes(processes: Sequence[Stoppable], grace_s: float = 10.0) -> None:
    """SIGTERM every process, then SIGKILL whatever still runs after ``grace_s``.

    The one way frl stops what it started: worker and vehicle processes (started with
    ``multiprocessing``) get the signal themselves; commands (Flower's SuperLink and
    SuperNodes, started in their own session) get it for their whole process group, so
    their children go too.
    """

    def signal_process(process: Stoppable, sig: signal.Signals) -> None:
        with contextlib.suppress(ProcessLookupError, PermissionError, ValueError):
            if isinstance(process, subprocess.Popen):
                if process.poll() is None:
                    os.killpg(process.pid, sig)
            elif process.is_alive() and process.pid is not None:
                os.kill(process.pid, sig)

    def wait(process: Stoppable, timeout: float) -> None:
        if isinstance(process, subprocess.Popen):
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.wait(timeout=timeout)
        else:
            with contextlib.suppress(ValueError):  # closed already
                process.join(timeout=timeout)

    def alive(process: Stoppable) -> bool:
        if isinstance(process, subprocess.Popen):
            return process.poll() is None
        with contextlib.suppress(ValueError):
            return process.is_alive()
        return False

    for process in processes:
        signal_process(process, signal.SIGTERM)
    deadline = time.monotonic() + grace_s
    for process in processes:
        wait(process, max(0.1, deadline - time.monotonic()))
    for process in processes:
        if alive(process):
            signal_process(process, signal.SIGKILL)
            wait(process, 5.0)


def _send(conn: Connection, message: Any) -> None:
    conn.send_bytes(pickle.dumps(message, protocol=_PROTOCOL))


def _receive(conn: Connection) -> Any:
    return pickle.loads(conn.recv_bytes())


def _exit_with_parent() -> None:
    """SIGTERM this worker when the coordinator dies, even by SIGKILL.

    Without it a worker would notice only at its next message, up to a round later. A
    thread waits on the coordinator's sentinel, which closes when it dies. (Linux's
    ``PR_SET_PDEATHSIG`` would watch the fork server instead, the worker's parent, which
    outlives it.)
    """
    coordinator = mp.parent_process()
    if coordinator is None:
        return

    def stop_when_gone() -> None:
        wait([coordinator.sentinel])
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=stop_when_gone, name="frl-parent-watch", daemon=True).start()


# glibc mallopt parameters (malloc.h).
_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3


def retain_freed_memory() -> bool:
    """Ask glibc to keep freed memory for reuse instead of returning it to the kernel.

    Every DDPG step allocates and frees the same few dozen 0.1-3 MB tensors. By default
    glibc serves those with fresh ``mmap`` pages and hands them back on free, so each step
    pays hundreds of page faults (measured: ~330 per step, 0.7 ms of a 20 ms bf16 step
    in a vehicle process on the 2-core VM). Raising the mmap and trim thresholds lets the
    heap keep and reuse them; a training process's working set is stable, so little
    memory is held back. Returns False (doing nothing) where glibc is not the allocator.
    """
    if not sys.platform.startswith("linux"):
        return False
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    ok = mallopt(_M_MMAP_THRESHOLD, 32 * 1024 * 1024)  # glibc's maximum on 64-bit
    ok &= mallopt(_M_TRIM_THRESHOLD, 1024 * 1024 * 1024)
    ok &= mallopt(_M_TOP_PAD, 64 * 1024 * 1024)
    return bool(ok)


PRELOADED = ("frl.federation.client",)
"""What the fork server imports once for every worker: torch, the agent, the environment."""


def worker_context() -> Any:
    """Where worker processes come from: a fork server that imported :data:`PRELOADED`
    once, or plain ``spawn`` where there is none (not on Windows).

    A spawned interpreter imports torch and frl anew, about 2 s of CPU per
    worker, which a run with many vehicles, a sweep or the test suite pays again and
    again; a fork of the server starts with them imported. The server runs no torch
    operation and starts no simulation, so what a child inherits is only the imports: its
    threads, seeds and SUMO it sets up itself (:func:`prepare_worker_process`).
    """
    if "forkserver" not in mp.get_all_start_methods():
        return mp.get_context("spawn")
    context = mp.get_context("forkserver")
    context.set_forkserver_preload(list(PRELOADED))
    return context


def flush_denormals() -> bool:
    """Flush denormal floats to zero on this thread and the threads it starts later.

    Adam's running mean of a parameter whose gradient stays zero (a unit that never
    fires) decays by 0.9 an update into the denormal range, where x86 arithmetic is many
    times slower: it made the optimizer's step four times as slow in a vehicle's
    training (docs/benchmarks.md, "Denormals"). Whether it is supported: False on CPUs
    without the flags (the run is then as before, only slower).
    """
    import torch

    return bool(torch.set_flush_denormal(True))


def prepare_worker_process(num_threads: int) -> None:
    """Set up a freshly started client process: threads, memory reuse, signals, death
    with its parent.

    The parent handles Ctrl-C and stops its workers; SIGTERM unwinds so that ``finally``
    blocks run (a TraCI backend's SUMO child is stopped with them).
    """
    for var in _THREAD_ENV_VARS:
        os.environ[var] = str(num_threads)
    retain_freed_memory()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    _exit_with_parent()
    import torch

    # Before the first parallel operation, so that torch's intra-op threads inherit it.
    flush_denormals()
    torch.set_num_threads(num_threads)
    with contextlib.suppress(RuntimeError):  # already set: harmless
        torch.set_num_interop_threads(1)


def _worker_main(conn: Connection, name: str, factory: Callable[[], Any], num_threads: int) -> None:
    """Entry point of a worker process: build the object, then serve calls until told to stop."""
    prepare_worker_process(num_threads)
    hosted: Any = None
    try:
        try:
            hosted = factory()
        except BaseException as error:
            _send(conn, ("error", f"{type(error).__name__}: {error}", traceback.format_exc()))
            return
        _send(conn, ("ready", None))
        while True:
            try:
                message = _receive(conn)
            except (EOFError, OSError):  # the coordinator is gone
                return
            if message[0] == "close":
                return
            _, method, args, kwargs, with_progress = message
            try:
                if with_progress:
                    kwargs = {**kwargs, "progress": lambda **info: _send(conn, ("progress", info))}
                result = getattr(hosted, method)(*args, **kwargs)
            except (BrokenPipeError, EOFError):
                return
            except BaseException as error:
                _send(conn, ("error", f"{type(error).__name__}: {error}", traceback.format_exc()))
                continue
            _send(conn, ("ok", result))
    except (BrokenPipeError, EOFError, ConnectionResetError):
        return
    finally:
        close = getattr(hosted, "close", None)
        if close is not None:
            with contextlib.suppress(Exception):
                close()
        conn.close()


@contextlib.contextmanager
def _caller_script_hidden() -> Any:
    """Spawn workers that do not import the caller's script.

    A spawned process imports the parent's ``__main__`` script (as ``__mp_main__``) before
    it unpickles its target, and so runs the script's top level again: a plain script
    without ``if __name__ == "__main__":`` that calls :func:`frl.evaluate.evaluate_policy`
    would start the evaluation anew in every worker, and multiprocessing refuses with its
    "freeze_support" error. frl's workers host frl's own objects, which need nothing of
    that script, so while they start ``__main__`` is an empty module: the children have no
    script to import. A notebook, whose ``__main__`` has no file, is unaffected.
    """
    main = sys.modules.get("__main__")
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        if main is None:
            del sys.modules["__main__"]
        else:
            sys.modules["__main__"] = main


class WorkerPool:
    """Spawned worker processes, each hosting ``factory()`` for one named client.

    Use as a context manager; :meth:`call` runs a method on every (or some) worker in
    parallel and returns the results in worker order.

    Args:
        clients: ``(name, factory)`` pairs; ``factory`` must be picklable (a class and a
            picklable spec via ``functools.partial``, for instance).
        num_threads: torch threads in each worker; default: the cores split evenly.
        timeout_s: longest a single call may take in any worker; None waits forever
            (deaths are still detected).
        poll_s: how often a waiting parent checks its workers for signs of life.
        start_timeout_s: longest the workers may take to start and build their objects.
        on_message: sees every message a worker sends (tests use it to audit traffic).
    """

    def __init__(
        self,
        clients: Sequence[tuple[str, Callable[[], Any]]],
        num_threads: int | None = None,
        timeout_s: float | None = None,
        poll_s: float = 0.5,
        on_message: MessageHook | None = None,
        start_timeout_s: float = 300.0,
    ) -> None:
        if not clients:
            raise ValueError("a worker pool needs at least one client")
        self.names = [name for name, _ in clients]
        self._factories = [factory for _, factory in clients]
        self.num_threads = num_threads or threads_per_worker(len(clients))
        self.timeout_s = timeout_s
        self.poll_s = poll_s
        self.start_timeout_s = start_timeout_s
        self.on_message = on_message
        self._processes: list[mp.process.BaseProcess] = []
        self._connections: list[Connection] = []
        self.busy_s = 0.0
        """Seconds the parent spent waiting in :meth:`call`."""

    def __enter__(self) -> WorkerPool:
        self.start()
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        self.close(graceful=exc_type is None)

    @property
    def pids(self) -> list[int | None]:
        return [process.pid for process in self._processes]

    def start(self) -> None:
        """Spawn the workers and wait until each has built its object."""
        context = worker_context()
        try:
            with _caller_script_hidden():
                self._spawn(context)
            self._collect(range(len(self.names)), expect="ready", timeout_s=self.start_timeout_s)
        except BaseException:
            self.close(graceful=False)
            raise

    def _spawn(self, context: Any) -> None:
        for name, factory in zip(self.names, self._factories, strict=True):
            parent_end, child_end = context.Pipe(duplex=True)
            process = context.Process(
                target=_worker_main,
                args=(child_end, name, factory, self.num_threads),
                name=f"frl-{name}",
                daemon=True,
            )
            process.start()
            child_end.close()
            self._processes.append(process)
            self._connections.append(parent_end)

    def call(
        self,
        method: str,
        args: Sequence[tuple[Any, ...]] | None = None,
        kwargs: Sequence[dict[str, Any]] | dict[str, Any] | None = None,
        workers: Sequence[int] | None = None,
        on_progress: Callable[[int, dict[str, Any]], None] | None = None,
    ) -> list[Any]:
        """Run ``method`` in ``workers`` (default: all) in parallel; their results in order.

        ``args[k]``/``kwargs[k]`` go to the k-th selected worker; a single ``kwargs`` dict
        goes to all. With ``on_progress``, the method receives a ``progress`` callback
        whose calls arrive here as ``on_progress(worker_index, info)``.
        """
        selected = list(range(len(self.names))) if workers is None else list(workers)
        args = args if args is not None else [()] * len(selected)
        if isinstance(kwargs, dict) or kwargs is None:
            kwargs = [dict(kwargs or {})] * len(selected)
        if len(args) != len(selected) or len(kwargs) != len(selected):
            raise ValueError("args and kwargs need one entry per selected worker")
        for index, a, k in zip(selected, args, kwargs, strict=True):
            try:
                message = ("call", method, tuple(a), k, on_progress is not None)
                _send(self._connections[index], message)
            except (BrokenPipeError, OSError) as error:
                raise self._death(index, f"cannot send {method!r}: {error}") from None
        results = self._collect(selected, expect="ok", on_progress=on_progress)
        return [results[index] for index in selected]

    def _collect(
        self,
        selected: Sequence[int] | range,
        expect: str,
        on_progress: Callable[[int, dict[str, Any]], None] | None = None,
        timeout_s: float | None = -1.0,
    ) -> dict[int, Any]:
        timeout_s = self.timeout_s if timeout_s == -1.0 else timeout_s
        started = time.monotonic()
        deadline = None if timeout_s is None else started + timeout_s
        pending = set(selected)
        results: dict[int, Any] = {}
        try:
            while pending:
                by_handle: dict[Any, tuple[str, int]] = {}
                for index in pending:
                    by_handle[self._connections[index]] = ("conn", index)
                    by_handle[self._processes[index].sentinel] = ("died", index)
                timeout = self.poll_s
                if deadline is not None:
                    timeout = max(0.0, min(timeout, deadline - time.monotonic()))
                ready = wait(list(by_handle), timeout=timeout)
                # Read messages before declaring deaths: a worker may report its error and exit.
                for handle in sorted(ready, key=lambda h: by_handle[h][0] != "conn"):
                    kind, index = by_handle[handle]
                    if index not in pending:
                        continue
                    if kind == "died":
                        if self._connections[index].poll():
                            continue  # its last words come first, next time round
                        raise self._death(index, "its worker process died")
                    try:
                        message = _receive(self._connections[index])
                    except (EOFError, OSError):
                        raise self._death(index, "its worker process closed the pipe") from None
                    tag, payload = message[0], message[1]
                    if self.on_message is not None:
                        self.on_message(self.names[index], tag, payload)
                    if tag == "progress":
                        if on_progress is not None:
                            on_progress(index, payload)
                    elif tag == "error":
                        raise ClientFailure(self.names[index], payload, None, message[2])
                    elif tag == expect:
                        results[index] = payload
                        pending.discard(index)
                    else:
                        raise ClientFailure(self.names[index], f"unexpected message {tag!r}")
                if deadline is not None and pending and time.monotonic() >= deadline:
                    index = min(pending)
                    raise ClientFailure(
                        self.names[index], f"no answer within timeout_s={timeout_s:g} s"
                    )
        finally:
            self.busy_s += time.monotonic() - started
        return results

    def _death(self, index: int, reason: str) -> ClientFailure:
        process = self._processes[index]
        process.join(timeout=1.0)
        code = process.exitcode
        detail = f"{reason} (pid {process.pid}, exit code {code}"
        if code is not None and code < 0:
            with contextlib.suppress(ValueError):
                detail += f", signal {signal.Signals(-code).name}"
        return ClientFailure(self.names[index], detail + ")", exitcode=code)

    def close(self, graceful: bool = True, grace_s: float = 10.0) -> None:
        """Stop every worker; safe to call twice. Never leaves a process running."""
        if graceful:
            for conn, process in zip(self._connections, self._processes, strict=False):
                if process.is_alive():
                    with contextlib.suppress(BrokenPipeError, OSError):
                        _send(conn, ("close",))
            deadline = time.monotonic() + grace_s
            for process in self._processes:
                process.join(timeout=max(0.0, deadline - time.monotonic()))
        stop_processes([p for p in self._processes if p.is_alive()], grace_s=3.0)
        for conn in self._connections:
            conn.close()
        for process in self._processes:
            if hasattr(process, "close") and not process.is_alive():
                process.close()
        self._processes = []
        self._connections = []
