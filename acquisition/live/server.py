"""The live view's HTTP server: a capture's own folder, read only, on 127.0.0.1 (docs/capture.md, "Live view").

``GET /`` is the page (:mod:`acquisition.live.page`: inline script and SVG, nothing fetched from elsewhere);
``GET /state.json`` what the page draws: the samples of ``slice.csv`` so far (angles, f_r and its standard
deviation averaged over the channels), ``progress.json`` (points done and planned, time left, the last
sample, the status: :mod:`acquisition.run.progress`) and the run record's status and estimate
(``capture.json``); ``GET /files/NAME`` one of the files the capture writes for it (:data:`SERVED`), as it is.

It changes nothing: GET and HEAD only (any other method: 405). It serves only the files of :data:`SERVED`: a name
with a ``/`` or a ``..`` once percent-decoded or an absolute path is refused (403), any other name is 404, and a
served name that is not the file the capture wrote (a symbolic link, a hard link: more than one name, another
owner, not a regular file) is refused (403); the files it reads for ``state.json`` are opened the same way. A
request whose ``Host`` is neither an IP address nor a name on its allow-list (``localhost``, the bound name, the
``--allow-host`` names) is refused (403: a web page elsewhere cannot read it through DNS rebinding, whatever the
address it is bound to). It holds under abuse: at most :data:`MAX_CONNECTIONS` connections at once (one more is
closed at once), :data:`MAX_HEADER_BYTES` and :data:`MAX_HEADERS` of headers (431 beyond), and a request must
arrive within :data:`READ_TIMEOUT_S` (the connection is closed otherwise). The slice is read incrementally (only
the complete lines appended since the last request), so a poll costs little however long the capture.
"""

from __future__ import annotations

import http.client
import ipaddress
import json
import logging
import math
import os
import socket
import stat
import threading
import time
import urllib.parse
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from acquisition.live.page import PAGE

log = logging.getLogger("acquisition.live")

__all__ = ["LiveServer", "SliceTail", "state_of"]

#: The files of a capture the live view reads (names in the folder, as the run writes them).
SLICE, RECORD, PROGRESS = "slice.csv", "capture.json", "progress.json"
#: The only files served under /files/: what a capture writes in its folder (acquisition.run's names; the live
#: view imports no run code): the slice, the run record, the progress file, the log and a simulated bench's log.
SERVED = frozenset({SLICE, RECORD, PROGRESS, "capture.log", "simulator.log"})
#: Largest file served under /files/ (bytes): a capture's log or slice, not anything bigger.
MAX_FILE_BYTES = 64 * 1024 * 1024
#: Connections served at once; one more is closed at once (a browser polls on one or two).
MAX_CONNECTIONS = 32
#: A request's header lines: at most this many, of at most this many bytes in all (request line apart); 431 beyond.
MAX_HEADERS, MAX_HEADER_BYTES = 64, 16 * 1024
#: Seconds a connection may take to send its whole request (and each read of it); then it is closed.
READ_TIMEOUT_S = 10.0
_TYPES = {".csv": "text/csv; charset=utf-8", ".json": "application/json", ".log": "text/plain; charset=utf-8",
          ".txt": "text/plain; charset=utf-8"}
_HEADERS = {"Cache-Control": "no-store", "X-Content-Type-Options": "nosniff", "Referrer-Policy": "no-referrer",
            "Content-Security-Policy": "default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; "
                                       "connect-src 'self'; img-src 'self' data:; base-uri 'none'; form-action 'none'"}


def open_own(path: Path) -> int:
    """A read-only descriptor of ``path`` if it is the file the capture wrote there: a regular file reached without
    following a symbolic link, with one name (no hard link to a file elsewhere) and this process's owner. Raises
    :class:`PermissionError` otherwise (:class:`FileNotFoundError` when it is not there)."""
    fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK)
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_nlink != 1 or st.st_uid != os.geteuid():
            raise PermissionError(f"{path.name}: not the file the capture wrote")
    except BaseException:
        os.close(fd)
        raise
    return fd


