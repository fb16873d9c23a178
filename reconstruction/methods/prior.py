"""A full BRDF from slices and a prior of measured materials (``--method prior --prior DIR``).

Real isotropic materials share structure that no single analytic family captures: how the specular peak
sharpens and brightens towards grazing theta_d, how the diffuse part falls off, how the two are tied. A folder
of measured materials (the user's own: NBRDF ``npy`` sets, MERL ``.binary`` tables, material TOML files, RGL or
Zemax ``.bsdf`` files)
holds that structure. Following Nielsen, Jensen and Ramamoorthi (2015, "On Optimal, Minimal BRDF Sampling for
Reflectance Acquisition", ACM TOG 34(6)), every prior material and channel becomes one vector

    y = log(f cos(theta_i) cos(theta_o) / s + EPS)

on a reduced Rusinkiewicz grid (theta_h: the 90 MERL bins, theta_d: 45 bins of 2 deg, phi_d: 45 bins of 4 deg
centred on 0, where in-plane samples lie), with ``s`` the median of f cos cos over the material's in-plane cells
(a scale: the basis holds shapes, not levels). A principal component basis of those vectors (mean + K
components) is the prior; a slice's samples, mapped the same way (``s`` estimated from the slice), fix the
coefficients by ridge regression with the prior's own variances (a Gaussian prior on the coefficients, weight
``lam``); the reconstruction is the whole grid of the posterior mean, mapped back to f_r.

The reconstruction is the mean, in the mapped space, of the posterior means for K = 10, 20, 30 components and
``lam`` = 0.01, 0.03, 0.1 (on the 48 real MERL materials, leave-one-out, steadier than choosing one pair by
cross-validation on the slice: median rmse80 from one slice 28 % against 31 %). ``auto`` cross-validates the method
as a whole against the others. The prior's materials and size are in the report. The tabulated materials are cached
per folder (``$XDG_CACHE_HOME/gonio-brdf``; the cache is keyed by every file's name, size and time): their f_r at
the training cells, each material coded on its own by :mod:`reconstruction.methods.priorcodec` (ln f_r within
0.001; about 100 kB a material, 14.6 MB for the 141 real ones).

**Anchoring** (``anchor`` a in [0, 1], ``--prior-anchor``): f = f_prior^(1 - a) f_bivariate^a, a weighted geometric
mean with the ``bivariate`` interpolation of the same samples. A material unlike the prior's is completed with
shapes it does not have (a sharp peak overshooting at incidences the slices do not show: specular-orange-phenolic
from 20/40/60 deg, 169 % rmse80); the measured lines pull it back. The blend is non-negative and reciprocal when
both are, and its directional albedo is at most the weighted mean of theirs (weighted AM-GM, cell by cell).
``auto`` scores anchors 0, 0.25 and 0.5 from the two methods' held-out predictions (no further fits).
"""

from __future__ import annotations

import bisect
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from reconstruction.base import ReconstructionError
from reconstruction.cache import cached_decoded, report_build
from reconstruction.core.geometry import dirs_from_half_diff, half_diff_from_dirs
from reconstruction.core.samples import at_samples, everywhere, sample_directions
from reconstruction.core.slicedata import Slice
from reconstruction.executor import usable_cores
from reconstruction.methods import priorcodec
from reconstruction.methods.priorfit import NoiseModel, posterior_coefficients

Array = NDArray[np.float64]

__all__ = ["GRID", "PriorSet", "PriorReconstruction", "AnchoredPrior", "anchored", "load_prior", "prior_folders",
           "reconstruct_prior"]

GRID = (90, 45, 45)  # theta_h (MERL's sqrt bins), theta_d (2 deg), phi_d (4 deg, centred on 0)
EPS = 1e-2
K_CHOICES = (10, 20, 30)
LAM_CHOICES = (0.01, 0.03, 0.1)
MAX_COMPONENTS = max(K_CHOICES)
CACHE_VERSION = 3  # 3: the training cells only, coded by reconstruction.methods.priorcodec (14.6 MB for 141)
INPLANE_MAX_DEG = 80.0


#: A channel's scale is at least this fraction of its material's brightest channel's: the median of a channel that
#: reflects almost nothing (a saturated red's blue) is noise-level, and dividing by it turned the mapped vector of a
#: dark channel into a bright material's (rgl-cg_sunflower and the cc_* car paints reconstructed 1e8-1e11 times too
#: bright from one slice, benchmarks/bench_real_materials.py).
SCALE_FLOOR = 0.02


