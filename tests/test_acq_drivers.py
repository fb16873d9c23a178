"""Driver robustness with the real dynamixel_sdk and pyserial on a pseudo-terminal whose far end disappears."""

from __future__ import annotations

import os
import select
import threading
import tty

import pytest
from dynamixel_sdk import PacketHandler, PortHandler

from acquisition import CommError
from acquisition.config import config_from_dict
from acquisition.devices.dynamixel import DynamixelAxes
from acquisition.devices.serial_link import ControllerError, SerialDetector, SerialLink
from tests.test_acq_support import make_raw


@pytest.fixture
def pty_path():
    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    state = {"master": master, "peers": []}
    yield path, state
    # stop and join every scripted peer before its fd is closed: a peer thread that outlived its pty read the
    # next test's pty (the same fd number, reused) and swallowed its first command (CI, 10 s timeouts)
    for stop, thread in state["peers"]:
        stop.set()
        thread.join(timeout=5.0)
        assert not thread.is_alive(), "a scripted peer thread did not stop"
    for fd in (state.get("master"), slave):
        if fd is not None:
            try:
                os.close(fd)
            except OSError:
                pass


def _unplug(state) -> None:
    os.close(state.pop("master"))


def test_sdk_leaves_is_using_set_when_an_exception_escapes(pty_path):
    """The SDK behaviour the driver guards against (documented in the reference notes)."""
    path, state = pty_path
    port = PortHandler(path)
    assert port.openPort()
    _unplug(state)
    with pytest.raises(Exception):  # noqa: B017 - whatever pyserial raises for a vanished tty
        PacketHandler(2.0).ping(port, 1)
    assert port.is_using is True  # every later transaction would now fail with COMM_PORT_BUSY
    port.is_using = False
    port.closePort()


def test_dynamixel_driver_releases_is_using_and_names_the_failure(pty_path):
    path, state = pty_path
    cfg = config_from_dict(make_raw(), "t.toml")
    ax = DynamixelAxes(path, 1000000, cfg.axes, cfg.motion)
    ax.port = PortHandler(path)
    assert ax.port.openPort()
    # nobody answers: bounded retries, then an error naming the servo and the failure
    with pytest.raises(CommError, match=r"servo 1 \(light arm\) on /dev/pts/\d+: ping failed after 4 attempts: "
                                        r"There is no status packet"):
        ax._txrx("ping", 1, ax.ph.ping)
    _unplug(state)
    with pytest.raises(CommError, match="port failed"):
        ax._txrx("ping", 1, ax.ph.ping)
    assert ax.port.is_using is False
    assert not ax.healthy()
    ax.release()  # no exception: logs that the bus is gone
    ax.close()


def test_serial_link_timeout_and_vanished_port(pty_path):
    path, state = pty_path
    link = SerialLink(path, 115200, timeout_s=0.05, retries=2)
    with pytest.raises(CommError, match=r"no valid reply to 'ID\?' after 3 attempts \(last: no reply within"):
        link.command("ID?")
    assert link.stats["retries"] == 2
    _unplug(state)
    with pytest.raises(CommError, match="port failed|cannot send"):
        link.command("ID?")
    assert link.dead
    link.close()


def _scripted_peer(state: dict, replies: dict[str, list[bytes]], seen: list[str]) -> threading.Thread:
    """A scripted device on the far end of the pty (``state["master"]``): answers each command line with the
    next scripted reply. It polls a stop event that the fixture sets, and never reads once that is set."""
    master = state["master"]
    stop = threading.Event()

    def run() -> None:
        buf = b""
        while not stop.is_set():
            try:
                ready, _, _ = select.select([master], [], [], 0.02)
                if stop.is_set():
                    return
                if not ready:
                    continue
                data = os.read(master, 1024)
            except OSError:
                return
            if not data:
                return
            buf += data
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                cmd = line.decode()
                seen.append(cmd)
                queue = replies.get(cmd.split()[0], [])
                if queue:
                    os.write(master, queue.pop(0))

    t = threading.Thread(target=run, daemon=True)
    state["peers"].append((stop, t))
    t.start()
    return t


def test_serial_reply_checks_and_retries(pty_path):
    path, state = pty_path
    seen: list[str] = []
    replies = {
        # 1st READ: a digit corrupted in values (disagrees with mean): retried; 2nd READ: consistent
        "READ": [b"READ n=3 sat=0 t_int=0.01 mean=201.000 std=1.000 values=200,201,212\nok\n",
                 b"READ n=3 sat=0 t_int=0.01 mean=201.000 std=1.000 values=200,201,202\nok\n"],
        "MOVE": [b"ALARM:20\nerror:20\n"],
        "TIME?": [b"TI\xcdE t=1.5\nok\n", b"TIME t=1.5\nok\n"],
    }
    _scripted_peer(state, replies, seen)
    # the scripted peer always answers; the long timeout only rides out a peer thread starved on a loaded machine
    link = SerialLink(path, 115200, timeout_s=10.0, retries=2)
    det = SerialDetector(link, "photodiode", 0.01, 65535)
    rd = det.read(3)
    assert rd.mean.tolist() == [201.0] and rd.std.tolist() == [1.0] and rd.n == 3
    assert seen.count("READ 3") == 2 and link.stats["corrupt"] == 1
    with pytest.raises(ControllerError, match=r"error:20 collision.*ALARM:20") as ei:
        link.command("MOVE L1 D2")
    assert ei.value.code == 20 and ei.value.alarm == 20 and seen.count("MOVE L1 D2") == 1  # not retried
    det.has_time = True
    assert det.time() == 1.5 and link.stats["corrupt"] == 2
    link.close()


