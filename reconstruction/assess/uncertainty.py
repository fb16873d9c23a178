"""The per-cell uncertainty of a written table and the errors to expect from it.

Model. A prior of materials (the user's ``--prior`` folders; without one, a built-in family of analytic materials,
:func:`analytic_prior`) is fitted to the samples as :mod:`reconstruction.methods.prior` does, and its posterior
gives sigma of ln f per cell (:data:`reconstruction.methods.prior.SIGMA_TAU`): small where samples fix the
coefficients, large where the basis has to guess (grazing theta_d, out-of-plane phi_d far from any sample). When
the written table comes from another method, the two estimates' disagreement is part of the uncertainty:
sigma^2 = sigma_posterior^2 + (ln f_table - ln f_posterior)^2 / 4 (the variance of a two-member ensemble). The
written sigma is that of the table's own cells (the MERL layout), as a float32 array (C, 90, 90, 180). Without a
prior the analytic family is narrower than real materials and its sigma too small, so that sigma is multiplied by
:data:`SIGMA_SCALE_ANALYTIC`, a calibration chosen on real materials (``benchmarks/bench_uncertainty.py --no-prior
--scales``; docs/methods.md has the figures on all 141).

Cell classes (the report's ``uncertainty.median_sigma``): *measured* cells are those a sample falls in or next to
(one bin in theta_h and theta_d, two in phi_d); *interpolated* cells lie between measured ones (their theta_h
within the measured range of their theta_d row or the rows next to it); the rest are *extrapolated*.

Expected errors (what the user should expect against the truth, from sigma): the expected cosl2 over direction
pairs drawn uniformly in solid angle (both angles <= 80 deg), sqrt(sum (f c sigma)^2 / sum (f c)^2); the expected
linear image error and PSNR from a render of f sigma beside the render of f (the renderer is linear in the BRDF,
so f sigma renders the spread of each pixel when the errors within a pixel's footprint move together), under the
key and rim lightings, at :data:`EXPECT_SIZE` pixels with a light quadrature.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from reconstruction.cache import cached_decoded
from reconstruction.core import merlgrid
from reconstruction.core.metrics import IMAGE_MAX_VIEW_DEG, image_exposure, tone_map
from reconstruction.core.render import Quadrature, render_sphere, view_angle_mask
from reconstruction.core.slicedata import Slice
from reconstruction.methods import prior as P
from reconstruction.methods import priorcodec

Array = NDArray[np.float64]

__all__ = ["ANALYTIC_NAME", "analytic_prior", "reference_posterior", "sigma_grid", "cell_classes", "expected_errors",
           "assess_table", "EXPECT_SIZE", "expected_scene_errors", "scene_section", "SIGMA_SCALE_ANALYTIC"]

#: The analytic family standing in for a prior when none is given: lambert albedo x GGX alpha x Fresnel f0.
ANALYTIC_ALBEDOS = (0.02, 0.1, 0.35, 0.8)
ANALYTIC_ALPHAS = tuple(float(a) for a in np.geomspace(0.01, 0.7, 7))
ANALYTIC_F0 = (0.04, 0.5, 0.95)
ANALYTIC_VERSION = 3  # 2: grey, one channel per material; 3: the training cells, coded (priorcodec)
#: Image size and quadrature of the expected image errors (a cheap render; the metrics' own renders are 128 px).
EXPECT_SIZE = 32
EXPECT_QUADRATURE = Quadrature(n_cosine=21, alphas=(0.01, 0.05, 0.2, 0.5), n_per_alpha=21)
N_PAIRS = 20000
#: The calibration of sigma without a prior (the built-in family as the reference): chosen on the 16 materials of
#: nbrdf-merl among every third of the 141 (auto's tables, 1, 2 and 3 slices), where it brings the share of uniform
#: direction pairs within 2 sigma to about 90 % (76-80 % unscaled) and within 1 sigma to about 70 % (52-60 %).
#: 1.65 x 0.75 / 0.72: the same product with the prior's SIGMA_TAU, 0.75 -> 0.72 when the prior's posterior took its
#: materials' misfit covariance (issue 50; reconstruction.methods.priorfit), so the family's scale is as calibrated.
SIGMA_SCALE_ANALYTIC = 1.72


def _analytic_tables() -> tuple[Array, ...]:
    """The analytic family at the grid's training cells, coded (:func:`reconstruction.methods.priorcodec.pack`)."""
    from reconstruction.core.models import Material

    g = P._grid()
    tr = g["train"]
    wi, wo = g["wi"][tr], g["wo"][tr]
    rows = []
    for a in ANALYTIC_ALBEDOS:  # 4 x 7 x 3 materials, each a vectorised evaluation of the training cells
        for al in ANALYTIC_ALPHAS:
            for f0 in ANALYTIC_F0:
                spec = 1.0 if f0 < 0.3 else 0.9
                mat = Material.from_dict({"name": "analytic", "lobes": [
                    {"type": "lambert", "albedo": a if f0 < 0.3 else 0.02 * a},
                    {"type": "ggx", "alpha": al, "specular": spec, "f0": f0}]})
                v = np.asarray(mat.eval(wi, wo), dtype=np.float64).reshape(wi.shape[0], -1)
                rows.append(priorcodec.encode_rows(v[:, :1].T, tr.reshape(P.GRID)))  # grey: one row per material
    return priorcodec.pack(rows, tr.reshape(P.GRID))


