"""Opening a user's file safely, in one place: :func:`check_user_file` checks that a path names an existing regular
file (not a directory, a device or a pipe, which would block the read) no larger than the caller's limit;
:func:`read_user_bytes` reads at most that many bytes and :func:`read_user_text` decodes them as UTF-8 (a byte-order
mark accepted). Every refusal is a :class:`UserFileError` with its kind and a message naming the file, which each
reader (bench files, slice files, CSV tables, MERL tables, scene files) raises as its own error, in its own words
where it has them. Here also: the bench files' bounded text
(:func:`open_text`), and the one reader of a user's numeric CSV (:func:`open_user_csv`: comment lines, the header,
rows parsed vectorised into one array, errors naming the file, the line, the column and what was expected), which
slice files (:mod:`reconstruction.formats.slicefile`), generic tables (:mod:`reconstruction.formats.inputs`) and the
``wavelength_nm,reflectance`` spectrum CSV that bench files and materials point to (:func:`read_spectrum_csv`) read
through."""

from __future__ import annotations

import csv
import os
import stat
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from reconstruction.core.slicedata import shorten
from reconstruction.schema.core import SchemaError

__all__ = ["MAX_TEXT_BYTES", "UserFileError", "check_user_file", "read_user_bytes", "read_user_text", "open_text",
           "UserCsv", "open_user_csv", "parse_rows", "CSV_CHUNK_CHARS", "read_spectrum_csv"]

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


# --- a user's numeric CSV table, read one way -----------------------------------------------------------------

#: Characters of data lines parsed at a time by :meth:`UserCsv.rows`: its temporaries (the lines as strings, a few
#: times the text) stay a few tens of MB whatever the file's size; the rows go straight into one array.
CSV_CHUNK_CHARS = 4 * 1024 * 1024

#: How a reader raises its error: called with the message (``file:line, column NAME: what was expected``).
Raise = Callable[[str], Exception]
#: A row check of :meth:`UserCsv.rows`: ``(rows, r, cells, where)`` raises the reader's error for row ``r`` of
#: ``rows`` (its cells as text; ``where``: ``file:line``) if it fails.
RowCheck = Callable[[NDArray[np.float64], int, Sequence[str], str], None]


def parse_rows(lines: Sequence[str], n_cols: int, delimiter: str = ",", quotechar: str | None = None
               ) -> NDArray[np.float64] | None:
    """Fast, vectorised parse of data lines into an (N, n_cols) float array; None if any line does not hold
    exactly ``n_cols`` numbers (the caller then finds the culprit line by line, for the message)."""
    if not lines:
        return np.empty((0, n_cols))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            a = np.loadtxt(lines, delimiter=delimiter, dtype=np.float64, ndmin=2, comments=None,
                           quotechar=quotechar)
    except (ValueError, TypeError, OverflowError):
        return None
    if a.shape != (len(lines), n_cols):
        return None
    return a


def _delimiter(header: str, candidates: Sequence[str]) -> str:
    """The candidate the header line holds most of (the first when it holds none)."""
    counts = {d: header.count(d) for d in candidates}
    return max(counts, key=lambda d: counts[d]) if max(counts.values()) > 0 else candidates[0]


