"""Is the white reference what it claims to be? A plausibility check of its reading, run before the sweep.

A relative calibration divides every sample by the white reference's signal, so a wrong reference makes every f_r
wrong by the same factor with a normal-looking log: a new user who pressed Enter at the operator prompt without
mounting the panel calibrated against the sample itself (every f_r 2.68 times too high, issue 49). The reading is
doubtful, and named in a warning before the first point, when:

* against the dark: its signal (reference - dark) is less than :data:`MIN_SNR` times its uncertainty (the
  combined standard deviations of the means): the beam is blocked, the source off, the panel missing;
* against the expected reflectance: the sample, read once at the reference geometry, gives at least
  :data:`MAX_SAMPLE_FRACTION` of the reference's signal, i.e. a reflectance factor of at least that fraction of the
  panel's (``[calibration].reference_reflectance``) in the panel's own (diffuse) geometry: a reference no
  brighter than the sample there is most likely the sample. This costs one reading of the sample and is taken when
  the reference was mounted by hand (no sample changer: the operator prompt), the case that goes wrong;
* against the previous reference (a re-reading within the capture, e.g. ``examples/reference_every_n.py``): the
  signal changed by more than :data:`MAX_CHANGE` of the previous one.

:func:`reference_doubts` is the rule (pure, on readings); :func:`check_reference` the plan step of the capture.
"""

from __future__ import annotations

import logging
from collections.abc import Generator
from typing import Any

import numpy as np

from acquisition.calibration import Reading
from acquisition.plans.messages import Msg, Read

log = logging.getLogger("acquisition.plans")

__all__ = ["MIN_SNR", "MAX_SAMPLE_FRACTION", "MAX_CHANGE", "reference_doubts", "check_reference"]

#: the reference's signal must exceed this many standard deviations of (reference - dark)
MIN_SNR = 10.0
#: a sample reading at least this fraction of the reference's signal in the reference geometry makes it doubtful
MAX_SAMPLE_FRACTION = 0.9
#: a re-read reference whose signal moved by more than this fraction of the previous one is doubtful
MAX_CHANGE = 0.2


def _signal(rd: Reading, dark: Reading) -> tuple[float, float]:
    """(mean signal over channels, its standard deviation) of ``rd`` above ``dark``, in counts."""
    s = np.asarray(rd.mean, dtype=float) - np.asarray(dark.mean, dtype=float)
    sd = np.sqrt(np.asarray(rd.std_of_mean, dtype=float) ** 2 + np.asarray(dark.std_of_mean, dtype=float) ** 2)
    return float(np.mean(s)), float(np.sqrt(np.mean(sd ** 2)))


def reference_doubts(ref: Reading, dark: Reading, sample: Reading | None = None, rho_ref: Any = None,
                     previous: Reading | None = None) -> list[str]:
    """Why the white reference reading ``ref`` is doubtful (empty: plausible), against ``dark``, the ``sample``
    read in the same geometry (with the panel's reflectance ``rho_ref``, a number or per channel) and the
    ``previous`` reference reading; one phrase each (module docstring)."""
    out = []
    sig, sd = _signal(ref, dark)
    if not sig > MIN_SNR * sd:
        out.append(f"its signal above the dark, {sig:.4g} counts, is less than {MIN_SNR:g} times its uncertainty "
                   f"({sd:.2g} counts): is the beam blocked, the source off or the panel missing?")
    if sample is not None and sig > 0:
        frac = _signal(sample, dark)[0] / sig
        if frac >= MAX_SAMPLE_FRACTION:
            rho = float(np.mean(rho_ref)) if rho_ref is not None else 1.0
            out.append(f"the sample in the same geometry gives {frac:.0%} of its signal (a reflectance factor of "
                       f"{frac * rho:.2f} against the panel's {rho:.2f}): a reference no brighter than the sample is "
                       "most likely the sample itself; was the white reference mounted?")
    if previous is not None:
        was = _signal(previous, dark)[0]
        if was > 0 and abs(sig - was) > MAX_CHANGE * was:
            out.append(f"its signal {sig:.4g} counts differs from the previous reference's {was:.4g} by "
                       f"{(sig - was) / was:+.0%} (more than {MAX_CHANGE:.0%}): another panel, or the panel moved?")
    return out


def check_reference(ref: Reading, dark: Reading, repeats: int, rho_ref: Any, by_hand: bool
                    ) -> Generator[Msg, Any, list[str]]:
    """The capture's check of its white reference, before the sweep (the sample is in place, the arms at the
    reference geometry): with ``by_hand`` (the reference came through the operator prompt) the sample is read once
    there. Logs a warning naming each doubt; returns them."""
    sample = None
    if by_hand:  # the operator has mounted the sample again (white_reference's end): read it where the panel was
        sample, _ = yield Read(repeats, "the sample at the reference geometry (checking the white reference)", rung=0)
    doubts = reference_doubts(ref, dark, sample, rho_ref)
    for why in doubts:
        log.warning("white reference doubtful: %s", why)
    return doubts
