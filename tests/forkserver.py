"""Command lines run as children forked from one warm Python process (a fork server), for test campaigns of many
short runs (tests/hostile.py): each child is a process of its own, as ``python -m MODULE ARGV...`` is, with its
own exit status, its own file descriptors 0/1/2 (stdin /dev/null, stdout and stderr to files), working directory,
environment and resource limits, and it runs MODULE as ``__main__`` the way ``python -m`` does
(:func:`runpy.run_module`); what it does not pay is the interpreter's start and the imports of numpy, scipy and
the project (about 0.4 s of CPU per run, most of a run that only reads a hostile file and refuses it).

What differs from a fresh interpreter: modules in ``preload`` are already imported (their import-time state is
the same; nothing else runs before the child), and the interpreter's own exit is imitated: an uncaught exception
prints its traceback and exits 1, ``SystemExit`` gives its status, then non-daemon threads are joined, ``atexit``
handlers run and stdio is flushed, as at a normal interpreter exit. Campaigns keep a share of their cases as real
``python -m`` runs (tests/hostile.py) so that the real interpreter's exit codes and stderr stay checked.

The server (``python -m tests.forkserver REQ_FD REPLY_FD MODULE...``) reads one JSON request per line and answers
one JSON line per request, one child at a time; :class:`ForkServer` is its client.
"""

from __future__ import annotations

import atexit
import importlib
import json
import os
import runpy
import signal
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

REPO = Path(__file__).resolve().parents[1]


@dataclass
class Result:
    returncode: int  # as subprocess gives it: -N for a child killed by signal N
    stdout: str
    stderr: str
    timed_out: bool = False


class ForkServer:
    """A server process that has imported ``preload``; :meth:`run` runs one command line in a forked child."""

    def __init__(self, preload: tuple[str, ...] = ()) -> None:
        r_req, w_req = os.pipe()
        r_rep, w_rep = os.pipe()
        self._proc = subprocess.Popen([sys.executable, "-m", "tests.forkserver", str(r_req), str(w_rep), *preload],
                                      cwd=REPO, pass_fds=(r_req, w_rep), stdin=subprocess.DEVNULL,
                                      stdout=subprocess.DEVNULL)
        os.close(r_req)
        os.close(w_rep)
        self._req = os.fdopen(w_req, "w")
        self._rep = os.fdopen(r_rep, "r")
        self._lock = threading.Lock()
        self._tmp = Path(tempfile.mkdtemp(prefix="gonio-forkserver-"))
        self._n = 0

    def run(self, module: str, argv: list[str], *, cwd: Path = REPO, env: dict[str, str] | None = None,
            timeout: float = 120.0, file_size_limit: int | None = None) -> Result:
        """``python -m MODULE ARGV...`` in ``cwd`` with ``env`` (default: this process's), stdin /dev/null;
        ``file_size_limit``: writes beyond it fail (EFBIG), a full disk. A child still running after ``timeout`` s
        is killed (SIGKILL). (No option drops root's capabilities: dropping them from the bounding set, as
        tests/hostile.py does before an exec, takes effect only at an exec; such runs need a new interpreter.)"""
        with self._lock:
            self._n += 1
            out, err = self._tmp / f"{self._n}.out", self._tmp / f"{self._n}.err"
            q = {"module": module, "argv": argv, "cwd": str(cwd), "env": dict(os.environ if env is None else env),
                 "timeout": timeout, "file_size_limit": file_size_limit,
                 "stdout": str(out), "stderr": str(err)}
            self._req.write(json.dumps(q) + "\n")
            self._req.flush()
            line = self._rep.readline()
        if not line:
            raise RuntimeError(f"the fork server stopped (exit status {self._proc.poll()})")
        rep = json.loads(line)
        res = Result(rep["returncode"], out.read_text(errors="replace"), err.read_text(errors="replace"),
                     rep["timed_out"])
        out.unlink()
        err.unlink()
        return res

    def close(self) -> None:
        self._req.close()
        try:
            self._proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._rep.close()
        for p in self._tmp.iterdir():
            p.unlink()
        self._tmp.rmdir()

    def __enter__(self) -> ForkServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --- the server ------------------------------------------------------------------------------------------------


def _exit_status(code: Any) -> int:
    """The exit status of ``SystemExit(code)`` as the interpreter makes it."""
    if code is None:
        return 0
    if isinstance(code, int):
        return code & 0xFF
    print(code, file=sys.stderr)
    return 1


def _child(q: dict[str, Any], server_fds: tuple[int, ...]) -> NoReturn:
    status = 1
    try:
        for fd in server_fds:
            os.close(fd)
        os.chdir(q["cwd"])
        nul = os.open(os.devnull, os.O_RDONLY)
        os.dup2(nul, 0)
        os.close(nul)
        for fd, path in ((1, q["stdout"]), (2, q["stderr"])):
            f = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            os.dup2(f, fd)
            os.close(f)
        os.environ.clear()
        os.environ.update(q["env"])
        if q["file_size_limit"] is not None:
            import resource

            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (q["file_size_limit"], q["file_size_limit"]))
        sys.argv = [q["module"], *q["argv"]]  # run_module sets argv[0] to the module's file, as python -m does
        sys.modules.pop(q["module"], None)  # preloaded as a module: run afresh as __main__ (as python -m does)
        runpy.run_module(q["module"], run_name="__main__", alter_sys=True)
        status = 0
    except SystemExit as e:
        status = _exit_status(e.code)
    except KeyboardInterrupt:
        traceback.print_exc()
        status = -signal.SIGINT
    except BaseException:  # noqa: BLE001 - what the interpreter does with an uncaught exception
        traceback.print_exc()
        status = 1
    try:
        shutdown = getattr(threading, "_shutdown", None)
        if shutdown is not None:
            shutdown()  # non-daemon threads are joined, as at interpreter exit
        atexit._run_exitfuncs()
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
    except BaseException:  # noqa: BLE001
        traceback.print_exc()
    if status < 0:  # an uncaught KeyboardInterrupt: the interpreter exits through SIGINT
        signal.signal(-status, signal.SIG_DFL)
        os.kill(os.getpid(), -status)
    os._exit(status)


def _wait(pid: int, timeout: float) -> tuple[int, bool]:
    deadline = time.monotonic() + timeout
    pause = 0.001
    while True:
        done, st = os.waitpid(pid, os.WNOHANG)
        if done:
            return os.waitstatus_to_exitcode(st), False
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            _, st = os.waitpid(pid, 0)
            return os.waitstatus_to_exitcode(st), True
        time.sleep(pause)
        pause = min(pause * 2, 0.02)


def serve(req_fd: int, rep_fd: int, preload: list[str]) -> None:
    for name in preload:
        importlib.import_module(name)
    with os.fdopen(req_fd, "r") as req, os.fdopen(rep_fd, "w") as rep:
        for line in req:
            q = json.loads(line)
            sys.stdout.flush()
            sys.stderr.flush()
            pid = os.fork()
            if pid == 0:
                _child(q, (req_fd, rep_fd))
            code, timed_out = _wait(pid, q["timeout"])
            rep.write(json.dumps({"returncode": code, "timed_out": timed_out}) + "\n")
            rep.flush()


if __name__ == "__main__":
    serve(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3:])
