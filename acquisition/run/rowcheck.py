"""What a resume checks of the rows already on disk: each is a point of the plan and its values are possible for
their standard deviations; the rows that are not are named and refused, or set aside with ``--force``.

A row is a point of the plan when both its angles are within ``[motion].tolerance_deg`` of a measurable point of
the plan; with adaptive refinement (whose midpoints are not known in advance) also when its theta_i is within that
tolerance of a planned incidence, its theta_o lies within that incidence's planned range, and the bench can
measure it. A row's values are impossible when a channel lies below zero by more than
:data:`~reconstruction.core.slicedata.NEGATIVE_SIGMAS` standard deviations plus
:data:`~reconstruction.core.slicedata.NEGATIVE_FLOOR` of the slice's largest value
(:func:`reconstruction.core.slicedata.below_zero`). A row whose check value in ``slice.crc`` does not match its
line (a digit flipped, an edit; :mod:`acquisition.run.sliceout`) is refused too. Set-aside rows move, as they
were written, to ``DIR/slice.set-aside.csv`` (the slice's header lines, then the rows), and the slice is
rewritten atomically without them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from reconstruction.atomic import atomic_open
from reconstruction.core.slicedata import Slice, below_zero

__all__ = ["RowProblem", "SET_ASIDE_NAME", "row_problems", "describe_problems", "set_aside"]

SET_ASIDE_NAME = "slice.set-aside.csv"


@dataclass(frozen=True)
class RowProblem:
    """A row of the slice a resume may not continue from: its index among the data rows, its line in the file
    (1-based), its angles (degrees) and why."""

    index: int
    line: int
    theta_i_deg: float
    theta_o_deg: float
    why: str


def _header_lines(path: Path) -> int:
    """How many lines precede the first data row (the magic line, metadata and comments, the column header)."""
    n = 0
    with open(path, encoding="utf-8-sig", errors="replace", newline=None) as fh:
        for line in fh:
            n += 1
            if not line.startswith("#"):
                return n
    return n


def _nearest(rows: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each row (N, 2), the larger angle difference (deg) to its nearest point of ``points`` (M, 2) in that
    (Chebyshev) sense, and that point's index; a k-d tree, so 20,000 x 20,000 stays fast."""
    if len(points) == 0:
        return np.full(len(rows), np.inf), np.zeros(len(rows), dtype=int)
    from scipy.spatial import cKDTree

    d, k = cKDTree(points).query(rows, k=1, p=np.inf)
    return np.asarray(d, dtype=float), np.asarray(k, dtype=int)


def row_problems(existing: Slice, measurable: Sequence[Sequence[float]], tolerance_deg: float,
                 adaptive: bool = False, geometry: Any = None, path: Path | None = None) -> list[RowProblem]:
    """The rows of ``existing`` (a slice being resumed) that are not points of the plan (``measurable``: its
    measurable points, degrees) within ``tolerance_deg``, or whose values are impossible for their standard
    deviations; see the module docstring. ``adaptive``: the plan refines (``geometry``: what the bench can
    measure, :meth:`acquisition.plans.geometry.Geometry.reasons`). ``path``: the file, for line numbers."""
    n = len(existing)
    if n == 0:
        return []
    rows = np.stack([existing.theta_i_deg, existing.theta_o_deg], axis=1)
    pts = np.asarray(measurable, dtype=float).reshape(-1, 2)
    tol = max(float(tolerance_deg), 1e-6)
    dist, near = _nearest(rows, pts)
    off = dist > tol
    if adaptive and off.any() and len(pts):
        inc = np.unique(pts[:, 0])
        k = np.argmin(np.abs(rows[:, :1] - inc[None, :]), axis=1)  # the nearest planned incidence of each row
        on_inc = np.abs(inc[k] - rows[:, 0]) <= tol
        lo = np.array([pts[pts[:, 0] == t, 1].min() for t in inc])[k]
        hi = np.array([pts[pts[:, 0] == t, 1].max() for t in inc])[k]
        inside = on_inc & (rows[:, 1] >= lo - tol) & (rows[:, 1] <= hi + tol)
        if geometry is not None and inside.any():
            why = geometry.reasons(rows[inside])
            inside[np.flatnonzero(inside)] = np.array([w is None for w in why], dtype=bool)
        off &= ~inside
    f, sd = existing.brdf()
    low = below_zero(f, sd)
    first = _header_lines(path) + 1 if path is not None else 1
    edited = _check_values(path, n) if path is not None else {}
    out = []
    for i in np.flatnonzero(off | low | np.isin(np.arange(n), list(edited))):
        ti, to = float(rows[i, 0]), float(rows[i, 1])
        if i in edited:
            why = edited[int(i)]
        elif off[i]:
            if len(pts):
                p = pts[near[i]]
                why = (f"not a point of the plan (nearest planned point ({p[0]:g}, {p[1]:g}) is {dist[i]:.3g} deg "
                       f"away; [motion].tolerance_deg = {tol:g})")
            else:
                why = "not a point of the plan (it has no measurable point)"
        else:
            c = int(np.argmin(f[i]))
            sig = -f[i, c] / sd[i, c] if sd[i, c] > 0 else float("inf")
            why = (f"f_r {f[i, c]:.4g} +- {sd[i, c]:.2g} 1/sr is {sig:.0f} standard deviations below zero "
                   "(impossible for its uncertainty)")
        out.append(RowProblem(int(i), first + int(i), ti, to, why))
    return out


