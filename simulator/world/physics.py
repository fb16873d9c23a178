"""Bench physics: what the detector reads for given arm angles.

Signal model (counts at gain 1, before noise)::

    S = source_power * Omega_d * R(theta_i, theta_o) * cos(theta_o) * frac(theta_i) * (t_int / t_int_ref)

with ``Omega_d`` the detector cone (``[detector].solid_angle_sr``), ``t_int_ref`` = ``[detector].integration_time_s``
(so ``source_power`` is "counts per (1/sr * sr) at gain 1 and the configured integration time"). ``R`` is the
physical reading (:func:`reconstruction.instrument.response.instrument_average`): the integral of f cos(theta_o)
over the detector's cone and the source's divergence (``[bench].source_divergence_deg``), over ``Omega_d cos(theta_o)``,
so f at the centre for a smooth BRDF and the lobe's energy for a mirror. ``frac`` is the part of the illuminated
spot that falls on the sample (:func:`reconstruction.schema.optics.footprint_fraction`): the light lost where
the spot, growing as 1 / cos theta_i, overfills it.

Room light (``[simulator].ambient``, in the units of S) reaches the detector whether the source is on or off: it
is added to S (and to its shot noise) in :meth:`BenchPhysics.expected_signal`; its flicker
(``flicker_depth`` at ``flicker_hz``) averages out over a reading here and is put on the emulated board's ADC
conversion by conversion (:class:`simulator.devices.firmware.PhysicsFeed`). The source drifts by
``source_drift_per_h`` (relative, per hour of bench time) when a reading's times are given.

A reading at gain g is ``round(g * (S + shot + input_offset + input_noise) + dark_offset + read_noise)`` clipped
to ``[0, min(saturation, 2**adc_bits - 1)]`` (with ``frontend`` set, :mod:`simulator.world.frontend`, the circuit's
own transfer at the range of g takes the place of ``g * (...) + dark_offset``: the emulated board, and
``[simulator].frontend = "netlist"``): each gain has its own offset (``g * input_offset``) and noise
(``sqrt(read_noise**2 + (g * input_noise)**2)``); ``shot`` is Poisson(S e) / e - S with ``e`` =
``electrons_per_count`` when ``shot_noise`` is on. ``[detector].gains`` lists the gains ``GAIN`` accepts. The
source arm shadows the detector when ``|theta_i + theta_o| < blind_spot_half_width_deg``: then S = 0. A bench out of
alignment (``[simulator.misalignment]``) reads at the true angles against the sample's normal
(:meth:`BenchPhysics.true_angles`).

Channels: a photodiode sees one channel, the material's reflectance weighted by the band (``[detector]
.responsivity`` x ``[bench].source_spectrum``, :mod:`reconstruction.schema.optics`), an RGB material (linear sRGB)
becoming spectra through the Mallett-Yuksel (2019) sRGB basis of colour-science. A spectrometer evaluates a
spectral material on its own grid (linear interpolation, clamped at the ends) and an RGB one through the same
basis, which converts back to the same RGB under D65; a grey material is flat.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from simulator.config import BenchConfig

log = logging.getLogger("simulator.physics")

#: Angle pairs whose physical reading is remembered per material (then the memory starts afresh).
_CACHE_SIZE = 20000



def _interp_matrix(grid: np.ndarray, src: np.ndarray) -> np.ndarray:
    """(len(grid), len(src)) matrix of linear interpolation from wavelengths ``src`` to ``grid`` (clamped)."""
    eye = np.eye(src.size)
    return np.stack([np.interp(grid, src, eye[j]) for j in range(src.size)], axis=1)


@lru_cache(maxsize=1)
def _mallett2019() -> tuple[np.ndarray, np.ndarray]:
    """colour-science's MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019: (wavelengths (W,) in nm, values (W, 3)), read
    through the disk cache (:mod:`reconstruction.cache`, keyed by colour-science's version): importing colour
    takes about 0.7 s (it imports matplotlib), most of a simulator's start, for 81 x 3 numbers."""
    from importlib.metadata import version

    from reconstruction.cache import cached_arrays

    def build() -> tuple[np.ndarray, np.ndarray]:
        from colour.recovery import MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019 as basis

        return np.asarray(basis.wavelengths, dtype=float), np.asarray(basis.values, dtype=float)

    wl, values = cached_arrays("srgb-basis-mallett2019", f"colour-science {version('colour-science')}", build)
    return wl, values


def _srgb_basis(grid: np.ndarray) -> np.ndarray:
    """(len(grid), 3): reflectance spectra of linear sRGB R, G, B (Mallett and Yuksel 2019, colour-science).

    A linear-sRGB albedo (r, g, b) becomes the spectrum r B_R + g B_G + b B_B, which converts back to (r, g, b)
    under D65 with the CIE 1931 observer, and (1, 1, 1) is a flat reflectance of 1.
    """
    wl, values = _mallett2019()
    return _interp_matrix(grid, wl) @ values


class BRDF(Protocol):
    """What the physics needs from a material (``reconstruction.core.models.Material`` satisfies it)."""

    n_channels: int
    wavelengths_nm: Any

    def eval(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray: ...


def load_material(cfg: BenchConfig) -> BRDF:
    """The ground-truth material of the config's ``[material]`` table; the tables of ``tabulated`` lobes are read
    now (a simulator that cannot load its material refuses the config before serving, rather than answering
    ``error:1`` to a reading later). Raises ValueError naming the lobe."""
    from reconstruction.core.merltable import MerlError
    from reconstruction.core.models import Material, read_lobe_table

    mat = Material.from_dict(cfg.material, cfg.base_dir)
    for i, lobe in enumerate(mat.lobes):
        try:
            read_lobe_table(lobe, f"[material].lobes[{i}]", record=False)
        except MerlError as e:
            raise ValueError(str(e)) from None
    return mat


def white_reference(cfg: BenchConfig) -> BRDF:
    """Lambertian white reference: ``reference_reflectance`` (grey) or ``reference_spectrum`` (CSV
    ``wavelength_nm,reflectance``, relative to the config file)."""
    from reconstruction.core.models import Material

    if cfg.reference_spectrum:
        path = Path(cfg.reference_spectrum)
        if not path.is_absolute():
            path = cfg.base_dir / path
        from reconstruction.schema.files import read_spectrum_csv  # the one reader, as gonio-capture's

        wl, val = read_spectrum_csv(path, "[calibration].reference_spectrum")
        albedo: Any = {"wavelengths_nm": list(wl), "values": list(val)}
    else:
        albedo = float(cfg.reference_reflectance)
    return Material.from_dict({"name": "white-reference", "lobes": [{"type": "lambert", "albedo": albedo}]},
                              cfg.base_dir)


@dataclass
class Detector:
    """Detector state that the serial protocol can change (integration time, gain)."""

    type: str
    integration_time_s: float
    ref_integration_time_s: float
    gain: float
    adc_bits: int
    saturation: float
    wavelengths_nm: np.ndarray | None = None

    @property
    def max_code(self) -> float:
        return float(min(self.saturation, 2 ** int(self.adc_bits) - 1))

    @property
    def n_channels(self) -> int:
        return 1 if self.wavelengths_nm is None else int(self.wavelengths_nm.size)


class BenchPhysics:
    """Turns arm angles (degrees) into detector readings; noise from ``rng``, saturation faults from ``faults``."""

    def __init__(self, cfg: BenchConfig, rng: np.random.Generator, faults=None, material: BRDF | None = None,
                 reference: BRDF | None = None) -> None:
        self.cfg = cfg
        s = cfg.sim
        self.rng = rng
        self.faults = faults
        self.material = material if material is not None else load_material(cfg)
        self._reference = reference
        self.sample = "TARGET"
        #: the source, switched by the board's ``SOURCE ON|OFF`` pin (a dark of a seabreeze/pm100 bench); a
        #: ``DARK`` reading is dark whatever it says
        self.source_on = True
        #: how often the source was switched (a spectrometer's scan running at a switch sees both states)
        self.source_switches = 0
        wl = s.spectrometer.grid() if cfg.detector.kind == "spectrometer" else None
        self.detector = Detector(
            type=cfg.detector.kind,
            integration_time_s=float(cfg.detector.integration_time_s),
            ref_integration_time_s=float(cfg.detector.integration_time_s),
            gain=float(s.gain),
            adc_bits=int(s.adc_bits),
            saturation=float(cfg.detector.saturation),
            wavelengths_nm=wl,
        )
        self.source_power = float(s.source_power)
        self.solid_angle = float(cfg.detector.solid_angle_sr)
        self.dark_offset = float(s.dark_offset)
        self.read_noise = float(s.read_noise)
        self.input_noise = float(s.input_noise)
        self.input_offset = float(s.input_offset)
        self.electrons_per_count = float(s.electrons_per_count)
        self.shot_noise = bool(s.shot_noise)
        self.blind_half_width = float(cfg.bench.blind_spot_half_width_deg)
        self.ambient = float(s.ambient)
        self.flicker_depth = float(s.flicker_depth)
        self.flicker_hz = float(s.flicker_hz)
        self.source_drift_per_h = float(s.source_drift_per_h)
        self.source_warmup_depth = float(s.source_warmup_depth)
        self.source_warmup_s = float(s.source_warmup_s)
        #: the amplifier's real gain over its nominal one, by nominal gain ([simulator].gain_errors)
        self.gain_factors = {float(g): 1.0 + float(e) for g, e in zip(sorted(cfg.detector.gains or ()),
                                                                       s.gain_errors, strict=False)}
        self.gains = cfg.detector.gains
        from reconstruction.instrument.response import Instrument

        b = cfg.bench
        self.instrument = Instrument(self.solid_angle, float(b.source_divergence_deg), b.beam_diameter_mm,
                                     b.sample_diameter_mm)
        #: the amplifier's circuit (:class:`simulator.world.frontend.FrontEnd`) or None: the formula above
        self.frontend = None
        if getattr(s, "frontend", "ideal") == "netlist":
            from simulator.world.frontend import load_frontend

            self.frontend = load_frontend()
        self._band_cache: dict[int, np.ndarray] = {}
        self._fc_cache: dict[int, dict[tuple[float, float], np.ndarray]] = {}

    def warm_up(self) -> None:
        """Do the slow first-time work now (``gonio-sim serve`` calls it before the ports serve: imports, the
        band's sRGB basis, the first integration): a first reading must not take longer than a controller's reply
        deadline."""
        for mat in (self.material, self.reference):
            self.f_cos(30.0, 20.0, mat)

    @property
    def reference(self) -> BRDF:
        if self._reference is None:
            self._reference = white_reference(self.cfg)
        return self._reference

    @property
    def active_material(self) -> BRDF:
        return self.reference if self.sample == "REF" else self.material

    # -- channels ----------------------------------------------------------------------------------------------
    def to_detector_channels(self, f: np.ndarray, mat: BRDF) -> np.ndarray:
        """Map material channels (..., C) to detector channels (..., n_det)."""
        det = self.detector
        if det.wavelengths_nm is None:
            return f @ self._band_vector(f.shape[-1], mat)[:, None]
        grid = det.wavelengths_nm
        c = f.shape[-1]
        wl = getattr(mat, "wavelengths_nm", None)
        if c == 1:
            return np.broadcast_to(f, f.shape[:-1] + (grid.size,)).copy()
        if wl is not None and np.asarray(wl).size == c:
            m = _interp_matrix(np.asarray(grid, dtype=float), np.asarray(wl, dtype=float))
        elif c == 3:
            m = _srgb_basis(np.asarray(grid, dtype=float))
        else:
            raise ValueError(f"cannot map {c} material channels to a spectrometer grid")
        return f @ m.T  # linear in the channels: (..., C) -> (..., n_det)

    def _band_vector(self, c: int, mat: BRDF) -> np.ndarray:
        """(C,) weights of the material's channels in the photodiode's one channel (they sum to 1)."""
        v = self._band_cache.get(id(mat))
        if v is not None and v.size == c:
            return v
        from reconstruction.schema.optics import BAND_NM

        w = self.cfg.detector.band_weights
        wl = getattr(mat, "wavelengths_nm", None)
        if c == 1:
            v = np.ones(1)
        elif w is None:  # no band known: the mean of the channels
            v = np.full(c, 1.0 / c)
        elif wl is not None and np.asarray(wl).size == c:
            v = w @ _interp_matrix(BAND_NM, np.asarray(wl, dtype=float))
        elif c == 3:
            v = w @ _srgb_basis(BAND_NM)
        else:
            raise ValueError(f"cannot map {c} material channels to the photodiode's band")
        self._band_cache[id(mat)] = v
        return v

    # -- geometry ----------------------------------------------------------------------------------------------
    def f_cos(self, theta_i_deg, theta_o_deg, mat: BRDF | None = None) -> np.ndarray:
        """The physical reading R(theta_i, theta_o) * cos(theta_o) (1/sr; see the module docstring) on the
        detector channels: (..., n_det). Angles in degrees; each angle pair is integrated once and remembered
        (the arms stop at whole controller units, so a capture reads the same pairs again)."""
        from reconstruction.instrument.response import instrument_average

        mat = mat if mat is not None else self.active_material
        ti, to = np.broadcast_arrays(np.asarray(theta_i_deg, dtype=float), np.asarray(theta_o_deg, dtype=float))
        pairs = np.stack([ti.ravel(), to.ravel()], axis=1)
        uniq, inv = np.unique(pairs, axis=0, return_inverse=True)
        cache = self._fc_cache.setdefault(id(mat), {})
        keys = [(float(a), float(b)) for a, b in uniq]
        todo = [i for i, k in enumerate(keys) if k not in cache]
        if todo:
            if len(cache) > _CACHE_SIZE:
                cache.clear()
            u = uniq[todo]
            r = np.asarray(instrument_average(mat, u[:, 0], u[:, 1], self.instrument), dtype=float)
            fc = r * np.clip(np.cos(np.radians(u[:, 1])), 0.0, None)[:, None]
            for i, row in zip(todo, self.to_detector_channels(fc, mat), strict=True):
                cache[keys[i]] = row
        out = np.stack([cache[k] for k in keys])[np.asarray(inv).ravel()]
        return out.reshape(ti.shape + out.shape[-1:])

    def true_angles(self, theta_i_deg: np.ndarray, theta_o_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The angles (degrees) against the normal of the sample in the beam for the arms' angles: the arms' own
        with no ``[simulator.misalignment]``, else through its zero offsets, the sample's (or the white
        reference's) tilt and the surface's offset from the axis
        (:func:`reconstruction.instrument.alignment.true_angles`; the detector at ``[bench].detector_distance_mm``,
        70 mm when not given)."""
        m = self.cfg.sim.misalignment
        if not m.active:
            return theta_i_deg, theta_o_deg
        from reconstruction.instrument.alignment import true_angles

        if self.sample == "REF":
            tilt = m.reference_tilt_deg
        else:
            tilt = -m.sample_tilt_deg if m.sample_turned else m.sample_tilt_deg
        return true_angles(theta_i_deg, theta_o_deg, m.light_zero_deg, m.detector_zero_deg, tilt,
                           m.surface_offset_mm, self.cfg.bench.detector_distance_mm or 70.0)

    def source_scale(self, t_s) -> np.ndarray:
        """The source's power relative to nominal at bench times ``t_s`` (s): its drift and its warm-up,
        ``(1 + source_drift_per_h * t / 3600) * (1 - source_warmup_depth * exp(-t / source_warmup_s))``."""
        t = np.asarray(t_s, dtype=float)
        return (1.0 + self.source_drift_per_h * t / 3600.0) * \
            (1.0 - self.source_warmup_depth * np.exp(-t / self.source_warmup_s))

    def ambient_signal(self, integration_time_s: float | None = None) -> float:
        """The room light's mean signal (counts at gain 1) over an integration time: ``[simulator].ambient``
        scaled from the configured integration time; its flicker averages out."""
        t_int = self.detector.integration_time_s if integration_time_s is None else integration_time_s
        return self.ambient * t_int / self.detector.ref_integration_time_s

    def expected_signal(self, theta_i_deg, theta_o_deg, source_on: bool = True,
                        integration_time_s: float | None = None, t_s=None) -> np.ndarray:
        """Noise-free signal S in counts at gain 1, before dark offset: (..., n_det); 0 in the blind spot; the
        room light added whether the source is on or not. ``t_s``: the bench time of each reading (s, broadcast
        with the angles) for the source's drift (none without)."""
        t_int = self.detector.integration_time_s if integration_time_s is None else integration_time_s
        ti = np.asarray(theta_i_deg, dtype=float)
        to = np.asarray(theta_o_deg, dtype=float)
        room = self.ambient_signal(t_int)
        if not source_on:
            return np.full(np.broadcast_shapes(ti.shape, to.shape) + (self.detector.n_channels,), room)
        arm_ti, arm_to = ti, to
        ti, to = self.true_angles(ti, to)
        fc = self.f_cos(ti, to)
        from reconstruction.schema.optics import footprint_fraction

        s = self.source_power * fc * self.solid_angle * (t_int / self.detector.ref_integration_time_s)
        s = s * footprint_fraction(ti, self.cfg.bench.beam_diameter_mm, self.cfg.bench.sample_diameter_mm)[..., None]
        blind = np.abs(arm_ti + arm_to) < self.blind_half_width
        s = np.where(blind[..., None], 0.0, s)
        if t_s is not None and (self.source_drift_per_h or self.source_warmup_depth):
            s = s * self.source_scale(np.broadcast_to(t_s, blind.shape))[..., None]
        return s + room

    def expected_reading(self, theta_i_deg, theta_o_deg, source_on: bool = True) -> np.ndarray:
        """Noise-free reading (counts): gain * S + dark, clipped to the detector range (not quantised)."""
        s = self.expected_signal(theta_i_deg, theta_o_deg, source_on)
        return np.clip(self._amplify(s + self.input_offset), 0.0, self.detector.max_code)

    def range_index(self, gain: float | None = None) -> int:
        """The amplifier's range (multiplexer channel) of ``gain`` (default: the present one): its place in
        ``[detector].gains`` (the nearest), 0 without a list."""
        g = self.detector.gain if gain is None else gain
        if not self.gains:
            return 0
        return int(np.argmin(np.abs(np.log(np.asarray(self.gains, dtype=float) / g))))

    def _amplify(self, x_in: np.ndarray) -> np.ndarray:
        """Counts at gain 1 (signal + offset referred to the input) -> the reading before the ADC's noise: the
        formula, or the circuit's transfer when ``frontend`` is set."""
        det = self.detector
        if self.frontend is None:
            return self.real_gain() * x_in + self.dark_offset
        # a resistor's error ([simulator].gain_errors) scales the range's output above Vref as a photocurrent would
        factor = self.gain_factors.get(float(det.gain), 1.0)
        return self.frontend.reading_counts(x_in * factor, self.range_index(), det.integration_time_s)

    def real_gain(self, gain: float | None = None) -> float:
        """The amplifier's real gain at nominal ``gain`` (default: the present one): ``[simulator].gain_errors``."""
        g = self.detector.gain if gain is None else gain
        return g * self.gain_factors.get(float(g), 1.0)

    def noise_rms(self, gain: float | None = None) -> float:
        """Dark-reading noise (counts rms) at ``gain`` (default: the present one): ADC and amplifier."""
        g = self.detector.gain if gain is None else gain
        return float(np.hypot(self.read_noise, g * self.input_noise))

    def read(self, theta_i_deg, theta_o_deg, source_on: bool = True, t_s=None) -> tuple[np.ndarray, np.ndarray]:
        """Noisy readings for arrays of angles (one per repeat): (codes (n, n_det) float, saturated (n,) bool);
        ``t_s``: the repeats' bench times (s) for the source's drift."""
        ti = np.atleast_1d(np.asarray(theta_i_deg, dtype=float))
        to = np.atleast_1d(np.asarray(theta_o_deg, dtype=float))
        s = self.expected_signal(ti, to, source_on, t_s=None if t_s is None else np.atleast_1d(t_s))
        det = self.detector
        if self.shot_noise:
            e = self.electrons_per_count
            s = self.rng.poisson(np.maximum(s, 0.0) * e).astype(float) / e if e != 1.0 else \
                self.rng.poisson(np.maximum(s, 0.0)).astype(float)
        if self.input_noise > 0:
            s = s + self.input_noise * self.rng.standard_normal(s.shape)
        x = self._amplify(s + self.input_offset)
        if self.read_noise > 0:
            x = x + self.read_noise * self.rng.standard_normal(x.shape)
        x = np.round(x)
        top = det.max_code
        forced = self.faults.saturate(x.shape[0]) if self.faults is not None else np.zeros(x.shape[0], bool)
        if forced.any():
            x[forced] = top
        sat = (x >= top).any(axis=-1) | forced
        x = np.clip(x, 0.0, top)
        return x, sat
