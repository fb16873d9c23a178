"""One way to run independent cases in parallel: a ``concurrent.futures`` executor.

A local process pool by default; a Dask cluster when given a scheduler address (``dask.distributed``, the
optional ``dask`` extra), so a large study or a batch reconstruction runs on many machines unchanged.
"""

from __future__ import annotations

import contextvars
import os
import pickle
import queue
import signal
import struct
import sys
import threading
import warnings
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Executor, Future, ThreadPoolExecutor, as_completed
from contextlib import contextmanager
from typing import Any, TypeVar

from threadpoolctl import threadpool_limits

T = TypeVar("T")

__all__ = ["make_executor", "run_all", "Background", "SpareCore", "release_spare_core", "Forked", "forked", "can_fork",
           "fork_child", "end_child", "write_message", "incoming", "usable_cores"]


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
    from concurrent.futures import ProcessPoolExecutor  # here: it imports multiprocessing, which little else needs

    n = workers or os.cpu_count() or 1
    pool: Executor = ThreadPoolExecutor(1) if n == 1 else ProcessPoolExecutor(n, initializer=_one_blas_thread)
    try:
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _one_blas_thread() -> None:
    """Worker initializer: one BLAS thread per process, so N workers do not oversubscribe the N cores."""
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


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system says it, else the machine's)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def once(fn: Callable[..., T], *args: Any) -> Callable[[], T]:
    """A function that gives ``fn(*args)``, computed when first asked for and only then (the work a second
    thread or a child would have done, here)."""
    done: list[T] = []

    def here() -> T:
        if not done:
            done.append(fn(*args))
        return done[0]

    return here


class Background:
    """A second thread for independent work when the machine has a second core (else the work runs when its result
    is asked for); ``submit`` returns a function that gives the result (or raises the work's exception). The
    work runs in submission order, in a copy of the caller's context (the shared cone integrals of
    :func:`reconstruction.instrument.response.shared_cone_averages` included): auto's cross-validation of the methods
    that do not wait for fit, and the pipeline's uncertainty and HTML page beside the main thread."""

    def __init__(self, enabled: bool = True) -> None:
        self.pool = ThreadPoolExecutor(max_workers=1) if enabled and usable_cores() > 1 else None

    def __enter__(self) -> Background:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)

    def submit(self, fn: Callable[..., T], *args: Any) -> Callable[[], T]:
        if self.pool is None:  # run when first asked for, once
            return once(fn, *args)
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


# --- a forked child for work that holds the GIL --------------------------------------------------------------------

_FORKED: contextvars.ContextVar[Forked | None] = contextvars.ContextVar("forked", default=None)


def can_fork(switch: str = "GONIO_FORK") -> bool:
    """Whether work may run in a forked child: on Linux (fork is what the standard library's process pools use
    there; macOS's system libraries are not fork-safe), with a second core, unless the environment variable
    ``switch`` is ``0`` (``GONIO_FORK`` for auto's child, ``GONIO_HTML_FORK`` for the HTML page's drawer)."""
    return (sys.platform.startswith("linux") and hasattr(os, "fork") and usable_cores() > 1
            and os.environ.get(switch, "1") != "0")


def fork_child(child: Callable[[int, int], None]) -> tuple[int, int, int]:
    """Fork a child process that runs ``child(inbox, outbox)`` (which must end it with ``os._exit``), with a pipe
    each way: (its pid, the write end of its inbox, the read end of its outbox), or (0, -1, -1) when fork fails.
    Python 3.12 warns of fork in a process with threads: the children here take none of their locks."""
    to_r, to_w = os.pipe()
    back_r, back_w = os.pipe()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            pid = os.fork()
    except OSError:
        for fd in (to_r, to_w, back_r, back_w):
            os.close(fd)
        return 0, -1, -1
    if pid == 0:
        os.close(to_w)
        os.close(back_r)
        child(to_r, back_w)  # never returns
    os.close(to_r)
    os.close(back_w)
    return pid, to_w, back_r


def end_child(pid: int, *fds: int) -> None:
    """Close this side's pipes to a forked child (those >= 0) and end it: killed (its answers are no longer
    wanted) and waited for, so that it leaves no process behind. ``pid`` 0: pipes only."""
    for fd in fds:
        if fd >= 0:
            os.close(fd)
    if pid:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
        os.waitpid(pid, 0)


