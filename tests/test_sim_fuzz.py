"""Property-based fuzzing of the packet parser and the device model (in-process, fast)."""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from simulator.bench import VirtualBench
from simulator.config import config_from_dict
from simulator.devices import dxl_codec as c

INSTS = [c.INST_PING, c.INST_READ, c.INST_WRITE, c.INST_REG_WRITE, c.INST_ACTION, c.INST_FACTORY_RESET,
         c.INST_REBOOT, c.INST_CLEAR, c.INST_SYNC_READ, c.INST_SYNC_WRITE, c.INST_FAST_SYNC_READ,
         c.INST_BULK_READ, c.INST_BULK_WRITE, c.INST_FAST_BULK_READ, 0x55, 0x77]

valid_packets = st.builds(
    c.instruction_packet,
    st.sampled_from([1, 2, 3, c.BROADCAST_ID]),
    st.sampled_from(INSTS),
    st.binary(max_size=40),
)


@st.composite
def mutated(draw):
    pkt = bytearray(draw(valid_packets))
    for _ in range(draw(st.integers(0, 4))):
        op = draw(st.sampled_from(["flip", "insert", "delete", "truncate"]))
        if not pkt:
            break
        i = draw(st.integers(0, len(pkt) - 1))
        if op == "flip":
            pkt[i] ^= draw(st.integers(1, 255))
        elif op == "insert":
            pkt.insert(i, draw(st.integers(0, 255)))
        elif op == "delete":
            del pkt[i]
        else:
            del pkt[i:]
    return bytes(pkt)


def responsive(bench: VirtualBench) -> bool:
    bench.bus.last_rx -= 1.0  # let the device's packet timeout expire (a partial packet is then dropped)
    out = bench.process("dynamixel", c.instruction_packet(1, c.INST_PING))
    return c.split_status_stream(out)[:1] == [(1, 0, bytes([0xFC, 0x03, 48]))]


def make_bench(base):
    raw = {k: v for k, v in base.items()}
    return VirtualBench(config_from_dict(raw))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.lists(st.one_of(st.binary(max_size=64), mutated(), valid_packets), max_size=6))
def test_random_and_mutated_packets(base_config_dict, data):
    bench = make_bench(base_config_dict)
    for chunk in data:
        out = bench.process("dynamixel", chunk)
        assert isinstance(out, bytes)
        # every reply is a well-formed status packet
        frames = c.PacketParser().feed(out)
        assert all(f.crc_ok and f.body[:1] == b"\x55" for f in frames)
    assert bench.bus.stats["internal_errors"] == 0  # no exception was swallowed by the safety net
    assert responsive(bench)


COMMANDS = ["?", "STATUS?", "ID?", "TIME?", "HELP", "MOVE", "HOME", "STOP", "RESET", "READ", "DARK", "DWELL",
            "DETECTOR?", "INT", "INT?", "GAIN", "SAMPLE", "SAMPLE?"]
ARGS = st.one_of(
    st.integers(-10**12, 10**12).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.builds(lambda a, n: f"{a}{n}", st.sampled_from("LDSQ"), st.integers(-10**6, 10**6)),
    st.sampled_from(["REF", "TARGET", "L", "D", "nan", "inf", "-0", "1e400", "L=100"]),
    st.text(max_size=8),
)
command_lines = st.builds(lambda c, a: " ".join([c, *a]), st.sampled_from(COMMANDS), st.lists(ARGS, max_size=3))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(lines=st.lists(st.one_of(st.text(max_size=40), command_lines), max_size=8),
       motion=st.sampled_from(["dynamixel", "serial"]))
def test_serial_interpreter_never_raises(base_config_dict, lines, motion):
    bench = make_bench({**base_config_dict, "bench": {**base_config_dict["bench"], "motion": motion}})
    for ln in lines:
        out = bench.process("serial", (ln + "\n").encode("utf-8", errors="replace"))
        assert isinstance(out, bytes)
        for reply in out.decode("ascii").splitlines():
            assert reply.isprintable()
    assert bench.controller.internal_errors == 0
    assert bench.process("serial", b"\nTIME?\n").decode().splitlines()[-1] == "ok"
