"""What a detector that is not the board's (an Ocean Insight spectrometer, a Thorlabs PM100) borrows from the
rest of the bench: the detector board's clock (``TIME?``), its waits (``DWELL``), its sample changer (``SAMPLE``)
and its source pin (``SOURCE ON|OFF``), when the bench has a board; and the ways a dark reading turns the source
off (``[detector].source_off``): the board's pin, the spectrometer's shutter, or the operator.

:class:`BoardBacked` is the base of :class:`acquisition.devices.seabreeze.SeabreezeDetector` and
:class:`acquisition.devices.pm100.Pm100Detector`; a bench without a board (``serial_port`` empty) has the wall
clock, an operator to swap the sample and, for the darks, the shutter or the operator.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable
from typing import Any

from acquisition.calibration import Reading
from acquisition.devices.serial_link import ControllerError, SerialDetector, SerialLink
from acquisition.errors import DeviceError

log = logging.getLogger("acquisition.board")

__all__ = ["BoardBacked", "SOURCE_OFF_WAYS"]

#: Values of ``[detector].source_off``.
SOURCE_OFF_WAYS = ("auto", "board", "shutter", "prompt")


def _ask_operator(text: str) -> None:  # pragma: no cover - interactive
    input(f"{text}, then press Enter to continue... ")


class BoardBacked:
    """Clock, waits, sample changer and source of a detector that is not the board's; angles and times as the
    bench's (degrees, seconds). ``link``: the board's serial link (None: the bench has none); ``source_off``: one
    of :data:`SOURCE_OFF_WAYS`; ``name``: the device in messages."""

    type = "external"

    def __init__(self, link: SerialLink | None, source_off: str = "auto", name: str = "detector") -> None:
        self.link = link
        self.name = name
        self.source_off = source_off
        # the board's services through the serial detector's own code (it is never asked for a reading)
        self._board = SerialDetector(link, "board", 1.0, 1.0) if link is not None else None
        self.has_source_pin = False
        self.shutter: Callable[[bool], None] | None = None  # open (True) / close (False), if the device has one
        self.operator: Callable[[str], None] | None = _ask_operator if sys.stdin is not None and \
            sys.stdin.isatty() else None
        self._t0 = time.monotonic()
        self.dark_way = "none"
        #: the wait after the source is switched before a reading (s): the board's ``SETTLE?`` (its source's
        #: settle time: an LED's 2 ms, a halogen lamp's 300 ms), 0 without one
        self.source_settle_s = 0.0
        #: the source was switched since the last reading: a free-running spectrometer's next scan began before
        #: (the driver discards it)
        self.source_switched = False

    # -- the board --------------------------------------------------------------------------------------------
    def connect_board(self) -> None:
        """Learn what the board offers (``HELP``) and choose how darks turn the source off."""
        b = self._board
        if b is not None and self.link is not None:
            cmds = {w.upper() for w in self.link.command("HELP").words}
            b.has_time = "TIME?" in cmds
            b.has_dwell = "DWELL" in cmds
            b.has_sample_changer = "SAMPLE" in cmds
            self.has_source_pin = "SOURCE" in cmds
            if "SETTLE?" in cmds:
                self.source_settle_s = float(self.link.fields("SETTLE?")["source"])
        self.dark_way = self._choose_dark_way()
        if self.dark_way == "board":
            self.link.command("SOURCE ON")  # type: ignore[union-attr]
        log.info("%s: darks with the source off by %s", self.name, {
            "board": "the detector board's SOURCE pin", "shutter": "the device's shutter",
            "prompt": "the operator", "none": "nothing (no dark can be read)"}[self.dark_way])

    def _choose_dark_way(self) -> str:
        way = self.source_off
        have = {"board": self.has_source_pin, "shutter": self.shutter is not None,
                "prompt": self.operator is not None}
        if way == "auto":
            return next((w for w in ("board", "shutter", "prompt") if have[w]), "none")
        if not have[way]:
            why = {"board": "the bench has no detector board with a SOURCE pin (serial_port, docs/"
                            "serial-protocol.md)",
                   "shutter": "the device has no shutter",
                   "prompt": "there is no terminal to ask the operator at"}[way]
            raise DeviceError(f"{self.name}: [detector].source_off = {way!r}, but {why}")
        return way

    @property
    def has_time(self) -> bool:
        return self._board is not None and self._board.has_time

    def time(self) -> float | None:
        """The board's clock (s; simulated time on the simulator), None without one."""
        return self._board.time() if self._board is not None else None

    def dwell(self, seconds: float) -> None:
        """Wait ``seconds`` of bench time (the board's ``DWELL``, else a sleep)."""
        if self._board is not None:
            self._board.dwell(seconds)
        elif seconds > 0:
            time.sleep(seconds)

    @property
    def manual_swap(self) -> Callable[[str], None] | None:
        return self._board.manual_swap if self._board is not None else self._swap

    @manual_swap.setter
    def manual_swap(self, fn: Callable[[str], None] | None) -> None:
        if self._board is not None:
            self._board.manual_swap = fn
        else:
            self._swap = fn

    _swap: Callable[[str], None] | None = None

    def set_sample(self, which: str) -> bool:
        """"REF" (the white reference) or "TARGET": the board's sample changer, else the operator (then True)."""
        if self._board is not None:
            return bool(self._board.set_sample(which))
        if which == "TARGET" and self._swap is None:
            return False
        if self._swap is None:
            raise DeviceError(f"{self.name}: no sample changer (no detector board) and no operator prompt: mount "
                              "the white reference by hand, or use absolute calibration")
        self._swap(which)
        return True

    # -- darks ----------------------------------------------------------------------------------------------------
    def with_source_off(self, read: Callable[[int], Reading], n: int) -> Reading:
        """``read(n)`` with the source off (:attr:`dark_way`), the source back on afterwards whatever happens."""
        way = self.dark_way
        if way == "none":
            raise DeviceError(f"{self.name}: cannot read a dark: the bench has no detector board with a SOURCE pin, "
                              "the device no shutter, and there is no terminal to ask the operator at; run "
                              "gonio-capture in a terminal, or wire the source to the board")
        self._source(way, False)
        try:
            return read(n)
        finally:
            self._source(way, True)

    def _source(self, way: str, on: bool) -> None:
        if way == "board":
            try:
                self.link.command("SOURCE ON" if on else "SOURCE OFF")  # type: ignore[union-attr]
            except ControllerError as e:
                raise DeviceError(f"{self.name}: the board refused to switch the source {'on' if on else 'off'}: "
                                  f"{e}") from None
        elif way == "shutter":
            assert self.shutter is not None
            self.shutter(on)
        elif self.operator is not None:
            self.operator("Switch the source ON again" if on else "Switch the source OFF (or block the beam) for "
                          "a dark reading")
        self.source_switched = True
        if way in ("board", "shutter") and self.source_settle_s > 0:
            self.dwell(self.source_settle_s)  # the lamp at full light, or dark, before the next scan

    def board_description(self) -> dict[str, Any]:
        return {"board": self._board is not None, "darks": self.dark_way}
