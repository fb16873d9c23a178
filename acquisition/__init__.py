"""gonio-brdf acquisition: drive a real or simulated in-plane gonioreflectometer and capture BRDF slices.

Reaches every device through its port only (a Dynamixel bus with ``dynamixel_sdk``, a serial text-protocol
controller with ``pyserial``); a simulated bench is ``gonio-sim serve`` in a child process, driven through the
pseudo-terminals it prints. This package never imports ``simulator``.

    from acquisition import Bench
    with Bench.from_config("configs/simulated.toml") as bench:
        result = bench.capture(bench.plan(), out="out/run1")
"""


from acquisition.bench import Bench, SimulatorProcess
from acquisition.calibration import Calibration, Reading
from acquisition.config import BenchConfig, config_from_dict, load_config
from acquisition.errors import (
    AcquisitionError,
    CaptureInterrupted,
    CommError,
    ConfigError,
    DeviceError,
    HardwareError,
    PlanError,
    SaturationWarning,
)
from acquisition.plans.geometry import Geometry, Reason
from acquisition.plans.ordering import order_points, path_time
from acquisition.plans.plan import Plan, PlanCheck, load_scene

__all__ = [
    "AcquisitionError",
    "Bench",
    "BenchConfig",
    "Calibration",
    "CaptureInterrupted",
    "CaptureResult",
    "CommError",
    "ConfigError",
    "DeviceError",
    "Engine",
    "Geometry",
    "HardwareError",
    "Plan",
    "PlanCheck",
    "PlanError",
    "Reading",
    "Reason",
    "RunEngine",
    "SaturationWarning",
    "SimulatorProcess",
    "Stop",
    "config_from_dict",
    "load_config",
    "load_scene",
    "order_points",
    "path_time",
]


#: Names imported when first used: a capture's machinery is not loaded by ``gonio-capture --check`` (which
#: returns in well under a second for the largest plan).
_LAZY = {"RunEngine": "run.capture", "Engine": "run.engine", "CaptureResult": "run.record", "Stop": "run.record"}


def __getattr__(name: str) -> object:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