def test_serial_detector_integration_time(pty_path):
    """INT then INT?: a detector that rounds the setting is believed, later readings are checked against it (a
    reply with another t_int is retried); a detector without INT? is taken at its word."""
    path, state = pty_path
    seen: list[str] = []
    replies = {
        "INT": [b"ok\n", b"ok\n"],
        "INT?": [b"INT t_int=0.0032\nok\n", b"error:1\n"],
        "READ": [b"READ n=2 sat=0 t_int=0.01 mean=300.000 std=0.000 values=300,300\nok\n",
                 b"READ n=2 sat=0 t_int=0.0032 mean=300.000 std=0.000 values=300,300\nok\n"],
    }
    _scripted_peer(state, replies, seen)
    # the scripted peer always answers; the long timeout only rides out a peer thread starved on a loaded machine
    link = SerialLink(path, 115200, timeout_s=10.0, retries=2)
    det = SerialDetector(link, "photodiode", 0.01, 65535)
    assert det.set_integration_time(0.00316228) == 0.0032 and det.integration_time_s == 0.0032
    rd = det.read(2)
    assert rd.mean.tolist() == [300.0] and seen.count("READ 2") == 2 and link.stats["corrupt"] == 1
    assert det.set_integration_time(0.001) == 0.001
    assert seen[:2] == ["INT 0.00316228", "INT?"] and "INT 0.001" in seen
    link.close()


def test_a_simulated_bus_gets_a_longer_reply_deadline_than_the_sdks():
    """The SDK's deadline is 2 x 16 ms (its adapter latency) + 2 ms + the bytes' time; a simulated bus, answered by
    another process, gets the same formula with 100 ms, so a loaded machine's scheduling is not a lost reply."""
    from dynamixel_sdk import PortHandler

    from acquisition.devices.dynamixel import _LatentPort

    sdk, ours = PortHandler("/dev/null"), _LatentPort("/dev/null", 100.0)
    for p in (sdk, ours):
        p.tx_time_per_byte = 0.01
        p.setPacketTimeout(10)
    assert sdk.packet_timeout == pytest.approx(0.1 + 34.0)
    assert ours.packet_timeout == pytest.approx(0.1 + 202.0)
    from acquisition import Bench

    root = __import__("pathlib").Path(__file__).resolve().parents[1]
    with Bench.from_config(root / "configs" / "simulated.toml") as bench:  # the simulated bus opens with it
        assert isinstance(bench.motion.port, _LatentPort) and bench.motion.port.latency_ms == 100.0


def test_a_corrupt_list_in_the_detector_reply_is_a_corrupt_reply_read_again():
    """A corrupt byte inside DETECTOR?'s gains= or wavelengths= list (seen in a fault storm: '1000J10000') makes
    the reply corrupt, so the link reads it again, instead of an error escaping as an unexpected one."""
    from acquisition.devices.serial_link import Reply, _check_detector

    f = {"type": "photodiode", "channels": "1", "saturation": "65535", "t_int": "0.01", "gains": "1,10,100"}
    _check_detector(Reply(dict(f), []))
    bad = Reply({**f, "gains": "1,1J0,100"}, [])
    with pytest.raises(ValueError):
        _check_detector(bad)


def test_a_boards_monitor_field_becomes_the_readings_monitor_rate(pty_path):
    """READ ... monitor=<sum> (firmware built with MONITOR=1): the sum over one repeat's integration time, kept as a
    rate (counts/s) so that auto-ranging's other integration times compare; a reply without it has none."""
    path, state = pty_path
    replies = {"READ": [b"READ n=2 sat=0 t_int=0.01 mean=300.000 std=0.000 values=300,300 monitor=41000\nok\n",
                        b"READ n=2 sat=0 t_int=0.01 mean=300.000 std=0.000 values=300,300\nok\n"]}
    _scripted_peer(state, replies, [])
    link = SerialLink(path, 115200, timeout_s=10.0, retries=2)
    det = SerialDetector(link, "photodiode", 0.01, 65535)
    assert det.read(2).monitor == pytest.approx(41000 / 0.01)
    assert det.read(2).monitor is None
    link.close()
