"""The messages of capture plans. A plan is a generator that yields these; the engine
(:class:`acquisition.run.engine.Engine`) carries each out against the devices and sends back its reply (shown after
``->``): a plan that needs readings (adaptive refinement) is sent them. (Plain slotted dataclasses, not frozen:
a plan of 20,000 points yields 100,000 of them, and a dry run of it must take well under a second.)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["Msg", "Move", "Settle", "Wait", "Read", "ReadAt", "Dark", "SelectSample", "Calibrate", "UseReference",
           "Save", "Convert", "Checkpoint",
           "Where", "Now", "Announce", "RestoreSetting", "Tally"]


class Msg:
    """Base class of plan messages."""

    __slots__ = ()


@dataclass(slots=True)
class Move(Msg):
    """Move both arms to (theta_i, theta_o) degrees and wait until in position -> :class:`MoveStatus`. A move is
    a :class:`Checkpoint` first (a pending stop stops before it) unless ``checkpoint`` is false."""

    theta_i_deg: float
    theta_o_deg: float
    checkpoint: bool = True


@dataclass(slots=True)
class Settle(Msg):
    """Wait ``[motion].settle_s`` of bench time -> None."""


@dataclass(slots=True)
class Wait(Msg):
    """Let ``seconds`` of bench time pass (the detector board's ``DWELL``) -> None."""

    seconds: float


@dataclass(slots=True)
class Read(Msg):
    """``repeats`` readings with the source on, auto-ranged when the detector is -> (Reading in counts at the
    reference integration time, its Ranged record or None). ``what`` names it in messages (or ``point``, the
    (theta_i, theta_o) it is of); ``rung``: the auto-range setting to start on."""

    repeats: int
    what: str = ""
    rung: int | None = None
    point: tuple[float, float] | None = None

    @property
    def label(self) -> str:
        return self.what or (f"point ({self.point[0]:g}, {self.point[1]:g})" if self.point else "reading")


@dataclass(slots=True)
class ReadAt(Msg):
    """``repeats`` readings with the source on at the auto-ranging setting (rung) ``setting``, not ranged and not
    re-read (a clipped reading comes back as it is) -> (Reading in raw counts, the gain read at or None). The white
    reference at every gain, for the gain ratios (:func:`acquisition.calibration.measure_gain_factors`); a detector
    not auto-ranged reads at its present setting (a dry run)."""

    repeats: int
    setting: int
    what: str = ""


@dataclass(slots=True)
class Dark(Msg):
    """``repeats`` readings with the source off, re-read around saturation -> Reading. ``calibration``: this is
    the calibration's dark level (auto-ranging converts with it from now on). ``setting``: the auto-ranging setting
    (rung) to read it at, kept for the conversions of the readings taken there (at the present setting when the
    detector is not auto-ranged, as in a dry run)."""

    repeats: int
    what: str = "dark reading"
    calibration: bool = False
    setting: int | None = None


@dataclass(slots=True)
class SelectSample(Msg):
    """Put ``"REF"`` (the white reference) or ``"TARGET"`` (the sample) in front of the detector -> None."""

    which: str


@dataclass(slots=True)
class Calibrate(Msg):
    """From now on convert readings with this :class:`~acquisition.calibration.Calibration` -> None.
    ``reference_integration_time_s``: the integration time the white reference was read at (auto-ranging)."""

    calibration: Any
    reference_integration_time_s: float | None = None


@dataclass(slots=True)
class UseReference(Msg):
    """A new reading of the white reference: convert with it from now on (the dark level is kept) -> None."""

    reading: Any


@dataclass(slots=True)
class Save(Msg):
    """Convert the reading of point (theta_i, theta_o) to f_r and append it to the slice file (fsynced)
    -> (theta_i, theta_o, mean f_r, mean std) over channels."""

    theta_i_deg: float
    theta_o_deg: float
    reading: Any
    ranged: Any = None
    repeats: int = 0  # the repeats asked for (0: the reading's own count)


@dataclass(slots=True)
class Convert(Msg):
    """Convert the reading of point (theta_i, theta_o) to f_r as :class:`Save` does, without saving it (a point
    measured again to compare) -> (theta_i, theta_o, mean f_r, mean std) over channels; its move, settling and
    reading count as a point's in the times."""

    theta_i_deg: float
    theta_o_deg: float
    reading: Any


@dataclass(slots=True)
class Checkpoint(Msg):
    """A safe place to stop: a pending Ctrl-C / SIGTERM stops the capture here -> None."""


@dataclass(slots=True)
class Where(Msg):
    """-> the arms' present (theta_i, theta_o) in degrees."""


@dataclass(slots=True)
class Now(Msg):
    """-> the bench time (s)."""


@dataclass(slots=True)
class Announce(Msg):
    """The capture will hold ``total`` points, ``done`` of them measured already (the progress bar) -> None."""

    total: int
    done: int


@dataclass(slots=True)
class RestoreSetting(Msg):
    """Set the detector back to the configured integration time (after auto-ranging) -> None."""


@dataclass(slots=True)
class Tally(Msg):
    """Note a figure of the run in its result (e.g. ``adaptive_rounds``) -> None."""

    name: str
    value: Any
