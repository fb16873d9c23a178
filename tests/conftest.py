"""Shared, generic test fixtures: repository paths, config variants, a `gonio-sim serve` child process."""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import tomli_w

from tests import helpers

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]
SIMULATED_TOML = REPO / "configs" / "simulated.toml"


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


@pytest.fixture(scope="session")
def simulated_toml() -> Path:
    """Path of the shared configs/simulated.toml."""
    return SIMULATED_TOML


@pytest.fixture(scope="session")
def deep_merge() -> Callable[[dict[str, Any], dict[str, Any]], dict[str, Any]]:
    """``deep_merge(base, over)`` -> a new dict with ``over`` merged into ``base`` table by table."""
    return helpers.deep_merge


@pytest.fixture(scope="session")
def serve_process() -> type:
    """The ServeProcess class, for module-scoped fixtures: ``serve_process(config_path, *extra_args)``."""
    return ServeProcess


@pytest.fixture(scope="session")
def base_config_dict() -> dict[str, Any]:
    """configs/simulated.toml as a dict (do not mutate; use ``config_dict``)."""
    with open(SIMULATED_TOML, "rb") as fh:
        return tomllib.load(fh)


@pytest.fixture
def config_dict(base_config_dict) -> Callable[..., dict[str, Any]]:
    """``config_dict({"simulator": {"seed": 3}})`` -> the base config deep-merged with the overrides."""

    def make(over: dict[str, Any] | None = None) -> dict[str, Any]:
        return helpers.deep_merge(base_config_dict, over or {})

    return make


@pytest.fixture
def config_file(tmp_path, config_dict) -> Callable[..., Path]:
    """Write a config variant to a TOML file in ``tmp_path`` (in the configs dir semantics: base_dir = tmp)."""
    counter = [0]

    def make(over: dict[str, Any] | None = None) -> Path:
        counter[0] += 1
        p = tmp_path / f"config{counter[0]}.toml"
        p.write_text(tomli_w.dumps(config_dict(over)))
        return p

    return make


class ServeProcess:
    """A running ``gonio-sim serve`` child; ``ports`` is the JSON line it printed."""

    def __init__(self, config: Path, *extra: str, timeout: float = 20.0) -> None:
        cmd = [sys.executable, "-m", "simulator.cli", "serve", "--config", str(config), "--exit-with-parent",
               "--log-level", "warning", *extra]
        self.proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     stdin=subprocess.DEVNULL)
        deadline = time.monotonic() + timeout
        line = b""
        while not line.endswith(b"\n"):
            left = deadline - time.monotonic()
            r, _, _ = select.select([self.proc.stdout], [], [], max(left, 0))
            if not r:
                self.stop()
                raise RuntimeError("gonio-sim serve printed no port line in time")
            ch = os.read(self.proc.stdout.fileno(), 1)
            if not ch:
                err = self.proc.stderr.read().decode(errors="replace")
                self.stop()
                raise RuntimeError(f"gonio-sim serve exited early: {err}")
            line += ch
        self.ports: dict[str, str | None] = json.loads(line)
        self.rest_stdout = ""
        self.stderr = ""

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 10.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stdout and not self.proc.stdout.closed:
            self.rest_stdout = self.proc.stdout.read().decode(errors="replace")
            self.stderr = self.proc.stderr.read().decode(errors="replace")
            self.proc.stdout.close()
            self.proc.stderr.close()
        return self.proc.returncode


@pytest.fixture
def serve() -> Iterator[Callable[..., ServeProcess]]:
    """Factory starting ``gonio-sim serve`` children; all are stopped at teardown."""
    procs: list[ServeProcess] = []

    def start(config: Path, *extra: str) -> ServeProcess:
        sp = ServeProcess(config, *extra)
        procs.append(sp)
        return sp

    yield start
    for sp in procs:
        sp.stop()
