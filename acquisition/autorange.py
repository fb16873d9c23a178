"""Detector auto-ranging: measure a sample's full dynamic range without the operator tuning the exposure.

With ``[detector].gains`` (a photodiode amplifier's switchable gains) the ladder's rungs are settings (gain,
integration time) from the most sensitive down: every gain from the highest at ``t_ref``, then the lowest gain
at the shorter times below (:func:`settings_ladder`); the reference setting (rung 0) is the highest gain at
``t_ref``, a dark is measured at every setting used, and a reading is converted with the ratio of gain x time.
A clean reading is taken up the ladder again while the prediction says it fits (each gain's noise is overstated
by the prediction, so a dim point may climb in two steps). Without gains, the ladder is over integration time:

A glossy sample's specular peak can be 1e4-1e6 times its diffuse floor, more than one detector setting can hold.
:class:`AutoRanger` reads a point at the configured integration time ``t_ref`` and, when a repeat saturates,
reads it again at shorter times from a fixed ladder ``t_ref``, ``t_ref / sqrt(10)``, ``t_ref / 10``, ... down to
``min_integration_time_s`` (sent with the protocol's ``INT``):

- all repeats clipped (the excess is unknown): two rungs down (a factor of 10);
- some repeats clipped: the same setting once more (a transient does not repeat), then one rung down;
- no repeat clipped, but the brightest channel's mean plus 3 standard deviations above :data:`HEADROOM` of the
  saturation: one rung down (readings that only just stay below the clip are biased low, and real detectors are
  least linear near full scale);
- a clean reading at a shorter time than ``t_ref``: the longest rung (up to ``t_ref``) at which it is predicted to
  stay below that same limit is read once more (best signal-to-noise ratio); should that one exceed it, the
  clean shorter reading is kept.

Readings are therefore kept within the same limit whichever way the ladder was walked.

The setting that worked stays for the next point (neighbours around a peak need it too; a dim point costs one
short extra reading before going back up), so the ladder is walked once per peak, not once per point.

A reading at time ``t`` is converted to the reference exposure: the signal above the dark level scales with the
integration time, the dark level itself is measured at ``t`` (once, then cached: a photodiode's dark current
scales with ``t`` while its offset does not, and neither is assumed), so::

    mean_ref = dark_ref + (mean_t - dark_t) * t_ref / t        std_ref = std_t * t_ref / t

which :class:`~acquisition.calibration.Calibration` then turns into f_r exactly as a reading taken at ``t_ref``.
A spectrometer saturates per pixel: the rules above look at the brightest pixel. Times in seconds, readings in
raw counts.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .calibration import Reading, pool
from .errors import DeviceError

log = logging.getLogger("acquisition.autorange")

__all__ = ["AutoRanger", "Ranged", "ladder", "settings_ladder", "setting_key", "read_clean", "HEADROOM",
           "RUNG_RATIO"]

#: Ratio between neighbouring integration times of the ladder.
RUNG_RATIO = math.sqrt(10.0)
#: A kept reading's brightest channel (mean + NEAR_SIGMAS standard deviations of one repeat) stays below this
#: fraction of the saturation; a longer setting is chosen only if it is predicted to.
HEADROOM = 0.8
NEAR_SIGMAS = 3.0


class RangedDetector(Protocol):
    """What auto-ranging needs from a detector driver (:class:`~acquisition.serial_link.SerialDetector`); with
    gains also ``set_gain(g) -> the gain the amplifier reports``."""

    integration_time_s: float
    saturation: float

    def read(self, n: int) -> Reading: ...

    def set_integration_time(self, seconds: float) -> float: ...


def settings_ladder(t_ref: float, t_min: float, gains: tuple[float, ...] | None) -> list[tuple[float | None, float]]:
    """(gain, integration time) settings from the most sensitive down: every gain, highest first, at ``t_ref``,
    then the lowest gain at the shorter times of :func:`ladder`. Without gains: (None, t) for every time."""
    times = ladder(t_ref, t_min)
    if not gains:
        return [(None, t) for t in times]
    g = sorted(gains, reverse=True)
    return [(x, t_ref) for x in g] + [(g[-1], t) for t in times[1:]]


def ladder(t_ref: float, t_min: float) -> list[float]:
    """Integration times (s): ``t_ref``, then ``t_ref / sqrt(10)**k`` rounded to 6 significant digits while longer
    than ``t_min``, and ``t_min`` last (when shorter than ``t_ref``)."""
    out = [t_ref]
    k = 1
    while out[-1] > t_min * (1 + 1e-9):
        t = float(f"{t_ref / RUNG_RATIO ** k:.6g}")
        out.append(t if t > t_min * (1 + 1e-9) else t_min)
        k += 1
    return out


def read_clean(read: Callable[[int], Reading], n: int, retries: int = 3) -> tuple[Reading, int, int]:
    """``n`` repeats through ``read(n)`` without transient clips: (reading, commands sent, repeats read).

    A reading with some, but not all, repeats clipped is read again in two halves, recursively; a half that
    clips entirely is read again up to ``retries`` times. A transient (a glitch that clips random repeats) then
    costs a few short readings instead of failing a long one, however often it strikes; a real saturation (every
    repeat of the reading clipped) comes back clipped at once for the caller to range down, and a reading at the
    edge of the range comes back clipped or near the clip, which the ranger's headroom rule also ranges down. At
    most about ``(retries + 1) n log2 n`` repeats."""
    stats = [0, 0]

    def clean(m: int, top: bool) -> Reading:
        for _ in range(retries + 1):
            rd = read(m)
            stats[0] += 1
            stats[1] += m
            if not rd.saturated:
                return rd
            if rd.saturated < m:  # some repeats clipped: read the two halves
                k = m // 2
                return pool(clean(k, False), clean(m - k, False))
            if top:  # every repeat clipped: a real saturation, for the caller to range down
                return rd
            # a piece of a split reading clipped entirely: a transient again, or real; read it once more
        return rd

    return clean(n, True), stats[0], stats[1]


def setting_key(t: float, gain: float | None = None) -> str:
    """The cache key of an integration time (s), 6 significant digits as the detector reports it, and of the gain
    when the amplifier's is switched (``"0.01 s, gain 100"``)."""
    return f"{t:.6g}" if gain is None else f"{t:.6g} s, gain {gain:g}"


