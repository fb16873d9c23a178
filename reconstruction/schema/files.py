"""Reading the project's text files safely: a bounded, regular, UTF-8 file (a byte-order mark accepted), and the
``wavelength_nm,reflectance`` spectrum CSV that bench files and materials point to. Every failure is a
:class:`~reconstruction.schema.core.SchemaError` naming the file (and the line)."""

from __future__ import annotations

import csv
import math
import stat
from pathlib import Path

from reconstruction.schema.core import SchemaError

__all__ = ["MAX_TEXT_BYTES", "open_text", "read_spectrum_csv"]

#: Largest config-like file read (bytes): a bench file is a few kilobytes (an explicit list of 20,000 points fits).
MAX_TEXT_BYTES = 512 * 1024


def open_text(path: Path, what: str, limit: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of a config-like file; every failure is a :class:`SchemaError` naming the file."""
    try:
        st = path.stat()
    except FileNotFoundError:
        raise SchemaError(f"{path}: no such file") from None
    except OSError as e:
        raise SchemaError(f"{path}: cannot read ({e.strerror or e})") from None
    if stat.S_ISDIR(st.st_mode):
        raise SchemaError(f"{path}: is a directory, expected {what}")
    if not stat.S_ISREG(st.st_mode):
        raise SchemaError(f"{path}: not a regular file (a device or a pipe), expected {what}")
    if st.st_size > limit:
        raise SchemaError(f"{path}: {st.st_size} bytes; {what} is at most {limit} bytes")
    try:
        with open(path, "rb") as fh:
            data = fh.read(limit + 1)
    except OSError as e:
        raise SchemaError(f"{path}: cannot read ({e.strerror or e})") from None
    try:
        return data.decode("utf-8-sig")  # a byte-order mark (Windows editors write one) is not part of the text
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        raise SchemaError(f"{path}:{line}: not a UTF-8 text file ({e.reason} at byte {e.start}); {what} is "
                          "UTF-8 TOML") from None



def read_spectrum_csv(path: Path, where: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Read a ``wavelength_nm,reflectance`` CSV (a header line and ``#`` comments allowed)."""
    wl: list[float] = []
    val: list[float] = []
    try:
        text = open_text(path, "a wavelength_nm,reflectance CSV file")
    except SchemaError as e:
        raise SchemaError(f"{where}: cannot read {e}") from None
    for lineno, line in enumerate(text.splitlines(), 1):
        try:
            row = next(csv.reader([line]), [])
        except csv.Error as e:
            raise SchemaError(f"{where}: {path}:{lineno}: {e}") from None
        if not row or not row[0].strip() or row[0].strip().startswith("#"):
            continue
        try:
            w, v = float(row[0]), float(row[1])
        except (ValueError, IndexError):
            if not wl and lineno == 1:
                continue  # header
            raise SchemaError(f"{where}: {path}:{lineno}: expected wavelength_nm,reflectance numbers, "
                              f"got {','.join(row)[:60]!r}") from None
        if not (math.isfinite(w) and math.isfinite(v) and 0 < v <= 1.5):
            raise SchemaError(f"{where}: {path}:{lineno}: reflectance must lie in (0, 1.5], got {v:g}")
        if not 100.0 <= w <= 3000.0:
            raise SchemaError(f"{where}: {path}:{lineno}: wavelength must lie in [100, 3000] nm, got {w:g}")
        if wl and w <= wl[-1]:
            raise SchemaError(f"{where}: {path}:{lineno}: wavelengths must increase")
        wl.append(w)
        val.append(v)
    if len(wl) < 2:
        raise SchemaError(f"{where}: {path}: needs at least two wavelength_nm,reflectance rows")
    return tuple(wl), tuple(val)
