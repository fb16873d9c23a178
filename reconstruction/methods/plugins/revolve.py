"""The ``revolve`` method as a plugin: its options (holes, the sub-curves' axis, the smoothing) and its call of
:func:`reconstruction.methods.revolve.reconstruct_revolve`."""

from __future__ import annotations

from typing import Annotated, Any, Literal

import msgspec

from reconstruction.base import Reconstruction
from reconstruction.core.slicedata import Slice
from reconstruction.methods.plugins.used import with_samples_used
from reconstruction.methods.registry import Context, Method, option

__all__ = ["Fill", "RevolveOptions", "reconstruct", "METHOD"]

#: Holes: the option ``revolve`` and ``bivariate`` share (one ``--fill`` flag).
Fill = Annotated[Literal["interpolate", "zero"], option(
    "holes (blind spot, missing samples): interpolate (default) or leave zero (bivariate, revolve; a fitted model "
    "covers holes itself)", flag="--fill", attr="fill")]


class RevolveOptions(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Options of ``revolve``."""

    fill: Fill = "interpolate"
    axis: Annotated[Literal["auto", "vertical", "pca"], option(
        "revolve: axis of each sub-curve, vertical through its highest point or its first principal component "
        "(auto: chosen per sub-curve)", flag="--axis", attr="revolve_axis")] = "auto"
    smoothing: Annotated[float, option(
        "revolve: Gaussian sigma (deg of theta_o) of the smoothing before the sub-curves are split (default 5)",
        flag="--smoothing", attr="revolve_smoothing", ge=0.0)] | None = None


def reconstruct(s: Slice, opts: RevolveOptions, ctx: Context) -> Reconstruction:
    """The thesis's solids of revolution, made reciprocal (f(wi, wo) and f(wo, wi) averaged, so the BRDF passes
    the reciprocity check)."""
    from reconstruction.methods.revolve import reconstruct_revolve

    kw: dict[str, Any] = {"axis": opts.axis, "fill": opts.fill, "reciprocal": True}
    if opts.smoothing is not None:
        kw["smoothing"] = opts.smoothing
    return with_samples_used(reconstruct_revolve(s, **kw), s, None, "revolve")


METHOD = Method("revolve", "the thesis's solids of revolution, extended to every incidence",
                reconstruct=reconstruct, options=RevolveOptions, modules=("reconstruction.methods.revolve",))
