"""A port that cannot be opened (issue 41, item 9): the capture names the bench file's key to fix in one line,
advises no resume (nothing was captured), leaves no lock and no run files in the output folder; ``--check`` says
whether each port can be opened, moving nothing; the output folder's lock file goes with the run that held it."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
import tomli_w

from acquisition.cli import main
from acquisition.run.lock import LOCK_NAME, OutDirLocked, OutLock

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]


def bench_file(tmp_path: Path, name: str, **ports: str) -> Path:
    """configs/NAME.toml with its [bench] ports replaced."""
    cfg = tomllib.loads((REPO / "configs" / f"{name}.toml").read_text(encoding="utf-8"))
    cfg["bench"].update(ports)
    path = tmp_path / f"{name}.toml"
    path.write_text(tomli_w.dumps(cfg), encoding="utf-8")
    return path


@pytest.fixture
def pty_port():
    """A port that can be opened: a pseudo-terminal's slave (nobody answers on it)."""
    master, slave = os.openpty()
    yield os.ttyname(slave)
    os.close(slave)
    os.close(master)


def test_a_missing_port_names_its_key_in_one_line_and_leaves_nothing(tmp_path, capsys):
    missing = str(tmp_path / "ttyACM9")
    cfg = bench_file(tmp_path, "serial-bench", serial_port=missing)
    out = tmp_path / "run"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert f"[bench].serial_port = '{missing}'" in err and str(cfg) in err and "no such file" in err, err
    assert "nothing was moved or captured" in err and "--resume" not in err and "Traceback" not in err, err
    assert not out.exists()  # the folder the run made for itself is gone with it


def test_a_missing_port_leaves_a_folder_as_it_found_it(tmp_path, capsys):
    cfg = bench_file(tmp_path, "serial-bench", serial_port=str(tmp_path / "nope"))
    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 1
    capsys.readouterr()
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]  # no capture.json, capture.log, capture.lock


@pytest.mark.slow
def test_the_dynamixel_port_is_named_when_the_detector_opened(tmp_path, capsys, serve, simulated_toml):
    """A Dynamixel bench whose detector controller answers (the simulator's serial port) and whose U2D2 port
    does not exist: the message names [bench].dynamixel_port."""
    sp = serve(simulated_toml)
    missing = str(tmp_path / "ttyUSB9")
    cfg = bench_file(tmp_path, "dynamixel-bench", serial_port=sp.ports["serial"], dynamixel_port=missing)
    out = tmp_path / "run"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err.strip()
    assert f"[bench].dynamixel_port = '{missing}'" in err and "Dynamixel" in err and "--resume" not in err, err
    assert not out.exists()


def test_check_says_whether_each_port_opens(tmp_path, capsys, pty_port):
    missing = str(tmp_path / "ttyUSB9")
    cfg = bench_file(tmp_path, "dynamixel-bench", serial_port=pty_port, dynamixel_port=missing)
    assert main(["--config", str(cfg), "--check"]) == 0
    out = capsys.readouterr().out
    assert f"port [bench].serial_port = '{pty_port}' (detector controller): can be opened" in out, out
    assert f"port [bench].dynamixel_port = '{missing}' (Dynamixel bus (U2D2)): warning: cannot be opened (no such " \
           "file or directory" in out, out


def test_the_lock_file_goes_with_its_holder(tmp_path):
    a = OutLock(tmp_path)
    assert a.acquire() is None and (tmp_path / LOCK_NAME).exists()
    with pytest.raises(OutDirLocked):
        OutLock(tmp_path).acquire()
    a.release()
    assert not (tmp_path / LOCK_NAME).exists()
    b = OutLock(tmp_path)
    assert b.acquire() is None
    b.release()


def test_a_lock_taken_on_a_removed_file_is_taken_again_on_the_new_one(tmp_path, monkeypatch):
    """A capture that opened the lock file just before its holder removed it must not hold a lock on the removed
    file (a third capture would make a new one and lock it too)."""
    holder = OutLock(tmp_path)
    holder.acquire()
    late = OutLock(tmp_path)
    real_open = late._open
    calls = []

    def open_then_holder_leaves() -> int:
        fd = real_open()
        if not calls:  # the first file this capture opened is the holder's, removed as the holder releases
            holder.release()
        calls.append(fd)
        return fd

    monkeypatch.setattr(late, "_open", open_then_holder_leaves)
    late.acquire()
    assert len(calls) == 2  # the old file was locked, found removed, and the new one locked
    assert os.fstat(late.fd).st_ino == os.stat(tmp_path / LOCK_NAME).st_ino
    late.release()


def test_a_grbl_bench_names_grbls_own_port_key(tmp_path, capsys, pty_port):
    """A real GRBL bench has two ports: the detector board's ([bench].serial_port) and GRBL's
    ([motion.grbl].port): --check looks at both, and a GRBL port that cannot be opened is named by its key."""
    from acquisition.config import load_config
    from acquisition.devices.grbl import GrblAxes
    from acquisition.errors import PortError
    from acquisition.ports import name_the_key

    missing = str(tmp_path / "ttyUSB7")
    raw = tomllib.loads((REPO / "configs" / "grbl-bench.toml").read_text(encoding="utf-8"))
    raw["bench"].update(transport="serial", serial_port=pty_port)
    raw["motion"]["grbl"]["port"] = missing
    path = tmp_path / "grbl.toml"
    path.write_text(tomli_w.dumps(raw), encoding="utf-8")
    assert main(["--config", str(path), "--check"]) == 0
    out = capsys.readouterr().out
    assert f"port [bench].serial_port = '{pty_port}' (detector controller): can be opened" in out, out
    assert f"port [motion.grbl].port = '{missing}' (GRBL controller (the arms)): warning: cannot be opened" in out
    cfg = load_config(path)
    with pytest.raises(PortError) as e:
        GrblAxes(missing, cfg.axes, cfg.motion)
    msg = str(name_the_key(e.value, cfg))
    assert f"{path}: [motion.grbl].port = '{missing}'" in msg and "set port to the port it is on" in msg, msg
