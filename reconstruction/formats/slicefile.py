"""Slice files: the versioned CSV format in which captured in-plane slices travel.

The contract between acquisition (which writes them, one durable row per sample) and reconstruction (which
reads them). Format version 1 (documented in docs/formats.md, "Slice files")::

    # gonio-brdf slice
    # meta: {"format_version": 1, "quantity": "brdf", "material": "blue-plastic", ...}
    theta_i_deg,theta_o_deg,R,G,B,R_std,G_std,B_std,repeats,unix_time_s
    30,-80,0.0123,0.0234,0.1012,0.0002,0.0003,0.0011,4,1795000000.25
    ...

Value columns are ``value`` (one channel), ``R,G,B``, or spectral columns named by wavelength (``550nm``);
each has a ``<name>_std`` column (standard deviation of the mean of the repeats, same unit). Angles in
degrees; theta_o is signed (+ = specular side). ``quantity`` says what the values are: ``brdf`` (f_r, 1/sr),
``reflectance_factor`` (pi f_r) or ``brdf_cos`` (f_r cos theta_o).
"""

from __future__ import annotations

import io
import json
import os
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from reconstruction.atomic import atomic_open
from reconstruction.core.slicedata import (
    Slice,
    SliceError,
    _show_list,
    channel_kind,
    shorten,
)
from reconstruction.schema.files import UserFileError, open_user_csv, read_user_text
from reconstruction.schema.slice_meta import FORMAT_VERSION, QUANTITIES, check_instrument  # the metadata's schema

Array = NDArray[np.float64]

MAGIC = "# gonio-brdf slice"
META_PREFIX = "# meta: "
#: Largest input file (slice file or generic table) the readers accept, in bytes; a larger one is refused with a
#: message (read in memory: a 100 MB table takes a few seconds and about 0.5 GB).
MAX_INPUT_BYTES = 256 * 1024 * 1024
#: Largest ``repeats`` a row may give (far above any detector's; beyond it the count is not one).
MAX_REPEATS = 10**9

__all__ = ["SliceWriter", "read_slice", "write_slice", "MAX_INPUT_BYTES", "read_input_text"]








def read_input_text(path: str | Path, error: type[ValueError] = ValueError, what: str = "a CSV file") -> str:
    """The text of an input file, UTF-8 with an optional byte-order mark, line endings as they are.

    Raises ``error`` naming the file for: no such file, a directory or other non-regular file, an unreadable
    file, a file above :data:`MAX_INPUT_BYTES`, text that is not UTF-8.
    """
    try:
        return read_user_text(path, what, MAX_INPUT_BYTES)
    except UserFileError as e:
        if e.kind == "too_big":
            raise error(f"{e.path}: {e.size / 1e6:.0f} MB is larger than the {MAX_INPUT_BYTES / 1e6:.0f} MB an "
                        f"input may have; split it (e.g. one file per incidence)") from None
        if e.kind == "grew":  # since the stat
            raise error(f"{e.path}: larger than the {MAX_INPUT_BYTES / 1e6:.0f} MB an input may have") from None
        raise error(str(e)) from None


def _normalise_newlines(text: str) -> str:
    """CRLF and CR-only line endings (other tools, old Mac exports) as LF."""
    if "\r" not in text:
        return text
    return text.replace("\r\n", "\n").replace("\r", "\n")


# --- writing ---------------------------------------------------------------------------------------------


def _columns(channels: Sequence[str]) -> list[str]:
    return ["theta_i_deg", "theta_o_deg", *channels, *(f"{c}_std" for c in channels), "repeats", "unix_time_s"]


def _header(channels: Sequence[str], meta: Mapping[str, Any]) -> str:
    m = {"format_version": FORMAT_VERSION, "quantity": "brdf", **dict(meta)}
    if m["quantity"] not in QUANTITIES:
        raise SliceError(f"unknown quantity {m['quantity']!r}; expected one of {', '.join(QUANTITIES)}")
    channel_kind(channels)
    return f"{MAGIC}\n{META_PREFIX}{json.dumps(m, sort_keys=True)}\n{','.join(_columns(channels))}\n"


def _fmt(x: float) -> str:
    return repr(float(x))


