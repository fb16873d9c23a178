"""The live view of a running capture (``gonio-capture --live``, docs/capture.md): its server serves only the
capture's own files and changes nothing (in process, on a folder made here), the run's progress file, and the
page itself in headless Chromium on a running simulated capture."""

from __future__ import annotations

import http.client
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import tomli_w

from acquisition.live.server import LiveServer
from acquisition.run.progress import ProgressFile

HEADER = "theta_i_deg,theta_o_deg,value,value_std,repeats,unix_time_s\n"


@pytest.fixture
def served(tmp_path) -> Iterator[tuple[LiveServer, Path, Path]]:
    """A live server on a capture folder with a slice, a progress file, a run record, a secret outside it and a
    symbolic link to that secret inside it."""
    out = tmp_path / "capture"
    out.mkdir()
    (out / "slice.csv").write_text("# gonio-brdf slice\n# meta: {}\n" + HEADER + "30.0,-10.0,0.25,0.01,4,1.0\n"
                                   "30.0,0.0,0.5,0.02,4,2.0\n")
    (out / "capture.json").write_text(json.dumps({"status": "running"}))
    (out / "sub").mkdir()
    secret = tmp_path / "secret.txt"
    secret.write_text("not yours")
    (out / "link.txt").symlink_to(secret)
    ProgressFile(out / "progress.json", 12.0, 10).announce(10, 2)
    srv = LiveServer(out)
    th = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    th.start()
    try:
        yield srv, out, secret
    finally:
        srv.shutdown()
        srv.server_close()


def _request(srv: LiveServer, method: str, path: str, host: str | None = None) -> tuple[int, dict[str, str], bytes]:
    h, p = srv.server_address[:2]
    conn = http.client.HTTPConnection(h, p, timeout=10)
    try:
        conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)  # the path as given, not cleaned
        conn.putheader("Host", host if host is not None else f"127.0.0.1:{p}")
        conn.putheader("Content-Length", "0")
        conn.endheaders()
        r = conn.getresponse()
        return r.status, {k.lower(): v for k, v in r.getheaders()}, r.read()
    finally:
        conn.close()


def test_the_page_and_its_state(served):
    srv, out, _ = served
    assert srv.url.startswith("http://127.0.0.1:")
    status, headers, body = _request(srv, "GET", "/")
    assert status == 200 and headers["content-type"].startswith("text/html")
    assert "default-src 'none'" in headers["content-security-policy"] and headers["cache-control"] == "no-store"
    page = body.decode()
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", page), "the page fetches nothing from elsewhere"
    status, _, body = _request(srv, "GET", "/state.json")
    st = json.loads(body)
    assert status == 200 and st["samples"] == [[30.0, -10.0, 0.25, 0.01], [30.0, 0.0, 0.5, 0.02]]
    assert st["progress"]["points_total"] == 10 and st["progress"]["points_done"] == 2
    assert st["record"]["status"] == "running"
    status, headers, body = _request(srv, "HEAD", "/state.json")
    assert status == 200 and body == b"" and int(headers["content-length"]) > 0
    status, _, body = _request(srv, "GET", "/files/slice.csv")
    assert status == 200 and body.startswith(b"# gonio-brdf slice")


def test_the_slice_is_read_as_it_grows(served):
    srv, out, _ = served
    with open(out / "slice.csv", "a") as fh:
        fh.write("30.0,10.0,0.75,0.03,4,3.0\n30.0,20.0,1.")  # the second row is being written
    st = json.loads(_request(srv, "GET", "/state.json")[2])
    assert [s[1] for s in st["samples"]] == [-10.0, 0.0, 10.0]
    with open(out / "slice.csv", "a") as fh:
        fh.write("25,0.04,4,4.0\n")
    st = json.loads(_request(srv, "GET", "/state.json")[2])
    assert st["samples"][-1] == [30.0, 20.0, 1.25, 0.04]


@pytest.mark.parametrize(("path", "want"), [
    ("/files/../secret.txt", 403),
    ("/files/%2e%2e/secret.txt", 403),
    ("/files/%2E%2E%2Fsecret.txt", 403),
    ("/files/..%2fsecret.txt", 403),
    ("/files/%252e%252e%252fsecret.txt", 404),  # decoded once: a file named "%2e%2e%2fsecret.txt", not there
    ("/files/%252e%252e/secret.txt", 403),
    ("/files//etc/passwd", 403),
    ("/files/%2Fetc%2Fpasswd", 403),
    ("/files/..", 403),
    ("/files/link.txt", 404),  # a symbolic link out of the folder, under a name the capture never writes
    ("/files/sub", 404),  # a folder, not a file
    ("/files/sub%2f..%2f..%2fsecret.txt", 403),
    ("/files/%ff%fe", 403),
    ("/../secret.txt", 404),
    ("/%2e%2e/secret.txt", 404),
    ("/files/nothing.csv", 404),
])
def test_only_the_captures_own_files(served, path, want):
    srv, _, secret = served
    status, _, body = _request(srv, "GET", path)
    assert status == want, (path, status)
    assert b"not yours" not in body


@pytest.mark.parametrize("method", ["POST", "PUT", "DELETE", "PATCH", "OPTIONS", "TRACE", "MKCOL", "FOO"])
def test_it_changes_nothing(served, method):
    srv, out, _ = served
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    status, headers, _ = _request(srv, method, "/files/slice.csv")
    assert status == 405 and headers["allow"] == "GET, HEAD"
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before


def test_another_host_name_is_refused(served):
    srv, _, _ = served
    assert _request(srv, "GET", "/state.json", host="evil.example:80")[0] == 403


