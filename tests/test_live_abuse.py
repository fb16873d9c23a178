"""The live view under abuse (issue 49, items 8-10; the cases are in tests/hostile_live.py, also run by
scripts/hostile_campaign.py): memory and threads stay flat under a header flood and 1000 half-open connections, a
slow request is closed, a foreign ``Host`` is refused on every bind, and only the files the capture wrote for it
are served (no symbolic or hard link to a file outside the folder)."""

from __future__ import annotations

import socket
import threading

import pytest

from acquisition.live import server
from acquisition.live.server import LiveServer
from tests import hostile_live


@pytest.mark.parametrize("case", hostile_live.LIVE_CASES, ids=lambda c: c.__name__.strip("_"))
def test_live_view_under_abuse(tmp_path, case):
    out = case(tmp_path)
    assert out.clean, f"{out.name}: {out.note}"


def test_a_request_that_never_ends_is_closed(tmp_path, monkeypatch):
    monkeypatch.setattr(server, "READ_TIMEOUT_S", 0.5)
    monkeypatch.setattr(server._Handler, "timeout", 0.5)
    srv = LiveServer(hostile_live.capture_folder(tmp_path / "c"))
    th = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    th.start()
    try:
        before = threading.active_count()
        port = srv.server_address[1]
        slow = []
        for _ in range(5):  # a header line now and then, never the end of the request
            s = socket.create_connection(("127.0.0.1", port), timeout=30)
            s.sendall(f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n".encode())
            slow.append(s)
        got = [s.recv(4096) for s in slow]  # the server closes each (30 s is only a guard against a hang)
        assert all(g == b"" or g.startswith(b"HTTP/1.0 408") for g in got), got
        assert hostile_live.answers(port) == 200
        hostile_live.close_all(slow)
        for _ in range(100):  # the handlers' threads end
            if threading.active_count() <= before:
                break
            threading.Event().wait(0.05)
        assert threading.active_count() <= before
    finally:
        srv.shutdown()
        srv.server_close()


def test_too_many_or_too_long_headers_are_431(tmp_path):
    srv = LiveServer(hostile_live.capture_folder(tmp_path / "c"))
    th = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    th.start()
    try:
        port = srv.server_address[1]
        for extra in ([f"X-{k}: 1" for k in range(server.MAX_HEADERS + 1)], ["X-Long: " + "a" * 20_000]):
            with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
                s.sendall(("\r\n".join(["GET / HTTP/1.1", f"Host: 127.0.0.1:{port}", *extra]) + "\r\n\r\n").encode())
                assert s.recv(4096).startswith(b"HTTP/1.0 431"), extra[0][:20]
        assert hostile_live.answers(port) == 200
    finally:
        srv.shutdown()
        srv.server_close()


def test_gonio_capture_passes_live_allow_host_on(tmp_path):
    from acquisition.cli import build_parser
    from acquisition.live import LiveView

    args = build_parser().parse_args(["--config", "c.toml", "--out", "o", "--live-host", "0.0.0.0",
                                      "--live-allow-host", "bench.lab", "--live-allow-host", "Bench2"])
    assert args.live_allow_host == ["bench.lab", "Bench2"]
    view = LiveView(hostile_live.capture_folder(tmp_path / "c"), "0.0.0.0", 0, tuple(args.live_allow_host))
    url = view.start()
    try:
        assert url is not None
        port = int(url.rstrip("/").rsplit(":", 1)[1])
        assert hostile_live.request(port, host=f"bench2:{port}")[0] == 200
        assert hostile_live.request(port, host=f"evil.example:{port}")[0] == 403
    finally:
        view.stop()