def _row(theta_i: float, theta_o: float, values: Sequence[float], std: Sequence[float], repeats: int,
         t: float) -> str:
    return ",".join([_fmt(theta_i), _fmt(theta_o), *map(_fmt, values), *map(_fmt, std), str(int(repeats)),
                     _fmt(t)]) + "\n"


def write_slice(path: str | Path, s: Slice) -> None:
    """Write a whole slice to ``path`` atomically (temporary file, fsync, rename)."""
    path = Path(path)
    assert s.std is not None and s.repeats is not None and s.unix_time_s is not None
    buf = io.StringIO()
    buf.write(_header(s.channels, s.meta))
    for k in range(len(s)):
        buf.write(_row(s.theta_i_deg[k], s.theta_o_deg[k], s.values[k], s.std[k], s.repeats[k],
                       s.unix_time_s[k]))
    with atomic_open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(buf.getvalue())


class SliceWriter:
    """Append samples to a slice file durably: each :meth:`append` writes one row, flushes and fsyncs.

    Opening an existing file (a resumed capture) checks that it has exactly the columns of ``channels`` and cuts
    off a torn last line left by a crash, so appending continues cleanly (``notes`` says so, for the caller's log,
    instead of a Python warning). Rows are appended in the file's own
    column order and with its own line ending (a file whose columns another tool reordered, or whose line endings
    it converted, stays consistent); a file with other columns is refused. Use as a context manager.
    """

    def __init__(self, path: str | Path, channels: Sequence[str], meta: Mapping[str, Any] | None = None
                 ) -> None:
        self.path = Path(path)
        self.channels = list(channels)
        header = _header(self.channels, meta or {})
        self.columns = _columns(self.channels)
        self.newline = "\n"
        self.notes: list[str] = []  # what reading the existing file warned of (a torn last line, cut off below)
        if self.path.exists() and self.path.stat().st_size > 0:
            with warnings.catch_warnings(record=True) as seen:  # the caller logs them (a resumed capture: its log)
                warnings.simplefilter("always")
                existing = read_slice(self.path)  # validates; warns on a torn last line
            self.notes = [str(w.message) for w in seen]
            if sorted(existing.channels) != sorted(self.channels):
                raise SliceError(f"{self.path}: has value columns {_show_list(existing.channels)}, "
                                 f"cannot append {_show_list(self.channels)}")
            file_columns, self.newline = self._file_layout()
            if sorted(file_columns) != sorted(self.columns):
                raise SliceError(f"{self.path}: its columns {_show_list(file_columns)} are not the columns "
                                 f"{_show_list(self.columns)} of these samples; cannot append")
            self.columns = file_columns
            self._cut_torn_tail()
            self._fh = open(self.path, "a", encoding="utf-8", newline="")
        else:
            self._fh = open(self.path, "w", encoding="utf-8", newline="\n")
            self._fh.write(header)
            self._sync()

    def _file_layout(self) -> tuple[list[str], str]:
        """(column names in the file's order, the file's line ending) from its header lines."""
        with open(self.path, "rb") as fh:
            head = fh.read(1 << 20)
        newline = "\r\n" if b"\r\n" in head else ("\r" if b"\r" in head and b"\n" not in head else "\n")
        text = _normalise_newlines(head.decode("utf-8-sig", errors="replace"))
        for line in text.split("\n")[1:]:
            if not line.startswith("#"):
                return [c.strip() for c in line.split(",")], newline
        raise SliceError(f"{self.path}: no column header line")  # pragma: no cover - read_slice checked it

    def _cut_torn_tail(self) -> None:
        with open(self.path, "rb+") as fh:
            data = fh.read()
            if data and not data.endswith((b"\n", b"\r")):
                fh.truncate(max(data.rfind(b"\n"), data.rfind(b"\r")) + 1)
                fh.flush()
                os.fsync(fh.fileno())

    def _sync(self) -> None:
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def append(self, theta_i_deg: float, theta_o_deg: float, values: Sequence[float],
               std: Sequence[float], repeats: int, unix_time_s: float) -> str:
        """Write one sample (in the file's column order) and make it durable before returning; returns the line
        written (with its line ending)."""
        if len(values) != len(self.channels) or len(std) != len(self.channels):
            raise SliceError(f"{self.path}: expected {len(self.channels)} values and stds, "
                             f"got {len(values)} and {len(std)}")
        cells = {"theta_i_deg": _fmt(theta_i_deg), "theta_o_deg": _fmt(theta_o_deg), "repeats": str(int(repeats)),
                 "unix_time_s": _fmt(unix_time_s)}
        for c, v, e in zip(self.channels, values, std, strict=True):
            cells[c] = _fmt(v)
            cells[f"{c}_std"] = _fmt(e)
        line = ",".join(cells[c] for c in self.columns) + self.newline
        try:
            self._fh.write(line)
            self._sync()
        except OSError as e:  # a full disk: name the file (buffered writes do not)
            raise OSError(e.errno, e.strerror or str(e), str(self.path)) from None
        return line

    def close(self) -> None:
        if not self._fh.closed:
            try:
                self._sync()
            finally:
                try:
                    self._fh.close()
                except OSError:  # the sync above already failed and said why
                    pass

    def __enter__(self) -> SliceWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --- reading ---------------------------------------------------------------------------------------------


