"""Reading reconstruction inputs: our slice files and generic in-plane CSV tables from other instruments.

Two kinds of file are accepted (told apart by the first line):

* slice files (``# gonio-brdf slice``, docs/formats.md), read with
:func:`reconstruction.formats.slicefile.read_slice`;
  their metadata says which quantity they hold, and row order is free (captures may be scheduled);
* generic tables: optional ``#`` comment lines, a header line, then one row per sample, separated by commas,
  semicolons or tabs. Columns:

  - the incidence angle (degrees; radians with ``angles_in="radians"``, the CLI's ``--angles-in radians``:
    angles all within +-1.6 are refused as radians read as degrees): ``theta_i_deg``, ``theta_i``,
    ``incidence_deg`` or ``incidence``;
  - the measured (outgoing) angle, signed, positive on the specular side (degrees): ``theta_o_deg``,
    ``theta_o``, ``outgoing_deg`` or ``outgoing``;
  - the values: ``value`` (one channel), ``R,G,B``, or one column per wavelength (``450nm``, ``450 nm``,
    ``450.5nm``); optionally ``<name>_std`` per value column, ``repeats`` and ``unix_time_s``; ``tilt_deg`` or
    ``phi_i_deg, phi_o_deg`` for rows out of the plane (:mod:`reconstruction.formats.directions`).

  Other names are mapped with ``columns={"theta_i": NAME, "theta_o": NAME, "value": NAME}`` (the CLI's
  ``--columns theta_i=NAME,theta_o=NAME``); any column left unknown is an error. Generic tables do not say what
  their values are, so ``quantity`` (``brdf``, ``reflectance_factor`` or ``brdf_cos``) is required. Rows may
  come in any order (a capture's own order, incidences interleaved), but no (theta_i, theta_o) twice.

In both kinds, rows whose values are all exactly zero in the blind spot around the retro direction
(|theta_i + theta_o| <= ``blind_spot_deg``, and zero rows contiguous with them) are missing data, not measured
zeros: they are dropped and counted, and the methods interpolate across the hole.

Errors are :class:`InputError` with ``file:line, column NAME: what was expected``.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from reconstruction.base import ReconstructionError
from reconstruction.core.samples import thin_samples
from reconstruction.core.slicedata import Slice, SliceError, channel_kind, shorten
from reconstruction.formats.angleunits import to_degrees
from reconstruction.formats.directions import (
    RowsWithDirections,
    as_points,
    role_of,
    row_keys,
    same_rows,
    with_directions,
)
from reconstruction.formats.merl import MAX_CELL_VALUE
from reconstruction.formats.slicefile import MAGIC, MAX_REPEATS, read_input_text, read_slice
from reconstruction.schema.files import UserFileError, open_user_csv, read_user_bytes
from reconstruction.schema.slice_meta import QUANTITIES

Array = NDArray[np.float64]

__all__ = [
    "InputError",
    "LoadedInput",
    "DEFAULT_BLIND_SPOT_DEG",
    "MAX_BRDF",
    "MIN_SAMPLES",
    "parse_columns",
    "read_input",
    "read_table",
    "load_inputs",
    "drop_blind_spot_zeros",
    "check_slice",
]

#: Largest |f_r| (and standard deviation of f_r) an input may hold, 1/sr: far above any real BRDF, low enough
#: that f cos cos and the fits' weights stay finite.
MAX_BRDF = MAX_CELL_VALUE
DEFAULT_BLIND_SPOT_DEG = 10.0  # half width of the retro blind spot, in |theta_i + theta_o| (degrees)
MIN_SAMPLES = 3  # fewer samples cannot define any reconstruction

THETA_I_NAMES = ("theta_i_deg", "theta_i", "incidence_deg", "incidence")
THETA_O_NAMES = ("theta_o_deg", "theta_o", "outgoing_deg", "outgoing")
COLUMN_KEYS = ("theta_i", "theta_o", "value", "R", "G", "B", "tilt", "phi_i", "phi_o")
_WAVELENGTH = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*nm\s*$", re.IGNORECASE)


class InputError(ReconstructionError):
    """An input file cannot be used; the message names file, line and column where it can."""


@dataclass
class LoadedInput:
    """Samples of all inputs merged, converted to f_r (1/sr), plus what was done to them.

    ``slice`` holds quantity ``brdf`` in the files' own channels (grey, RGB or spectral).
    """

    slice: Slice
    files: list[str]
    quantities: list[str]
    dropped_blind_spot: int = 0
    notes: list[str] = field(default_factory=list)
    #: the first slice file's whole metadata and its path ({"file", "meta"}), which records its bench (the advice's
    #: limits: reconstruction.assess.advice.capture_limits); empty for generic tables
    capture: dict[str, object] = field(default_factory=dict)


def parse_columns(spec: str | None) -> dict[str, str]:
    """Parse ``"theta_i=Inc,theta_o=Det"`` into ``{"theta_i": "Inc", "theta_o": "Det"}``."""
    if not spec:
        return {}
    out: dict[str, str] = {}
    for part in spec.split(","):
        key, sep, name = part.partition("=")
        key, name = key.strip(), name.strip()
        if not sep or not key or not name:
            raise InputError(f"--columns: expected KEY=NAME pairs separated by commas, got {part!r}")
        if key not in COLUMN_KEYS:
            raise InputError(f"--columns: unknown key {key!r}; expected one of {', '.join(COLUMN_KEYS)}")
        if key in out:
            raise InputError(f"--columns: {key} given twice")
        out[key] = name
    return out


# --- generic tables --------------------------------------------------------------------------------------


def _canonical_value_name(name: str) -> str | None:
    """``value``, ``R``/``G``/``B`` or ``<wavelength>nm`` for a value column name (any letter case), else None."""
    low = name.strip().lower()
    if low == "value":
        return "value"
    if low in ("r", "g", "b"):
        return low.upper()
    m = _WAVELENGTH.match(low)
    if m:
        wl = float(m.group(1))
        return f"{int(wl)}nm" if wl == int(wl) else f"{wl}nm"
    return None


def _column_list(names: Sequence[str], limit: int = 12) -> str:
    shown = ", ".join(shorten(n) for n in list(names)[:limit])
    return shown + (f", ... ({len(names)} columns)" if len(names) > limit else "")


def read_table(path: str | Path, *, quantity: str | None, columns: Mapping[str, str] | None = None,
               angles_in: str = "degrees") -> Slice:
    """Read a generic in-plane CSV table (see the module docstring) into a :class:`Slice` of ``quantity``, its
    angles in ``angles_in`` (:mod:`reconstruction.formats.angleunits`: radians read as degrees are refused)."""
    path = Path(path)
    columns = dict(columns or {})
    table = open_user_csv(path, "a CSV file", error=InputError, delimiters=(",", ";", "\t"), quoted=True,
                          read_text=lambda p: read_input_text(p, InputError, "a CSV file"))
    if not table.text.strip():
        raise InputError(f"{path}: empty file")
    if quantity is None:
        raise InputError(f"{path}: a generic table does not say what its values are; pass --quantity "
                         f"{'|'.join(QUANTITIES)}")
    if quantity not in QUANTITIES:
        raise InputError(f"--quantity: unknown quantity {quantity!r}; expected one of {', '.join(QUANTITIES)}")
    if not table.header_line:
        raise InputError(f"{path}: no header line (only comments or blank lines)")
    header, hline = table.header, table.header_line
    role = _header_roles(path, hline, header, columns)
    value_cols, channels, std_cols = _value_channels(path, hline, header, role)
    names_by_role = {r: header[k] for k, r in role.items()}
    data, line_of = table.rows(nan_hint=" (leave missing samples out)")
    del table
    if not len(data):
        raise InputError(f"{path}: no samples (the table has a header but no rows)")
    lines_arr = line_of
    ti = data[:, [k for k, r in role.items() if r == "theta_i"][0]]
    to = data[:, [k for k, r in role.items() if r == "theta_o"][0]]
    ti, to = to_degrees(path, ti, to, shorten(names_by_role["theta_i"]), shorten(names_by_role["theta_o"]),
                        angles_in, InputError)
    for name, arr in (("theta_i", ti), ("theta_o", to)):
        out = np.abs(arr) >= 90.0
        if out.any():
            r = int(np.argmax(out))
            raise InputError(f"{path}:{line_of[r]}, column {shorten(names_by_role[name])}: {arr[r]} is outside "
                             f"(-90, 90) degrees")
    dirs = {r: data[:, k] for k, r in role.items() if r in ("tilt", "phi_i", "phi_o")}  # rows out of the plane
    _check_duplicates(path, ti, to, lines_arr, shorten(names_by_role["theta_o"]), *dirs.values())
    values = data[:, value_cols]
    std = np.zeros_like(values)
    for c, k in std_cols.items():
        std[:, channels.index(c)] = data[:, k]
    if (std < 0).any():
        r, c = (int(x) for x in np.argwhere(std < 0)[0])
        raise InputError(f"{path}:{line_of[r]}, column {shorten(header[std_cols[channels[c]]])}: a standard "
                         f"deviation must be >= 0, got {std[r, c]}")
    repeats = data[:, [k for k, r in role.items() if r == "repeats"][0]] if "repeats" in role.values() else None
    times = data[:, [k for k, r in role.items() if r == "unix_time_s"][0]] if "unix_time_s" in role.values() \
        else None
    if repeats is not None:
        badr = ~((repeats >= 1) & (repeats <= MAX_REPEATS)) | (repeats != np.round(repeats))
        if badr.any():
            r = int(np.argmax(badr))
            raise InputError(f"{path}:{line_of[r]}, column repeats: expected a positive integer, got {repeats[r]}")
    s = Slice(ti, to, values, channels, std, repeats, times,
              meta={"quantity": quantity, "source_kind": "generic table"},
              source=str(path))
    try:
        return with_directions(s, dirs, str(path), lines_arr)  # s itself without direction columns
    except SliceError as e:
        raise InputError(str(e)) from None


def _header_roles(path: Path, hline: int, header: list[str], columns: dict[str, str]) -> dict[int, str]:
    """Each column's role ("theta_i", "theta_o", a value channel, "<channel>_std", "repeats", "unix_time_s"), from
    the header's names (line ``hline``) and ``--columns``."""
    if len(set(header)) != len(header):
        dup = next(c for c in header if header.count(c) > 1)
        raise InputError(f"{path}:{hline}, column {shorten(dup)}: the column name appears twice")
    lower = [c.lower() for c in header]  # known names match in any letter case (Value, THETA_I_DEG)

    def index_of(name: str) -> int | None:
        if name in header:
            return header.index(name)
        return lower.index(name.lower()) if name.lower() in lower else None

    for key, name in columns.items():
        if index_of(name) is None:
            raise InputError(f"{path}:{hline}: --columns {key}={shorten(name)}: no such column; the columns are "
                             f"{_column_list(header)}")
    role: dict[int, str] = {}  # column index -> role ("theta_i", "theta_o", value name, "<value>_std", ...)
    for key, name in columns.items():
        role[index_of(name)] = key  # type: ignore[index]
    for key, names in (("theta_i", THETA_I_NAMES), ("theta_o", THETA_O_NAMES)):
        if key in columns:
            continue
        found = [k for k in (index_of(n) for n in names) if k is not None]
        if not found:
            raise InputError(f"{path}:{hline}: no {key} column (looked for {', '.join(names)}); the columns are "
                             f"{_column_list(header)}; map one with --columns {key}=NAME")
        role[found[0]] = key
    renamed = {name.lower(): key for key, name in columns.items() if key not in ("theta_i", "theta_o")}
    for k, name in enumerate(header):
        if k in role:
            continue
        low = name.lower()
        is_std = low.endswith("_std")
        base = name[:-4] if is_std else name
        canon = renamed.get(base.lower()) or _canonical_value_name(base)
        if low in ("repeats", "unix_time_s") or role_of(low):
            role[k] = role_of(low) or low
        elif canon is not None and is_std:
            role[k] = canon + "_std"
        elif canon is not None:
            role[k] = canon
        elif low in THETA_I_NAMES + THETA_O_NAMES:
            raise InputError(f"{path}:{hline}, column {name}: a second angle column; map the one to use with "
                             f"--columns")
        else:
            raise InputError(f"{path}:{hline}, column {shorten(name)}: unknown column; expected theta_i/theta_o angle "
                             f"columns, value, R,G,B or wavelength columns such as 450nm (with optional _std "
                             f"columns), repeats, unix_time_s; map other names with --columns theta_i=NAME,"
                             f"theta_o=NAME")
    return role


