"""An in-plane slice in memory: N samples (theta_i, theta_o) with C value channels (files: formats/slicefile.py).

:class:`Slice` is the data structure every method reads; ``reconstruction.formats.slicefile`` reads and writes it
as our CSV slice files; every module imports these names from here (``from reconstruction.core.slicedata import
Slice``).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.schema.slice_meta import FORMAT_VERSION, QUANTITIES  # the metadata's schema

Array = NDArray[np.float64]

_WAVELENGTH = re.compile(r"^(\d+(?:\.\d+)?)nm$")
#: Names and cells longer than this are cut in messages.
SHOW_CHARS = 60

__all__ = ["Slice", "SliceError", "channel_kind", "wavelengths_of", "to_brdf", "shorten"]


class SliceError(ValueError):
    """A slice file or slice is invalid; the message names file, line and column where it can."""


def shorten(text: str, limit: int = SHOW_CHARS) -> str:
    """``text`` for a message: as it is when short, else its start and end with the length (a 200 KB column name
    must not fill the terminal)."""
    if len(text) <= limit:
        return text
    return f"{text[:limit - 20]}...{text[-8:]} ({len(text)} characters)"


def _show_list(names: Sequence[str], limit: int = 8) -> str:
    shown = [repr(shorten(n)) for n in list(names)[:limit]]
    more = f", ... ({len(names)} in all)" if len(names) > limit else ""
    return f"[{', '.join(shown)}{more}]"


def channel_kind(channels: Sequence[str]) -> str:
    """"grey" for ``["value"]``, "rgb" for ``["R", "G", "B"]``, "spectral" for wavelength names."""
    ch = list(channels)
    if ch == ["value"]:
        return "grey"
    if ch == ["R", "G", "B"]:
        return "rgb"
    if ch and all(_WAVELENGTH.match(c) for c in ch):
        return "spectral"
    raise SliceError(
        f"value columns {_show_list(ch)} are not one of: value | R,G,B | wavelength columns such as 550nm"
    )


def wavelengths_of(channels: Sequence[str]) -> Array | None:
    """Wavelengths in nm of spectral channel names, or None for grey/RGB."""
    if channel_kind(channels) != "spectral":
        return None
    return np.array([float(_WAVELENGTH.match(c).group(1)) for c in channels])  # type: ignore[union-attr]


def to_brdf(values: ArrayLike, theta_o_deg: ArrayLike, quantity: str) -> Array:
    """Convert ``values`` (N, C) of ``quantity`` to f_r in 1/sr (theta_o in degrees)."""
    v = np.asarray(values, dtype=np.float64)
    if quantity == "brdf":
        return v
    if quantity == "reflectance_factor":
        return v / np.pi
    if quantity == "brdf_cos":
        c = np.cos(np.radians(np.asarray(theta_o_deg, dtype=np.float64)))
        return v / np.maximum(c, 1e-6)[:, None]
    raise SliceError(f"unknown quantity {quantity!r}; expected one of {', '.join(QUANTITIES)}")


@dataclass
class Slice:
    """One or more in-plane slices: N samples with C value channels.

    ``theta_i_deg``, ``theta_o_deg``: (N,) degrees; ``values``, ``std``: (N, C) in the unit of
    ``meta["quantity"]``; ``repeats``: (N,) ints; ``unix_time_s``: (N,) seconds since the epoch.
    """

    theta_i_deg: Array
    theta_o_deg: Array
    values: Array
    channels: list[str]
    std: Array | None = None
    repeats: NDArray[np.int64] | None = None
    unix_time_s: Array | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    source: str = "<memory>"

    def __post_init__(self) -> None:
        self.theta_i_deg = np.asarray(self.theta_i_deg, dtype=np.float64).reshape(-1)
        self.theta_o_deg = np.asarray(self.theta_o_deg, dtype=np.float64).reshape(-1)
        n = self.theta_i_deg.size
        channel_kind(self.channels)
        values = np.asarray(self.values, dtype=np.float64)
        if self.theta_o_deg.size != n or values.size != n * len(self.channels):
            raise SliceError(f"{self.source}: {n} theta_i, {self.theta_o_deg.size} theta_o and {values.size} values "
                             f"do not make {n} samples of channels {self.channels}")
        self.values = values.reshape(n, len(self.channels))
        self.std = (np.zeros_like(self.values) if self.std is None
                    else np.asarray(self.std, dtype=np.float64).reshape(self.values.shape))
        self.repeats = (np.ones(n, dtype=np.int64) if self.repeats is None
                        else np.asarray(self.repeats, dtype=np.int64).reshape(n))
        self.unix_time_s = (np.zeros(n) if self.unix_time_s is None
                            else np.asarray(self.unix_time_s, dtype=np.float64).reshape(n))
        self.meta = {"format_version": FORMAT_VERSION, "quantity": "brdf", **dict(self.meta)}
        if self.meta["quantity"] not in QUANTITIES:
            raise SliceError(f"{self.source}: unknown quantity {self.meta['quantity']!r}; "
                             f"expected one of {', '.join(QUANTITIES)}")

    def __len__(self) -> int:
        return int(self.theta_i_deg.size)

    @property
    def quantity(self) -> str:
        return str(self.meta["quantity"])

    @property
    def kind(self) -> str:
        """"grey", "rgb" or "spectral"."""
        return channel_kind(self.channels)

    @property
    def wavelengths_nm(self) -> Array | None:
        return wavelengths_of(self.channels)

    def brdf(self) -> tuple[Array, Array]:
        """(f_r, std of f_r), each (N, C) in 1/sr, whatever quantity the file holds."""
        return (to_brdf(self.values, self.theta_o_deg, self.quantity),
                to_brdf(self.std, self.theta_o_deg, self.quantity))

    def incidences(self) -> Array:
        """Sorted distinct theta_i (degrees)."""
        return np.unique(self.theta_i_deg)

    def take(self, idx: ArrayLike) -> Slice:
        """A new Slice holding the samples ``idx`` (index array or boolean mask)."""
        idx = np.asarray(idx)
        assert self.std is not None and self.repeats is not None and self.unix_time_s is not None
        return Slice(self.theta_i_deg[idx], self.theta_o_deg[idx], self.values[idx], list(self.channels),
                     self.std[idx], self.repeats[idx], self.unix_time_s[idx], dict(self.meta), self.source)

    def sorted(self) -> Slice:
        """Samples sorted by (theta_i, theta_o)."""
        return self.take(np.lexsort((self.theta_o_deg, self.theta_i_deg)))

    def validate(self) -> None:
        """Raise :class:`SliceError` for non-finite values, angles outside (-90, 90) or duplicate samples."""
        for name, arr in (("theta_i_deg", self.theta_i_deg), ("theta_o_deg", self.theta_o_deg)):
            bad = ~np.isfinite(arr) | (np.abs(arr) >= 90.0)
            if bad.any():
                i = int(np.argmax(bad))
                raise SliceError(f"{self.source}: sample {i}: {name} = {arr[i]} is outside (-90, 90) degrees")
        bad_v = ~np.isfinite(self.values)
        if bad_v.any():
            i, c = (int(x) for x in np.argwhere(bad_v)[0])
            raise SliceError(f"{self.source}: sample {i}, column {self.channels[c]}: value is {self.values[i, c]}")
        key = np.stack([self.theta_i_deg, self.theta_o_deg], axis=1)
        _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
        if (counts > 1).any():
            i = int(first[np.argmax(counts > 1)])
            raise SliceError(f"{self.source}: duplicate sample theta_i_deg = {self.theta_i_deg[i]}, "
                             f"theta_o_deg = {self.theta_o_deg[i]}")


#: A value is impossibly far below zero when it lies below -(NEGATIVE_SIGMAS standard deviations + NEGATIVE_FLOOR of
#: the slice's largest |value|): dark-subtracted noise scatters around zero by its standard deviation, so 5 sigma is
#: one chance in 3.5 million per sample, and the floor keeps a zero or tiny std (one repeat) from flagging noise.
NEGATIVE_SIGMAS = 5.0
NEGATIVE_FLOOR = 1e-3


def below_zero(values: ArrayLike, std: ArrayLike) -> NDArray[np.bool_]:
    """(N,) True for the samples with a channel impossibly far below zero for its uncertainty (see
    :data:`NEGATIVE_SIGMAS`); ``values``, ``std``: (N, C) in one unit (e.g. f_r in 1/sr)."""
    v = np.asarray(values, dtype=np.float64)
    s = np.asarray(std, dtype=np.float64)
    if v.size == 0:
        return np.zeros(v.shape[:1], dtype=bool)
    v = v.reshape(v.shape[0], -1)
    s = s.reshape(v.shape)
    floor = NEGATIVE_FLOOR * float(np.max(np.abs(v)))
    return np.any(v < -(NEGATIVE_SIGMAS * s + floor), axis=1)


def describe_below_zero(s: Slice, limit: int = 4) -> str | None:
    """One phrase naming the samples of ``s`` impossibly far below zero for their standard deviation (None: none),
    e.g. ``2 sample(s) below zero far beyond their uncertainty: (40, 10) f_r -0.5 +- 7e-05 (7143 sigma), ...``."""
    assert s.std is not None
    f, sd = s.brdf()
    bad = np.flatnonzero(below_zero(f, sd))
    if bad.size == 0:
        return None
    shown = []
    for i in bad[:limit]:
        c = int(np.argmin(f[i]))
        sig = -f[i, c] / sd[i, c] if sd[i, c] > 0 else float("inf")
        shown.append(f"({s.theta_i_deg[i]:g}, {s.theta_o_deg[i]:g}) f_r {f[i, c]:.4g} +- {sd[i, c]:.2g} "
                     f"({sig:.0f} sigma)")
    more = f", ... ({bad.size} in all)" if bad.size > limit else ""
    return (f"{bad.size} sample(s) below zero far beyond their uncertainty (more than {NEGATIVE_SIGMAS:g} sigma): "
            f"{', '.join(shown)}{more}")
