"""Never a catastrophic table: where the samples cannot decide, lean to the conservative estimate.

A reconstruction is an estimate of f_r in every cell; the samples fix it in the cells they touch (and their
neighbours), and elsewhere it is whatever the method extrapolates: a fitted lobe's Fresnel rise, a prior
material's grazing peak. The error a renderer shows is lopsided there: a table too dark where it was not
measured costs at most the missing light (a linear image error of at most 100 %), one too bright costs without
bound (a black plastic fitted from one slice with a bright grazing rim: 121 % linear image error).

So with a prior of measured materials (``--prior``), ``auto``'s table is kept below an upper credible bound
wherever it is not measured: the prior's posterior median (:func:`reconstruction.assess.uncertainty.reference_for`)
times ``exp(GUARD_SIGMAS x sigma)``, its own sigma of ln f. Without a prior nothing is bounded: the built-in
analytic family is too narrow (on the demo's exact lambert + GGX fit it would lower 11 % of the unmeasured
cells and 13 % of the energy). In measured cells the
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

from reconstruction.formats import merl
from reconstruction.formats.slicefile import Slice
from reconstruction.methods import Reconstruction
from reconstruction.methods import prior as P

Array = NDArray[np.float64]

__all__ = ["GUARD_SIGMAS", "Conservative", "conservative", "upper_bound_table"]

#: the upper bound is the prior posterior's median times exp(GUARD_SIGMAS sigma): 1 and 2 did equally on 42 real
#: materials from one slice (1 lowered the worst linear image error from 171 % to 129 %, 2 to 133 %);
#: benchmarks/bench_real_materials.py --methods auto+prior,auto+prior-unbounded compares with and without
GUARD_SIGMAS = 1.0


def upper_bound_table(ref: P.PriorReconstruction, k: float = GUARD_SIGMAS) -> Array:
    """(C, 90, 90, 180) the reference posterior's median times exp(k sigma of ln f), in the MERL cells."""
    assert ref.sigma_ln is not None
    med = np.maximum(P.grid_to_merl(ref.values), 0.0)
    return med * np.exp(k * P.grid_to_merl(ref.sigma_ln.astype(np.float64)))


@dataclass
class Conservative:
    """``inner`` bounded above by ``bound`` (C, 90, 90, 180) in the cells where ``free`` (90, 90, 180) is True
    (not measured); everything else (its method, parameters, report) is ``inner``'s."""

    inner: Reconstruction
    bound: Array
    free: NDArray[np.bool_]
    info: dict[str, Any] = field(default_factory=dict)

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
        b = np.nan_to_num(merl.lookup(self.bound, wi[up], wo[up], interpolate=True), nan=np.inf)
        idx, _ = merl.lookup_cells(wi[up], wo[up], interpolate=False)
        free = self.free.ravel()[idx[:, 0]]
        b = b[:, : v.shape[1]] if b.shape[1] >= v.shape[1] else np.broadcast_to(b[:, :1], (b.shape[0], v.shape[1]))
        out = v.copy()
        out[up] = np.where(free[:, None], np.minimum(v[up], b), v[up])
        return out

    def bound_table(self, table: Array) -> Array:
        """``table`` (3, 90, 90, 180), the method's, bounded where not measured."""
        b = self.bound if self.bound.shape[0] == table.shape[0] else np.broadcast_to(self.bound[:1], table.shape)
        return np.where(self.free[None] & (table > b), b, table)

    def report(self) -> dict[str, Any]:
        return self.inner.report()


def conservative(rec: Reconstruction, table: Array, s: Slice, ref: P.PriorReconstruction,
                 k: float = GUARD_SIGMAS) -> tuple[Conservative, Array, dict[str, Any]]:
    """(the bounded reconstruction, its table, the report's ``conservative`` section) of ``rec`` and its
    ``table`` (3, 90, 90, 180) from the samples ``s``, with ``ref`` the reference posterior."""
    from reconstruction.assess.uncertainty import cell_classes

    free = cell_classes(s) > 0
    bound = upper_bound_table(ref, k)
    wrapped = Conservative(rec, bound, free)
    out = wrapped.bound_table(table)
    valid = merl.valid_mask()[None]
    lowered = valid[0] & np.any(out < table, axis=0)  # a cell is lowered when any of its channels is
    fc = _cos_weights()[None]
    before = float(np.sum(np.where(valid, table, 0.0) * fc))
    after = float(np.sum(np.where(valid, out, 0.0) * fc))
    info = {"applied": bool(lowered.any()),
            "rule": f"where no sample rests on a cell, f_r is at most the reference posterior's median times "
                    f"exp({k:g} sigma) (its own sigma of ln f); measured cells are the method's",
            "reference": ref.info.get("prior", {}).get("folder") or "built-in analytic family",
            "cells_lowered": int(lowered.sum()), "cells": int(np.sum(valid & free[None])),
            "energy_removed": (1.0 - after / before) if before > 0 else 0.0}
    wrapped.info = info
    return wrapped, out, info


@lru_cache(maxsize=1)
def _cos_weights() -> Array:
    """(90, 90, 180) cos theta_i cos theta_o at the bin centres (the weight of a cell's light in a render)."""
    from reconstruction.core.geometry import dirs_from_half_diff

    th, td, pd = np.broadcast_arrays(*merl.cell_angles())
    wi, wo = dirs_from_half_diff(th.ravel(), np.zeros(th.size), td.ravel(), pd.ravel())
    return (np.clip(wi[:, 2], 0, None) * np.clip(wo[:, 2], 0, None)).reshape(th.shape)