def _value_channels(path: Path, hline: int, header: list[str], role: dict[int, str]
                    ) -> tuple[list[int], list[str], dict[str, int]]:
    """The value columns in channel order, the channel names, and each channel's _std column."""
    value_cols = [k for k in range(len(header)) if role[k] in ("value", "R", "G", "B") or role[k].endswith("nm")]
    channels = [role[k] for k in value_cols]
    if not channels:
        raise InputError(f"{path}:{hline}: no value columns; expected value, R,G,B or wavelength columns such "
                         f"as 450nm")
    if len(set(channels)) != len(channels):
        raise InputError(f"{path}:{hline}: two columns give the same channel {_column_list(channels)}")
    if all(c.endswith("nm") for c in channels):
        order = np.argsort([float(c[:-2]) for c in channels], kind="stable")
        value_cols = [value_cols[i] for i in order]
        channels = [channels[i] for i in order]
    elif set(channels) == {"R", "G", "B"}:
        value_cols = [value_cols[channels.index(c)] for c in ("R", "G", "B")]
        channels = ["R", "G", "B"]
    try:
        channel_kind(channels)
    except SliceError as e:
        raise InputError(f"{path}:{hline}: {e}") from None
    std_cols = {role[k][:-4]: k for k in role if role[k].endswith("_std")}
    for c in std_cols:
        if c not in channels:
            raise InputError(f"{path}:{hline}, column {shorten(header[std_cols[c]])}: a _std column without its "
                             f"value column")
    return value_cols, channels, std_cols