#: the analytic prior's name: its ``folder``, and the ``reference`` of a bound or an uncertainty without a prior
ANALYTIC_NAME = "built-in analytic family"


@lru_cache(maxsize=1)
def analytic_prior() -> P.PriorSet:
    """A prior of :data:`ANALYTIC_ALBEDOS` x :data:`ANALYTIC_ALPHAS` x :data:`ANALYTIC_F0` lambert + GGX materials
    (84, grey), tabulated once and cached: the uncertainty and the advice of a reconstruction without ``--prior``."""
    key = f"analytic v{ANALYTIC_VERSION} {P.GRID} {ANALYTIC_ALBEDOS} {ANALYTIC_ALPHAS} {ANALYTIC_F0}"
    tables = cached_decoded("analytic-prior", key, _analytic_tables,
                            lambda arrays: priorcodec.unpack(arrays, P._grid()["train"].reshape(P.GRID)))
    return P.PriorSet(ANALYTIC_NAME, [f"m{k:03d}" for k in range(len(tables))], tables)


def reference_posterior(s: Slice, prior: Any = None, exclude: tuple[str, ...] = ()) -> P.PriorReconstruction:
    """The prior's reconstruction of ``s`` with its posterior: from ``prior`` (what ``--prior`` gives) or, without
    one, from :func:`analytic_prior`, on one BLAS thread (its matrices are 84 rows by the grid's training cells:
    on the 2-core machine a second BLAS thread saves under 0.1 s when idle and costs seconds when the machine is
    busy, both threads spinning against other jobs)."""
    if prior:
        return P.reconstruct_prior(s, prior, exclude=exclude)
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1, user_api="blas"):
        return P.reconstruct_prior(s, analytic_prior())


def reference_for(rec: Any, s: Slice, prior: Any = None, exclude: tuple[str, ...] = ()
                  ) -> P.PriorReconstruction:
    """The reference posterior of the reconstruction ``rec`` of ``s``: the prior method's own (fitted already)
    when ``rec`` is the prior or an anchored variant of it, else :func:`reference_posterior`."""
    own = _own_posterior(rec)
    return own if own is not None else reference_posterior(s, prior, exclude)


def _own_posterior(rec: Any) -> P.PriorReconstruction | None:
    """The prior method's reconstruction inside ``rec`` (itself, or an anchored variant's; through a wrapper such
    as :class:`reconstruction.assess.guard.Conservative`) when it carries its posterior: then it is the
    reference, fitted already."""
    rec = rec.__dict__.get("inner", rec) if hasattr(rec, "__dict__") else rec
    inner = rec.prior if isinstance(getattr(rec, "prior", None), P.PriorReconstruction) else rec
    ok = isinstance(inner, P.PriorReconstruction) and inner.sigma_ln is not None and inner.posterior is not None
    return inner if ok else None