def channel_scales(at: Array) -> Array:
    """The scale of each channel (..., C) from its f cos cos at the samples ``at`` (..., C, n): the median, floored at
    :data:`SCALE_FLOOR` times the largest channel's median (and at 1e-12)."""
    med = np.median(np.asarray(at, dtype=np.float64), axis=-1)
    return np.maximum(np.maximum(med, SCALE_FLOOR * med.max(axis=-1, keepdims=True)), 1e-12)


# --- the reduced grid ------------------------------------------------------------------------------------------


@lru_cache(maxsize=1)
def _grid() -> dict[str, Array]:
    """Bin-centre angles, directions and cos theta_i cos theta_o of the reduced grid (flattened, n = 182,250)."""
    nh, nd, npd = GRID
    th = ((np.arange(nh) + 0.5) / nh) ** 2 * (np.pi / 2)
    td = (np.arange(nd) + 0.5) / nd * (np.pi / 2)
    pd = np.arange(npd) / npd * np.pi
    TH, TD, PD = (a.ravel() for a in np.meshgrid(th, td, pd, indexing="ij"))
    wi, wo = dirs_from_half_diff(TH, np.zeros_like(TH), TD, PD)
    cos = np.clip(wi[:, 2], 0.0, None) * np.clip(wo[:, 2], 0.0, None)
    c80 = np.cos(np.radians(INPLANE_MAX_DEG)) - 1e-12
    within = (wi[:, 2] >= c80) & (wo[:, 2] >= c80)
    inplane = (np.abs(PD) < 1e-9) & within
    c81 = np.cos(np.radians(INPLANE_MAX_DEG + 1.0))
    train = (wi[:, 2] >= c81) & (wo[:, 2] >= c81) & (cos > 0)
    return {"wi": wi, "wo": wo, "cos": cos, "within": within, "inplane": inplane, "train": train}


def _weights(theta_h: Array, theta_d: Array, phi_d: Array) -> tuple[NDArray[np.intp], Array]:
    """Trilinear interpolation on the reduced grid: flat cell indices (n, 8) and weights (n, 8)."""
    nh, nd, npd = GRID
    xh = np.sqrt(np.maximum(theta_h, 0.0) / (np.pi / 2)) * nh - 0.5
    xd = theta_d / (np.pi / 2) * nd - 0.5
    xp = np.mod(phi_d, np.pi) / np.pi * npd
    h0 = np.clip(np.floor(xh), 0, nh - 2).astype(np.intp)
    d0 = np.clip(np.floor(xd), 0, nd - 2).astype(np.intp)
    p0 = np.floor(xp).astype(np.intp)
    fh, fd, fp = np.clip(xh - h0, 0, 1), np.clip(xd - d0, 0, 1), xp - p0
    idx, w = [], []
    for dh, wh in ((0, 1 - fh), (1, fh)):
        for dd, wd in ((0, 1 - fd), (1, fd)):
            for dp, wp in ((0, 1 - fp), (1, fp)):
                idx.append(((h0 + dh) * nd + d0 + dd) * npd + (p0 + dp) % npd)
                w.append(wh * wd * wp)
    return np.stack(idx, axis=-1), np.stack(w, axis=-1)


def _dirs_weights(wi: Array, wo: Array) -> tuple[NDArray[np.intp], Array]:
    th, _, td, pd = half_diff_from_dirs(wi, wo)
    return _weights(th, td, pd)


# --- the prior's materials -------------------------------------------------------------------------------------


def _material_files(folder: Path) -> dict[str, Path]:
    """name -> file of every material in ``folder``: NBRDF sets (NAME_fc1.npy ...), MERL .binary, material .toml,
    RGL or Zemax .bsdf."""
    from reconstruction.core.models import NBRDF_SUFFIXES

    found: dict[str, Path] = {}
    for p in sorted(folder.iterdir()):
        if not p.is_file():
            continue
        if p.name.endswith(f"_{NBRDF_SUFFIXES[0]}.npy"):
            stem = p.name[: -len(f"_{NBRDF_SUFFIXES[0]}.npy")]
            if all((folder / f"{stem}_{s}.npy").is_file() for s in NBRDF_SUFFIXES):
                found[stem] = folder / stem
        elif p.suffix.lower() in (".binary", ".toml", ".bsdf"):
            found[p.stem] = p
    return found


@lru_cache(maxsize=1)
def _grid_nbrdf_features() -> NDArray[np.float32]:
    """The neural BRDFs' inputs at the grid's training cells (M, 6), float32 (computed once)."""
    from reconstruction.core.models import nbrdf_features

    g = _grid()
    return nbrdf_features(g["wi"][g["train"]], g["wo"][g["train"]]).astype(np.float32)