@dataclass(frozen=True)
class UserCsv:
    """A user's numeric CSV table, opened by :func:`open_user_csv`: ``text`` (line endings as LF), ``head`` (the
    lines above the column header: comments, a slice file's magic and metadata lines), ``header`` (the column
    names, stripped; empty when the file has none), ``header_line`` (1-based; 0: none), ``delimiter``; the rows
    below are parsed by :meth:`rows`."""

    path: Path
    text: str
    head: list[str]
    header: list[str]
    header_line: int
    delimiter: str
    body: int  # the offset in ``text`` where the data lines begin
    quoted: bool
    skip_blank: bool
    torn: bool
    error: Raise

    def rows(self, check: Callable[[NDArray[np.float64]], bool] | None = None, check_row: RowCheck | None = None,
             nan_hint: str = "", chunk_chars: int = CSV_CHUNK_CHARS) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """The rows below the header as floats (N, columns) and each row's 1-based line number (N,).

        Parsed vectorised, ``chunk_chars`` of text at a time into one array (the largest file takes about its own
        size plus the array); ``check``: the reader's vectorised check of a chunk's rows (True: all pass). A chunk
        that fails is read again line by line for the message, the first failure in the file's order: the number
        of fields (``file:line: N fields, expected M (the header)``), a cell that is not a number or not finite
        (``file:line, column NAME: expected a number, got 'x'``, ``nan_hint`` after the latter), then
        ``check_row``. Blank and ``#`` lines are skipped when the file was opened with ``skip_blank``; with
        ``torn``, a last line without its newline (a write cut short) is dropped with a warning."""
        text, body, n_cols = self.text, self.body, len(self.header)
        end = max(text.rfind("\n") + 1 if self.torn and not text.endswith("\n") else len(text), body)
        if self.torn and end < len(text):
            warnings.warn(f"{self.path}:{text.count(chr(10), 0, end) + 1}: torn last line (interrupted write) "
                          f"dropped: {text[end:end + 60]!r}", stacklevel=3)
        n = text.count("\n", body, end) + (1 if end > body and text[end - 1] != "\n" else 0)
        data = np.empty((n, n_cols))
        line_of = np.empty(n, dtype=np.int64)
        pos, r, line = body, 0, text.count("\n", 0, body) + 1
        while pos < end:  # a chunk of whole lines at a time
            stop = text.find("\n", min(pos + chunk_chars, end - 1), end)
            stop = end if stop < 0 else stop
            lines = text[pos:stop].split("\n")
            numbers, line = line + np.arange(len(lines)), line + len(lines)
            if self.skip_blank:
                keep = [k for k, x in enumerate(lines) if (t := x.strip()) and not t.startswith("#")]
                lines, numbers = [lines[k] for k in keep], numbers[keep]
            data[r:r + len(lines)] = self._parse_chunk(lines, numbers, check, check_row, nan_hint)
            line_of[r:r + len(lines)] = numbers
            r += len(lines)
            pos = stop + 1
        return (data, line_of) if r == n else (data[:r].copy(), line_of[:r].copy())

    def _cells(self, line: str, where: str) -> list[str]:
        if not self.quoted:
            return line.split(self.delimiter)
        try:
            return next(csv.reader([line], delimiter=self.delimiter), [])
        except csv.Error as e:
            raise self.error(f"{where}: {e}") from None

    def _parse_chunk(self, lines: list[str], numbers: NDArray[np.int64],
                     check: Callable[[NDArray[np.float64]], bool] | None, check_row: RowCheck | None,
                     nan_hint: str) -> NDArray[np.float64]:
        """The rows of one chunk as an array (vectorised); the first bad line, at its number in the file, raised."""
        n_cols = len(self.header)
        data = parse_rows(lines, n_cols, self.delimiter, '"' if self.quoted else None)
        if data is not None and np.all(np.isfinite(data)) and (check is None or check(data)):
            return data
        data = np.empty((len(lines), n_cols))  # the slow path: finds the first bad line for the message
        for r, line in enumerate(lines):
            where = f"{self.path}:{numbers[r]}"
            cells = self._cells(line, where)
            if len(cells) != n_cols:
                raise self.error(f"{where}: {len(cells)} fields, expected {n_cols} "
                                 f"({shorten(self.delimiter.join(self.header), 200)})")
            for k, (name, cell) in enumerate(zip(self.header, cells, strict=True)):
                try:
                    data[r, k] = float(cell.strip())
                except ValueError:
                    raise self.error(f"{where}, column {shorten(name)}: expected a number, got "
                                     f"{shorten(cell.strip())!r}") from None
                if not np.isfinite(data[r, k]):
                    raise self.error(f"{where}, column {shorten(name)}: value is {shorten(cell.strip())!r}; NaN and "
                                     f"infinity are not allowed{nan_hint}")
            if check_row is not None:
                check_row(data, r, cells, where)
        return data  # pragma: no cover - parse_rows or check failed on some line, found above


