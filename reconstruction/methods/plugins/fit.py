"""The ``fit`` method as a plugin: its options (the lobe kinds it may use) and its call of
:func:`reconstruction.methods.fit.reconstruct_fit` on every sample."""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from reconstruction.base import Reconstruction
from reconstruction.core.slicedata import Slice
from reconstruction.methods.plugins.used import with_samples_used
from reconstruction.methods.registry import Context, Method, option

__all__ = ["FitOptions", "reconstruct", "METHOD"]

LobeKind = Literal["lambert", "ggx", "beckmann", "retro", "fresnel"]


class FitOptions(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Options of ``fit`` (the scene, common to every method, is passed beside them)."""

    lobes: Annotated[list[LobeKind] | None, option(
        "lobe kinds the fit may use: lambert, ggx, beckmann, retro, fresnel (default: all, or the scene's list)",
        flag="--lobes", attr="lobes", metavar="KIND,...")] = None


def reconstruct(s: Slice, opts: FitOptions, ctx: Context) -> Reconstruction:
    """Analytic lobes fitted to every sample of ``s`` (the scene's budget and ``opts.lobes`` restrict them)."""
    from reconstruction.core.samples import everywhere
    from reconstruction.methods.fit import reconstruct_fit

    pts = everywhere(s)
    return with_samples_used(reconstruct_fit(pts, scene=ctx.scene, lobes=opts.lobes, progress=ctx.progress), s, pts,
                             "fit")


METHOD = Method("fit", "analytic lobes (lambert, ggx/beckmann with Fresnel, retro) chosen by BIC, energy-constrained",
                reconstruct=reconstruct, options=FitOptions, modules=("reconstruction.methods.fit",))
