"""Never a catastrophic table: where the samples cannot decide, lean to the conservative estimate.

A reconstruction is an estimate of f_r in every cell; the samples fix it in the cells they touch (and their
neighbours), and elsewhere it is whatever the method extrapolates: a fitted lobe's Fresnel rise, a prior
material's grazing peak. The error a renderer shows is lopsided there: a table too dark where it was not
measured costs at most the missing light (a linear image error of at most 100 %), one too bright costs without
bound (a black plastic fitted from one slice with a bright grazing rim: 121 % linear image error).

So with a prior of measured materials (``--prior``), ``auto``'s table is kept below an upper credible bound
wherever it is not measured: the prior's posterior median (:func:`reconstruction.assess.uncertainty.reference_for`)
times ``exp(GUARD_SIGMAS x sigma)``, its own sigma of ln f. Without a prior the reference is the built-in
analytic family's posterior, a narrower family: the bound is looser (``GUARD_SIGMAS_ANALYTIC``) and is applied
only where it takes at least ``ANALYTIC_MIN_ENERGY`` of the table's light (a bold extrapolation), not to trim a
table within the family's band (the demo's exact lambert + GGX fit: it would take 9 %), and only where the
family's band holds the samples themselves (``ANALYTIC_MAX_ABOVE``: not a mirror, whose measured peak lies far
above it). In measured cells the
table is the method's. Only ever lowering cells keeps every check the table passed (albedo, non-negativity) and
the lowering is the same for (wi, wo) and (wo, wi), so reciprocity too. The report's ``conservative`` section says
how many cells were lowered and how much energy that took.

:class:`Conservative` wraps the reconstruction so that every output (the table, the previews, the RGL, Zemax and
principled exports) sees the same bounded BRDF.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.base import Reconstruction
from reconstruction.core import merlgrid, merltable
from reconstruction.core.slicedata import Slice
from reconstruction.methods import prior as P

Array = NDArray[np.float64]

__all__ = ["GUARD_SIGMAS", "GUARD_SIGMAS_ANALYTIC", "ANALYTIC_MIN_ENERGY", "ANALYTIC_MAX_ABOVE", "Conservative",
           "conservative", "samples_above", "upper_bound_table"]

#: the upper bound is the prior posterior's median times exp(GUARD_SIGMAS sigma): 1 and 2 did equally on 42 real
#: materials from one slice (1 lowered the worst linear image error from 171 % to 129 %, 2 to 133 %);
#: benchmarks/bench_real_materials.py --methods auto+prior,auto+prior-unbounded compares with and without
GUARD_SIGMAS = 1.0
#: without a prior (the built-in analytic family's posterior as the reference, whose sigma is too small: 44-53 %
#: of direction pairs within 1 sigma, docs/methods.md): median x exp(3 sigma), applied when it takes at least 10 %
#: of the table's cosine-weighted light. On every third of the 141 real materials (benchmarks/bench_guard.py
#: --every 3 --slices 1,2 --no-prior; the two numbers chosen on them) that takes the PSNR median from 29.8 to
#: 30.8 dB from one slice at 40 deg and the worst from 10.7 to 18.5 dB from 40/70 deg (tables above 50 % linear
#: image error 9 -> 8 and 4 -> 3), and leaves exact lambert + GGX fits as written (the demo's plastic: the bound
#: would take 9.0 %; a synthetic blue plastic from 20/40/60 deg 7.1 %, and at k = 2 its 14 % cost 7.5 % of linear
#: image error on a perfect fit)
GUARD_SIGMAS_ANALYTIC = 3.0
ANALYTIC_MIN_ENERGY = 0.10
#: ... and only when its band holds the measured samples: at most this share of their light above the bound (a
#: mirror, ggx alpha 0.001, has 13.9 % of its measured light above it: the family does not describe the material,
#: its bound would cut the lobe off the plane; a black phenolic from 40/70 deg 3.0 %, where the bound takes its
#: PSNR from 10.7 to 26.7 dB)
ANALYTIC_MAX_ABOVE = 0.05


def upper_bound_table(ref: P.PriorReconstruction, k: float = GUARD_SIGMAS) -> Array:
    """(C, 90, 90, 180) the reference posterior's median times exp(k sigma of ln f), in the MERL cells (a grey
    posterior: one channel's numbers seen in all three)."""
    assert ref.sigma_ln is not None
    med = np.array(P.grid_to_merl(ref.values)[: 3 if ref.values.shape[0] == 3 else 1])  # computed in place:
    sg = np.array(P.grid_to_merl(ref.sigma_ln.astype(np.float64))[: med.shape[0]])  # two tables' memory, no more
    np.maximum(med, 0.0, out=med)
    sg *= k
    np.exp(sg, out=sg)
    med *= sg
    return np.broadcast_to(med, (3, *med.shape[1:])) if med.shape[0] == 1 else med


