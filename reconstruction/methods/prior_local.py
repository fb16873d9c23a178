"""Local priors: the prior of :mod:`reconstruction.methods.prior` built from the materials nearest to the sample.

The linear prior is one space for every material: a glossy metal is completed with directions that also serve
fabrics and paints. A **local** prior keeps, of the prior's materials, only the ``n_near`` whose mapped values
y = log(f cos theta_i cos theta_o / s + EPS) at the samples are nearest to the sample's (each row scaled by its own
median at the samples, as the basis scales it), and builds the principal-component basis from those alone
(:func:`reconstruct_local`): the model bends with the material, a linear space per neighbourhood.

A second, non-parametric use of the same distances (:func:`reconstruct_blend`): the sample's mapped vector is the
kernel-weighted mean of its ``n_near`` nearest prior rows (material x channel), offset to the samples' level;
no linear space at all (a Nadaraya-Watson regression over materials). It tells whether a local prior's gain comes
from the neighbours or from the linear fit among them.

Distances are mean squared differences in the mapped space over the samples (dimensionless, ln units squared);
a material's distance is, per channel of the sample, the nearest of its channel rows, averaged over the sample's
channels.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from reconstruction.core.samples import everywhere
from reconstruction.core.slicedata import Slice
from reconstruction.methods import prior as P

Array = NDArray[np.float64]

__all__ = ["N_NEAR", "BLEND_NEAR", "BLEND_TAU", "row_distances", "nearest_materials", "reconstruct_local",
           "reconstruct_blend", "blend_mapped"]

#: materials in a local basis (their 3 channels each: up to 3 N_NEAR - 1 components). Chosen among 10/20/30/45 on
#: 13 real materials that the evaluation leaves out (benchmarks/bench_prior_candidates.py --dev --every 9
#: --offset 1 --slices 1,2): 20 had the best worst material from one and two slices, medians within 0.3 dB of 30's
N_NEAR = 20
#: rows (material x channel) a blend averages, and the kernel's width in the mapped space (ln units, rms); chosen
#: among (4, 0.3), (8, 0.3), (16, 1) the same way
BLEND_NEAR, BLEND_TAU = 4, 0.3


def _mapped_rows(ps: P.PriorSet, idx: NDArray[np.intp], w: Array, keep: list[int]) -> tuple[Array, Array]:
    """The rows of materials ``keep`` at the samples (``idx``, ``w``: their interpolation on the training cells):
    (mapped values (T, n), scales (T,)), T = len(keep) x channels."""
    nc = ps.tables.shape[1]
    rows = (np.asarray(keep)[:, None] * nc + np.arange(nc)).ravel()
    fc = ps._fc()[rows]
    at = np.einsum("nj,tnj->tn", w, fc[:, idx]).astype(np.float64)  # (T, n) f cos cos at the samples
    scales = P.channel_scales(at.reshape(len(keep), nc, -1)).reshape(-1)
    return np.log(at / scales[:, None] + P.EPS), scales


def _observed(s: Slice) -> tuple[Slice, NDArray[np.intp], Array, Array, Array]:
    """The samples within the basis's cells, their design (idx, w), their mapped values y (C, n) and scales (C,)."""
    s, _ = P._within_basis(everywhere(s))
    idx, w, cs = P._design(s)
    obs = np.maximum(np.asarray(s.values, dtype=np.float64), 0.0) * cs[:, None]  # (n, C) f cos cos
    scale = P.channel_scales(obs.T)
    return s, idx, w, np.log(obs.T / scale[:, None] + P.EPS), scale


def row_distances(y: Array, rows: Array) -> Array:
    """Mean squared difference (C, T) between the sample's mapped channels ``y`` (C, n) and prior rows (T, n)."""
    return (np.sum(y**2, axis=1)[:, None] - 2.0 * y @ rows.T + np.sum(rows**2, axis=1)[None, :]) / y.shape[1]


def _keep(ps: P.PriorSet, exclude: tuple[str, ...]) -> list[int]:
    drop = set(exclude)
    return [i for i, n in enumerate(ps.names) if n not in drop]


def nearest_materials(ps: P.PriorSet, idx: NDArray[np.intp], w: Array, y: Array, n_near: int,
                      exclude: tuple[str, ...] = ()) -> list[str]:
    """The ``n_near`` materials of ``ps`` (not in ``exclude``) nearest to the mapped values ``y`` (C, n) at the
    samples (``idx``, ``w``), nearest first."""
    keep = _keep(ps, exclude)
    rows, _ = _mapped_rows(ps, idx, w, keep)
    nc = ps.tables.shape[1]
    d = row_distances(y, rows).reshape(y.shape[0], len(keep), nc).min(axis=2).mean(axis=0)  # (materials,)
    order = np.argsort(d, kind="stable")[: max(1, min(n_near, len(keep)))]
    return [ps.names[keep[i]] for i in order]


