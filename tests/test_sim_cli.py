"""The gonio-sim command line."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "simulator.cli", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=30)


def test_help_is_useful():
    r = run("--help")
    assert r.returncode == 0 and "serve" in r.stdout and "bench" in r.stdout
    r = run("serve", "--help")
    assert r.returncode == 0
    for opt in ("--config", "--seed", "--time-scale"):
        assert opt in r.stdout


def test_bench_help_describes_the_study():
    r = run("bench", "--help")
    assert r.returncode == 0
    for flag in ("--quick", "--scheduler", "--workers", "--materials"):
        assert flag in r.stdout


def test_bad_config_fails_cleanly(tmp_path):
    r = run("serve", "--config", str(tmp_path / "missing.toml"))
    assert r.returncode == 2 and "gonio-sim:" in r.stderr


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_serve_prints_one_json_line_and_exits_0_on_signals(serve, simulated_toml, sig):
    sp = serve(simulated_toml, "--seed", "3", "--time-scale", "0", "--log-level", "info")
    assert set(sp.ports) == {"dynamixel", "serial"}
    assert all(os.path.exists(p) for p in sp.ports.values())
    assert sp.stop(sig=sig) == 0
    assert sp.stdout_rest == b""  # exactly one line on stdout
    assert "total simulated time" in sp.log_path.read_text()


def _variant(tmp_path: Path, name: str, old: str, new: str) -> Path:
    text = (REPO / "configs" / "simulated.toml").read_text()
    assert old in text
    p = tmp_path / name
    p.write_text(text.replace(old, new, 1))
    return p


def test_check_says_so_in_one_line_on_a_good_config():
    r = run("check", "--config", "configs/simulated.toml")
    assert (r.returncode, r.stderr) == (0, "")
    assert r.stdout == ("gonio-sim: configs/simulated.toml: ready to serve (dynamixel motion, material "
                        "'blue-plastic'); nothing opened\n")


@pytest.mark.parametrize("old, new, message", [
    ("settle_time_s = 0.05 ", 'settle_time_s = "abc" ', '[simulator].settle_time_s: expected a number, got "abc"'),
    ("seed = 1\n", "seed = 1\nsettle_tme_s = 1.0\n",
     "[simulator].settle_tme_s: unknown key; did you mean 'settle_time_s'?"),
    ("seed = 1\n", "seed = 1.5\n", "[simulator].seed: expected an integer, got 1.5"),
    ("shot_noise = true", "shot_noise = 1", "[simulator].shot_noise: expected true or false, got 1"),
    ("drop_reply_rate = 0.0", "drop_reply_rate = 1.5", "[simulator.faults].drop_reply_rate: must lie in [0, 1]"),
    ('vanish_ports = "all"', 'vanish_ports = "usb"', '[simulator.faults].vanish_ports: must be "all"'),
    ("wl_step_nm = 5.0", "wl_step_nm = 0.0", "[simulator.spectrometer].wl_step_nm: must be > 0"),
    ("[simulator]\n", "[simulator]\n[simulator.extra]\n", "[simulator].extra: unknown key"),
    ("[bench]\n", "[bench\n", "invalid TOML: "),
])
def test_check_and_serve_refuse_a_bad_config_naming_file_and_key(tmp_path, old, new, message):
    cfg = _variant(tmp_path, "bad.toml", old, new)
    for argv in (["check", "--config", str(cfg)], ["serve", "--config", str(cfg), "--exit-with-parent"]):
        r = run(*argv)
        assert r.returncode == 2 and r.stdout == "", (argv, r.stdout, r.stderr)
        assert r.stderr.startswith(f"gonio-sim: {cfg}: {message}"), (argv, r.stderr)
        assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr


def test_check_names_the_file_for_missing_files_and_bench_errors(tmp_path):
    r = run("check", "--config", str(tmp_path / "missing.toml"))
    assert r.returncode == 2 and r.stderr == f"gonio-sim: {tmp_path / 'missing.toml'}: no such file\n"
    cfg = _variant(tmp_path, "serial-ids.toml", "[axes.light]\nid = 1 ", '[axes.light]\nid = "L" ')
    r = run("check", "--config", str(cfg))  # a Dynamixel bench needs integer IDs: refused by the bench itself
    assert r.returncode == 2 and r.stderr.startswith(f"gonio-sim: {cfg}: ") and "[axes.light].id" in r.stderr