def _tabulate_material(path: Path) -> Array:
    """(3, M) f_r of one prior material at the reduced grid's training cells (NaN and negative cells -> 0)."""
    from reconstruction.formats import merl

    g = _grid()
    tr = g["train"]
    if path.suffix.lower() == ".binary":
        t = np.nan_to_num(merl.read(path), nan=0.0, posinf=0.0)  # (3, 90, 90, 180) -> cell averages
        t = t.reshape(3, 90, 45, 2, 180).mean(axis=3)
        t = np.roll(t, 2, axis=3).reshape(3, 90, 45, 45, 4).mean(axis=4)  # phi_d bins centred on 0, 4, 8 ... deg
        f = t.reshape(3, -1)[:, tr]
    elif path.suffix.lower() in (".toml", ".bsdf"):  # a material file; an RGL or Zemax file (spectral: in RGB)
        from reconstruction.formats.brdffile import load_brdf

        v = np.asarray(load_brdf(path)(g["wi"][tr], g["wo"][tr]), dtype=np.float64)
        f = (np.repeat(v, 3, axis=1) if v.shape[1] == 1 else v[:, :3]).T
    else:  # an NBRDF set: the network on the grid's inputs (the same for every material), in float32, on one
        # BLAS thread (matrices of 21 columns: threads only contend, 5 times slower on a busy machine)
        from threadpoolctl import threadpool_limits

        from reconstruction.core.models import _nbrdf_weights, nbrdf_forward

        with threadpool_limits(1):
            f = nbrdf_forward(_grid_nbrdf_features(), _nbrdf_weights(str(path))).T
    f = np.nan_to_num(np.maximum(f, 0.0), nan=0.0, posinf=0.0)
    peak = np.max(np.where(g["within"][tr], f, 0.0), axis=1, keepdims=True)  # fits blow up at grazing: bound them
    return np.minimum(f, np.maximum(peak, 1e-12))


def _cache_key(folder: Path, files: dict[str, Path]) -> str:
    """Everything the tabulated prior depends on: the grid, the folder and every file's name, size and time."""
    parts = [f"v{CACHE_VERSION} {GRID} {folder.resolve()}"]
    listed: dict[Path, list[str]] = {}
    for name, p in sorted(files.items()):
        if p.suffix:
            found = [p]
        else:  # an NBRDF set: every NAME_*.npy (one sorted listing of the folder, not one glob per material)
            names = listed.setdefault(p.parent, sorted(os.listdir(p.parent)))
            run = names[bisect.bisect_left(names, f"{p.name}_"):bisect.bisect_left(names, f"{p.name}`")]
            found = [p.parent / n for n in run if n.endswith(".npy")]
        for q in found:
            st = q.stat()
            parts.append(f"{name} {q.name} {st.st_size} {st.st_mtime_ns}")
    return "\n".join(parts)