def _check_row(data: NDArray[np.float64], r: int, cells: Sequence[str], where: str, header: list[str],
               col: dict[str, int], std_cols: list[int]) -> None:
    """The per-row checks of a slice file (angles, repeats, standard deviations), raising the first failure."""
    for name in ("theta_i_deg", "theta_o_deg"):
        x = data[r, col[name]]
        if not -90.0 < x < 90.0:
            raise SliceError(f"{where}, column {name}: {x} is outside (-90, 90) degrees")
    rep = data[r, col["repeats"]]
    if not 1 <= rep <= MAX_REPEATS or rep != int(rep):
        raise SliceError(f"{where}, column repeats: expected a positive integer, got "
                         f"{shorten(cells[col['repeats']])!r}")
    for k in std_cols:
        if data[r, k] < 0:
            raise SliceError(f"{where}, column {shorten(header[k])}: a standard deviation must be >= 0, got "
                             f"{data[r, k]}")


def _rows_ok(data: NDArray[np.float64], col: dict[str, int], std_cols: list[int]) -> bool:
    """True if every row passes :func:`_check_row` (vectorised; the values are finite)."""
    ang = data[:, [col["theta_i_deg"], col["theta_o_deg"]]]
    rep = data[:, col["repeats"]]
    rep_ok = (rep >= 1) & (rep <= MAX_REPEATS) & (rep == np.floor(rep))
    return bool(np.all(np.abs(ang) < 90.0) and np.all(rep_ok)
                and np.all(data[:, std_cols] >= 0))


#: Characters of data lines parsed at a time by :func:`read_slice`: its temporaries (the lines as strings, a few
#: times the text) stay a few tens of MB whatever the file's size; the rows go straight into one array.
CHUNK_CHARS = 4 * 1024 * 1024


def _first_duplicate(key: NDArray[np.float64]) -> tuple[int, int] | None:
    """(row, row of its first occurrence) of the first key (theta_i, theta_o[, tilt]: the columns of ``key``, (N, k))
    given twice, else None; a stable sort (a few arrays of the rows' length, not ``np.unique``'s copies)."""
    if len(key) < 2:
        return None
    order = np.lexsort(key.T[::-1])  # stable: equal keys in file order
    same = np.zeros(len(order), dtype=bool)
    same[1:] = np.all(key[order[1:]] == key[order[:-1]], axis=1)
    if not same.any():
        return None
    start = np.maximum.accumulate(np.where(same, 0, np.arange(len(order))))  # each run's first position
    dups = np.nonzero(same)[0]
    i = dups[np.argmin(order[dups])]
    return int(order[i]), int(order[start[i]])


def _columns_of(data: NDArray[np.float64], cols: list[int]) -> NDArray[np.float64]:
    """``data[:, cols]``: a view when the columns are consecutive (as the writer lays them out), else a copy."""
    if cols == list(range(cols[0], cols[0] + len(cols))):
        return data[:, cols[0]:cols[0] + len(cols)]
    return data[:, cols]