class SliceTail:
    """``slice.csv`` read as it grows: each call reads only the bytes appended since the last one, and keeps the
    complete lines (the writer appends whole lines; a half-written one waits for the next call)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.offset = 0
        self.rest = b""
        self.columns: list[str] | None = None
        self.rows: list[list[float]] = []
        self.lock = threading.Lock()

    def poll(self) -> list[list[float]]:
        """[theta_i, theta_o, f_r (mean of the channels), std (mean of the channels)] per sample so far."""
        with self.lock:
            try:
                with os.fdopen(open_own(self.path), "rb") as fh:
                    size = os.fstat(fh.fileno()).st_size
                    if size < self.offset:  # a new file (a fresh capture in the folder): start again
                        self.offset, self.rest, self.columns, self.rows = 0, b"", None, []
                    fh.seek(self.offset)
                    data = fh.read(min(size - self.offset, 16 * 1024 * 1024))
            except OSError:
                return self.rows
            self.offset += len(data)
            lines = (self.rest + data).split(b"\n")
            self.rest = lines.pop()
            for raw in lines:
                self._line(raw.decode("utf-8", errors="replace").strip())
            return self.rows

    def _line(self, text: str) -> None:
        if not text or text.startswith("#"):
            return
        parts = text.split(",")
        if self.columns is None:
            self.columns = parts
            return
        cols = self.columns
        try:
            vals = [float(x) for x in parts]
        except ValueError:
            return
        if len(vals) != len(cols):
            return
        f = [v for c, v in zip(cols[2:], vals[2:], strict=False) if c not in ("repeats", "unix_time_s")
             and not c.endswith("_std")]
        s = [v for c, v in zip(cols[2:], vals[2:], strict=False) if c.endswith("_std")]
        if f and all(math.isfinite(x) for x in f + s):
            self.rows.append([vals[0], vals[1], sum(f) / len(f), sum(s) / len(s) if s else 0.0])


_CACHE: dict[Path, tuple[tuple[int, int], dict[str, Any]]] = {}
_CACHE_LOCK = threading.Lock()


def _read_json(path: Path) -> dict[str, Any]:
    """The JSON object in ``path`` ({} when missing or unreadable), read again only when it changed (the run
    replaces its files atomically, so a read sees the old or the new one whole)."""
    try:
        st = path.stat()
        key = (st.st_mtime_ns, st.st_size)
        with _CACHE_LOCK:
            hit = _CACHE.get(path)
        if hit is not None and hit[0] == key:
            return hit[1]
        with os.fdopen(open_own(path), encoding="utf-8") as fh:
            d = json.load(fh)
    except (OSError, ValueError):
        return {}
    d = d if isinstance(d, dict) else {}
    with _CACHE_LOCK:
        _CACHE[path] = (key, d)
    return d


def state_of(folder: Path, tail: SliceTail) -> dict[str, Any]:
    """What the page draws (see the module docstring)."""
    rows = tail.poll()
    record = _read_json(folder / RECORD)
    est = record.get("estimate")
    return {"folder": folder.name, "samples": rows, "progress": _read_json(folder / PROGRESS),
            "record": {"status": record.get("status"),
                       "estimate_s": est.get("total_s") if isinstance(est, dict) else None},
            "channels": (len(tail.columns) - 4) // 2 if tail.columns else 0}


class _Bounded:
    """The request's stream while its headers are read: at most :data:`MAX_HEADERS` lines and
    :data:`MAX_HEADER_BYTES` bytes, all before the request's deadline (``http.client.parse_headers`` reads it
    line by line; its own limits, 100 lines of 64 KB, let 40 connections hold 250 MB)."""

    def __init__(self, raw: Any, sock: socket.socket, deadline: float) -> None:
        self.raw, self.sock, self.deadline = raw, sock, deadline
        self.left, self.lines = MAX_HEADER_BYTES, 0

    def readline(self, size: int = -1) -> bytes:
        self.lines += 1
        if self.lines > MAX_HEADERS + 1:  # the blank line that ends them is one more
            raise http.client.HTTPException(f"more than {MAX_HEADERS} headers")
        left = self.deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError("the request's headers took too long")
        self.sock.settimeout(min(left, READ_TIMEOUT_S))
        line = self.raw.readline(min(size if size >= 0 else self.left + 1, self.left + 1))
        self.left -= len(line)
        if self.left < 0:
            raise http.client.LineTooLong(f"headers longer than {MAX_HEADER_BYTES} bytes")
        return line  # type: ignore[no-any-return]


class _Handler(BaseHTTPRequestHandler):
    server: LiveServer  # type: ignore[assignment]
    server_version = "gonio-live"
    sys_version = ""
    timeout = READ_TIMEOUT_S  # each read of the request (socketserver sets it on the socket)

    def setup(self) -> None:
        self.deadline = time.monotonic() + READ_TIMEOUT_S
        super().setup()

    def parse_request(self) -> bool:
        """The base class's, its headers read through :class:`_Bounded` (431 beyond its limits)."""
        raw = self.rfile
        self.rfile = _Bounded(raw, self.connection, self.deadline)  # type: ignore[assignment]
        try:
            return super().parse_request()
        finally:
            self.rfile = raw
            self.connection.settimeout(self.timeout)

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - the base class's name
        log.debug("%s %s", self.address_string(), format % args)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("do_"):  # every method other than GET and HEAD changes something: refused
            return self._not_allowed
        raise AttributeError(name)

    def _not_allowed(self) -> None:
        self._send(HTTPStatus.METHOD_NOT_ALLOWED, b"GET and HEAD only\n", "text/plain; charset=utf-8",
                   {"Allow": "GET, HEAD"})

    def do_HEAD(self) -> None:
        self._serve(head=True)

    def do_GET(self) -> None:
        self._serve(head=False)

    def _send(self, status: int, body: bytes, ctype: str, extra: dict[str, str] | None = None,
              head: bool = False) -> None:
        self.send_response(status)
        for k, v in {**_HEADERS, **(extra or {}), "Content-Type": ctype, "Content-Length": str(len(body))}.items():
            self.send_header(k, v)
        self.end_headers()
        if not head:
            self.wfile.write(body)

    def _serve(self, head: bool) -> None:
        try:
            if not self.server.host_ok(self.headers.get("Host", "")):
                self._send(HTTPStatus.FORBIDDEN, b"forbidden host\n", "text/plain; charset=utf-8", head=head)
                return
            path = urllib.parse.urlsplit(self.path).path
            if path in ("/", "/index.html"):
                self._send(HTTPStatus.OK, PAGE.encode("utf-8"), "text/html; charset=utf-8", head=head)
            elif path == "/state.json":
                body = json.dumps(state_of(self.server.folder, self.server.tail)).encode("utf-8")
                self._send(HTTPStatus.OK, body, "application/json", head=head)
            elif path.startswith("/files/"):
                status, body, ctype = self.server.file(path[len("/files/"):])
                self._send(status, body, ctype, head=head)
            else:
                self._send(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain; charset=utf-8", head=head)
        except (BrokenPipeError, ConnectionResetError):  # the browser went away
            pass


class LiveServer(ThreadingHTTPServer):
    """The live view of the capture in ``folder`` on ``(host, port)`` (port 0: a free one)."""

    daemon_threads = True
    allow_reuse_address = True
    request_queue_size = 128  # the listen backlog: a burst of connections waits here, not in SYN retries

    def __init__(self, folder: str | Path, host: str = "127.0.0.1", port: int = 0,
                 allow_hosts: tuple[str, ...] = ()) -> None:
        self.folder = Path(folder).resolve()
        self.tail = SliceTail(self.folder / SLICE)
        self.slots = threading.BoundedSemaphore(MAX_CONNECTIONS)
        if ":" in host:  # an IPv6 address
            self.address_family = socket.AF_INET6
        super().__init__((host, port), _Handler)
        h, p = self.server_address[:2]
        shown = f"[{h}]" if ":" in str(h) else str(h)
        self.url = f"http://{shown}:{p}/"
        self.port = int(p)
        self.names = {"localhost", host.strip("[]").lower(), *(n.strip().strip("[]").lower() for n in allow_hosts)}

    def process_request(self, request: Any, client_address: Any) -> None:
        """A thread for the connection while fewer than :data:`MAX_CONNECTIONS` are served; else it is closed."""
        if not self.slots.acquire(blocking=False):
            log.debug("live view: %s refused, %d connections already", client_address, MAX_CONNECTIONS)
            self.shutdown_request(request)
            return
        try:
            super().process_request(request, client_address)
        except BaseException:
            self.slots.release()
            raise

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self.slots.release()

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A request that failed (a bug, a browser gone): logged at debug level, never printed."""
        log.debug("live view: request from %s failed", client_address, exc_info=True)

    def host_ok(self, host: str) -> bool:
        """The ``Host`` header names this server's port and, as the host, an IP address (no name was resolved:
        nothing to rebind) or a name on the allow-list (``localhost``, the bound name, ``allow_hosts``), whatever
        the address it is bound to."""
        host = host.strip().lower()
        name, sep, port = host.rpartition(":") if not host.endswith("]") else (host, "", "")
        if not sep:
            name, port = host, "80"
        if port != str(self.port) or not name:
            return False
        name = name[1:-1] if name.startswith("[") and name.endswith("]") else name
        if name in self.names:
            return True
        try:
            ipaddress.ip_address(name)
        except ValueError:
            return False
        return True

    def file(self, name: str) -> tuple[int, bytes, str]:
        """(status, body, content type) of ``/files/NAME``: one of :data:`SERVED`, the file the capture wrote."""
        text = "text/plain; charset=utf-8"
        try:
            name = urllib.parse.unquote(name, errors="strict")  # once: "%252e" stays the name "%2e"
        except UnicodeDecodeError:
            return HTTPStatus.FORBIDDEN, b"forbidden\n", text
        if (not name or "/" in name or "\\" in name or "\0" in name or name in (".", "..")
                or name.startswith("..") or os.path.isabs(name)):
            return HTTPStatus.FORBIDDEN, b"forbidden\n", text
        if name not in SERVED:
            return HTTPStatus.NOT_FOUND, b"not found\n", text
        try:
            fd = open_own(self.folder / name)
        except FileNotFoundError:
            return HTTPStatus.NOT_FOUND, b"not found\n", text
        except OSError:  # a symbolic link (ELOOP), a hard link, another owner, not a regular file
            return HTTPStatus.FORBIDDEN, b"forbidden\n", text
        with os.fdopen(fd, "rb") as fh:
            try:
                if os.fstat(fh.fileno()).st_size > MAX_FILE_BYTES:
                    return HTTPStatus.FORBIDDEN, b"too large for the live view\n", text
                body = fh.read(MAX_FILE_BYTES + 1)[:MAX_FILE_BYTES]
            except OSError:
                return HTTPStatus.NOT_FOUND, b"not found\n", text
        return HTTPStatus.OK, body, _TYPES.get(Path(name).suffix.lower(), "application/octet-stream")