@dataclass
class PriorSet:
    """The prior's materials on the reduced grid: ``names`` (N) and ``tables`` (N, 3, M) f_r in 1/sr at the M
    training cells (:func:`train_index`; the only cells the basis reads), float32, or (N, 1, M) for a grey family
    (the basis then has one row per material, not three equal ones). Tables given on the whole grid (N, C, n_cells)
    are cut to the training cells."""

    folder: str
    names: list[str]
    tables: NDArray[np.float32]
    _fc_cache: NDArray[np.float32] | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        g = _grid()
        if self.tables.shape[-1] == g["cos"].size:
            self.tables = np.ascontiguousarray(self.tables[..., g["train"]])

    def _fc(self, cache: bool = True) -> NDArray[np.float32]:
        """f cos theta_i cos theta_o of every material and channel at the training cells, (C N, M) float32, kept
        for the next call with ``cache``."""
        if self._fc_cache is not None:
            return self._fc_cache
        g = _grid()
        fc = self.tables.reshape(-1, self.tables.shape[-1]) * g["cos"][g["train"]].astype(np.float32)
        self._fc_cache = fc if cache else None
        return fc

    def basis(self, idx: NDArray[np.intp], w: Array, exclude: tuple[str, ...] = (), residual: bool = False
              ) -> tuple[Array, ...]:
        """(mean (M,), components (K, M), standard deviations (K,)) in the mapped space over the training cells
        (:func:`train_index`), from every material and channel except the materials named in ``exclude`` (a
        benchmark's leave-one-out). Each row's scale is the median of its f cos cos at the samples (``idx``,
        ``w``: their interpolation on the training cells), so the basis holds shapes relative to what a slice of
        that geometry sees. With ``residual``, a fourth array (M,): the variance per cell of the rows' part outside
        the components (dof-corrected), what no coefficient can reach; a fifth (T, n), that part of each row at the
        samples, and a sixth (T, K), the rows' coefficients (:mod:`reconstruction.methods.priorfit`)."""
        drop = set(exclude) & set(self.names)
        keep = [i for i, n in enumerate(self.names) if n not in drop]
        if len(keep) < 2:
            raise ReconstructionError(f"--prior {self.folder}: at least 2 materials are needed, {len(keep)} remain")
        nc = self.tables.shape[1]  # 3, or 1 for a grey family (the analytic prior: one row per material)
        rows = (np.asarray(keep)[:, None] * nc + np.arange(nc)).ravel()
        # a run's one basis of every material (not a benchmark's leave-one-out): f cos cos made once, its own copy
        fc = self._fc(cache=False) if self._fc_cache is None and len(keep) == len(self.names) else self._fc()[rows]
        at = at_samples(w, fc, idx)  # (T, n) f cos cos at the samples
        scales = channel_scales(at.reshape(len(keep), nc, -1)).reshape(-1).astype(np.float32)
        y = np.divide(fc, scales[:, None], out=fc)  # in place: fc is this call's own copy (80 MB for 48 materials)
        y += np.float32(EPS)
        np.log(y, out=y)
        mu = y.mean(axis=0)
        y -= mu
        ev, vec = np.linalg.eigh((y @ y.T).astype(np.float64))  # (T, T): components from the small Gram matrix
        order = np.argsort(ev)[::-1][: min(MAX_COMPONENTS, len(ev) - 1)]
        sv = np.sqrt(np.maximum(ev[order], 1e-30))
        comps = np.divide(vec[:, order].T.astype(np.float32) @ y, sv[:, None])  # float64, one allocation
        comps[sv <= 1e-6 * sv.max()] = 0.0  # no variance (fewer rows than components): round-off, not a shape
        out = (mu.astype(np.float64), comps, sv / np.sqrt(max(y.shape[0] - 1, 1)))
        if residual:  # y minus its projection on the components, in place (y is this call's own), a few
            coef = y @ (comps32 := comps.astype(np.float32)).T  # thousand cells at a time: no second copy of y
            for a in range(0, y.shape[1], _CHUNK):
                y[:, a:a + _CHUNK] -= coef @ comps32[:, a:a + _CHUNK]
            dof = max(y.shape[0] - comps.shape[0] - 1, 1)  # then the rows' part beyond the components at the
            at = sum(w[:, j] * y[:, idx[:, j]] for j in range(idx.shape[1]))  # samples (T, n) and coefficients
            out += (np.einsum("tm,tm->m", y, y, dtype=np.float64) / dof, at.astype(np.float64), coef.astype(float))
        return out


_CHUNK = 8192  #: cells per step where :meth:`PriorSet.basis` works through its rows (temporaries of a few MB)


@lru_cache(maxsize=1)
def train_index() -> NDArray[np.intp]:
    """Index of each grid cell among the training cells (theta_i and theta_o within 81 deg); 0 elsewhere."""
    t = _grid()["train"]
    out = np.zeros(t.size, dtype=np.intp)
    out[t] = np.arange(int(t.sum()))
    return out


#: threads that tabulate a prior's materials (one material and one BLAS thread each)
PRIOR_BUILD_THREADS = max(1, min(4, usable_cores()))


