"""MERL binary BRDF files (Matusik et al. 2003): read and write (the table in memory: ``core.merltable``).

On disk (see ../shared/reference/merl-format.md): an int32 header ``90 90 180``, then all red, all green, all blue
as little-endian float64, each divided by its channel scale; invalid cells are stored as -1. This module (the
README's ``merl``) also re-exports the table's layout, lookup and tabulation (``merl.tabulate``, ``merl.lookup``,
...) and its grid's names.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.atomic import atomic_open
from reconstruction.core.merlgrid import (  # noqa: F401  (the grid's names, re-exported)
    N_PD,
    N_TD,
    N_TH,
    _cell_dirs,
    _continuous_index,
    _grid_dirs,
    cell_angles,
    cell_cosines,
    cell_to_dirs,
    dirs_to_cell,
    phi_d_index,
    theta_d_index,
    theta_h_index,
    valid_mask,
)
from reconstruction.core.merltable import (  # noqa: F401  (the table's names, re-exported)
    N_CELLS,
    SCALES,
    SHAPE,
    MerlError,
    _cell_average,
    _edge_curvature,
    _eval,
    _threads,
    average_theta_h_cells,
    brdf_of,
    lookup,
    lookup_cells,
    tabulate,
    tabulate_reciprocal,
)
from reconstruction.schema.files import UserFileError, read_user_bytes

Array = NDArray[np.float64]

FILE_SIZE = 12 + 3 * N_CELLS * 8  # 34,992,012 bytes
_HEADER = np.array([N_TH, N_TD, N_PD], dtype="<i4").tobytes()

__all__ = ["SHAPE", "N_CELLS", "FILE_SIZE", "SCALES", "MerlError", "MerlWarning", "MAX_CELL_VALUE", "read", "write",
           "theta_h_index", "theta_d_index", "phi_d_index", "cell_angles", "cell_to_dirs", "dirs_to_cell",
           "valid_mask", "cell_cosines", "lookup", "brdf_of", "lookup_cells", "tabulate"]




# --- file I/O --------------------------------------------------------------------------------------------


def _describe_cells(mask: NDArray[np.bool_], limit: int = 5) -> str:
    where = np.argwhere(mask)
    names = "rgb"
    shown = ", ".join(f"{names[c]}[{i},{j},{k}]" for c, i, j, k in where[:limit])
    more = f" and {len(where) - limit} more" if len(where) > limit else ""
    return f"{len(where)} cell(s) ({shown}{more})"


def write(path: str | Path, f: ArrayLike, require_above_horizon: bool = False) -> None:
    """Write a table (3, 90, 90, 180) of f_r in 1/sr to ``path`` in the MERL binary layout, atomically.

    NaN cells are written as -1 (invalid). Infinite or negative values raise :class:`MerlError`; with
    ``require_above_horizon`` so does a NaN in any cell above the horizon. The file is written to a temporary
    name in the same folder, fsynced, then renamed, so a failure never leaves a half-written file.

    Examples
    --------
    >>> import tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "grey.binary")
    >>> write(path, np.full(SHAPE, 0.1))
    >>> os.path.getsize(path) == FILE_SIZE
    True
    """
    path = Path(path)
    t = np.asarray(f)
    if t.shape != SHAPE:
        raise MerlError(f"{path}: table has shape {t.shape}, expected {SHAPE} [channel, theta_h, theta_d, phi_d]")
    t = t.astype(np.float64, copy=False)
    bad = np.isinf(t)
    if bad.any():
        raise MerlError(f"{path}: infinite value in {_describe_cells(bad)}")
    neg = t < 0
    if neg.any():
        raise MerlError(f"{path}: negative BRDF value in {_describe_cells(neg)}; a BRDF is >= 0")
    if require_above_horizon:
        missing = np.isnan(t) & valid_mask()[None]
        if missing.any():
            raise MerlError(f"{path}: no value (NaN) above the horizon in {_describe_cells(missing)}")
    stored = np.divide(t, SCALES[:, None, None, None], dtype="<f8")  # one table-sized array, NaN -> -1 in place
    np.copyto(stored, -1.0, where=np.isnan(stored))
    with atomic_open(path, "wb") as fh:
        fh.write(_HEADER)
        fh.write(memoryview(np.ascontiguousarray(stored)).cast("B"))


#: Physical bound of a stored cell that :func:`read` accepts by default (1/sr): a real BRDF, even a mirror seen by a
#: detector of a few square millidegrees, stays far below it; random bytes after a valid header do not.
MAX_CELL_VALUE = 1e8


class MerlWarning(UserWarning):
    """A MERL file was read, but something in it was taken as invalid (the message says how many cells)."""


def read(path: str | Path, max_value: float | None = MAX_CELL_VALUE) -> Array:
    """Read a MERL binary file -> (3, 90, 90, 180) float64 f_r in 1/sr; negative (invalid) cells -> NaN.

    Cells stored as -1 are the format's invalid marker; other negative cells are also read as NaN, with a
    :class:`MerlWarning` saying how many. A cell above ``max_value`` (1/sr; default :data:`MAX_CELL_VALUE`) is a
    :class:`MerlError` (the file is not a BRDF table); ``max_value=None`` accepts any finite value.

    Examples
    --------
    >>> import tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "grey.binary")
    >>> write(path, np.where(valid_mask(), 0.1, np.nan)[None].repeat(3, axis=0))
    >>> t = read(path)
    >>> t.shape, round(float(np.nanmax(t)), 12), bool(np.isnan(t[0, 89, 89, 0]))
    ((3, 90, 90, 180), 0.1, True)
    """
    path = Path(path)
    try:
        data = read_user_bytes(path, "a .binary file", read=FILE_SIZE + 1)  # its size is judged below
    except UserFileError as e:
        raise MerlError(str(e)) from None
    if len(data) < 12:
        raise MerlError(f"{path}: {len(data)} bytes, too short for the 12-byte header")
    dims = np.frombuffer(data[:12], dtype="<i4")
    if tuple(dims) != (N_TH, N_TD, N_PD):
        raise MerlError(f"{path}: header says {tuple(int(x) for x in dims)}, expected (90, 90, 180)")
    if len(data) < FILE_SIZE:
        raise MerlError(f"{path}: truncated: {len(data)} bytes, expected {FILE_SIZE}")
    if len(data) > FILE_SIZE:
        try:
            size = path.stat().st_size
        except OSError:  # pragma: no cover - vanished in between
            size = len(data)
        raise MerlError(f"{path}: oversized: {size} bytes, expected {FILE_SIZE}")
    stored = np.frombuffer(data, dtype="<f8", offset=12).reshape(SHAPE)
    bad = ~np.isfinite(stored)
    if bad.any():
        raise MerlError(f"{path}: NaN or infinite value stored in {_describe_cells(bad)}")
    scales = SCALES[:, None, None, None]
    if max_value is not None:
        big = stored > max_value / scales
        if big.any():
            with np.errstate(over="ignore"):
                largest = float(np.max(stored * scales))
            raise MerlError(f"{path}: {_describe_cells(big)} above {max_value:g} 1/sr, far beyond any physical "
                            f"BRDF (largest {largest:.3g}); not a BRDF table")
    negative = stored < 0
    odd = negative & (stored != -1.0)
    with np.errstate(over="ignore"):  # only with max_value=None: huge values become inf, as asked
        t = stored.astype(np.float64) * scales
    t[negative] = np.nan
    if odd.any():
        warnings.warn(MerlWarning(f"{path}: {int(odd.sum())} negative cell(s) other than the invalid marker -1 "
                                  "read as invalid (NaN)"), stacklevel=2)
    return t


def _register_reader() -> None:
    """A material's tabulated lobe (core.models.Tabulated) reads its MERL file with :func:`read`."""
    from reconstruction.core import models

    models.TABLE_READER = read


_register_reader()
