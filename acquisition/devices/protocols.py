"""The device protocols the capture engine runs plans against (``typing.Protocol``): it knows nothing of
Dynamixel servos, serial controllers or simulators, only of these.

* :class:`Axes`: the movable pair of arms, (theta_i, theta_o) in degrees: ``set`` moves both and returns a
  :class:`MoveStatus`, ``check_value`` says why a pair cannot be measured (or None), ``stop`` halts them.
* :class:`Detector`: ``read`` (source on) and ``dark`` (source off) readings in raw counts, its settings
  (integration time, which sample is in front of it) and ``describe``.
* :class:`Clock`: the bench's time (s) and waiting on it.

:class:`acquisition.bench.Bench` provides them for a real or simulated bench (``bench.devices()``),
:class:`acquisition.run.dryrun.DryRunBench` for ``gonio-capture --check``, which runs the very same plan without
moving anything, checking limits and accumulating the time model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from acquisition.calibration import Reading

__all__ = ["MoveStatus", "Axes", "Detector", "Clock", "Devices"]


@dataclass(frozen=True)
class MoveStatus:
    """The outcome of :meth:`Axes.set`: ``done`` (the drivers return once both arms are in position and not
    moving), ``success``, and the positions reached (degrees)."""

    done: bool
    success: bool
    position: tuple[float, float]


@runtime_checkable
class Axes(Protocol):
    """The light and detector arms, moved together."""

    def set(self, theta_i_deg: float, theta_o_deg: float) -> MoveStatus: ...

    def check_value(self, theta_i_deg: float, theta_o_deg: float) -> str | None: ...

    def stop(self) -> None: ...

    def positions(self) -> tuple[float, float]: ...


@runtime_checkable
class Detector(Protocol):
    """A photodiode or spectrometer behind the detector arm; readings in raw counts."""

    channels: list[str]
    saturation: float
    integration_time_s: float

    def read(self, n: int) -> Reading: ...

    def dark(self, n: int) -> Reading: ...

    def set_integration_time(self, seconds: float) -> float: ...

    def set_sample(self, which: str) -> bool | None: ...  # True: the operator was asked (no changer)

    def describe(self) -> dict[str, Any]: ...


@runtime_checkable
class Clock(Protocol):
    """The bench's clock: simulated time on the simulator, the controller's or wall time otherwise (s)."""

    def now(self) -> float: ...

    def dwell(self, seconds: float) -> None: ...


@dataclass
class Devices:
    """What a plan runs against."""

    axes: Axes
    detector: Detector
    clock: Clock