def _check_duplicates(path: Path, ti: Array, to: Array, line_of: NDArray[np.int_], to_name: str, *more: Array
                      ) -> None:
    """Rows in any order (a capture's own order included), but no (theta_i, theta_o) twice (with the same
    direction columns ``more``): the later row is named with the line of the earlier (vectorised: one sort)."""
    if ti.size < 2:
        return
    order = np.lexsort((line_of, *more, to, ti))  # by incidence, angle, then file order
    same = np.all([a[order][1:] == a[order][:-1] for a in (ti, to, *more)], axis=0)
    if not same.any():
        return
    k = np.nonzero(same)[0]
    later, earlier = order[k + 1], order[k]
    j = int(np.argmin(line_of[later]))  # the first repeated row in the file
    r, p = int(later[j]), int(earlier[j])
    raise InputError(f"{path}:{line_of[r]}, column {to_name}: duplicate sample theta_i = {ti[r]}, theta_o = "
                     f"{to[r]} (also at line {line_of[p]})")


# --- any input -------------------------------------------------------------------------------------------


def _is_slice_file(path: Path) -> bool:
    try:
        first = read_user_bytes(path, "a slice file or a CSV table", read=len(MAGIC) + 16)
    except UserFileError as e:
        raise InputError(str(e)) from None
    text = first.decode("utf-8", "replace").lstrip("\ufeff")  # a byte-order mark; any line ending
    return text.replace("\r", "\n").split("\n")[0].strip() == MAGIC


