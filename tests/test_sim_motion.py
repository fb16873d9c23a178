"""Motion profile, simulated clock, quantisation and backlash."""

from __future__ import annotations

import math
import time

import pytest
from dynamixel_sdk import COMM_SUCCESS, PacketHandler

from simulator.bench import VirtualBench
from simulator.config import config_from_dict
from simulator.ports.sdk_port import SimPortHandler
from simulator.ports.transports import register_bench, unregister_bench
from simulator.world.clock import SimClock
from simulator.world.motion import AxisMotion, TrapezoidProfile, dxl_profile_to_units


def test_profile_units():
    v, a = dxl_profile_to_units(200, 50)
    assert v == pytest.approx(200 * 0.229 / 60 * 4096)
    assert a == pytest.approx(50 * 214.577 / 3600 * 4096)
    assert dxl_profile_to_units(0, 0) == (math.inf, math.inf)


def test_trapezoid_shapes():
    p = TrapezoidProfile(0.0, 1000.0, 2.0, v_max=1000.0, a_max=4000.0)
    assert p.duration == pytest.approx(1000 / 1000 + 1000 / 4000)  # d/v + v/a
    assert p.position(2.0) == 0.0 and p.position(p.t_end) == pytest.approx(1000.0)
    assert p.position(2.0 + 0.125) == pytest.approx(0.5 * 4000 * 0.125**2)
    assert p.velocity(2.0 + p.duration / 2) == pytest.approx(1000.0)
    tri = TrapezoidProfile(0.0, -10.0, 0.0, v_max=1000.0, a_max=4000.0)  # never reaches v_max
    assert tri.duration == pytest.approx(2 * math.sqrt(10 / 4000))
    assert tri.position(tri.duration / 2) == pytest.approx(-5.0)
    assert TrapezoidProfile(0, 50, 0).duration == 0.0  # unlimited: instantaneous


def test_backlash_dead_band():
    m = AxisMotion(0.0, backlash=4.0)
    m.start(100.0, 0.0, math.inf, math.inf)
    assert m.arm_position(1.0) == pytest.approx(98.0)  # arm lags by half the play
    m.start(50.0, 1.0, math.inf, math.inf)
    assert m.arm_position(2.0) == pytest.approx(52.0)  # reversing: lags on the other side
    m.start(51.0, 2.0, math.inf, math.inf)
    assert m.arm_position(3.0) == pytest.approx(52.0)  # small move inside the dead band: arm stays


def test_scaled_clock_flows(monkeypatch):
    """Simulated time is 10 x the wall time between two readings, however long the machine takes to get there
    (bracketed by wall-clock readings, so load cannot make this fail)."""
    clk = SimClock(10.0)
    w0 = time.monotonic()
    t0 = clk.now()
    time.sleep(0.05)
    t1 = clk.now()
    w1 = time.monotonic()
    assert 0.5 - 1e-9 <= t1 - t0 <= 10.0 * (w1 - w0) + 1e-9
    s0 = clk.now()
    w0 = time.monotonic()
    clk.advance(1.0)  # 1 simulated second = 0.1 s wall
    assert time.monotonic() - w0 >= 0.1 - 1e-9 and clk.now() - s0 >= 1.0 - 1e-9
    slept: list[float] = []
    import simulator.world.clock

    monkeypatch.setattr(simulator.world.clock.time, "sleep", slept.append)
    clk.advance(1.0)
    clk.advance(0.0)
    clk.advance(-1.0)
    assert slept == [pytest.approx(0.1)]  # exactly dt / time_scale of wall time, and nothing for dt <= 0
    monkeypatch.undo()
    fast = SimClock(0.0)
    fast.advance(100.0)
    assert fast.now() == 100.0