def sigma_grid(rec: Any, ref: P.PriorReconstruction) -> Array:
    """sigma of ln f (C, n_cells) on the prior's reduced grid for the reconstruction ``rec``: the posterior's own
    for the prior method (and its anchored variants), else with the two estimates' disagreement (module doc)."""
    own = _own_posterior(rec)
    if own is not None:
        assert own.sigma_ln is not None
        return own.sigma_ln.astype(np.float64)
    g = P._grid()
    assert ref.sigma_ln is not None
    f_rec = np.asarray(rec.eval(g["wi"], g["wo"]), dtype=np.float64).reshape(g["cos"].size, -1).T
    f_ref = ref.values
    if f_rec.shape[0] != f_ref.shape[0]:
        f_rec = np.broadcast_to(f_rec[:1], f_ref.shape) if f_rec.shape[0] == 1 else f_rec[: f_ref.shape[0]]
    floor = 1e-3 * np.max(np.where(g["within"], f_ref, 0.0), axis=1, keepdims=True) + 1e-9
    d = np.log((np.maximum(f_rec, 0.0) + floor) / (np.maximum(f_ref, 0.0) + floor))
    out = np.sqrt(ref.sigma_ln.astype(np.float64) ** 2 + d**2 / 4.0)
    if ref.info.get("prior", {}).get("folder") == ANALYTIC_NAME:  # no prior: calibrated (module doc)
        out *= SIGMA_SCALE_ANALYTIC
    return np.where(g["cos"][None] > 0, np.minimum(out, P.SIGMA_LN_MAX), P.SIGMA_LN_MAX)


def cell_classes(s: Slice) -> NDArray[np.int8]:
    """(90, 90, 180) MERL cells: 0 measured, 1 interpolated, 2 extrapolated (module doc), from the samples of
    ``s`` (in-plane rows, or every point it carries: :func:`~reconstruction.core.samples.everywhere`)."""
    from reconstruction.core.geometry import half_diff_from_dirs
    from reconstruction.core.samples import everywhere, sample_directions

    wi, wo = sample_directions(everywhere(s))
    th, _, td, pd = half_diff_from_dirs(wi, wo)
    ih = merlgrid.theta_h_index(th)
    idd = np.clip((np.degrees(td)).astype(int), 0, 89)
    ip = np.clip((np.degrees(np.mod(pd, np.pi))).astype(int), 0, 179)
    meas = np.zeros((90, 90, 180), dtype=bool)
    meas[ih, idd, ip] = True
    for ax, r in ((0, 1), (1, 1), (2, 2)):  # dilate: the cells next to a sample rest on it too
        m = meas.copy()
        for k in range(1, r + 1):
            m |= np.roll(meas, k, axis=ax) | np.roll(meas, -k, axis=ax)
        meas = m
    rows = meas.any(axis=2)  # (theta_h, theta_d) touched in any phi_d
    hi = np.where(rows.any(axis=0), 89 - np.argmax(rows[::-1], axis=0), -1)  # per theta_d row: measured range
    lo = np.where(rows.any(axis=0), np.argmax(rows, axis=0), 90)
    lo = np.minimum.reduce([lo, np.roll(lo, 1), np.roll(lo, -1)])
    hi = np.maximum.reduce([hi, np.roll(hi, 1), np.roll(hi, -1)])
    i = np.arange(90)[:, None]
    inside = (i >= lo[None, :]) & (i <= hi[None, :])
    out = np.full((90, 90, 180), 2, dtype=np.int8)
    out[np.broadcast_to(inside[..., None], out.shape)] = 1
    out[meas] = 0
    return out


@lru_cache(maxsize=1)
def _uniform_pairs() -> tuple[Array, Array]:
    rng = np.random.default_rng(7)
    c0 = np.cos(np.radians(IMAGE_MAX_VIEW_DEG))

    def cap() -> Array:
        ct = rng.uniform(c0, 1.0, N_PAIRS)
        ph = rng.uniform(0.0, 2 * np.pi, N_PAIRS)
        st = np.sqrt(1.0 - ct**2)
        return np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1)

    return cap(), cap()