def read_input(path: str | Path, *, quantity: str | None = None, columns: Mapping[str, str] | None = None,
               angles_in: str = "degrees") -> Slice:
    """Read one input file, slice file or generic table, into a :class:`Slice` in its own quantity, its angles in
    degrees (the file's in ``angles_in``: :mod:`reconstruction.formats.angleunits`)."""
    path = Path(path)
    if _is_slice_file(path):
        try:
            s = read_slice(path)
        except SliceError as e:
            raise InputError(str(e)) from None
        ti, to = to_degrees(path, s.theta_i_deg, s.theta_o_deg, "theta_i_deg", "theta_o_deg", angles_in, InputError)
        s = dataclasses.replace(s, theta_i_deg=ti, theta_o_deg=to)
        if columns:
            raise InputError(f"{path}: --columns applies to generic tables; this is a gonio-brdf slice file")
        if quantity is not None and quantity != s.quantity:
            raise InputError(f"{path}: the file says quantity {s.quantity!r}; --quantity {quantity} disagrees")
        return s
    return read_table(path, quantity=quantity, columns=columns, angles_in=angles_in)


def drop_blind_spot_zeros(s: Slice, half_width_deg: float = DEFAULT_BLIND_SPOT_DEG) -> tuple[Slice, int]:
    """Drop rows that are all exactly zero in the retro blind spot (missing data); returns (slice, dropped).

    A zero row is missing when |theta_i + theta_o| <= ``half_width_deg`` (degrees) or when it is contiguous, in
    theta_o order at the same incidence, with such a row (a shadow wider than assumed).
    """
    if len(s) == 0:
        return s, 0
    missing = blind_spot_missing(s.theta_i_deg, s.theta_o_deg, s.values, half_width_deg)
    n = int(missing.sum())
    return (s.take(~missing) if n else s), n