@dataclass(frozen=True)
class Ranged:
    """An auto-ranged reading: ``reading`` converted to the reference exposure (counts at ``t_ref``), ``raw``
    as read at ``integration_time_s`` (s), ``readings`` taken in all (``readings - 1`` discarded) and
    ``overhead_s`` = integration time spent on the discarded ones and on new dark readings (s)."""

    reading: Reading
    raw: Reading
    integration_time_s: float
    readings: int
    overhead_s: float
    gain: float | None = None
    dark: Reading | None = None  # the dark at the setting read (a ranged reading), converted like the reading

    @property
    def ranged(self) -> bool:
        """True if the reading was taken at a shorter integration time than the reference."""
        return self.raw is not self.reading


class AutoRanger:
    """Auto-ranging state over one capture: the ladder, the current rung, and the dark level per setting.

    ``detector``: the driver; ``t_ref``: the configured integration time (s), the exposure every reading is
    converted to; ``t_min``: the shortest time to try (s); ``read_dark()``: a dark reading at the present
    setting (the engine's, with its retries); ``on_dark(t, reading)``: called when a dark at a new setting was
    measured (the engine stores it in the run record, so a resumed capture converts with the same darks).
    """

    def __init__(self, detector: RangedDetector, t_ref: float, t_min: float, read_dark: Callable[[], Reading],
                 on_dark: Callable[..., None] | None = None, retries: int = 3,
                 gains: tuple[float, ...] | None = None) -> None:
        self.det = detector
        self.retries = retries
        self.t_ref = float(t_ref)
        self.t_min = float(t_min)
        self.settings = settings_ladder(self.t_ref, self.t_min, gains)
        self.ladder = [t for _, t in self.settings]
        self.gains = [g for g, _ in self.settings] if gains else None
        self.read_dark = read_dark
        self.on_dark = on_dark
        self.darks: dict[str, Reading] = {}      # setting_key(actual t, gain) -> dark reading at that setting
        self.ref_dark: Reading | None = None     # the calibration's dark at the reference setting (rung 0); None:
        #                                          measured when first needed (reference_dark)
        self._actual: dict[int, float] = {0: float(detector.integration_time_s)}
        self._gain: dict[int, float | None] = {}
        self._rung = 0                           # where the next point starts (the last rung that worked)
        self._current = 0                        # the rung the detector is set to
        self._det_gain: float | None = None      # the gain the amplifier reported last

    def sensitivity(self, i: int) -> float:
        """Counts per unit signal on rung ``i`` relative to gain 1 and ``t_ref`` (gain x time / t_ref)."""
        g = self._gain.get(i, self.settings[i][0])
        return (1.0 if g is None else g) * self._actual.get(i, self.ladder[i]) / self.t_ref

    def _describe(self, i: int) -> str:
        """Rung ``i`` for a log line: "t_int = 0.01 s" (and ", gain 100" when the gain is switched)."""
        g = self._gain.get(i, self.settings[i][0])
        return f"t_int = {self._actual.get(i, self.ladder[i]):g} s" + ("" if g is None else f", gain {g:g}")

    def setting_key_of(self, i: int) -> str:
        return setting_key(self._actual.get(i, self.ladder[i]), self._gain.get(i, self.settings[i][0]))

    # -- settings -------------------------------------------------------------------------------------------------
    def _set(self, i: int) -> float:
        """Put the detector on rung ``i`` (gain, then integration time); returns the integration time it reports
        (s)."""
        g = self.settings[i][0]
        if g is not None:
            have = self._gain.get(i)
            if have is None or self._det_gain != have:
                self._gain[i] = self._det_gain = float(self.det.set_gain(g))  # type: ignore[attr-defined]
        if i != self._current or self.det.integration_time_s != self._actual.get(i):
            cur = self._actual.get(self._current)
            if (self.ladder[i] == self.ladder[self._current] and cur is not None
                    and self.det.integration_time_s == cur):  # another gain at the same time: no INT
                self._actual[i] = cur
            else:
                self._actual[i] = self.det.set_integration_time(self.ladder[i])
            self._current = i
        return self._actual[i]

    def restore(self, keep_start: bool = False) -> None:
        """Back to the reference setting (next reading, end-of-run dark, the caller's bench). ``keep_start``: the
        next reading still starts on the setting the last one needed (between readings of one bench script)."""
        if self.gains is not None:
            self._set(0)
        elif self._current != 0 or self.det.integration_time_s != self._actual[0]:
            self._actual[0] = self.det.set_integration_time(self.t_ref)
            self._current = 0
        if not keep_start:
            self._rung = 0

    def reference_dark(self) -> Reading:
        """The dark at the reference setting (rung 0): the calibration's, else measured now (once)."""
        if self.ref_dark is None:
            self._set(0)
            self.ref_dark = self.read_dark()
            log.info("dark level at the reference setting (%s): %s counts (%d repeats)", self._describe(0),
                     np.round(self.ref_dark.mean, 3).tolist()[:8], self.ref_dark.n)
        return self.ref_dark

    # -- darks -------------------------------------------------------------------------------------------------
    def dark_at(self, i: int) -> Reading:
        """The dark reading at rung ``i`` (measured once, then cached; rung 0 is the calibration's dark)."""
        if i == 0:
            return self.reference_dark()
        t = self._set(i)
        key = self.setting_key_of(i)
        d = self.darks.get(key)
        if d is None:
            d = self.read_dark()
            self.darks[key] = d
            log.info("dark level at t_int = %s s: %s counts (%d repeats)", key, np.round(d.mean, 3).tolist()[:8],
                     d.n)
            if self.on_dark is not None:
                if self.gains is None:
                    self.on_dark(t, d)
                else:
                    self.on_dark(t, d, self._gain.get(i))
        return d

    # -- reading ----------------------------------------------------------------------------------------------
    def _state(self, rd: Reading) -> str:
        """"ok", "near" (brightest channel's mean + NEAR_SIGMAS std above HEADROOM of the clip), "partial" or
        "full" saturation."""
        if rd.saturated >= rd.n:
            return "full"
        if rd.saturated:
            return "partial"
        if np.any(rd.mean + NEAR_SIGMAS * rd.std >= HEADROOM * self.det.saturation):
            return "near"
        return "ok"

    def _longest_fitting(self, rd: Reading, i: int, t: float, excluded: set[int]) -> int:
        """The longest rung j < i (not in ``excluded``) at which ``rd`` (taken on rung i, time t) is predicted to
        stay below HEADROOM of the saturation; ``i`` if none."""
        base = self.ref_dark.mean if self.ref_dark is not None else np.zeros_like(rd.mean)
        if self.gains is not None:  # the dark at this rung, if known, is the better base (each gain has its offset)
            base = self.darks.get(self.setting_key_of(i), Reading(base, base, 1)).mean if i else base
        net = np.max(np.maximum(rd.mean - base, 0.0) + NEAR_SIGMAS * rd.std)
        top = HEADROOM * self.det.saturation - float(np.max(base))
        s_i = self.sensitivity(i)
        for j in range(i):
            if j in excluded:
                continue
            if net * self.sensitivity(j) / s_i < top:
                return j
        return i

    def read(self, n: int, what: str, start: int | None = None) -> Ranged:
        """``n`` repeats, ranged: see the module docstring. ``start``: the rung to begin on (default: the rung
        the last point needed). Raises DeviceError if even ``t_min`` saturates."""
        i = self._rung if start is None else start
        best: tuple[int, float, Reading] | None = None
        excluded: set[int] = set()
        retried: set[int] = set()
        upranged = False
        upranges = 0
        reads = 0
        spent = 0.0
        last = len(self.ladder) - 1
        while True:
            t = self._set(i)
            if i in retried:  # read again after a partial clip: transients are read around (read_clean)
                rd, _, repeats = read_clean(self.det.read, n, self.retries)
            else:
                rd, repeats = self.det.read(n), n
            reads += 1  # one (possibly pieced) reading
            spent += repeats * t
            state = self._state(rd)
            if state == "ok":
                if best is None or i < best[0]:
                    best = (i, t, rd)
                # up the ladder once (with gains, whose noise the prediction overstates, until it stops gaining)
                if i > 0 and not upranged:
                    j = self._longest_fitting(rd, i, t, excluded)
                    if j < i:
                        upranges += 1
                        upranged = self.gains is None or upranges >= len(self.settings)
                        log.debug("%s: clean at %s; trying %s", what, self.setting_key_of(i),
                                  setting_key(self.ladder[j], self.settings[j][0]))
                        i = j
                        continue
                break
            if best is not None:  # a longer setting, tried after a clean reading, saturates: keep the clean one
                break
            if state == "partial" and i not in retried:
                retried.add(i)
                log.warning("%s: %d of %d repeats saturated at %s; reading again", what, rd.saturated,
                            n, self._describe(i))
                continue
            excluded.add(i)
            if i == last:
                lowest = "" if self.gains is None else f"the lowest gain ({self.settings[-1][0]:g}) and "
                raise DeviceError(
                    f"{what}: the detector saturates ({self.det.saturation:g} counts) even at {lowest}the shortest "
                    f"integration time, [detector].min_integration_time_s = {self.t_min:g} s; reduce the gain or "
                    "the source power")
            nxt = min(i + (2 if state == "full" else 1), last)
            log.info("%s: %s at %s (%d of %d repeats clipped); trying %s", what,
                     "saturated" if state != "near" else "near saturation", self._describe(i), rd.saturated, n,
                     self._describe(nxt))
            i = nxt
        i, t, rd = best
        spent -= n * t
        gain = self._gain.get(i)
        if i == 0:
            self._rung = 0
            return Ranged(rd, rd, t, reads, spent, gain)
        n_darks = len(self.darks)
        dark = self.dark_at(i)
        if len(self.darks) > n_darks:
            spent += dark.n * t
        if self.ref_dark is None:  # no calibration (a bench script's reading): measured once, now
            spent += self.reference_dark().n * self.t_ref
        ref_dark = self.reference_dark()
        r = self.sensitivity(0) / self.sensitivity(i)
        conv = Reading(ref_dark.mean + (rd.mean - dark.mean) * r, rd.std * r, rd.n, 0)
        self._rung = i
        return Ranged(conv, rd, t, reads, spent, gain, Reading(dark.mean * r, dark.std * r, dark.n, 0))
