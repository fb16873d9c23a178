"""The ``microfacet`` method as a plugin: no options of its own; its call of
:func:`reconstruction.methods.microfacet.reconstruct_microfacet` on every sample."""

from __future__ import annotations

from reconstruction.base import Reconstruction
from reconstruction.core.slicedata import Slice
from reconstruction.methods.plugins.used import with_samples_used
from reconstruction.methods.registry import Context, Method, NoOptions

__all__ = ["reconstruct", "METHOD"]


def reconstruct(s: Slice, opts: NoOptions, ctx: Context) -> Reconstruction:
    """The non-parametric microfacet model fitted to every sample of ``s``."""
    from reconstruction.core.samples import everywhere
    from reconstruction.methods.microfacet import reconstruct_microfacet

    pts = everywhere(s)
    return with_samples_used(reconstruct_microfacet(pts), s, pts, "microfacet")


METHOD = Method("microfacet", "non-parametric microfacet: tabulated NDF, Smith G from it, physical Fresnel",
                reconstruct=reconstruct, modules=("reconstruction.methods.microfacet",))