class Forked:
    """A child process forked when this is made (as early as a run allows: the process is small and its own
    threads have not started) that runs tasks in the order they are sent, beside this process: work that holds the
    GIL (fits of many small solves) runs truly beside the main thread's, where a second thread would take turns
    with it. :meth:`submit` sends a module-level function and picklable arguments and returns a function that
    gives the result (blocking, without holding the GIL). Without fork (:func:`can_fork`, ``enabled`` False), when
    the child is gone, or when a task fails there (its error may not pickle), the task runs here when its result is
    asked for, so that an error is raised in this process as without a child. Within the block, :func:`forked`
    gives it to the code the run calls (auto's cross-validation). Leaving the block ends the child."""

    def __init__(self, enabled: bool = True) -> None:
        self._pid = 0
        self._to = self._back = -1
        self._lock = threading.Lock()
        self._sent = 0  # tasks submitted
        self._order: list[int] = []  # those sent to the child, in order: its answers come in this order
        self._got: dict[int, tuple[str, Any]] = {}
        self._token: contextvars.Token[Forked | None] | None = None
        if enabled and can_fork():
            self._pid, self._to, self._back = fork_child(_forked_child)

    @property
    def alive(self) -> bool:
        """Whether tasks go to a child."""
        return self._pid != 0

    def submit(self, fn: Callable[..., T], *args: Any) -> Callable[[], T]:
        here = once(fn, *args)
        if not self._pid:
            return here
        n = self._sent
        self._sent += 1
        try:
            data = pickle.dumps((fn, args), protocol=pickle.HIGHEST_PROTOCOL)
            write_message(self._to, data)  # the child's reader takes it at once
            self._order.append(n)
        except (OSError, pickle.PicklingError, AttributeError, TypeError):
            self._got[n] = ("here", None)  # not sent: run here when asked for

        answer: list[tuple[str, Any]] = []

        def result() -> T:
            if not answer:
                answer.append(self._answer(n))
            status, value = answer[0]
            return value if status == "ok" else here()  # type: ignore[no-any-return]

        return result

    def _answer(self, n: int) -> tuple[str, Any]:
        """The child's answer to task ``n``: ("ok", value), or ("here", None) when it must run here."""
        with self._lock:  # answers come in the order the tasks were sent: read until n's
            while n not in self._got:
                msg = _read_message(self._back) if self._back >= 0 else None
                k = self._order.pop(0)
                if msg is None:  # the child is gone: this and every later task run here
                    self._got.update({x: ("here", None) for x in [k, *self._order]})
                    self._order.clear()
                    break
                try:
                    self._got[k] = pickle.loads(msg)
                except Exception:  # noqa: BLE001 - an answer that does not unpickle: run here
                    self._got[k] = ("here", None)
            return self._got.pop(n)

    def close(self) -> None:
        """End the child (:func:`end_child`: its pipes closed, the process killed and waited for)."""
        end_child(self._pid, self._to, self._back)
        self._pid, self._to, self._back = 0, -1, -1

    def __enter__(self) -> Forked:
        self._token = _FORKED.set(self if self._pid else None)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._token is not None:
            _FORKED.reset(self._token)
        self.close()


def forked() -> Forked | None:
    """The run's forked child (:class:`Forked`) when there is one."""
    return _FORKED.get()


def write_message(fd: int, data: bytes) -> None:
    """Write ``data`` to the descriptor ``fd`` as one length-prefixed message (what :func:`incoming` reads), all of
    it (a pipe may take it in parts)."""
    view = memoryview(struct.pack(">Q", len(data)) + data)
    while view:
        view = view[os.write(fd, view):]


def incoming(fd: int) -> queue.Queue[bytes | None]:
    """The length-prefixed messages of the pipe ``fd``, read by a thread as they come into the queue returned,
    None at the pipe's end: a forked child's inbox, so that the parent's writes never wait for the child's work."""
    todo: queue.Queue[bytes | None] = queue.Queue()

    def read() -> None:
        while (m := _read_message(fd)) is not None:
            todo.put(m)
        todo.put(None)

    threading.Thread(target=read, daemon=True).start()
    return todo


def _read_message(fd: int) -> bytes | None:
    """One length-prefixed message from ``fd``, or None at its end."""
    head = _read_exactly(fd, 8)
    return None if head is None else _read_exactly(fd, struct.unpack(">Q", head)[0])


def _read_exactly(fd: int, n: int) -> bytes | None:
    parts, left = [], n
    while left:
        chunk = os.read(fd, min(left, 1 << 20))
        if not chunk:
            return None
        parts.append(chunk)
        left -= len(chunk)
    return b"".join(parts)


def _forked_child(inbox: int, outbox: int) -> None:
    """The child of :class:`Forked`: only its two pipes (and standard streams) open, one BLAS thread; a thread reads
    the tasks as they come, each is run in turn and its answer ("ok", value) or ("here", None) sent back; exits
    without cleanup (``os._exit``) at the end of its input."""
    code = 1
    try:
        # the parent's other descriptors closed: a pipe to another child (the HTML page's drawer) held open here
        # would keep that child from seeing the end of its input
        for name in os.listdir("/proc/self/fd"):  # Linux (can_fork); a few dozen
            if int(name) not in (0, 1, 2, inbox, outbox):
                try:
                    os.close(int(name))
                except OSError:  # the listing's own descriptor, already closed
                    pass
        warnings.simplefilter("ignore")
        threadpool_limits(1, user_api="blas")
        todo = incoming(inbox)  # tasks read as they come: the parent's write of a large one never waits for a task
        while (msg := todo.get()) is not None:
            try:
                fn, args = pickle.loads(msg)
                answer = pickle.dumps(("ok", fn(*args)), protocol=pickle.HIGHEST_PROTOCOL)
            except Exception:  # noqa: BLE001 - run again in the parent, which raises the error there
                answer = pickle.dumps(("here", None))
            write_message(outbox, answer)
        code = 0
    finally:
        os._exit(code)