def test_a_live_view_that_cannot_start_is_a_warning(tmp_path, caplog):
    from acquisition.live import LiveView

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        view = LiveView(tmp_path, "127.0.0.1", busy.getsockname()[1])
        assert view.start() is None
    assert "live view did not start" in caplog.text and "the capture goes on without it" in caplog.text


def test_progress_file(tmp_path):
    p = ProgressFile(tmp_path / "progress.json", estimate_s=30.0, points_planned=0)
    p.announce(4, 1)
    for k in range(3):
        p.sample(20.0, 10.0 * k, [0.1, 0.3], [0.01, 0.03], 4)
    p.finish("complete", "captured 3 new sample(s)\nmore")
    st = json.loads((tmp_path / "progress.json").read_text())
    assert st["status"] == "complete" and st["points_done"] == 4 and st["time_left_s"] == 0.0
    assert st["last"] == {"theta_i_deg": 20.0, "theta_o_deg": 20.0, "f_r": pytest.approx(0.2),
                          "std": pytest.approx(0.02), "repeats": 4, "channels": 2}
    assert st["message"] == "captured 3 new sample(s)"
    assert [q.name for q in tmp_path.iterdir()] == ["progress.json"]  # no temporary file left
    gone = ProgressFile(tmp_path / "missing" / "progress.json")  # cannot be written: quiet, the capture goes on
    gone.sample(0.0, 10.0, [1.0], [0.1], 4)
    gone.finish("failed")


# -- the page in headless Chromium on a running simulated capture -----------------------------------------------


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def _chromium(url: str, *args: str) -> str:
    profile = tempfile.mkdtemp(prefix="gonio-live-chromium-")
    try:
        r = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                            "--disable-component-update", "--disable-sync", "--no-first-run",
                            f"--user-data-dir={profile}", "--virtual-time-budget=3000", "--window-size=1200,800",
                            *args, url], capture_output=True, text=True, timeout=60)
        return r.stdout
    finally:
        shutil.rmtree(profile, ignore_errors=True)


def _rows(path: Path) -> int:
    try:
        return sum(1 for ln in path.read_text().splitlines() if ln and ln[0].isdigit())
    except OSError:
        return 0


def _live_children(parent: int) -> list[int]:
    """PIDs of live-view servers started by the process ``parent``."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                argv = (d / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if b"acquisition.live" in argv and str(parent).encode() in argv:
                out.append(int(d.name))
    return out


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="Chromium is not installed here, so the page cannot be checked in a "
                                             "browser (apt-get install chromium)")
def test_live_page_in_chromium_on_a_running_capture(tmp_path, config_dict):
    cfg = tmp_path / "bench.toml"
    cfg.write_text(tomli_w.dumps(config_dict({"plan": {"theta_i_deg": [20.0, 50.0], "theta_o_step_deg": 10.0},
                                              "bench": {"motion": "serial"}, "simulator": {"time_scale": 3.0}})))
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    proc = subprocess.Popen([sys.executable, "-m", "acquisition.cli", "--config", str(cfg), "--out", str(out),
                             "--live", "--no-progress"], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                            env=env)
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        m = re.search(r"live view at (http://127\.0\.0\.1:\d+/)", line)
        assert m, line
        url = m.group(1)
        deadline = time.monotonic() + 60
        while _rows(out / "slice.csv") < 4 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.1)
        assert proc.poll() is None, "the capture ended before the page could be looked at"
        dom = _chromium(url, "--dump-dom")
        shown = len(re.findall(r'class="sample"', dom))
        assert shown >= 4, dom[:2000]
        total = re.search(r'id="total">(\d+)<', dom)
        assert re.search(r'id="status"[^>]*>running<', dom) and total, dom[:2000]
        assert re.search(r'id="current">\(\d+, -?\d+\) deg: f_r [0-9.e+-]+ \+- ', dom), dom[:2000]
        assert 'data-theta-i="20"' in dom or 'data-theta-i="50"' in dom
        keep = os.environ.get("GONIO_KEEP_SCREENSHOT")  # to look at the page: GONIO_KEEP_SCREENSHOT=/tmp/live.png
        if keep:
            _chromium(url, f"--screenshot={keep}")
            assert Path(keep).stat().st_size > 10_000
        # the live view can never stop the capture: kill it, and the capture goes on to the end
        children = _live_children(proc.pid)
        assert len(children) == 1, children
        os.kill(children[0], signal.SIGKILL)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
        assert _rows(out / "slice.csv") == int(total.group(1)) > shown
        assert json.loads((out / "progress.json").read_text())["status"] == "complete"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.slow
def test_live_view_ends_with_the_capture(tmp_path, config_dict):
    from acquisition.cli import main

    cfg = tmp_path / "bench.toml"
    cfg.write_text(tomli_w.dumps(config_dict({"plan": {"theta_i_deg": [30.0], "theta_o_step_deg": 20.0},
                                              "bench": {"motion": "serial"}})))
    urls: list[Any] = []
    import acquisition.live.view as view

    start = view.LiveView.start

    def spy(self: Any, *a: Any) -> Any:
        urls.append(start(self, *a))
        return urls[-1]

    view.LiveView.start = spy  # type: ignore[method-assign]
    try:
        assert main(["--config", str(cfg), "--out", str(tmp_path / "o"), "--live", "--no-progress"]) == 0
    finally:
        view.LiveView.start = start  # type: ignore[method-assign]
    assert urls and urls[0] and _live_children(os.getpid()) == []
    port = int(urls[0].rsplit(":", 1)[1].strip("/"))
    with pytest.raises(OSError):
        http.client.HTTPConnection("127.0.0.1", port, timeout=5).request("GET", "/")