def blind_spot_missing(theta_i_deg: NDArray[np.float64], theta_o_deg: NDArray[np.float64],
                       values: NDArray[np.float64], half_width_deg: float = DEFAULT_BLIND_SPOT_DEG
                       ) -> NDArray[np.bool_]:
    """The blind-spot rule of the whole reconstruction: True for the rows (N,) of ``values`` (N, C) that are
    missing data, not measured zeros: rows that are all exactly zero where |theta_i + theta_o| <=
    ``half_width_deg`` (degrees), and the zero rows contiguous with them in theta_o order at the same incidence
    (a shadow wider than assumed). Used by :func:`drop_blind_spot_zeros` and by revolve's incidence preparation.
    """
    n = len(theta_i_deg)
    if n == 0:
        return np.zeros(0, dtype=bool)
    order = np.lexsort((theta_o_deg, theta_i_deg))
    zero = np.all(np.asarray(values)[order] == 0.0, axis=1)
    ti = np.asarray(theta_i_deg)[order]
    near = np.abs(ti + np.asarray(theta_o_deg)[order]) <= half_width_deg
    change = np.r_[True, (zero[1:] != zero[:-1]) | (ti[1:] != ti[:-1])]
    run = np.cumsum(change) - 1
    run_near = np.bincount(run, weights=(near & zero).astype(float)) > 0
    missing = np.zeros(n, dtype=bool)
    missing[order] = zero & run_near[run]
    return missing


def _merge(slices: Sequence[Slice]) -> Slice:
    first = slices[0]
    for s in slices[1:]:
        if s.channels != first.channels:
            raise InputError(f"{s.source}: value columns {s.channels} differ from {first.source}'s "
                             f"{first.channels}; all inputs must have the same channels")
    inst = first.meta.get("instrument")
    for s in slices[1:]:
        if s.meta.get("instrument") != inst:
            raise InputError(f"{s.source}: its metadata's instrument {s.meta.get('instrument')} differs from "
                             f"{first.source}'s {inst}; reconstruct inputs taken with different instruments "
                             f"separately")
    cat = np.concatenate
    assert all(s.std is not None and s.repeats is not None and s.unix_time_s is not None for s in slices)
    merged = Slice(cat([s.theta_i_deg for s in slices]), cat([s.theta_o_deg for s in slices]),
                   cat([s.values for s in slices]), list(first.channels), cat([s.std for s in slices]),  # type: ignore[misc]
                   cat([s.repeats for s in slices]), cat([s.unix_time_s for s in slices]),  # type: ignore[misc]
                   meta={"quantity": "brdf", **({"instrument": inst} if inst is not None else {})},
                   source=", ".join(s.source for s in slices))
    key = np.concatenate([row_keys(s) for s in slices])  # (theta_i, theta_o) and the directions
    _, first_idx, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    dup = np.nonzero(np.arange(len(merged)) != first_idx[inverse.reshape(-1)])[0]
    if dup.size:
        owner = np.repeat(np.arange(len(slices)), [len(s) for s in slices])
        r = int(dup[0])
        o = int(first_idx[inverse.reshape(-1)[r]])
        raise InputError(f"{slices[owner[r]].source}: sample theta_i = {key[r, 0]}, theta_o = {key[r, 1]} is also "
                         f"in {slices[owner[o]].source}; inputs must not overlap")
    return merged


def _check_bounds(s: Slice, f: Array, sd: Array) -> None:
    """f_r and its standard deviation within [-MAX_BRDF, MAX_BRDF] (1/sr): beyond it the input is not a BRDF,
    and f cos cos or the fits' weights would overflow."""
    for what, arr in (("f_r", f), ("the standard deviation of f_r", sd)):
        big = ~(np.abs(arr) <= MAX_BRDF)
        if big.any():
            r, c = (int(x) for x in np.argwhere(big)[0])
            raise InputError(f"{s.source}: sample theta_i = {s.theta_i_deg[r]:g}, theta_o = {s.theta_o_deg[r]:g}, "
                             f"column {shorten(s.channels[c])}: {what} = {arr[r, c]:.3g} 1/sr is beyond the physical "
                             f"bound {MAX_BRDF:g} 1/sr ({int(big.sum())} value(s) in all)")