@lru_cache(maxsize=4)
def _load_cached(folder: str) -> PriorSet:
    p = Path(folder)
    if not p.is_dir():
        raise ReconstructionError(f"--prior {folder}: not a folder (expected a folder of materials: NBRDF npy sets, "
                                  f"MERL .binary tables, material TOML or RGL/Zemax .bsdf files)")
    files = _material_files(p)
    if len(files) < 2:
        raise ReconstructionError(f"--prior {folder}: {len(files)} material(s) found; expected at least 2 (NBRDF npy "
                                  f"sets NAME_fc1.npy ... NAME_b3.npy, MERL .binary tables, material TOML or RGL/Zemax "
                                  f".bsdf files)")
    names = sorted(files)

    mask = _grid()["train"].reshape(GRID)

    def one(n: str) -> tuple[bytes, bytes, Array]:
        try:
            f = _tabulate_material(files[n])
        except (OSError, ValueError, ReconstructionError) as e:
            msg = str(e)
            raise ReconstructionError(f"--prior {folder}: material {n}: {msg}") from None
        return priorcodec.encode_rows(f, mask)

    def tabulate() -> tuple[Any, ...]:
        from concurrent.futures import ThreadPoolExecutor

        from threadpoolctl import threadpool_limits

        encoded = []
        _grid_nbrdf_features()  # shared by the threads: computed once, before them
        what = f"tabulating the prior's materials ({folder})"
        report_build(what, 0, len(names))
        # one material per thread on one BLAS thread each (numpy's kernels and zlib release the GIL): 2 cores, 2
        # materials; each coded as it comes (about 1.4 MB of float32 -> 100 kB)
        with threadpool_limits(1), ThreadPoolExecutor(max_workers=max(1, min(PRIOR_BUILD_THREADS, len(names)))) as ex:
            for k, e in enumerate(ex.map(one, names)):
                encoded.append(e)
                report_build(what, k + 1, len(names))
        return priorcodec.pack(encoded, mask)

    tables = cached_decoded("prior", _cache_key(p, files), tabulate,  # the key holds every name
                            lambda a: priorcodec.unpack(a, mask, PRIOR_BUILD_THREADS, rows=(len(names), 3)),
                            what=f"the prior of {len(names)} materials in {folder}")
    return PriorSet(folder, names, tables)


def prior_folders(folders: str | Path | Sequence[str | Path]) -> tuple[str, ...]:
    """The prior's folders: one folder, a list of them, or paths joined by ``os.pathsep`` (``--prior A:B``), in
    order, without repeats or empty entries."""
    items = [folders] if isinstance(folders, (str, Path)) else list(folders)
    out: list[str] = []
    for item in items:
        for part in str(item).split(os.pathsep):
            if part.strip() and str(Path(part)) not in out:
                out.append(str(Path(part)))
    return tuple(out)


@lru_cache(maxsize=4)
def _load_set(folders: tuple[str, ...]) -> PriorSet:
    """The materials of every folder of ``folders`` in one :class:`PriorSet` (each folder tabulated once and
    cached on its own; this in-memory set is keyed by the whole folder list)."""
    sets = [_load_cached(f) for f in folders]
    seen: dict[str, str] = {}
    for f, ps in zip(folders, sets, strict=True):
        for n in ps.names:
            if n in seen:
                raise ReconstructionError(f"--prior {f}: material {n} is also in {seen[n]}; expected each material "
                                          f"once over the prior's folders")
            seen[n] = f
    return PriorSet(os.pathsep.join(folders), [n for ps in sets for n in ps.names],
                    np.concatenate([ps.tables for ps in sets], axis=0))


def load_prior(folder: str | Path | Sequence[str | Path]) -> PriorSet:
    """The prior's materials in ``folder``: one folder, several (a list, or paths joined by ``os.pathsep``); each
    folder is tabulated once, then read from the cache."""
    folders = prior_folders(folder)
    if not folders:
        raise ReconstructionError("--prior: no folder given (expected one or more folders of materials)")
    if len(folders) == 1:
        return _load_cached(folders[0])
    return _load_set(folders)


# --- the reconstruction ----------------------------------------------------------------------------------------


def _design(s: Slice) -> tuple[NDArray[np.intp], Array, Array]:
    """Interpolation (indices, weights) of every sample on the grid, and cos theta_i cos theta_o per sample (the
    samples anywhere: in-plane rows, or the points of a :class:`~reconstruction.core.samples.DirectionalSlice`)."""
    wi, wo = sample_directions(s)
    idx, w = _dirs_weights(wi, wo)
    w = np.where(_grid()["train"][idx], w, 0.0)  # only cells the basis holds (within 81 deg)
    w = w / np.maximum(w.sum(axis=1, keepdims=True), 1e-300)
    return train_index()[idx], w, np.clip(wi[:, 2], 0.0, 1.0) * np.clip(wo[:, 2], 0.0, 1.0)


def _within_basis(s: Slice) -> tuple[Slice, int]:
    """The samples of ``s`` whose theta_i and theta_o are within the basis's cells (81 deg), and how many lie
    beyond: there f cos cos is not what the cells hold (a 87.5 deg sample read as an 81 deg cell's put the
    analytic family's misfit on a hemispherical file at 1.08 in ln, against 0.011 without them)."""
    wi, wo = sample_directions(s)
    c81 = np.cos(np.radians(INPLANE_MAX_DEG + 1.0))
    keep = (wi[:, 2] >= c81) & (wo[:, 2] >= c81)
    if not keep.any():
        raise ReconstructionError(f"method prior: every sample lies beyond {INPLANE_MAX_DEG + 1.0:g} deg from the "
                                  "normal, where the prior's basis holds no cells; measure at least one slice "
                                  "nearer the normal")
    return (s if keep.all() else s.take(np.nonzero(keep)[0])), int((~keep).sum())


