"""The ``prior`` method as a plugin: its options (the folder of prior materials, the anchor's weight, a local
basis, the materials left out) and its call of :func:`reconstruction.methods.prior.reconstruct_prior` (or
:func:`reconstruction.methods.prior_local.reconstruct_local`), blended with ``bivariate`` for an anchor."""

from __future__ import annotations

import os
from typing import Annotated

import msgspec

from reconstruction.base import Reconstruction, ReconstructionError
from reconstruction.core.slicedata import Slice
from reconstruction.methods.plugins import bivariate
from reconstruction.methods.plugins.used import with_samples_used
from reconstruction.methods.registry import Context, Method, Options, option

__all__ = ["PriorOptions", "reconstruct", "METHOD"]


class PriorOptions(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Options of ``prior``."""

    prior: Annotated[str, option(
        "folder of measured materials (NBRDF npy sets, MERL .binary tables, material TOML files, RGL or Zemax .bsdf "
        "files): --method prior completes the slices from their structure; auto also tries it. Repeat it, or join "
        f"folders with '{os.pathsep}', for a prior of several folders", flag="--prior", attr="prior",
        metavar="DIR", repeat=True)] | None = None
    anchor: Annotated[float, option(
        "method prior: blend its completion with the samples' bivariate interpolation, f = f_prior^(1-A) "
        "f_bivariate^A (0: the prior alone, the default; auto scores 0, 0.25 and 0.5 by cross-validation and "
        "reports the one it chose)", metavar="A", ge=0.0, le=1.0,
        expected="a weight from 0 (the prior alone) to 1 (the bivariate interpolation alone)")] = 0.0
    near: Annotated[int, option(
        "method prior: a local prior, the basis of the N prior materials nearest to the samples (0: of every "
        "material, the default; benchmarks/bench_prior_candidates.py measures it)", metavar="N", ge=0)] = 0
    exclude: Annotated[tuple[str, ...], option(
        "materials of the folder left out (a benchmark's leave-one-out)", flag=None)] = ()


def _available(o: Options) -> bool:
    return bool(o.prior)


def reconstruct(s: Slice, opts: PriorOptions, ctx: Context) -> Reconstruction:
    """``s`` completed from the basis of the prior's materials (all, or the ``near`` nearest), blended with the
    samples' ``bivariate`` interpolation by ``anchor``."""
    if not opts.prior:
        raise ReconstructionError("method prior needs --prior DIR: a folder of measured materials (NBRDF npy sets, "
                                  "MERL .binary tables or material TOML files) whose structure the slice is "
                                  "completed with")
    from reconstruction.core.samples import everywhere

    if opts.near > 0:  # a local prior (reconstruction.methods.prior_local), on every point as below
        from reconstruction.methods.prior_local import reconstruct_local

        rec = reconstruct_local(s, opts.prior, exclude=opts.exclude, n_near=opts.near)
    else:
        from reconstruction.methods.prior import reconstruct_prior

        rec = reconstruct_prior(s, opts.prior, exclude=opts.exclude)  # on every point (everywhere(s))
    if opts.anchor <= 0.0:
        return with_samples_used(rec, s, everywhere(s), "prior")
    from reconstruction.methods.prior import AnchoredPrior

    anchor = bivariate.METHOD.build(s, ctx.options, None)
    return with_samples_used(AnchoredPrior(rec, anchor, opts.anchor), s, everywhere(s), "prior")


METHOD = Method("prior", "completed from a basis of measured materials (--prior DIR), fitted to the slices",
                reconstruct=reconstruct, options=PriorOptions, available=_available,
                modules=("reconstruction.methods.prior",))