def _check_values(path: Path, n: int) -> dict[int, str]:
    """The rows (index -> why) whose check value in ``slice.crc`` (:mod:`acquisition.run.sliceout`) does not match
    their line, or that have none while a later row has one; {} without the file."""
    from acquisition.run.sliceout import ROWCHECK_NAME, read_row_checks, row_check

    checks = read_row_checks(path)
    if checks is None:
        return {}
    with open(path, encoding="utf-8-sig", newline="") as fh:
        lines = fh.read().splitlines(keepends=True)
    head = _header_lines(path)
    columns = [c.strip() for c in lines[head - 1].split(",")]
    body = [ln for ln in lines[head:] if ln.endswith(("\n", "\r"))][:n]
    have = [row_check(ln, columns) for ln in body]  # the file was read as a slice: its rows are numbers
    want = [checks.get((a, b)) for a, b, _ in have]
    later = np.flip(np.cumsum(np.flip([w is not None for w in want]))) > 0  # a row at or after it has one
    out = {}
    for i, (got, w) in enumerate(zip(have, want, strict=True)):
        if w is None:
            if i + 1 < len(want) and later[i + 1]:
                out[i] = f"no check value for it in {ROWCHECK_NAME}: the capture did not write this row"
        elif w != got[2]:
            out[i] = (f"edited or corrupted since it was written (its check value in {ROWCHECK_NAME} does not "
                      "match)")
    return out


def describe_problems(path: Path, problems: Sequence[RowProblem], limit: int = 5) -> str:
    """``line 17 (70, 50): not a point of the plan (...); ...`` for the first ``limit`` problems."""
    shown = "; ".join(f"{path}:{p.line} ({p.theta_i_deg:g}, {p.theta_o_deg:g}): {p.why}" for p in problems[:limit])
    more = f"; ... ({len(problems)} rows in all)" if len(problems) > limit else ""
    return shown + more


def set_aside(path: Path, problems: Sequence[RowProblem]) -> Path:
    """Move the rows of ``problems`` out of the slice at ``path``: appended, as written, to ``SET_ASIDE_NAME``
    beside it (created with the slice's header lines), then the slice rewritten atomically without them. Returns
    the set-aside file."""
    drop = {p.index for p in problems}
    with open(path, encoding="utf-8-sig", newline="") as fh:
        lines = fh.read().splitlines(keepends=True)
    head = _header_lines(path)
    header, body = lines[:head], lines[head:]
    if body and not body[-1].endswith(("\n", "\r")):  # a torn last line: the resume cuts it off anyway
        body = body[:-1]
    kept = [ln for k, ln in enumerate(body) if k not in drop]
    gone = [ln for k, ln in enumerate(body) if k in drop]
    aside = path.with_name(SET_ASIDE_NAME)
    new_file = not aside.exists()
    with open(aside, "a", encoding="utf-8", newline="") as fh:
        fh.writelines((header if new_file else []) + gone)
        fh.flush()
    with atomic_open(path, "w", encoding="utf-8", newline="") as fh:
        fh.writelines(header + kept)
    return aside