@pytest.mark.parametrize("time_scale", [0.0, 1.0])
def test_servo_motion_in_simulated_time(config_dict, time_scale):
    """Fast time: the move is over by the first status query. Scaled time (real time here: the move and its
    settling take 0.58 s, so a status read lands inside it even on a loaded machine): Moving is reported while,
    and only while, simulated time is before the end of the move, and the position runs between start and goal."""
    bench = VirtualBench(config_from_dict(config_dict({"simulator": {"time_scale": time_scale,
                                                                     "backlash_deg": 1.0}})))
    name = f"motion-{time_scale}"
    register_bench(name, bench)
    port = SimPortHandler(f"sim://{name}/dynamixel")
    port.openPort()
    ph = PacketHandler(2.0)
    try:
        assert ph.write1ByteTxRx(port, 2, 64, 1) == (COMM_SUCCESS, 0)
        assert ph.write4ByteTxRx(port, 2, 112, 200) == (COMM_SUCCESS, 0)
        assert ph.write4ByteTxRx(port, 2, 108, 50) == (COMM_SUCCESS, 0)
        goal = round(2048 - 30.3 * 4096 / 360)
        assert ph.write4ByteTxRx(port, 2, 116, goal) == (COMM_SUCCESS, 0)
        t_end = bench.bus.servo(2).motion.settled_time()  # simulated time at which the move and settling end
        seen_moving = False
        for _ in range(2000):
            t_before = bench.clock.now()
            moving, res, _ = ph.read1ByteTxRx(port, 2, 122)
            t_after = bench.clock.now()
            assert res == COMM_SUCCESS
            # the flag agrees with simulated time whatever the wall-clock delays between the calls
            assert t_before < t_end if moving else t_after >= t_end, (moving, t_before, t_after, t_end)
            if not moving:
                break
            seen_moving = True
            if time_scale:
                pos = ph.read4ByteTxRx(port, 2, 132)[0]
                assert goal <= pos <= 2048 + 45 * 4096 / 360
            time.sleep(0.005)
        assert seen_moving == (time_scale > 0)  # fast time: done by the first status query
        assert ph.read4ByteTxRx(port, 2, 132)[0] == goal  # quantised to 0.088 deg units
        # profile time 75.3 deg at 200/50 units plus settle time
        v, a = dxl_profile_to_units(200, 50)
        d = 75.3 * 4096 / 360
        expected = d / v + v / a + bench.cfg.sim.settle_time_s
        assert bench.clock.now() >= expected - 0.05
        # backlash: moving down, the arm lags 0.5 deg above the motor
        assert bench.arm_angles()[1] == pytest.approx((goal - 2048) * 360 / 4096 + 0.5)
    finally:
        port.closePort()
        unregister_bench(name)


def test_scaled_detector_read_does_not_block_the_bus(config_dict):
    """While a serial READ integrates (scaled time: it really waits), the Dynamixel port is answered. The test
    holds the serial thread inside its integration wait until the ping is answered, so the order is certain
    whatever the machine's load; a bench lock held during the wait would leave the ping unanswered."""
    import threading

    bench = VirtualBench(config_from_dict(config_dict({"simulator": {"time_scale": 1.0}})))
    from simulator.devices import dxl_codec as c

    done = threading.Event()
    integrating, release = threading.Event(), threading.Event()
    real_advance = bench.clock.advance

    def held_advance(dt: float) -> None:
        if threading.current_thread() is th:
            integrating.set()
            release.wait(30)
        real_advance(dt)

    bench.clock.advance = held_advance

    def slow_read():
        bench.process("serial", b"READ 20\nTIME?\n")  # 20 x 10 ms of integration, in real time
        done.set()

    replies: list[bytes] = []

    def ping():
        replies.append(bench.process("dynamixel", c.instruction_packet(1, c.INST_PING)))

    th = threading.Thread(target=slow_read)
    w0 = time.monotonic()
    th.start()
    try:
        assert integrating.wait(30), "the READ never started integrating"
        pinger = threading.Thread(target=ping, daemon=True)
        pinger.start()
        pinger.join(10)  # returns at once unless the serial thread holds the bench lock while it integrates
        assert replies and c.split_status_stream(replies[0]), "the Dynamixel port was blocked by the READ"
        assert not done.is_set()  # answered during the integration
    finally:
        release.set()
    th.join(30)
    assert done.is_set() and time.monotonic() - w0 >= 0.19
