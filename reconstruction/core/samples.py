"""Samples at any direction pair, for the methods that can use them (``fit``, ``microfacet``).

A bench measures in the plane of incidence, so :class:`~reconstruction.core.slicedata.Slice` holds (theta_i, signed
theta_o) pairs. Other instruments' files (a Zemax tabular BSDF, :mod:`reconstruction.formats.zemax`) hold the whole
hemisphere. Such an input is handed to the methods as an ordinary in-plane :class:`Slice` (every method reads
it) that also carries every point as a :class:`DirectionalSlice` (:func:`everywhere`), which ``fit`` and
``microfacet`` use instead (:func:`sample_directions` gives their direction pairs).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.core.geometry import inplane_to_dirs
from reconstruction.core.slicedata import Slice

Array = NDArray[np.float64]

__all__ = ["DirectionalSlice", "SliceWithPoints", "sample_directions", "everywhere", "directional_slice",
           "out_of_plane", "points_anywhere", "scans_hemisphere", "PointFolds", "samples_used", "thin_samples",
           "MAX_SAMPLES", "at_samples"]


@dataclass
class DirectionalSlice(Slice):
    """Samples at arbitrary direction pairs ``wi``, ``wo`` (N, 3) (unit vectors, z = normal, wi towards the light).

    ``theta_i_deg`` is the polar angle of wi and ``theta_o_deg`` the polar angle of wo, signed + on the specular
    side (the side of wo opposite to wi's azimuth), so in-plane samples read as they would in a slice file.
    """

    wi: Array = field(default_factory=lambda: np.zeros((0, 3)))
    wo: Array = field(default_factory=lambda: np.zeros((0, 3)))

    def __post_init__(self) -> None:
        super().__post_init__()
        self.wi = np.asarray(self.wi, dtype=np.float64).reshape(-1, 3)
        self.wo = np.asarray(self.wo, dtype=np.float64).reshape(-1, 3)
        if self.wi.shape[0] != len(self) or self.wo.shape[0] != len(self):
            raise ValueError(f"{self.source}: {len(self)} samples but {self.wi.shape[0]} wi and {self.wo.shape[0]} "
                             f"wo directions")

    def take(self, idx: ArrayLike) -> DirectionalSlice:
        """The samples ``idx`` (index array or boolean mask), with their directions."""
        idx = np.asarray(idx)
        base = Slice.take(self, idx)
        return DirectionalSlice(base.theta_i_deg, base.theta_o_deg, base.values, base.channels, base.std,
                                base.repeats, base.unix_time_s, base.meta, base.source, self.wi[idx], self.wo[idx])


def directional_slice(wi: ArrayLike, wo: ArrayLike, values: ArrayLike, channels: list[str],
                      meta: dict[str, Any] | None = None, source: str = "<memory>") -> DirectionalSlice:
    """A :class:`DirectionalSlice` of f_r ``values`` (N, C) at ``wi``, ``wo`` (N, 3), angles derived from them."""
    wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
    wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
    ti = np.degrees(np.arctan2(np.hypot(wi[:, 0], wi[:, 1]), wi[:, 2]))
    side = wo[:, 0] * -wi[:, 0] + wo[:, 1] * -wi[:, 1]  # + when wo lies on the far side of wi's azimuth
    to = np.degrees(np.arctan2(np.hypot(wo[:, 0], wo[:, 1]), wo[:, 2])) * np.where(side >= 0, 1.0, -1.0)
    return DirectionalSlice(ti, to, values, list(channels), meta={"quantity": "brdf", **(meta or {})},
                            source=source, wi=wi, wo=wo)


@dataclass
class SliceWithPoints(Slice):
    """An in-plane :class:`Slice` that also carries ``points``: every sample of its source, anywhere.

    Sorting keeps the points (a permutation drops nothing); any real subset (a cross-validation fold) is a
    plain :class:`Slice`, so held-out in-plane samples cannot leak back through the points.
    """

    points: DirectionalSlice | None = None

    def take(self, idx: ArrayLike) -> Slice:
        idx = np.asarray(idx)
        base = Slice.take(self, idx)
        whole = bool(idx.all()) if idx.dtype == bool else np.unique(idx).size == len(self)
        if not whole or idx.size != len(self):
            return base
        return SliceWithPoints(base.theta_i_deg, base.theta_o_deg, base.values, base.channels, base.std,
                               base.repeats, base.unix_time_s, base.meta, base.source, self.points)


#: most points handed to fit / microfacet: on a 2-core machine fit takes ~2 s and microfacet ~0.5 s on 10,000
#: points, while all 129,000 points of a 361 x 181 x 4 file take 8.5 s and 150 s
MAX_POINTS = 10_000


def everywhere(s: Slice, max_points: int = MAX_POINTS) -> Slice:
    """The samples a method that can use any direction pair should fit: ``s.points`` if ``s`` carries them (all
    of them up to ``max_points``; beyond, every in-plane point and an even random subset, seed 0, of the rest)."""
    pts = getattr(s, "points", None)
    if not isinstance(pts, DirectionalSlice) or not len(pts):
        return s
    if len(pts) <= max_points:
        return pts
    inplane = (np.abs(pts.wi[:, 1]) < 1e-12) & (np.abs(pts.wo[:, 1]) < 1e-12)
    rest = np.nonzero(~inplane)[0]
    k = max(0, max_points - int(inplane.sum()))
    pick = np.random.default_rng(0).choice(rest, size=min(k, rest.size), replace=False)
    keep = np.sort(np.concatenate([np.nonzero(inplane)[0], pick]))
    sub = pts.take(keep)
    sub.meta = {**sub.meta, "points_used": f"{keep.size} of {len(pts)} (every in-plane point and an even random "
                                          f"subset of the rest; at most {max_points})"}
    return sub


def sample_directions(s: Slice) -> tuple[Array, Array]:
    """(wi, wo) unit vectors (N, 3) of the samples of ``s``: its own for a :class:`DirectionalSlice`, else from
    (theta_i, signed theta_o) in the plane of incidence."""
    if isinstance(s, DirectionalSlice):
        return s.wi, s.wo
    return inplane_to_dirs(np.radians(s.theta_i_deg), np.radians(s.theta_o_deg))


def out_of_plane(p: DirectionalSlice) -> NDArray[np.bool_]:
    """(N,) True where wo does not lie in the plane of wi and the normal."""
    return np.abs(p.wi[:, 0] * p.wo[:, 1] - p.wi[:, 1] * p.wo[:, 0]) > 1e-9


def scans_hemisphere(p: DirectionalSlice, tol: float = 1e-6) -> bool:
    """True when the outgoing directions of some light direction of ``p`` span the hemisphere in two angles (a
    Zemax or RGL file's scan), False when those of every light direction lie on one great circle: sweeps of a
    bench's detector arm, with the sample tilted or not (the smallest eigenvalue of sum(wo wo^T) per light
    direction, relative to its trace, at most ``tol``)."""
    _, group = np.unique(np.round(p.wi, 6), axis=0, return_inverse=True)
    group = group.reshape(-1)
    scatter = np.zeros((int(group.max()) + 1 if group.size else 0, 3, 3))
    np.add.at(scatter, group, p.wo[:, :, None] * p.wo[:, None, :])
    ev = np.linalg.eigvalsh(scatter)  # ascending, per light direction
    return bool(np.any(ev[:, 0] > tol * np.maximum(ev.sum(axis=1), 1e-300)))


def points_anywhere(s: Slice) -> DirectionalSlice | None:
    """``s.points`` when ``s`` carries points of which some lie out of the plane of incidence, else None."""
    pts = getattr(s, "points", None)
    if isinstance(pts, DirectionalSlice) and len(pts) and bool(out_of_plane(pts).any()):
        return pts
    return None


@dataclass
class PointFolds(DirectionalSlice):
    """Points anywhere, cross-validated as such: a subset (:meth:`take`, a fold's training set) is the methods'
    input, its in-plane points as the slice and the subset itself as the points (nothing held out leaks back)."""

    def take(self, idx: ArrayLike) -> Slice:  # type: ignore[override]
        sub = DirectionalSlice.take(self, idx)
        inplane = np.nonzero(~out_of_plane(sub))[0]
        # one row per in-plane direction pair (a grid may reach one twice: radial 0 at every azimuth, 0 and 360)
        _, first = np.unique(np.round(np.c_[sub.theta_i_deg[inplane], sub.theta_o_deg[inplane]], 6), axis=0,
                             return_index=True)
        base = Slice.take(sub, inplane[np.sort(first)])
        return SliceWithPoints(base.theta_i_deg, base.theta_o_deg, base.values, base.channels, base.std, base.repeats,
                               base.unix_time_s, base.meta, base.source, sub).sorted()  # as the methods expect

    @classmethod
    def of(cls, p: DirectionalSlice) -> PointFolds:
        return cls(p.theta_i_deg, p.theta_o_deg, p.values, p.channels, p.std, p.repeats, p.unix_time_s, p.meta,
                   p.source, p.wi, p.wo)


def samples_used(s: Slice, used: Slice | None, method: str) -> dict[str, Any]:
    """What a method built from ``s`` used and left out, for the report (``used``: the samples it fitted, None for
    the in-plane rows only)."""
    pts = points_anywhere(s)
    if pts is None:
        return {"used": len(s), "of": len(s), "left_out": 0, "why": "every sample used"}
    if used is None:
        n_out = int(out_of_plane(pts).sum())
        return {"used": len(s), "of": len(s) + n_out, "left_out": n_out,
                "why": f"{method} is built from in-plane slices: it used the {len(s)} in-plane samples (azimuths 0 "
                       f"and 180) and left out the {n_out} points out of the plane of incidence"}
    left = len(pts) - len(used)
    return {"used": len(used), "of": len(pts), "left_out": left,
            "why": ("every point used" if left == 0 else
                    f"at most {MAX_POINTS} points (time): every in-plane point and an even random subset of the "
                    f"rest (seed 0)")}


#: The most in-plane samples a reconstruction uses (:func:`thin_samples`; gonio-reconstruct's inputs): far more than
#: any method's table can tell apart (1000 incidences of 100 outgoing angles; a bench's plan is at most 20,000
#: points), and few enough that every method, the uncertainty's prior and the report stay well below 1.5 GB
#: (benchmarks/bench_memory.py).
MAX_SAMPLES = 100_000
#: ... and the most incidences (revolve builds a model of each: its memory grows with their number)
MAX_INCIDENCES = 90
#: Samples nearest the mirror direction that :func:`thin_samples` keeps in every incidence (the specular peak).
PEAK_SAMPLES = 3


def thin_samples(s: Slice, max_samples: int = MAX_SAMPLES, max_incidences: int = MAX_INCIDENCES
                 ) -> tuple[Slice, str | None]:
    """At most ``max_samples`` samples of ``s``, chosen deterministically, and a sentence saying what was left out
    (None, and ``s`` itself, when it is small enough).

    Within each incidence (theta_o increasing), every k-th sample from the first, k the smallest step that
    fits, and the :data:`PEAK_SAMPLES` nearest the mirror direction; when there are too many incidences for
    that or more than ``max_incidences``, every g-th incidence (theta_i increasing) as well. The samples kept
    stay in the order of ``s``."""
    n = len(s)
    if n <= max_samples and np.unique(s.theta_i_deg).size <= max_incidences:
        return s, None
    # lean on millions of rows: int32 positions, each temporary freed as soon as it is used
    order = np.lexsort((s.theta_o_deg, s.theta_i_deg))
    ti = s.theta_i_deg[order]
    first = np.r_[True, ti[1:] != ti[:-1]]
    starts = np.flatnonzero(first).astype(np.int32)  # each incidence's first sorted position
    n_inc = starts.size
    dist = s.theta_o_deg[order] - ti  # from the mirror direction: increasing within each incidence
    del ti
    group = (np.cumsum(first, dtype=np.int32) - 1).astype(np.int32)  # incidence number of each sorted sample
    del first
    rank = np.arange(n, dtype=np.int32) - starts[group]  # position within its incidence
    ends = np.r_[starts[1:], n]
    near = starts + np.add.reduceat((dist < 0).astype(np.int32), starts)  # where the mirror direction falls
    cand = near[:, None] + np.arange(-PEAK_SAMPLES, PEAK_SAMPLES)[None, :]  # (incidences, 2 x PEAK_SAMPLES)
    ok = (cand >= starts[:, None]) & (cand < ends[:, None])
    d = np.where(ok, np.abs(dist[np.clip(cand, 0, n - 1)]), np.inf)
    del dist
    pick = np.take_along_axis(cand, np.argsort(d, axis=1, kind="stable")[:, :PEAK_SAMPLES], axis=1)
    peak = np.zeros(n, dtype=bool)
    peak[pick[np.take_along_axis(ok, np.argsort(d, axis=1, kind="stable")[:, :PEAK_SAMPLES], axis=1)]] = True
    g = max(1, int(np.ceil(n_inc * 4 * PEAK_SAMPLES / max_samples)), int(np.ceil(n_inc / max_incidences)))
    k = max(1, n // (g * max_samples))
    while True:  # a few steps: k grows until the samples fit
        keep = (group % g == 0) & ((rank % k == 0) | peak)
        if int(keep.sum()) <= max_samples:
            break
        k = int(np.ceil(k * 1.25))
    del group, rank, peak
    idx = np.sort(order[keep])
    sub = s.take(idx)
    note = (f"{s.source}: {n:,} samples; the reconstruction uses {idx.size:,} of them (at most {max_samples:,} in "
            f"{max_incidences} incidences: memory and time): "
            + (f"one theta_o in {k} of " if k > 1 else "every theta_o of ")
            + (f"one incidence in {g} (of {n_inc})" if g > 1 else f"each of the {n_inc} incidences")
            + f", and the {PEAK_SAMPLES} nearest the mirror direction in each")
    sub.meta = {**sub.meta, "samples_thinned": note}
    return sub, note


def at_samples(w: Array, rows: NDArray[Any], idx: NDArray[np.intp], chunk: int = 4096) -> NDArray[Any]:
    """(R, n): each row of ``rows`` (R, M) interpolated at the samples (``idx``, ``w``: (n, J) cells and weights),
    ``chunk`` samples at a time: ``rows[:, idx]`` whole would be R x n x J numbers (2.7 GB for the analytic
    prior's 84 rows at a million samples, 13 GB for 141 materials' 423)."""
    out = np.empty((rows.shape[0], idx.shape[0]), dtype=np.result_type(rows.dtype, w.dtype))
    for a in range(0, idx.shape[0], chunk):  # samples in blocks: a few MB of temporaries each
        out[:, a:a + chunk] = np.einsum("nj,tnj->tn", w[a:a + chunk], rows[:, idx[a:a + chunk]])
    return out
