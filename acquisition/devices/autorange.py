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

The first reading of a point starts on the setting its neighbours predict (:meth:`AutoRanger.predict`: the
points already read at the same incidence, their signal at the point, interpolated or extrapolated along their
trend; between gains at one integration time with some hysteresis), so that the ladder is not walked at every
point where the signal crosses into another setting's range; a point without neighbours starts on the setting
the last point needed, and one whose setting is a guess (the white reference) searches with a probe of
:data:`PROBE_REPEATS` repeats before reading the rest. With gains, the darks at every gain are measured with the
calibration's (:func:`acquisition.plans.calibrate`), so the estimate counts them.

A photodiode on a DC amplifier read by oversampling (the detector board: ``DETECTOR?`` says ``amplifier=dc``) is
ranged over its gains only: a shorter integration time sums fewer conversions of the same voltage, which clips just
as soon.

A reading at time ``t`` is converted to the reference exposure: the signal above the dark level scales with the
integration time, the dark level itself is measured at ``t`` (once, then cached: a photodiode's dark current
scales with ``t`` while its offset does not, and neither is assumed), so::

    mean_ref = dark_ref + (mean_t - dark_t) * t_ref / t        std_ref = std_t * t_ref / t

which :class:`~acquisition.calibration.Calibration` then turns into f_r exactly as a reading taken at ``t_ref``.
A spectrometer saturates per pixel: the rules above look at the brightest pixel. Times in seconds, readings in
raw counts.
"""

from __future__ import annotations

import bisect
import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from acquisition.calibration import Reading, pool
from acquisition.errors import DeviceError

log = logging.getLogger("acquisition.devices.autorange")

__all__ = ["AutoRanger", "Ranged", "ladder", "settings_ladder", "setting_key", "read_clean", "HEADROOM",
           "RUNG_RATIO", "PROBE_REPEATS", "PREDICTION_BAND", "ranged_wording"]

#: Ratio between neighbouring integration times of the ladder.
RUNG_RATIO = math.sqrt(10.0)
#: A kept reading's brightest channel (mean + NEAR_SIGMAS standard deviations of one repeat) stays below this
#: fraction of the saturation; a longer setting is chosen only if it is predicted to.
HEADROOM = 0.8
NEAR_SIGMAS = 3.0
#: Repeats of a probe: a reading whose setting is a guess (no neighbour predicts it: the white reference, the first
#: point of an incidence) searches the ladder with this many repeats, then reads the rest at the setting found.
PROBE_REPEATS = 4
#: Hysteresis between gains at one integration time: a point starts on its neighbours' gain unless their signal,
#: x or / this factor, still says another, and a reading on a predicted gain goes to a higher one only if it fits
#: there by this factor (a lower gain costs no signal; near the edge of a range noise would decide back and forth).
PREDICTION_BAND = 2.0


class RangedDetector(Protocol):
    """What auto-ranging needs from a detector driver (:class:`~acquisition.devices.serial_link.SerialDetector`); with
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