def expected_errors(f_grid: Array, sigmas: Array) -> list[dict[str, float]]:
    """Expected errors of a BRDF ``f_grid`` (C, n_cells, on the reduced grid) for each sigma of ln f in ``sigmas``
    (m, C | 1, n_cells): ``expected_cosl2``, ``expected_linear_image_error`` (key and rim, their mean) and
    ``expected_psnr_db`` (from the mean squared tone-mapped spread of both). One stacked render per lighting."""
    m = sigmas.shape[0]
    fl = f_grid.mean(axis=0)  # grey: the channels' mean
    sl = np.sqrt(np.mean(sigmas**2, axis=1))  # (m, n_cells)
    wi, wo = _uniform_pairs()
    idx, w = P._dirs_weights(wi, wo)
    c = wi[:, 2] * wo[:, 2]
    fv = np.einsum("nk,nk->n", w, fl[idx]) * c
    sv = np.einsum("nk,mnk->mn", w, sl[:, idx])
    cosl2 = np.sqrt(np.sum((fv[None] * sv) ** 2, axis=1) / max(float(np.sum(fv**2)), 1e-300))
    stack = np.concatenate([fl[None], fl[None] * sl], axis=0)  # (1 + m, n_cells)

    def brdf(a: Array, b: Array) -> Array:
        ii, ww = P._dirs_weights(a.reshape(-1, 3), b.reshape(-1, 3))
        return np.einsum("nk,cnk->nc", ww, stack[:, ii])

    mask = view_angle_mask(EXPECT_SIZE, 1.0, IMAGE_MAX_VIEW_DEG)
    lin, mse = np.zeros(m), np.zeros(m)
    for name in ("key", "rim"):
        img = render_sphere(brdf, EXPECT_SIZE, name, quadrature=EXPECT_QUADRATURE)[mask]  # (pixels, 1 + m)
        base, spread = img[:, 0], img[:, 1:].T
        lin += np.sqrt(np.sum(spread**2, axis=1) / max(float(np.sum(base**2)), 1e-300)) / 2.0
        e = image_exposure(base[:, None])
        d = (tone_map(base[None] + spread, e) - tone_map(np.maximum(base[None] - spread, 0.0), e)) / 2.0
        mse += np.mean(d**2, axis=1) / 2.0
    psnr = 10.0 * np.log10(1.0 / np.maximum(mse, 1e-12))
    return [{"expected_cosl2": float(cosl2[k]), "expected_linear_image_error": float(lin[k]),
             "expected_psnr_db": float(psnr[k])} for k in range(m)]


def expected_scene_errors(f_grid: Array, sigmas: Array, pairs: Any) -> list[dict[str, float]]:
    """Expected errors in a scene's own images (:func:`reconstruction.core.scene.scene_pairs`: its pixels' direction
    pairs under its lights) of a BRDF ``f_grid`` (C, n_cells, reduced grid) for each sigma of ln f in ``sigmas``
    (m, C | 1, n_cells): ``expected_scene_linear_error`` (relative RMS of the pixels' spread, f sigma rendered
    beside f) and ``expected_scene_psnr_db`` (tone-mapped as the image metrics are: exposure at the base image's
    99.5th percentile, gamma 2.2)."""
    m = sigmas.shape[0]
    fl = f_grid.mean(axis=0)
    sl = np.sqrt(np.mean(sigmas**2, axis=1))  # (m, n_cells)
    shape = pairs.weight.shape
    idx, w = P._dirs_weights(pairs.wi.reshape(-1, 3), pairs.wo.reshape(-1, 3))
    fv = np.einsum("nk,nk->n", w, fl[idx]).reshape(shape) * pairs.weight  # (P, L) radiance of each light
    sv = np.einsum("nk,mnk->mn", w, sl[:, idx]).reshape(m, *shape)
    base = fv.sum(axis=1)  # (P,) a pixel's radiance: its lights' sum
    spread = np.einsum("pl,mpl->mp", fv, sv)  # (m, P)
    lin = np.sqrt(np.sum(spread**2, axis=1) / max(float(np.sum(base**2)), 1e-300))
    e = image_exposure(base[:, None])
    d = (tone_map(base[None] + spread, e) - tone_map(np.maximum(base[None] - spread, 0.0), e)) / 2.0
    psnr = 10.0 * np.log10(1.0 / np.maximum(np.mean(d**2, axis=1), 1e-12))
    return [{"expected_scene_linear_error": float(lin[k]), "expected_scene_psnr_db": float(psnr[k])}
            for k in range(m)]