@dataclass
class Conservative:
    """``inner`` bounded above by ``bound`` (C, 90, 90, 180) in the cells where ``free`` (90, 90, 180) is True
    (not measured); everything else (its method, parameters, report) is ``inner``'s."""

    inner: Reconstruction
    bound: Array
    free: NDArray[np.bool_]
    info: dict[str, Any] = field(default_factory=dict)
    #: the bounded ``eval`` is no longer the method's closed form: no ``analytic_lobes`` to export
    #: (:func:`reconstruction.base.offers`); its fitted parameters stay the method's
    analytic_lobes = None

    @property
    def method(self) -> str:
        return str(self.inner.method)

    def __getattr__(self, name: str) -> Any:  # parameters, report(), samples_left_out ...: the method's own
        if name in ("inner", "bound", "free", "info"):
            raise AttributeError(name)
        return getattr(self.inner, name)

    def eval(self, wi: ArrayLike, wo: ArrayLike) -> Array:
        """f_r (N, C): the method's value, at most the bound (trilinear between bin centres) where the nearest cell
        is not measured."""
        wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
        wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
        v = np.asarray(self.inner.eval(wi, wo), dtype=np.float64).reshape(wi.shape[0], -1)
        up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        if not up.any():
            return v
        b = np.nan_to_num(merltable.lookup(self.bound, wi[up], wo[up], interpolate=True), nan=np.inf)
        idx, _ = merltable.lookup_cells(wi[up], wo[up], interpolate=False)
        free = self.free.ravel()[idx[:, 0]]
        b = b[:, : v.shape[1]] if b.shape[1] >= v.shape[1] else np.broadcast_to(b[:, :1], (b.shape[0], v.shape[1]))
        out = v.copy()
        out[up] = np.where(free[:, None], np.minimum(v[up], b), v[up])
        return out

    def bound_table(self, table: Array) -> Array:
        """``table`` (3, 90, 90, 180), the method's, bounded where not measured."""
        b = self.bound if self.bound.shape[0] == table.shape[0] else np.broadcast_to(self.bound[:1], table.shape)
        out = np.array(table, dtype=np.float64)
        for a in range(0, table.shape[1], _ROWS):  # a few megabytes of temporaries at a time
            sl = slice(a, a + _ROWS)
            np.copyto(out[:, sl], b[:, sl], where=self.free[None, sl] & (table[:, sl] > b[:, sl]))
        return out

    def report(self) -> dict[str, Any]:
        return self.inner.report()


def samples_above(bound: Array, s: Slice) -> float:
    """The share of the samples' light (f cos theta_i cos theta_o, summed over samples and channels) above
    ``bound`` (3, 90, 90, 180) at their own directions (in-plane, or anywhere for points on the hemisphere): 0 when
    the reference's band holds what was measured."""
    from reconstruction.core.samples import sample_directions

    wi, wo = sample_directions(s)
    f = np.asarray(s.values, dtype=np.float64).reshape(len(s), -1)
    b = np.nan_to_num(merltable.lookup(bound, wi, wo, interpolate=True), nan=np.inf)[:, : f.shape[1]]
    w = (np.clip(wi[:, 2], 0, None) * np.clip(wo[:, 2], 0, None))[:, None]
    total = float(np.sum(np.clip(f, 0, None) * w))
    return float(np.sum(np.clip(f - b, 0, None) * w)) / total if total > 0 else 0.0