def open_user_csv(path: str | Path, what: str, *, limit: int | None = None, error: Raise = ValueError,
                  read_text: Callable[[Path], str] | None = None, delimiters: Sequence[str] = (",",),
                  quoted: bool = False, skip_blank: bool = True, first_in_head: int = 0, torn: bool = False,
                  names: Sequence[str] | None = None) -> UserCsv:
    """Open a user's numeric CSV table: its text read once (:func:`read_user_text` with ``limit``, a refusal raised
    as ``error``; or ``read_text``, the reader's own wording of it), its line endings made LF, the lines above the
    column header (the first ``first_in_head`` whatever they are, then ``#`` lines, and blank ones with
    ``skip_blank``) and the header split into names, the rows left to :meth:`UserCsv.rows`.

    ``delimiters``: the one the header holds most of; ``quoted``: cells may be quoted (csv rules; else split on the
    delimiter); ``skip_blank``: blank and ``#`` lines are skipped anywhere (else every line below the header is a
    row); ``torn``: a last line without its newline is a write cut short; ``names``: the column names when the
    first line below the head holds numbers (a file without a header)."""
    path = Path(path)
    if read_text is None:
        try:
            text = read_user_text(path, what, limit)
        except UserFileError as e:
            raise error(str(e)) from None
    else:
        text = read_text(path)
    if "\r" in text:  # CRLF and CR-only line endings (other tools, old Mac exports)
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    def in_head(line: str) -> bool:
        if skip_blank:
            return not line.strip() or line.strip().startswith("#")
        return line.startswith("#")

    head: list[str] = []
    pos = 0
    while pos < len(text) and len(head) < 1 << 16:
        stop = text.find("\n", pos)
        stop = len(text) if stop < 0 else stop
        line = text[pos:stop]
        if len(head) >= first_in_head and not in_head(line):
            break
        head.append(line)
        pos = stop + 1
    pos = min(pos, len(text))
    if pos >= len(text):
        return UserCsv(path, text, head, [], 0, delimiters[0], len(text), quoted, skip_blank, torn, error)
    stop = text.find("\n", pos)
    stop = len(text) if stop < 0 else stop
    line, hline = text[pos:stop], len(head) + 1
    delim = _delimiter(line, delimiters)
    try:
        header = [c.strip() for c in (next(csv.reader([line], delimiter=delim), []) if quoted else line.split(delim))]
    except csv.Error as e:
        raise error(f"{path}:{hline}: cannot read the header line: {e}") from None
    if names is not None:
        try:
            [float(c) for c in header]
        except ValueError:
            pass
        else:  # no header: the line is the first row
            return UserCsv(path, text, head, list(names), 0, delim, pos, quoted, skip_blank, torn, error)
    return UserCsv(path, text, head, header, hline, delim, min(stop + 1, len(text)), quoted, skip_blank, torn, error)


def read_spectrum_csv(path: Path, where: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Read a ``wavelength_nm,reflectance`` CSV (an optional header line and ``#`` comments; the first two columns;
    :func:`open_user_csv`); every failure is a :class:`~reconstruction.schema.core.SchemaError` naming ``where``,
    the file and the line."""

    def error(msg: str) -> SchemaError:
        return SchemaError(f"{where}: {msg}")

    def read_text(p: Path) -> str:
        try:
            return open_text(p, "a wavelength_nm,reflectance CSV file")
        except SchemaError as e:
            raise SchemaError(f"{where}: cannot read {e}") from None

    def ok(a: NDArray[np.float64]) -> bool:
        w, v = a[:, 0], a[:, 1]
        return bool(np.all((v > 0) & (v <= 1.5)) and np.all((w >= 100.0) & (w <= 3000.0)) and np.all(np.diff(w) > 0))

    def check_row(a: NDArray[np.float64], r: int, cells: Sequence[str], at: str) -> None:
        w, v = a[r, 0], a[r, 1]
        if not 0 < v <= 1.5:
            raise error(f"{at}: reflectance must lie in (0, 1.5], got {v:g}")
        if not 100.0 <= w <= 3000.0:
            raise error(f"{at}: wavelength must lie in [100, 3000] nm, got {w:g}")
        if r and w <= a[r - 1, 0]:
            raise error(f"{at}: wavelengths must increase")

    table = open_user_csv(path, "a wavelength_nm,reflectance CSV file", error=error, read_text=read_text,
                          quoted=True, names=("wavelength_nm", "reflectance"))
    if len(table.header) < 2:
        raise error(f"{path}:{max(table.header_line, 1)}: expected the columns wavelength_nm,reflectance")
    data, _ = table.rows(ok, check_row)
    if len(data) < 2:
        raise error(f"{path}: needs at least two wavelength_nm,reflectance rows")
    return tuple(float(x) for x in data[:, 0]), tuple(float(x) for x in data[:, 1])