@dataclass
class PriorReconstruction:
    """A BRDF on the reduced grid (``values``: (C, n_cells) f_r in 1/sr), trilinear between bin centres."""

    channels: list[str]
    values: Array
    info: dict[str, Any]
    method: str = "prior"
    sigma_ln: NDArray[np.float32] | None = None  # (C, n_cells) sigma of ln f_r, see :data:`SIGMA_TAU`
    posterior: dict[str, Any] | None = None  # what the capture advice needs: the basis, the scales, the misfit

    def eval(self, wi: Array, wo: Array) -> Array:
        wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
        wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
        idx, w = _dirs_weights(wi, wo)
        out = np.einsum("nk,cnk->nc", w, self.values[:, idx])
        below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
        out[below] = 0.0
        return out

    def table(self) -> Array:
        """The MERL table (3, 90, 90, 180): the grid interpolated to the MERL bin centres (:func:`grid_to_merl`)."""
        from reconstruction.core import merlgrid

        return np.where(merlgrid.valid_mask()[None], np.maximum(grid_to_merl(self.values), 0.0), 0.0)

    def uncertainty_table(self) -> NDArray[np.float32]:
        """sigma of ln f_r (3, 90, 90, 180) float32 in the MERL table's cells, interpolated as :meth:`table`."""
        assert self.sigma_ln is not None
        return grid_to_merl(self.sigma_ln.astype(np.float64)).astype(np.float32)

    def report(self) -> dict[str, Any]:
        return {"method": self.method, **self.info}


def grid_to_merl(values: Array) -> Array:
    """(C, n_cells) on the reduced grid -> (3, 90, 90, 180) at the MERL bin centres: linear in theta_d and phi_d,
    separable (two small matrix products; theta_h bins are MERL's own); one channel is repeated."""
    from reconstruction.core.colour import _interp_matrix

    nh, nd, npd = GRID
    v = values if values.shape[0] == 3 else values[:1]  # a grey BRDF: one channel, repeated
    v = v.reshape(v.shape[0], nh, nd, npd)
    v = np.concatenate([v, v[..., :1]], axis=-1)  # phi_d is periodic (pi)
    # linear interpolation matrices in bin-index units, ends held (as map_coordinates' mode="nearest")
    wd = _interp_matrix(np.arange(nd, dtype=np.float64), (np.arange(90) + 0.5) / 90 * nd - 0.5)  # (nd, 90)
    wp = _interp_matrix(np.arange(npd + 1, dtype=np.float64), (np.arange(180) + 0.5) / 180 * npd)  # (npd+1, 180)
    t = np.einsum("da,chdp,pb->chab", wd, v, wp, optimize=True)
    return np.broadcast_to(t, (3, *t.shape[1:]))  # the same numbers in every channel, not three roundings


def _extend(f: Array) -> Array:
    """Cells beyond the training range (theta_i or theta_o above 81 deg) take the value of the last cell within
    it along theta_d (same theta_h and phi_d)."""
    nh, nd, npd = GRID
    train = _grid()["train"].reshape(nh, nd, npd)
    last = np.maximum.accumulate(np.where(train, np.arange(nd)[None, :, None], -1), axis=1)
    v = f.reshape(f.shape[0], nh, nd, npd)
    out = np.take_along_axis(v, np.maximum(last, 0)[None], axis=2)
    return np.where((last >= 0)[None], out, 0.0).reshape(f.shape)


