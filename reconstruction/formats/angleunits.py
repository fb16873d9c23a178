"""The unit of an input's angle columns: degrees (the default, and what slice files promise) or radians.

A table whose angles were written in radians and read as degrees holds every angle within +-pi/2 (about 1.571),
so a reconstruction sees one narrow cone around the normal: it covers a handful of the table's (theta_h, theta_d)
bins and still exits 0. No bench measures a whole slice within +-1.6 deg (its blind spot alone is wider), so a
table whose angles all lie inside :data:`RADIAN_LIMIT` is refused, naming the column and pointing at
``--angles-in radians``; with that option the angles are converted to degrees as they are read.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from reconstruction.base import ReconstructionError

__all__ = ["ANGLE_UNITS", "RADIAN_LIMIT", "to_degrees"]

ANGLE_UNITS = ("degrees", "radians")
#: every |angle| of a table at or below this (in the file's numbers) reads as radians taken for degrees: pi/2 is
#: 1.571, and a real slice in degrees spans far more than +-1.6 deg
RADIAN_LIMIT = 1.6


def to_degrees(path: str | Path, theta_i: NDArray[np.float64], theta_o: NDArray[np.float64], ti_name: str,
               to_name: str, angles_in: str, error: type[ReconstructionError]) -> tuple[NDArray[np.float64],
                                                                                        NDArray[np.float64]]:
    """(theta_i, theta_o) in degrees from a file's angle columns (N,) in ``angles_in`` ("degrees" or "radians").

    Raises ``error`` (one line naming the file and the column) for angles in degrees that all lie within
    +-:data:`RADIAN_LIMIT` (radians read as degrees), or for angles said to be radians that exceed pi/2."""
    if angles_in not in ANGLE_UNITS:
        raise error(f"--angles-in: unknown unit {angles_in!r}; expected one of {', '.join(ANGLE_UNITS)}")
    ti = np.asarray(theta_i, dtype=np.float64)
    to = np.asarray(theta_o, dtype=np.float64)
    if angles_in == "radians":
        for name, a in ((ti_name, ti), (to_name, to)):
            big = np.abs(a) >= np.pi / 2
            if big.any():
                raise error(f"{path}: column {name}: {a[int(np.argmax(big))]:g} is not an angle in radians within "
                            f"(-pi/2, pi/2); are the angles in degrees? (leave out --angles-in radians)")
        return np.degrees(ti), np.degrees(to)
    if ti.size and max(float(np.max(np.abs(ti))), float(np.max(np.abs(to)))) <= RADIAN_LIMIT:
        span = f"{float(np.min(to)):.3g} to {float(np.max(to)):.3g}"
        raise error(f"{path}: column {to_name}: every angle lies within +-{RADIAN_LIMIT:g} ({span}; {ti_name} "
                    f"too): radians read as degrees? pass --angles-in radians (angles are read in degrees by "
                    f"default)")
    return ti, to
