"""Opening a user's file safely, in one place: :func:`check_user_file` checks that a path names an existing regular
file (not a directory, a device or a pipe, which would block the read) no larger than the caller's limit;
:func:`read_user_bytes` reads at most that many bytes and :func:`read_user_text` decodes them as UTF-8 (a byte-order
mark accepted). Every refusal is a :class:`UserFileError` with its kind and a message naming the file, which each
reader (bench files, slice files, CSV tables, MERL tables, scene files) raises as its own error, in its own words
where it has them. Here also: the bench files' bounded text
(:func:`open_text`) and the ``wavelength_nm,reflectance`` spectrum CSV that bench files and materials point to.
Every failure of these is a :class:`~reconstruction.schema.core.SchemaError` naming the file (and the line)."""

from __future__ import annotations

import csv
import math
import os
import stat
from pathlib import Path

from reconstruction.schema.core import SchemaError

__all__ = ["MAX_TEXT_BYTES", "UserFileError", "check_user_file", "read_user_bytes",
           "read_user_text", "open_text", "read_spectrum_csv"]

#: Largest config-like file read (bytes): a bench file is a few kilobytes (an explicit list of 20,000 points fits).
MAX_TEXT_BYTES = 512 * 1024


class UserFileError(ValueError):
    """A user's file that cannot be read. ``kind``: ``missing``, ``unreadable``, ``directory``, ``special`` (a device
    or a pipe), ``too_big`` (``size`` bytes at the stat), ``grew`` (beyond the limit while read) or ``not_utf8``
    (``line``, ``byte``, ``reason``); the message names the file in the common words of every reader."""

    def __init__(self, kind: str, path: Path, message: str, *, size: int = 0, why: str = "", line: int = 0,
                 byte: int = 0) -> None:
        super().__init__(message)
        self.kind, self.path, self.size, self.why, self.line, self.byte = kind, path, size, why, line, byte


def _why(e: OSError) -> str:
    return str(e.strerror or e)


def check_user_file(path: str | Path, what: str, limit: int | None = None) -> os.stat_result:
    """The stat of ``path`` when it names an existing regular file of at most ``limit`` bytes (no limit: None);
    else :class:`UserFileError`. ``what`` completes the messages ("is a directory, expected ``what``")."""
    path = Path(path)
    try:
        st = path.stat()
    except FileNotFoundError:
        raise UserFileError("missing", path, f"{path}: no such file") from None
    except OSError as e:
        raise UserFileError("unreadable", path, f"{path}: cannot read ({_why(e)})", why=_why(e)) from None
    if stat.S_ISDIR(st.st_mode):
        raise UserFileError("directory", path, f"{path}: is a directory, expected {what}")
    if not stat.S_ISREG(st.st_mode):
        raise UserFileError("special", path, f"{path}: not a regular file (a device or a pipe), expected {what}")
    if limit is not None and st.st_size > limit:
        raise UserFileError("too_big", path, f"{path}: {st.st_size} bytes; {what} is at most {limit} bytes",
                            size=st.st_size)
    return st


def read_user_bytes(path: str | Path, what: str, limit: int | None = None, read: int | None = None) -> bytes:
    """The bytes of a user's file (:func:`check_user_file`): at most ``read`` bytes (default: ``limit`` + 1, and a
    file that grew beyond ``limit`` since the check is refused). Every refusal is a :class:`UserFileError`."""
    path = Path(path)
    check_user_file(path, what, limit)
    try:
        with open(path, "rb") as fh:
            data = fh.read(-1 if read is None and limit is None else (read if read is not None else limit + 1))
    except OSError as e:
        raise UserFileError("unreadable", path, f"{path}: cannot read ({_why(e)})", why=_why(e)) from None
    if limit is not None and read is None and len(data) > limit:
        raise UserFileError("grew", path, f"{path}: larger than {limit} bytes; {what} is at most {limit} bytes",
                            size=len(data))
    return data


def read_user_text(path: str | Path, what: str, limit: int | None = None) -> str:
    """The UTF-8 text of a user's file (:func:`read_user_bytes`; a byte-order mark, which Windows editors write, is
    not part of the text). Every refusal is a :class:`UserFileError`."""
    path = Path(path)
    data = read_user_bytes(path, what, limit)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        raise UserFileError("not_utf8", path, f"{path}:{line}: not a UTF-8 text file ({e.reason} at byte {e.start})",
                            why=e.reason, line=line, byte=e.start) from None


def open_text(path: Path, what: str, limit: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of a config-like file; every failure is a :class:`SchemaError` naming the file."""
    try:
        return read_user_text(path, what, limit)
    except UserFileError as e:
        raise SchemaError(f"{e}; {what} is UTF-8 TOML" if e.kind == "not_utf8" else str(e)) from None



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