def reconstruct_prior(s: Slice, prior: PriorSet | str | Path, exclude: tuple[str, ...] = (),
                      k: int | None = None, lam: float | None = None) -> PriorReconstruction:
    """Reconstruct ``s`` (f_r, any channels) from the prior's basis: the mean of the posterior means for every K
    in :data:`K_CHOICES` and ``lam`` in :data:`LAM_CHOICES` (or the one given). ``exclude``: prior materials left
    out (a benchmark judging a material of the prior)."""
    ps = prior if isinstance(prior, PriorSet) else load_prior(prior)
    g = _grid()
    s, beyond = _within_basis(everywhere(s))  # every point of a file, placed by its directions (up to MAX_POINTS)
    idx, w, cs = _design(s)
    mu, comps, sig, resvar, e_all, rows_coef = ps.basis(idx, w, exclude, residual=True)
    sb = at_samples(w, comps, idx).T  # (n, K): the basis at the samples
    smu = np.sum(w * mu[idx], axis=1)
    obs = np.maximum(np.asarray(s.values, dtype=np.float64), 0.0) * cs[:, None]  # f cos cos, (n, C)
    scale = channel_scales(obs.T)  # as the basis's rows: the median at the samples (floored per channel)
    y = np.log(obs / scale + EPS) - smu[:, None]
    kmax = sb.shape[1]
    cfgs = [(min(a, kmax), b) for a in (K_CHOICES if k is None else (k,)) for b in (LAM_CHOICES if lam is None
                                                                               else (lam,))]
    # the posterior means of every (K, lam), averaged in the mapped space: on the 48 real materials this is
    # steadier than choosing one by cross-validation on the slice (median rmse80 28 % against 31 % from one slice)
    mapped = np.zeros((y.shape[1], mu.size))
    fitted = np.zeros_like(y)
    noise = {kk: NoiseModel(e_all, rows_coef, sb, kk, sig) for kk in {c[0] for c in cfgs}}  # the misfit, correlated
    for kk, ll in cfgs:
        coef = posterior_coefficients(sb, y, sig, kk, ll, noise[kk])  # (K, C) (reconstruction.methods.priorfit)
        mapped += (coef.T @ comps[:kk]) / len(cfgs)
        fitted += (sb[:, :kk] @ coef) / len(cfgs)
    mapped += mu[None, :]  # (C, M) over the training cells
    f = np.zeros((mapped.shape[0], g["cos"].size))
    f[:, g["train"]] = np.maximum(np.exp(mapped) - EPS, 0.0) * scale[:, None] / g["cos"][g["train"]]
    f = np.where(g["cos"] > 0, _extend(f), 0.0)
    misfit = float(np.sqrt(np.mean((fitted - y) ** 2)))  # in the mapped space, over samples and channels
    sigma_ln = sigma_ln_of(mapped_sigma(posterior_covariance(sb, sig), comps, resvar, misfit), f, scale)
    fitted = (np.exp(fitted + smu[:, None]) - EPS) * scale
    resid = float(np.sqrt(np.sum((fitted - obs) ** 2) / max(np.sum(obs**2), 1e-300)))
    used = [n for n in ps.names if n not in set(exclude)]
    info = {"prior": {"folder": ps.folder, "materials": len(used), "names": used,
                      "excluded": sorted(set(exclude) & set(ps.names))},
            "parameters": {"components": sorted({c[0] for c in cfgs}),
                           "ridge_weights": sorted({c[1] for c in cfgs}),
                           "combination": f"mean of the {len(cfgs)} posterior means in log(f cos cos / s + {EPS:g})"},
            "residuals": {"relative_rmse_cos_own_samples": resid,
                          "note": "on the samples the coefficients were fitted to; see cross-validation for "
                                  "prediction"},
            "notes": [f"reconstructed from a basis of {len(used)} prior materials x 3 channels "
                      f"(up to {max(c[0] for c in cfgs)} components); beyond 81 deg the last value within it along "
                      f"theta_d"] + ([f"{beyond} samples beyond {INPLANE_MAX_DEG + 1.0:g} deg from the normal not "
                                      "used (the basis holds no cells there)"] if beyond else [])}
    info["uncertainty"] = {"model": f"posterior of the coefficients (K = {SIGMA_COMPONENTS}, lam = {SIGMA_LAM:g}) "
                           f"+ the basis's residual variance + {SIGMA_KAPPA:g} x the misfit at the samples, times "
                           f"{SIGMA_TAU:g}", "misfit_mapped": misfit}
    return PriorReconstruction(list(s.channels), f, info, sigma_ln=sigma_ln,
                               posterior={"basis": (mu, comps, sig, resvar), "scale": scale, "misfit": misfit,
                                          "design": (idx, w)})


#: The uncertainty of the prior's table: sigma of y = ln(f cos cos / s + EPS) is SIGMA_TAU x sqrt(the posterior
#: variance of the coefficients' part (K = SIGMA_COMPONENTS, ridge SIGMA_LAM) + the basis's residual variance +
#: SIGMA_KAPPA x the misfit at the samples squared). Calibrated leave-one-out on the 141 real materials
#: (benchmarks/bench_uncertainty.py: the share of uniform direction pairs within 1 and 2 sigma). SIGMA_TAU 0.75 ->
#: 0.72 with the misfit's covariance in the coefficients' posterior (reconstruction.methods.priorfit, issue 50): the
#: tables came nearer the truth and 40/70 deg's share within 1 sigma rose to 76.8 % (every 6th material; with 0.72:
#: 73.0-75.5 % within 1 sigma, 90.5-91.9 % within 2).
SIGMA_COMPONENTS, SIGMA_LAM, SIGMA_TAU, SIGMA_KAPPA = 20, 0.03, 0.72, 1.0
#: sigma of ln f is at most this (a factor e^5 = 148): where f is 0 the log is undefined.
SIGMA_LN_MAX = 5.0