def scene_section(scene: Any, f_grid: Array, sg: Array) -> dict[str, Any]:
    """The ``uncertainty.scene`` section: the expected errors in ``scene``'s own images, and what weighs them."""
    from reconstruction.core.scene import scene_pairs

    pairs = scene_pairs(scene)
    what = {"sphere": "a sphere seen whole under the scene's lights ([scene.view])",
            "plane": "the scene's cameras and lights on a plane ([scene.view])",
            "ranges": "direction pairs uniform within the scene's theta_i and theta_o ranges"}[pairs.kind]
    return {"name": scene.name, "weighs": what, "pairs": int(np.count_nonzero(pairs.weight)),
            **expected_scene_errors(f_grid, sg[None], pairs)[0]}


def assess_table(rec: Any, s: Slice, prior: Any = None, exclude: tuple[str, ...] = (),
                 ref: P.PriorReconstruction | None = None, scene: Any = None
                 ) -> tuple[NDArray[np.float32], dict[str, Any], P.PriorReconstruction, Array, Array]:
    """(sigma of ln f per MERL cell (3, 90, 90, 180) float32, the report's ``uncertainty`` section, the reference
    posterior, sigma (C, n_cells) and f_r (C, n_cells) of ``rec`` on the reduced grid) for the reconstruction
    ``rec`` of the samples ``s``; ``ref``: the reference posterior when the caller has it
    (:func:`reference_for`); ``scene`` (:class:`reconstruction.core.scene.Scene`): the section's ``scene`` holds the
    errors to expect in that scene's own images (:func:`expected_scene_errors`)."""
    ref = ref if ref is not None else reference_for(rec, s, prior, exclude)
    sg = sigma_grid(rec, ref)
    table_sigma = P.grid_to_merl(sg).astype(np.float32)
    valid = merlgrid.valid_mask()
    classes = cell_classes(s)
    sig = table_sigma.mean(axis=0)
    med = {name: (float(np.median(sig[valid & (classes == k)])) if np.any(valid & (classes == k)) else None)
           for k, name in enumerate(("measured", "interpolated", "extrapolated"))}
    counts = {name: int(np.sum(valid & (classes == k))) for k, name in
              enumerate(("measured", "interpolated", "extrapolated"))}
    g = P._grid()
    f_grid = np.asarray(rec.eval(g["wi"], g["wo"]), dtype=np.float64).reshape(g["cos"].size, -1).T
    f_grid = np.maximum(f_grid, 0.0)
    exp = expected_errors(f_grid, sg[None])[0]
    section = {"quantity": "standard deviation of ln f_r per cell (the --uncertainty array)",
               "model": ("posterior of the prior's basis" if prior else
                         "posterior of a built-in analytic family (lambert + GGX with Fresnel; no --prior)")
               + ("" if isinstance(rec, P.PriorReconstruction) or hasattr(rec, "anchor") else
                  "; with the disagreement between the written table and that posterior"),
               "median_sigma": med, "cells": counts, **exp,
               "expected_note": (f"what to expect against the truth: cosl2 over uniform direction pairs within "
                                 f"{IMAGE_MAX_VIEW_DEG:g} deg; the image errors from a {EXPECT_SIZE} px render of f "
                                 "sigma beside f (key and rim lighting)")}
    if scene is not None:
        section["scene"] = scene_section(scene, f_grid, sg)
    return table_sigma, section, ref, sg, f_grid