def load_inputs(paths: Sequence[str | Path], *, quantity: str | None = None,
                columns: Mapping[str, str] | None = None, blind_spot_deg: float | None = None,
                angles_in: str = "degrees") -> LoadedInput:
    """Read every input (its angles in ``angles_in``), drop blind-spot zero rows, convert to f_r (1/sr) and merge
    into one :class:`Slice`.

    ``blind_spot_deg``: half width of the retro blind spot (degrees); default: the slice file's
    ``blind_spot_half_width_deg`` metadata if present, else :data:`DEFAULT_BLIND_SPOT_DEG`.
    """
    if not paths:
        raise InputError("no input files given")
    out: list[Slice] = []
    dropped = 0
    notes: list[str] = []
    quantities: list[str] = []
    capture: dict[str, object] = {}
    for p in paths:
        s = read_input(p, quantity=quantity, columns=columns, angles_in=angles_in)
        quantities.append(s.quantity)
        if not capture and "config_settings" in s.meta:
            capture = {"file": str(p), "meta": dict(s.meta)}
        if len(s) == 0:
            raise InputError(f"{s.source}: no samples")
        if not np.any(s.values != 0.0):
            raise InputError(f"{s.source}: every value is zero; nothing was measured")
        width = blind_spot_deg
        if width is None:
            w = s.meta.get("blind_spot_half_width_deg")
            width = float(w) if isinstance(w, (int, float)) and math.isfinite(w) else DEFAULT_BLIND_SPOT_DEG
        s, n = drop_blind_spot_zeros(s, width)
        if n:
            dropped += n
            notes.append(f"{s.source}: {n} all-zero row(s) in the retro blind spot (|theta_i + theta_o| <= "
                         f"{width:g} deg) treated as missing data")
        if len(s) == 0:
            raise InputError(f"{s.source}: every row is zero in the blind spot; no samples left")
        with np.errstate(all="ignore"):
            f, sd = s.brdf()
        _check_bounds(s, f, sd)
        inst = s.meta.get("instrument")  # how the samples were taken (docs/formats.md): kept for the methods
        one = same_rows(s, Slice(s.theta_i_deg, s.theta_o_deg, f, list(s.channels), sd, s.repeats, s.unix_time_s,
                                 meta={"quantity": "brdf", **({"instrument": inst} if inst is not None else {})},
                                 source=s.source))
        if not isinstance(one, RowsWithDirections):  # in the plane: a file of millions of rows thinned here (every
            one, thinned = thin_samples(one)  # row checked above); rows with directions are kept whole (points)
            notes += [thinned] if thinned else []
        out.append(one)
        del s, f, sd
    try:  # rows out of the plane of incidence (a tilt or azimuth columns): points, as a Zemax file's
        merged = as_points(_merge(out), out)
    except SliceError as e:
        raise InputError(str(e)) from None
    if not any(isinstance(p, RowsWithDirections) for p in out):
        merged, thinned = thin_samples(merged)  # several such files
        notes += [thinned] if thinned else []
    check_slice(merged)
    return LoadedInput(merged, [str(p) for p in paths], quantities, dropped, notes, capture)


def check_whole_file_input(paths: Sequence[str | Path], found: str | Path, kind: str, quantity: str | None,
                           columns: object, error: type[Exception]) -> None:
    """A file that holds every incidence (a Zemax or RGL file, ``kind`` names it) is read on its own, holds f_r and
    takes no ``--columns``: ``error`` (the format's own class) naming the file otherwise."""
    if len(paths) > 1:
        raise error(f"{found}: a {kind} file is read on its own (it holds every incidence); got {len(paths)} inputs")
    if quantity not in (None, "brdf"):
        raise error(f"{found}: a {kind} file holds f_r (1/sr); --quantity {quantity} does not apply")
    if columns:
        raise error(f"{found}: --columns applies to generic CSV tables, not to a {kind} file")


def check_slice(s: Slice, min_samples: int = MIN_SAMPLES) -> None:
    """Raise :class:`InputError` for input no method can reconstruct: too few samples, NaN, all zero, duplicates.

    ``s`` holds f_r; the message names the source.
    """
    try:
        s.validate()
    except SliceError as e:
        raise InputError(str(e)) from None
    if len(s) < min_samples:
        raise InputError(f"{s.source}: {len(s)} sample(s); a reconstruction needs at least {min_samples}")
    if np.unique(s.theta_o_deg).size < 2:
        raise InputError(f"{s.source}: every sample has theta_o = {s.theta_o_deg[0]}; a slice needs several "
                         f"outgoing angles")
    if not np.any(s.values > 0):
        raise InputError(f"{s.source}: every value is zero or negative; nothing was measured")

