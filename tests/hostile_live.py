"""The live view under abuse (issue 49, items 8-10), shared by ``tests/test_live_abuse.py`` and
``scripts/hostile_campaign.py``: a header flood, half-open connections, foreign ``Host`` names on every bind, and
links in the capture folder to files outside it. Loopback only; every loop is bounded.

Each case starts the server as the capture does (``python -m acquisition.live``, a process of its own) and
measures it from ``/proc/PID/status`` (resident memory, its peak, threads).
"""

from __future__ import annotations

import contextlib
import http.client
import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
HEADER = "theta_i_deg,theta_o_deg,value,value_std,repeats,unix_time_s\n"


def capture_folder(folder: Path) -> Path:
    """A capture folder as the run leaves it: a slice of two rows, a run record, a log."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "slice.csv").write_text("# gonio-brdf slice\n# meta: {}\n" + HEADER + "30.0,-10.0,0.25,0.01,4,1.0\n"
                                      "30.0,0.0,0.5,0.02,4,2.0\n")
    (folder / "capture.json").write_text(json.dumps({"status": "running"}))
    (folder / "capture.log").write_text("started\n")
    return folder


@contextlib.contextmanager
def live_server(folder: Path, host: str = "127.0.0.1", allow: tuple[str, ...] = ()) -> Iterator[tuple[int, int]]:
    """(PID, port) of ``python -m acquisition.live`` on ``folder``, stopped afterwards."""
    argv = [sys.executable, "-m", "acquisition.live", "--dir", str(folder), "--host", host, "--port", "0",
            *(a for n in allow for a in ("--allow-host", n))]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line, proc.stderr.read() if proc.stderr else ""
        port = int(json.loads(line)["url"].rstrip("/").rsplit(":", 1)[1])
        yield proc.pid, port
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        for fh in (proc.stdout, proc.stderr):
            if fh is not None:
                fh.close()


def status(pid: int) -> dict[str, int]:
    """VmRSS and VmHWM (kB) and Threads of process ``pid``."""
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM", "Threads"):
            out[key] = int(value.split()[0])
    return out


def request(port: int, path: str = "/state.json", host: str | None = None, addr: str = "127.0.0.1"
            ) -> tuple[int, bytes]:
    """(status, body) of a GET with ``Host: host`` (default ``127.0.0.1:PORT``)."""
    conn = http.client.HTTPConnection(addr, port, timeout=20)
    try:
        conn.putrequest("GET", path, skip_host=True, skip_accept_encoding=True)
        conn.putheader("Host", host if host is not None else f"127.0.0.1:{port}")
        conn.endheaders()
        r = conn.getresponse()
        return r.status, r.read()
    finally:
        conn.close()


def answers(port: int, tries: int = 100) -> int:
    """The status of a plain GET once the server answers one (at most ``tries`` attempts, 0.1 s apart)."""
    for _ in range(tries):
        try:
            return request(port)[0]
        except OSError:
            time.sleep(0.1)
    return 0


def header_flood(port: int, connections: int = 40, lines: int = 99, line_bytes: int = 64 * 1024
                 ) -> list[socket.socket]:
    """The issue's flood: ``connections`` connections each sending ``lines`` headers of ``line_bytes`` (within
    http.client's own 64 KB line limit) and never the blank line that ends them; the sockets, still open."""
    socks: list[socket.socket] = []
    pad = b"X-Pad: " + b"a" * (line_bytes - 9) + b"\r\n"

    def one() -> None:
        s = socket.create_connection(("127.0.0.1", port), timeout=20)
        socks.append(s)
        try:
            s.sendall(f"GET /state.json HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n".encode())
            for _ in range(lines):
                s.sendall(pad)
        except OSError:  # refused (431) and closed: what a bounded server does
            pass

    threads = [threading.Thread(target=one) for _ in range(connections)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    return socks


def half_open(port: int, n: int = 1000) -> list[socket.socket]:
    """``n`` connections that send half a request and wait; the sockets (some may have been closed by the server)."""
    socks = []
    for _ in range(n):
        try:
            s = socket.create_connection(("127.0.0.1", port), timeout=5)
            s.sendall(b"GET /state.json HTTP/1.1\r\nHost: 127.0.0.1:")
        except OSError:
            continue
        socks.append(s)
    return socks


def close_all(socks: list[socket.socket]) -> None:
    for s in socks:
        with contextlib.suppress(OSError):
            s.close()


#: The server's threads under 1000 half-open connections: its connection cap (acquisition.live.server's
#: MAX_CONNECTIONS, 32) and its main and serving threads, with a margin.
MAX_THREADS = 40


# --- the cases of the campaign -----------------------------------------------------------------------------------


@dataclass
class LiveOutcome:
    name: str
    clean: bool
    note: str


def _flood(work: Path) -> LiveOutcome:
    with live_server(capture_folder(work / "flood")) as (pid, port):
        before = status(pid)
        socks = header_flood(port)
        after = status(pid)
        ok = answers(port)
        close_all(socks)
    grew = (after["VmHWM"] - before["VmRSS"]) / 1024
    return LiveOutcome("40 connections x 99 x 64 KB of headers", grew < 40 and ok == 200,
                       f"peak memory +{grew:.0f} MB, {after['Threads']} threads, then a GET: {ok}")


def _half_open(work: Path) -> LiveOutcome:
    with live_server(capture_folder(work / "half-open")) as (pid, port):
        socks = half_open(port)
        time.sleep(0.5)  # the accepts of the last ones
        threads = status(pid)["Threads"]
        close_all(socks)
        ok = answers(port)
    return LiveOutcome("1000 half-open connections", threads <= MAX_THREADS and ok == 200,
                       f"{threads} threads (at most {MAX_THREADS}), then a GET: {ok}")


def _hosts(work: Path) -> LiveOutcome:
    bad = []
    for bind in ("127.0.0.1", "0.0.0.0"):
        with live_server(capture_folder(work / "hosts"), bind, allow=("bench.lab",)) as (_, port):
            for host, want in ((f"evil.example:{port}", 403), ("evil.example", 403), (f"127.0.0.1:{port}", 200),
                               (f"localhost:{port}", 200), (f"bench.lab:{port}", 200), ("127.0.0.1:1", 403)):
                got = request(port, host=host)[0]
                if got != want:
                    bad.append(f"{bind} Host {host}: {got}")
    return LiveOutcome("foreign Host names on 127.0.0.1 and 0.0.0.0", not bad, "; ".join(bad) or "refused")


def _links(work: Path) -> LiveOutcome:
    folder = capture_folder(work / "links")
    secret = work / "secret.csv"
    secret.write_text("30.0,20.0,123.0,0.01,4,9.0\nnot yours\n")
    (folder / "capture.log").unlink()
    os.link(secret, folder / "capture.log")  # a hard link to a file outside the folder, under a served name
    os.link(secret, folder / "notes.txt")  # ... and under a name the view never writes
    (folder / "progress.json").symlink_to(secret)
    bad = []
    with live_server(folder) as (_, port):
        for path, want in (("/files/capture.log", 403), ("/files/notes.txt", 404), ("/files/progress.json", 403),
                           ("/files/slice.csv", 200)):
            got, body = request(port, path)
            if got != want or b"not yours" in body:
                bad.append(f"{path}: {got}")
        (folder / "slice.csv").unlink()
        os.link(secret, folder / "slice.csv")
        got, body = request(port)
        if got != 200 or any(s[2] == 123.0 for s in json.loads(body)["samples"]):
            bad.append("state.json showed a hard-linked slice")
    return LiveOutcome("links out of the capture folder", not bad, "; ".join(bad) or "refused")


LIVE_CASES: tuple[Callable[[Path], LiveOutcome], ...] = (_flood, _half_open, _hosts, _links)


def live_cases(work: Path) -> list[LiveOutcome]:
    """Every case of the live view's abuse, run in ``work``."""
    work.mkdir(parents=True, exist_ok=True)
    return [case(work) for case in LIVE_CASES]