def posterior_covariance(sb: Array, sig: Array, k: int = SIGMA_COMPONENTS, lam: float = SIGMA_LAM) -> Array:
    """The posterior covariance (k, k) of the first ``k`` coefficients given the samples' basis rows ``sb`` (n, K)
    (Gaussian prior of variances ``sig**2``, noise variance ``lam``)."""
    k = min(k, sb.shape[1])
    a = sb[:, :k]
    return np.linalg.inv(a.T @ a / lam + np.diag(1.0 / sig[:k] ** 2))


def mapped_sigma(cov: Array, comps: Array, resvar: Array, misfit: float) -> Array:
    """sigma of y over the training cells (M,) from the coefficients' covariance ``cov`` (k, k), the components
    (K, M), the residual variance (M,) and the misfit (see :data:`SIGMA_TAU`)."""
    k = cov.shape[0]
    vpost = np.einsum("km,kl,lm->m", comps[:k], cov, comps[:k], optimize=True)
    return SIGMA_TAU * np.sqrt(np.maximum(vpost, 0.0) + resvar + SIGMA_KAPPA * misfit**2)


def sigma_ln_of(sigma_y: Array, f: Array, scale: Array) -> Array:
    """sigma of ln f_r (C, n_cells) on the reduced grid from sigma of y over the training cells (M,), the BRDF ``f``
    (C, n_cells) and the channels' scales (C,): d ln f = dy (x + EPS) / x with x = f cos cos / s; beyond the
    training range the last value along theta_d, as :func:`_extend` completes f."""
    g = _grid()
    full = np.zeros((1, g["cos"].size))
    full[0, g["train"]] = sigma_y
    sy = _extend(full)
    x = f * g["cos"][None] / scale[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = sy * (x + EPS) / x
    return np.where(x > 0, np.minimum(out, SIGMA_LN_MAX), SIGMA_LN_MAX).astype(np.float32)


def anchored(f_prior: Array, f_anchor: Array, anchor: float) -> Array:
    """f_prior^(1 - anchor) f_anchor^anchor (any shape, f_r >= 0): the weighted geometric mean of two BRDF values;
    ``anchor`` = 0 gives ``f_prior`` itself."""
    a = float(anchor)
    if a <= 0.0:
        return np.asarray(f_prior, dtype=np.float64)
    return np.power(np.maximum(f_prior, 0.0), 1.0 - a) * np.power(np.maximum(f_anchor, 0.0), a)


@dataclass
class AnchoredPrior:
    """The prior's reconstruction pulled towards the samples' ``bivariate`` interpolation (``anchor`` a in (0, 1]):
    f = f_prior^(1 - a) f_bivariate^a, by :meth:`eval` and by cell in :meth:`table`."""

    prior: PriorReconstruction
    anchor_rec: Any  # a BivariateReconstruction of the same samples
    anchor: float
    method: str = "prior"
    channels: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.channels = list(self.prior.channels)

    def eval(self, wi: Array, wo: Array) -> Array:
        return anchored(self.prior.eval(wi, wo), self.anchor_rec.eval(wi, wo), self.anchor)

    def table(self) -> Array:
        """The MERL table (3, 90, 90, 180): the two methods' own tables blended cell by cell (0 below the
        horizon)."""
        from reconstruction.core import merlgrid

        b = np.nan_to_num(self.anchor_rec.table(), nan=0.0)
        return np.where(merlgrid.valid_mask()[None], anchored(self.prior.table(), b, self.anchor), 0.0)

    def report(self) -> dict[str, Any]:
        rep = self.prior.report()
        rep["anchor"] = {"weight": self.anchor, "to": "bivariate",
                         "combination": f"f = f_prior^{1 - self.anchor:g} f_bivariate^{self.anchor:g}",
                         "bivariate": {k: v for k, v in self.anchor_rec.report().items()
                                       if k in ("parameters", "coverage_half_diff")}}
        rep["notes"] = [*rep.get("notes", []), f"anchored to the samples' bivariate interpolation with weight "
                        f"{self.anchor:g} (--prior-anchor)"]
        return rep