def read_slice(path: str | Path) -> Slice:
    """Read and validate a slice file; a torn last line (from a crash) is dropped with a warning.

    UTF-8 with or without a byte-order mark; LF, CRLF or CR-only line endings. Rows are parsed vectorised, a
    chunk of :data:`CHUNK_CHARS` at a time into one array (the largest file takes about its own size plus the
    array); a row that fails is then found line by line for the message (``file:line, column NAME: what was
    expected``).
    """
    path = Path(path)
    table = open_user_csv(path, "a slice file", error=SliceError, first_in_head=1, skip_blank=False, torn=True,
                          read_text=lambda p: read_input_text(p, SliceError, "a slice file"))
    lines = table.head
    if not lines or lines[0].strip() != MAGIC:
        raise SliceError(f"{path}:1: expected the first line {MAGIC!r}, got "
                         f"{lines[0][:60]!r}" if lines else f"{path}: empty file")
    meta: dict[str, Any] = {}
    lineno = 1
    while lineno < len(lines) and lines[lineno].startswith("#"):
        line = lines[lineno]
        if line.startswith(META_PREFIX):
            try:
                meta = json.loads(line[len(META_PREFIX):])
            except (json.JSONDecodeError, RecursionError) as e:
                raise SliceError(f"{path}:{lineno + 1}: metadata is not valid JSON: {shorten(str(e), 200)}"
                                 ) from None
            if not isinstance(meta, dict):
                raise SliceError(f"{path}:{lineno + 1}: metadata must be a JSON object")
        lineno += 1
    version = meta.get("format_version")
    if isinstance(version, bool) or version != FORMAT_VERSION:
        raise SliceError(f"{path}: unsupported format_version {shorten(repr(version))}; this reader supports "
                         f"{FORMAT_VERSION}")
    quantity = meta.get("quantity")
    if not isinstance(quantity, str) or quantity not in QUANTITIES:
        raise SliceError(f"{path}: unknown quantity {shorten(repr(quantity))}; expected one of "
                         f"{', '.join(QUANTITIES)}")
    if meta.get("instrument") is not None:
        try:
            check_instrument(meta["instrument"], "instrument")
        except ValueError as e:
            raise SliceError(f"{path}: metadata {shorten(str(e), 300)}") from None
    if not table.header_line:
        raise SliceError(f"{path}: no column header line")
    header, header_line = table.header, table.header_line
    for required in ("theta_i_deg", "theta_o_deg", "repeats", "unix_time_s"):
        if required not in header:
            raise SliceError(f"{path}:{header_line}: missing column {required!r}")
    channels = [c for c in header if c not in ("theta_i_deg", "theta_o_deg", "repeats", "unix_time_s", "tilt_deg")
                and not c.endswith("_std")]
    try:
        channel_kind(channels)
    except SliceError as e:
        raise SliceError(f"{path}:{header_line}: {e}") from None
    for c in channels:
        if f"{c}_std" not in header:
            raise SliceError(f"{path}:{header_line}: missing column {shorten(c + '_std')!r}")
    if len(set(header)) != len(header):
        raise SliceError(f"{path}:{header_line}: repeated column names")
    col = {c: k for k, c in enumerate(header)}
    std_cols = [col[f"{c}_std"] for c in channels]
    data, line_of = table.rows(lambda d: _rows_ok(d, col, std_cols),
                               lambda d, r, cells, where: _check_row(d, r, cells, where, header, col, std_cols),
                               chunk_chars=CHUNK_CHARS)
    del table
    key = data[:, [col[c] for c in ("theta_i_deg", "theta_o_deg", "tilt_deg") if c in col]]
    dup = _first_duplicate(key)
    if dup is not None:
        raise SliceError(f"{path}:{line_of[dup[0]]}: duplicate sample theta_i_deg = {key[dup[0], 0]}, "
                         f"theta_o_deg = {key[dup[0], 1]}" + (f", tilt_deg = {key[dup[0], 2]}" if key.shape[1] > 2
                                                              else "")
                         + f" (first at line {line_of[dup[1]]})")
    del key
    from reconstruction.formats.directions import with_directions  # the optional tilt column: rows out of the plane

    return with_directions(Slice(
        theta_i_deg=data[:, col["theta_i_deg"]],
        theta_o_deg=data[:, col["theta_o_deg"]],
        values=_columns_of(data, [col[c] for c in channels]),
        channels=channels,
        std=_columns_of(data, [col[f"{c}_std"] for c in channels]),
        repeats=data[:, col["repeats"]].astype(np.int64),
        unix_time_s=data[:, col["unix_time_s"]],
        meta=meta,
        source=str(path),
    ), {"tilt": data[:, col["tilt_deg"]]} if "tilt_deg" in col else {}, str(path), line_of)