def reconstruct_local(s: Slice, prior: P.PriorSet | str | Path, exclude: tuple[str, ...] = (),
                      n_near: int = N_NEAR, k: int | None = None, lam: float | None = None
                      ) -> P.PriorReconstruction:
    """``prior`` (:func:`reconstruct_prior`) with a basis of the ``n_near`` materials nearest to the samples
    (:func:`nearest_materials`); ``k``, ``lam`` as there (at most 3 ``n_near`` - 1 components)."""
    ps = prior if isinstance(prior, P.PriorSet) else P.load_prior(prior)
    _, idx, w, y, _ = _observed(s)
    near = nearest_materials(ps, idx, w, y, n_near, exclude)
    far = tuple(n for n in ps.names if n not in set(near))
    rec = P.reconstruct_prior(s, ps, exclude=far, k=k, lam=lam)
    rec.info["prior"]["local"] = {"nearest": near, "n_near": len(near),
                                  "distance": "mean squared difference of log(f cos cos / s + EPS) at the samples"}
    return rec


def blend_mapped(y: Array, rows_at: Array, rows_full: Array, n_near: int = BLEND_NEAR, tau: float = BLEND_TAU
                 ) -> Array:
    """The blend in the mapped space: per channel of ``y`` (C, n), the mean of the ``n_near`` nearest rows
    (``rows_at`` (T, n) at the samples, ``rows_full`` (T, M) everywhere) weighted by exp(-d / (2 tau^2)), plus the
    mean offset to ``y`` at the samples. (C, M)."""
    d = row_distances(y, rows_at)  # (C, T)
    n_near = max(1, min(n_near, d.shape[1]))
    near = np.argsort(d, axis=1, kind="stable")[:, :n_near]  # (C, n_near)
    dn = np.take_along_axis(d, near, axis=1)
    wk = np.exp(-(dn - dn[:, :1]) / (2.0 * tau**2))
    wk /= wk.sum(axis=1, keepdims=True)
    full = np.einsum("ck,ckm->cm", wk, rows_full[near])
    offset = np.mean(y - np.einsum("ck,ckn->cn", wk, rows_at[near]), axis=1)
    return full + offset[:, None]


def reconstruct_blend(s: Slice, prior: P.PriorSet | str | Path, exclude: tuple[str, ...] = (),
                      n_near: int = BLEND_NEAR, tau: float = BLEND_TAU) -> P.PriorReconstruction:
    """The kernel-weighted mean of the prior rows nearest to the samples (:func:`blend_mapped`), mapped back to
    f_r on the reduced grid (beyond 81 deg the last value along theta_d, as :func:`reconstruct_prior`)."""
    ps = prior if isinstance(prior, P.PriorSet) else P.load_prior(prior)
    g = P._grid()
    s, idx, w, y, scale = _observed(s)
    keep = _keep(ps, exclude)
    rows_at, rscale = _mapped_rows(ps, idx, w, keep)
    nc = ps.tables.shape[1]
    rows = (np.asarray(keep)[:, None] * nc + np.arange(nc)).ravel()
    mapped = np.empty((y.shape[0], int(g["train"].sum())))
    # the full rows are only read for the chosen neighbours: map them one channel of the sample at a time
    d = row_distances(y, rows_at)
    chosen = np.unique(np.argsort(d, axis=1)[:, : max(1, min(n_near, d.shape[1]))])
    full = np.log(ps._fc()[rows[chosen]].astype(np.float64) / rscale[chosen, None] + P.EPS)
    mapped[:] = blend_mapped(y, rows_at[chosen], full, n_near, tau)
    f = np.zeros((y.shape[0], g["cos"].size))
    f[:, g["train"]] = np.maximum(np.exp(mapped) - P.EPS, 0.0) * scale[:, None] / g["cos"][g["train"]]
    f = np.where(g["cos"] > 0, P._extend(f), 0.0)
    info = {"prior": {"folder": ps.folder, "materials": len(keep), "excluded": sorted(set(exclude) & set(ps.names))},
            "parameters": {"n_near": n_near, "tau": tau},
            "notes": [f"the kernel-weighted mean of the {n_near} prior rows nearest to the samples in "
                      f"log(f cos cos / s + {P.EPS:g})"]}
    return P.PriorReconstruction(list(s.channels), f, info, method="prior-blend")
