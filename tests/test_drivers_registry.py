"""Drivers as a registry (issue 51): ``Bench`` opens the arms and the detector through the drivers that the bench
file's ``type`` names (:mod:`acquisition.devices.registry`), each declaring its section, its ports and how it
opens and closes. A new driver is one module plus one registry line: shown with a stand-in driver below (its
"module" is this file's ``Standin*`` classes and their two ``Driver`` declarations), which a ``Bench`` opens,
moves, reads and closes from a bench file naming its types, without touching any other file."""

from __future__ import annotations

import typing
from pathlib import Path

import msgspec
import numpy as np
import pytest

from acquisition.bench import Bench
from acquisition.calibration import Reading
from acquisition.config import load_config
from acquisition.devices import registry
from acquisition.devices.driver import Driver, Opening, Port
from acquisition.errors import ConfigError
from acquisition.ports import configured_ports
from reconstruction.schema.bench import BenchTable, DetectorTable, GrblTable, MotionTable

REPO = Path(__file__).resolve().parents[1]


# --- the stand-in driver's module: a device pair and its two Driver declarations ---------------------------------


class StandinArms:
    """A stand-in for a pair of arms (not a device): it records what the bench asks of it and is where it was
    sent, as the arms' drivers are (``connect``, ``move``, ``positions``, ``healthy``, ``stop``, ``release``,
    ``close``)."""

    def __init__(self, port: str, calls: list[str]) -> None:
        self.port, self.calls = port, calls
        self.at = {"light": 0.0, "detector": 0.0}
        self.cancel = lambda: None

    def connect(self) -> None:
        self.calls.append(f"arms connect {self.port}")

    def move(self, goals: dict[str, float], check_cancel: bool = True) -> None:
        self.calls.append(f"arms move {goals['light']:g} {goals['detector']:g}")
        self.at.update(goals)

    def positions(self) -> dict[str, float]:
        return dict(self.at)

    def healthy(self) -> bool:
        return True

    def stop(self) -> None:
        self.calls.append("arms stop")

    def release(self) -> bool:
        self.calls.append("arms release")
        return True

    def close(self) -> None:
        self.calls.append("arms close")


class StandinMeter:
    """A stand-in for a one-channel detector (not a device): readings of 100 + the detector arm's angle counts,
    as :class:`acquisition.devices.protocols.Detector` documents them (``read``, ``dark``, ``describe``, ...)."""

    type = "standin-meter"
    channels = ["value"]
    saturation = 1e6
    integration_time_s = 0.01
    has_time = False

    def __init__(self, arms_at: typing.Callable[[], float], calls: list[str]) -> None:
        self.arms_at, self.calls = arms_at, calls

    def connect(self) -> None:
        self.calls.append("meter connect")

    def read(self, n: int) -> Reading:
        return Reading(np.array([100.0 + self.arms_at()]), np.zeros(1), n)

    def dark(self, n: int) -> Reading:
        return Reading(np.zeros(1), np.zeros(1), n)

    def dwell(self, seconds: float) -> None:
        pass

    def set_integration_time(self, seconds: float) -> float:
        return self.integration_time_s

    def set_sample(self, which: str) -> bool | None:
        return None

    def describe(self) -> dict[str, typing.Any]:
        return {"type": self.type}

    def close(self) -> None:
        self.calls.append("meter close")


CALLS: list[str] = []
ARMS: list[StandinArms] = []


def _open_arms(o: Opening) -> StandinArms:
    ARMS.append(StandinArms(o.ports["standin"], CALLS))
    return ARMS[-1]


STANDIN_ARMS = Driver("standin-arms", "motion", MotionTable,
                      (Port("standin", "[bench].dynamixel_port", "[bench].dynamixel_baudrate", "stand-in arms"),),
                      _open_arms)
STANDIN_METER = Driver("standin-meter", "detector", DetectorTable, (),
                       lambda o: StandinMeter(lambda: ARMS[-1].at["detector"], CALLS))

# --- the tests ----------------------------------------------------------------------------------------------------