def conservative(rec: Reconstruction, table: Array, s: Slice, ref: P.PriorReconstruction,
                 k: float = GUARD_SIGMAS, min_energy: float = 0.0, max_above: float | None = None,
                 bound: Array | None = None) -> tuple[Conservative, Array, dict[str, Any]]:
    """(the bounded reconstruction, its table, the report's ``conservative`` section) of ``rec`` and its
    ``table`` (3, 90, 90, 180) from the samples ``s``, with ``ref`` the reference posterior. Nothing is lowered
    (``applied`` False, the table as it was, ``why`` says so) when the bound would take less than ``min_energy``
    of the table's cosine-weighted light, or, with ``max_above``, when more than that share of the samples' own
    light lies above it (the reference does not describe this material: it would bound it wrongly). ``bound``:
    :func:`upper_bound_table` of ``ref`` and ``k`` when computed already (the pipeline's helper thread)."""
    from reconstruction.assess.uncertainty import ANALYTIC_NAME, cell_classes

    free = cell_classes(s) > 0
    bound = upper_bound_table(ref, k) if bound is None else bound
    wrapped = Conservative(rec, bound, free)
    lowered, before, removed = _lowering(table, bound, free)
    info = {"applied": bool(lowered.any()),
            "rule": f"where no sample rests on a cell, f_r is at most the reference posterior's median times "
                    f"exp({k:g} sigma) (its own sigma of ln f); measured cells are the method's",
            "reference": ref.info.get("prior", {}).get("folder") or ANALYTIC_NAME, "k": k,
            "cells_lowered": int(lowered.sum()), "cells": int(np.sum(merlgrid.valid_mask() & free)),
            "energy_removed": removed / before if before > 0 else 0.0}
    above = samples_above(bound, s) if max_above is not None and info["applied"] else 0.0
    if max_above is not None:
        info["samples_above"] = above
    why = None
    if info["applied"] and max_above is not None and above > max_above:  # the reference misses the measurement
        why = (f"{above:.1%} of the samples' own light lies above the reference's bound (more than "
               f"{max_above:.0%}): the reference does not describe this material")
    elif info["applied"] and info["energy_removed"] < min_energy:  # within the reference's band: left as it is
        why = (f"the bound would take {info['energy_removed']:.1%} of the light, less than {min_energy:.0%}: the "
               "table is within the reference's band")
    if why is not None:
        info.update({"applied": False, "cells_lowered": 0, "would_remove": info["energy_removed"],
                     "energy_removed": 0.0, "why": why})
    out = wrapped.bound_table(table) if info["applied"] else table
    wrapped.info = info
    return wrapped, out, info


#: theta_h rows per step of :func:`_lowering` (its temporaries a few megabytes, reused: on the 2-core VM a page of
#: memory touched for the first time costs about as much as computing on it)
_ROWS = 10


def _lowering(table: Array, bound: Array, free: NDArray[np.bool_]) -> tuple[NDArray[np.bool_], float, float]:
    """(the cells the bound lowers (90, 90, 180), the table's cosine-weighted light, the light the bound takes),
    over the cells above the horizon, ``table`` (3, 90, 90, 180) against ``bound`` where ``free``."""
    valid = merlgrid.valid_mask()
    fc = _cos_weights()
    lowered = np.zeros(free.shape, dtype=bool)
    before = removed = 0.0
    for a in range(0, free.shape[0], _ROWS):
        sl = slice(a, a + _ROWS)
        t, b, w = table[:, sl], bound[:, sl], fc[sl]  # fc is 0 below the horizon; the table NaN there
        over = free[None, sl] & valid[None, sl] & (t > b)
        lowered[sl] = over.any(axis=0)
        before += float(np.sum(np.where(valid[None, sl], t, 0.0) * w))
        removed += float(np.sum(np.where(over, t - b, 0.0) * w))
    return lowered, before, removed


@lru_cache(maxsize=1)
def _cos_weights() -> Array:
    """(90, 90, 180) cos theta_i cos theta_o at the bin centres (the weight of a cell's light in a render), from
    the table's cached bin-centre cosines."""
    ci, co = merlgrid.cell_cosines()
    return np.clip(ci, 0, None) * np.clip(co, 0, None)
