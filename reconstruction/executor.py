"""One way to run independent cases in parallel: a ``concurrent.futures`` executor.

A local process pool by default; a Dask cluster when given a scheduler address (``dask.distributed``, the
optional ``dask`` extra), so a large study or a batch reconstruction runs on many machines unchanged.
"""

from __future__ import annotations

import contextvars
import os
import threading
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor, as_completed
from contextlib import contextmanager
from typing import Any, TypeVar

T = TypeVar("T")

__all__ = ["make_executor", "run_all", "Background", "SpareCore", "release_spare_core"]


@contextmanager
def make_executor(scheduler: str | None = None, workers: int | None = None,
                  connect_timeout_s: float = 10.0) -> Iterator[Executor]:
    """Yield an executor: ``ProcessPoolExecutor(workers)`` locally, or a Dask client's executor.

    ``scheduler``: a dask.distributed scheduler address such as ``tcp://10.0.0.5:8786``; ``workers``: local
    processes (default: the number of CPUs; 1 runs in a thread, which keeps tracebacks simple).
    Raises RuntimeError (with the address) when the scheduler cannot be reached, or ``workers`` < 1.
    """
    if workers is not None and workers < 1:
        raise RuntimeError(f"--workers {workers}: expected a positive number of worker processes")
    if scheduler:
        try:
            from distributed import Client
        except ImportError:
            raise RuntimeError(
                "--scheduler needs dask.distributed: pip install 'gonio-brdf[dask]'"
            ) from None
        try:
            client = Client(scheduler, timeout=connect_timeout_s)
        except (OSError, TimeoutError, ValueError) as e:
            raise RuntimeError(f"--scheduler {scheduler}: cannot connect to a dask scheduler there ({e})") from None
        try:
            yield client.get_executor()
        finally:
            client.close()
        return
    n = workers or os.cpu_count() or 1
    pool: Executor = ThreadPoolExecutor(1) if n == 1 else ProcessPoolExecutor(n, initializer=_one_blas_thread)
    try:
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _one_blas_thread() -> None:
    """Worker initializer: one BLAS thread per process, so N workers do not oversubscribe the N cores."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")


def run_all(executor: Executor, fn: Callable[..., T], cases: Iterable[Any],
            on_done: Callable[[Any, Future[T]], None] | None = None) -> list[tuple[Any, Future[T]]]:
    """Submit ``fn(case)`` for every case; call ``on_done(case, future)`` as each finishes (any order).

    Returns (case, future) pairs in submission order; a case's exception stays in its future.
    """
    futures = [(case, executor.submit(fn, case)) for case in cases]
    index = {id(f): c for c, f in futures}
    for fut in as_completed([f for _, f in futures]):
        if on_done is not None:
            on_done(index[id(fut)], fut)
    return futures


class Background:
    """A second thread for independent work when the machine has a second core (else the work runs when its result
    is asked for); ``submit`` returns a function that gives the result (or raises the work's exception). The
    work runs in submission order, in a copy of the caller's context (the shared cone integrals of
    :func:`reconstruction.bench.instrument.shared_cone_averages` included): auto's cross-validation of the methods
    that do not wait for fit, and the pipeline's uncertainty and HTML page beside the main thread."""

    def __init__(self, enabled: bool = True) -> None:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        self.pool = ThreadPoolExecutor(max_workers=1) if enabled and cores > 1 else None

    def __enter__(self) -> Background:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)

    def submit(self, fn: Callable[..., T], *args: Any) -> Callable[[], T]:
        if self.pool is None:  # run when first asked for, once
            done: list[T] = []

            def here() -> T:
                if not done:
                    done.append(fn(*args))
                return done[0]

            return here
        fut = self.pool.submit(contextvars.copy_context().run, fn, *args)
        return fut.result


_SPARE: contextvars.ContextVar[threading.Event | None] = contextvars.ContextVar("spare_core", default=None)


class SpareCore:
    """Work that can wait until the second core is free: within this block, :meth:`later` wraps a function so that
    it first waits until :func:`release_spare_core` is called (by ``auto`` once its background cross-validation is
    done) or the block ends. On the 2-core machine a third busy thread only slows the other two: the run's
    critical path (fit's model search in the main thread) then shares two cores with two helpers. ``hold`` False:
    nothing waits (a method without background work of its own)."""

    def __init__(self, hold: bool = True) -> None:
        self.gate = threading.Event()
        if not hold:
            self.gate.set()
        self._token: contextvars.Token[threading.Event | None] | None = None

    def __enter__(self) -> SpareCore:
        self._token = _SPARE.set(self.gate)
        return self

    def __exit__(self, *exc: object) -> None:
        self.gate.set()
        if self._token is not None:
            _SPARE.reset(self._token)

    def release(self) -> None:
        """Let the waiting work run."""
        self.gate.set()

    def later(self, fn: Callable[..., T]) -> Callable[..., T]:
        """``fn``, first waiting for the spare core (at most a minute: a guard against a lost release)."""
        gate = self.gate

        def waiting(*args: Any, **kwargs: Any) -> T:
            gate.wait(timeout=60.0)
            return fn(*args, **kwargs)

        return waiting


def release_spare_core() -> None:
    """Called where background work of a method's own is done: the work a :class:`SpareCore` holds may start."""
    gate = _SPARE.get()
    if gate is not None:
        gate.set()