def ranged_wording(settings: Mapping[str, int], t_ref: float) -> str:
    """What auto-ranging changed, in words, from the settings of the ranged points (keys of
    :func:`setting_key`): "at lower gains", "at shorter integration times", "at lower gains and shorter
    integration times" ("at the reference setting" for none)."""
    gain = time = False
    for key in settings:
        t = float(key.split(" s,")[0])
        gain |= "gain" in key
        time |= t < t_ref * (1 - 1e-6)
    if gain and time:
        return "at lower gains and shorter integration times"
    return "at lower gains" if gain else "at shorter integration times" if time else "at the reference setting"


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
        if gains and getattr(detector, "dc_amplifier", False):
            # a DC amplifier read by oversampling: a shorter integration time sums fewer conversions of the same
            # voltage and clips as soon, so it cannot lower the signal: the gains are the whole ladder
            self.t_min = self.t_ref
        self.settings = settings_ladder(self.t_ref, self.t_min, gains)
        self.ladder = [t for _, t in self.settings]
        self.gains = [g for g, _ in self.settings] if gains else None
        #: real / nominal gain by nominal gain (measured on the white reference); empty: the nominal gains
        self.gain_factors: dict[float, float] = {}
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
        #: theta_i -> (sorted theta_o, their signals in reference-setting counts above the dark, their rungs):
        #: what predict() knows of the points read
        self._seen: dict[float, tuple[list[float], list[float], list[int]]] = {}

    def sensitivity(self, i: int) -> float:
        """Counts per unit signal on rung ``i`` relative to gain 1 and ``t_ref`` (gain x time / t_ref; the gain's
        measured factor when the calibration measured one, :meth:`set_gain_factors`)."""
        g = self._gain.get(i, self.settings[i][0])
        real = 1.0 if g is None else g * self.gain_factors.get(float(g), 1.0)
        return real * self._actual.get(i, self.ladder[i]) / self.t_ref

    def set_gain_factors(self, factors: Mapping[float, float]) -> None:
        """Convert with the amplifier's real gains from now on: ``factors`` = real / nominal gain, by nominal
        gain (:func:`acquisition.calibration.measure_gain_factors`)."""
        self.gain_factors = {float(g): float(f) for g, f in factors.items()}
        log.info("auto-ranging converts with the measured gain factors %s",
                 ", ".join(f"{g:g}: {f:.4f}" for g, f in sorted(self.gain_factors.items())))

    def set_setting(self, i: int) -> float:
        """Put the detector on rung ``i`` (as a reading there would); returns its integration time (s)."""
        return self._set(i)

    def gain_of(self, i: int) -> float | None:
        """The gain of rung ``i`` (the amplifier's report once set, else the nominal one)."""
        return self._gain.get(i, self.settings[i][0])

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
            log.info("dark level at %s: %s counts (%d repeats)", self._describe(i), np.round(d.mean, 3).tolist()[:8],
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

    def _longest_fitting(self, rd: Reading, i: int, t: float, excluded: set[int], margin: float = 1.0) -> int:
        """The longest rung j < i (not in ``excluded``) at which ``rd`` (taken on rung i, time t), times
        ``margin``, is predicted to stay below HEADROOM of the saturation; ``i`` if none."""
        base = self.ref_dark.mean if self.ref_dark is not None else np.zeros_like(rd.mean)
        if self.gains is not None:  # the dark at this rung, if known, is the better base (each gain has its offset)
            base = self.darks.get(self.setting_key_of(i), Reading(base, base, 1)).mean if i else base
        net = margin * np.max(np.maximum(rd.mean - base, 0.0) + NEAR_SIGMAS * rd.std)
        top = HEADROOM * self.det.saturation - float(np.max(base))
        s_i = self.sensitivity(i)
        for j in range(i):
            if j in excluded:
                continue
            # ``margin`` holds only for another gain at the same integration time (no signal lost by staying)
            if net * (margin if self.ladder[j] == self.ladder[i] else 1.0) * self.sensitivity(j) / s_i < top:
                return j
        return i

    # -- the setting a point starts on -----------------------------------------------------------------------------
    def _fitting_rung(self, net_ref: float) -> int:
        """The most sensitive rung on which a signal of ``net_ref`` (reference-setting counts above the dark, the
        brightest channel, with NEAR_SIGMAS of its noise) stays below HEADROOM of the saturation; the last rung if
        none does."""
        ref = self.ref_dark.mean if self.ref_dark is not None else None
        for j in range(len(self.settings)):
            d = self.darks.get(self.setting_key_of(j)) if j else None
            base = d.mean if d is not None else ref
            top = HEADROOM * self.det.saturation - (float(np.max(base)) if base is not None else 0.0)
            if net_ref * self.sensitivity(j) / self.sensitivity(0) < top:
                return j
        return len(self.settings) - 1

    def predict(self, point: tuple[float, float]) -> int | None:
        """The rung the first reading of ``point`` (theta_i, theta_o in degrees) starts on, predicted from its
        neighbours already read at the same incidence (None: there are none): the most sensitive setting their
        signal at the point fits, that signal being the brighter of the two neighbours on either side, or
        extrapolated from the two nearest on one side (their trend, at most x10 per step: a slope up to a peak
        ranges down ahead of it, a slope away from it up). Between gains at the same integration time the
        neighbours' setting (the nearest one's; on both sides the less sensitive) stays unless their signal says
        another by more than :data:`PREDICTION_BAND` either way: near the edge of a gain's range a reading's noise
        decides, a point would go back and forth, and a lower gain costs no signal."""
        row = self._seen.get(round(float(point[0]), 6))
        if not row:
            return None
        tos, nets, rungs = row
        to = round(float(point[1]), 6)
        k = bisect.bisect_left(tos, to)
        if k < len(tos) and tos[k] == to:  # read before (a point measured again)
            net, rung = nets[k], rungs[k]
        elif 0 < k < len(tos):
            net, rung = max(nets[k - 1], nets[k]), max(rungs[k - 1], rungs[k])
        else:
            j, j2 = (k - 1, k - 2) if k > 0 else (k, k + 1)
            net, rung = nets[j], rungs[j]
            if 0 <= j2 < len(tos) and nets[j] > 0 and nets[j2] > 0:
                steps = abs(to - tos[j]) / max(abs(tos[j] - tos[j2]), 1e-9)
                net *= min(max(nets[j] / nets[j2], 0.1), 10.0) ** min(steps, 1.0)
        best = self._fitting_rung(net)
        if (rung != best and self.ladder[rung] == self.ladder[best]
                and self._fitting_rung(net / PREDICTION_BAND) <= rung <= self._fitting_rung(net * PREDICTION_BAND)):
            return rung  # another gain at the same integration time, near the edge: the neighbours' stays
        return best

    def _remember(self, point: tuple[float, float], reading: Reading, rung: int) -> None:
        """Keep the signal of a point read (converted to the reference setting) and its rung for :meth:`predict`."""
        if self.ref_dark is None:
            return
        net = float(np.max(np.maximum(reading.mean - self.ref_dark.mean, 0.0) + NEAR_SIGMAS * reading.std))
        tos, nets, rungs = self._seen.setdefault(round(float(point[0]), 6), ([], [], []))
        to = round(float(point[1]), 6)
        k = bisect.bisect_left(tos, to)
        if k < len(tos) and tos[k] == to:
            nets[k], rungs[k] = net, rung
        else:
            tos.insert(k, to)
            nets.insert(k, net)
            rungs.insert(k, rung)

    def rung_of(self, t: float, gain: float | None = None) -> int:
        """The rung of a setting (integration time in s, gain) as a run record gives it: the same gain, the
        nearest time."""
        cands = [j for j, (g, _) in enumerate(self.settings) if (g is None or gain is None or g == gain)]
        return min(cands or range(len(self.settings)), key=lambda j: abs(math.log(max(t, 1e-12) / self.ladder[j])))

    def seed(self, theta_i_deg: np.ndarray, theta_o_deg: np.ndarray, mean: np.ndarray, std: np.ndarray,
             rungs: np.ndarray) -> None:
        """What earlier runs read (a resumed capture): per point (N) its reading converted to the reference setting
        (``mean``, ``std`` per repeat: (N, C) counts) and its rung (N), for :meth:`predict`. Needs ``ref_dark``."""
        if self.ref_dark is None or len(theta_i_deg) == 0:
            return
        nets = np.max(np.maximum(mean - self.ref_dark.mean, 0.0) + NEAR_SIGMAS * std, axis=1)
        ti = np.round(np.asarray(theta_i_deg, dtype=float), 6) + 0.0
        to = np.round(np.asarray(theta_o_deg, dtype=float), 6) + 0.0
        for t_i in np.unique(ti):  # per incidence: its outgoing angles sorted, as _remember keeps them
            sel = np.flatnonzero(ti == t_i)
            sel = sel[np.argsort(to[sel], kind="stable")]
            keep = np.r_[to[sel][1:] != to[sel][:-1], True]  # a point read twice: its last reading
            sel = sel[keep]
            self._seen[float(t_i)] = ([float(x) for x in to[sel]], [float(x) for x in nets[sel]],
                                      [int(x) for x in np.asarray(rungs)[sel]])

    # -- reading ----------------------------------------------------------------------------------------------
    def read(self, n: int, what: str, start: int | None = None, point: tuple[float, float] | None = None
             ) -> Ranged:
        """``n`` repeats, ranged: see the module docstring. ``start``: the rung to begin on; else the one
        :meth:`predict` gives for ``point`` from its neighbours; else the rung the last reading needed. A start
        that is not predicted is a guess: the search for the setting reads :data:`PROBE_REPEATS` repeats, the rest
        are read at the setting found and pooled with its probe. Raises DeviceError if even ``t_min`` saturates."""
        predicted = self.predict(point) if start is None and point is not None else None
        i = start if start is not None else predicted if predicted is not None else self._rung
        m = n if predicted is not None else min(n, PROBE_REPEATS)
        # a predicted setting is left for a more sensitive one only if the reading fits it by PREDICTION_BAND
        (i, t, rd), reads, spent = self._search(n, m, what, i, PREDICTION_BAND if predicted is not None else 1.0)
        if rd.n < n:  # the probe found the setting: the rest of the repeats there
            self._set(i)
            rest, _, repeats = read_clean(self.det.read, n - rd.n, self.retries)
            spent += repeats * t
            if rest.saturated:  # brighter than its probe (a transient that stays, a drifting source): search again
                (i, t, rd), more, again = self._search(n, n, what, i)
                reads, spent = reads + more, spent + again
            else:
                rd = pool(rd, rest)
        spent -= n * t
        gain = self._gain.get(i)
        if i == 0:
            self._rung = 0
            if point is not None:
                self._remember(point, rd, 0)
            return Ranged(rd, rd, t, reads, spent, gain)
        n_darks = len(self.darks)
        dark = self.dark_at(i)
        if len(self.darks) > n_darks:
            spent += dark.n * t
        if self.ref_dark is None:  # no calibration (a bench script's reading): measured once, now
            spent += self.reference_dark().n * self.t_ref
        ref_dark = self.reference_dark()
        r = self.sensitivity(0) / self.sensitivity(i)
        conv = Reading(ref_dark.mean + (rd.mean - dark.mean) * r, rd.std * r, rd.n, 0, rd.monitor)
        self._rung = i
        if point is not None:
            self._remember(point, conv, i)
        return Ranged(conv, rd, t, reads, spent, gain, Reading(dark.mean * r, dark.std * r, dark.n, 0))

    def _search(self, n: int, m: int, what: str, i: int, margin: float = 1.0
                ) -> tuple[tuple[int, float, Reading], int, float]:
        """Walk the ladder from rung ``i`` with readings of ``m`` repeats (of the ``n`` asked for) until one is
        clean and no more sensitive rung is predicted to fit (the reading times ``margin``): ((rung, integration
        time, reading), readings taken, integration time spent in all)."""
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
                rd, _, repeats = read_clean(self.det.read, m, self.retries)
            else:
                rd, repeats = self.det.read(m), m
            reads += 1  # one (possibly pieced) reading
            spent += repeats * t
            state = self._state(rd)
            if state == "ok":
                if best is None or i < best[0]:
                    best = (i, t, rd)
                # up the ladder once (with gains, whose noise the prediction overstates, until it stops gaining)
                if i > 0 and not upranged:
                    j = self._longest_fitting(rd, i, t, excluded, margin)
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
                            m, self._describe(i))
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
                     "saturated" if state != "near" else "near saturation", self._describe(i), rd.saturated, m,
                     self._describe(nxt))
            i = nxt
        return best, reads, spent