@pytest.fixture
def standin_registered(monkeypatch):
    """The registry with the stand-in's two lines added (the real registry is left as it was)."""
    monkeypatch.setattr(registry, "REGISTRY", dict(registry.REGISTRY))
    registry.register(STANDIN_ARMS)  # the registry lines a new driver adds
    registry.register(STANDIN_METER)
    CALLS.clear()
    ARMS.clear()


def _standin_config():
    """configs/serial-bench.toml with its arms and detector of the stand-in's types (a real bench file names a
    type among the schema's choices; the stand-in's are not in the file format, so the structs are replaced)."""
    cfg = load_config(REPO / "configs" / "serial-bench.toml")
    cfg.bench = msgspec.structs.replace(cfg.bench, motion="standin-arms", dynamixel_port="/dev/standin0")
    cfg.detector = msgspec.structs.replace(cfg.detector, type="standin-meter", auto_range=False)
    return cfg


def test_a_new_driver_is_one_module_plus_one_registry_line(standin_registered):
    cfg = _standin_config()
    with Bench(cfg) as bench:
        assert bench.drivers == (STANDIN_ARMS, STANDIN_METER)
        assert bench.link is None  # neither stand-in declares the detector board's port: it is not opened
        bench.move(30.0, -40.0)
        assert bench.positions() == (30.0, -40.0)
        assert bench.read(3).mean[0] == pytest.approx(60.0)  # 100 + the detector arm's -40
    assert CALLS == ["meter connect", "arms connect /dev/standin0", "arms move 30 -40",
                     "arms move 0 45", "arms release", "arms close", "meter close"]  # parked at park_deg, closed
    assert not bench.is_open and bench.motion is None
    # the port the stand-in declares is the one --check looks at, named by its key
    (use,) = configured_ports(cfg)
    assert (use.key, use.device, use.port) == ("[bench].dynamixel_port", "stand-in arms", "/dev/standin0")


def test_a_type_without_a_driver_is_a_config_error_naming_the_key(standin_registered):
    cfg = _standin_config()
    cfg.detector = msgspec.structs.replace(cfg.detector, type="no-such-meter")
    with pytest.raises(ConfigError, match=r"serial-bench\.toml: \[detector\]\.type: no detector driver for "
                                          r"'no-such-meter'; known: .*standin-meter"):
        Bench(cfg).open()
    assert CALLS == []  # nothing was opened


def test_every_type_of_the_bench_file_has_its_driver():
    """The file format's choices (reconstruction.schema.bench) and the registry name the same drivers."""
    def choices(cls: type, field: str) -> set[str]:
        hint = typing.get_type_hints(cls, include_extras=True)[field]
        return {a for t in typing.get_args(hint) for x in [t, *typing.get_args(t)]
                for a in typing.get_args(x) if isinstance(a, str)}

    motion = {t for r, t in registry.REGISTRY if r == "motion"}
    detector = {t for r, t in registry.REGISTRY if r == "detector"}
    assert motion == choices(BenchTable, "motion") == choices(MotionTable, "type") == {"dynamixel", "serial", "grbl"}
    assert detector == choices(DetectorTable, "type") == {"photodiode", "spectrometer", "seabreeze", "pm100"}
    tables = {BenchTable, MotionTable, GrblTable, DetectorTable}
    for (role, type_), drv in registry.REGISTRY.items():
        assert (drv.role, drv.type) == (role, type_) and drv.ports and drv.section in tables, drv
    with pytest.raises(ValueError, match="registered already"):
        registry.register(Driver("grbl", "motion", MotionTable, (), lambda o: None))


def test_the_old_module_paths_are_retired():
    """GRBL's settings live with its driver and autorange with the detectors (acquisition.devices); acquisition's
    copy of the bench file's tables is gone: the old names import nothing (no re-exports)."""
    import importlib

    for old in ("acquisition.grbl_settings", "acquisition.autorange", "acquisition.sections"):
        with pytest.raises(ModuleNotFoundError):
            importlib.import_module(old)
    from acquisition.devices import autorange, grbl_settings

    assert grbl_settings.alarm_text(1).startswith("ALARM:1: hard limit") and autorange.AutoRanger
