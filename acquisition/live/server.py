"""The live view's HTTP server: a capture's own folder, read only, on 127.0.0.1 (docs/capture.md, "Live view").

``GET /`` is the page (:mod:`acquisition.live.page`: inline script and SVG, nothing fetched from elsewhere);
``GET /state.json`` what the page draws: the samples of ``slice.csv`` so far (angles, f_r and its standard
deviation averaged over the channels), ``progress.json`` (points done and planned, time left, the last
sample, the status: :mod:`acquisition.run.progress`) and the run record's status and estimate
(``capture.json``); ``GET /files/NAME`` one regular file directly in the folder, as it is.

It changes nothing: GET and HEAD only (any other method: 405). It serves nothing outside the folder: a name with
a ``/`` or a ``..`` once percent-decoded, an absolute path, or a symbolic link that resolves outside the folder is
refused (403); anything else not there is 404. A request whose ``Host`` is not the address it was reached at is
refused (403: a web page elsewhere cannot read it through DNS rebinding). The slice is read incrementally (only the
complete lines appended since the last request), so a poll costs little however long the capture.
"""

from __future__ import annotations

import json
import logging
import math
import os
import socket
import threading
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
#: Largest file served under /files/ (bytes): a capture's log or slice, not anything bigger.
MAX_FILE_BYTES = 64 * 1024 * 1024
_TYPES = {".csv": "text/csv; charset=utf-8", ".json": "application/json", ".log": "text/plain; charset=utf-8",
          ".txt": "text/plain; charset=utf-8"}
_HEADERS = {"Cache-Control": "no-store", "X-Content-Type-Options": "nosniff", "Referrer-Policy": "no-referrer",
            "Content-Security-Policy": "default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; "
                                       "connect-src 'self'; img-src 'self' data:; base-uri 'none'; form-action 'none'"}


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
                with open(self.path, "rb") as fh:
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
        with open(path, encoding="utf-8") as fh:
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


class _Handler(BaseHTTPRequestHandler):
    server: LiveServer  # type: ignore[assignment]
    server_version = "gonio-live"
    sys_version = ""

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

    def __init__(self, folder: str | Path, host: str = "127.0.0.1", port: int = 0) -> None:
        self.folder = Path(folder).resolve()
        self.tail = SliceTail(self.folder / SLICE)
        if ":" in host:  # an IPv6 address
            self.address_family = socket.AF_INET6
        super().__init__((host, port), _Handler)
        h, p = self.server_address[:2]
        shown = f"[{h}]" if ":" in str(h) else str(h)
        self.url = f"http://{shown}:{p}/"
        self._hosts = {f"{shown}:{p}".lower(), f"localhost:{p}", f"127.0.0.1:{p}", f"[::1]:{p}"}
        self.any_host = host in ("0.0.0.0", "::", "")

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A request that failed (a bug, a browser gone): logged at debug level, never printed."""
        log.debug("live view: request from %s failed", client_address, exc_info=True)

    def host_ok(self, host: str) -> bool:
        """The ``Host`` header names this server (on a wildcard address, whatever the network calls it)."""
        return self.any_host or host.strip().lower() in self._hosts

    def file(self, name: str) -> tuple[int, bytes, str]:
        """(status, body, content type) of ``/files/NAME``: a regular file directly in the folder."""
        text = "text/plain; charset=utf-8"
        try:
            name = urllib.parse.unquote(name, errors="strict")  # once: "%252e" stays the name "%2e"
        except UnicodeDecodeError:
            return HTTPStatus.FORBIDDEN, b"forbidden\n", text
        if (not name or "/" in name or "\\" in name or "\0" in name or name in (".", "..")
                or name.startswith("..") or os.path.isabs(name)):
            return HTTPStatus.FORBIDDEN, b"forbidden\n", text
        path = self.folder / name
        try:
            real = path.resolve(strict=True)
        except (OSError, RuntimeError):
            return HTTPStatus.NOT_FOUND, b"not found\n", text
        if real.parent != self.folder or not real.is_file():
            return HTTPStatus.FORBIDDEN, b"forbidden\n", text
        try:
            if real.stat().st_size > MAX_FILE_BYTES:
                return HTTPStatus.FORBIDDEN, b"too large for the live view\n", text
            body = real.read_bytes()
        except OSError:
            return HTTPStatus.NOT_FOUND, b"not found\n", text
        return HTTPStatus.OK, body, _TYPES.get(real.suffix.lower(), "application/octet-stream")
