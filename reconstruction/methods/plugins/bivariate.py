"""The ``bivariate`` method as a plugin: its options (holes, the cos^P(theta_d) weight) and its call of
:func:`reconstruction.methods.bivariate.reconstruct_bivariate` (or, on points anywhere on the hemisphere,
:func:`reconstruction.methods.scattered.reconstruct_scattered`)."""

from __future__ import annotations

from typing import Annotated

import msgspec

from reconstruction.base import Reconstruction
from reconstruction.core.slicedata import Slice
from reconstruction.methods.plugins.revolve import Fill
from reconstruction.methods.plugins.used import with_samples_used
from reconstruction.methods.registry import Context, Method, option

__all__ = ["BivariateOptions", "reconstruct", "METHOD"]


class BivariateOptions(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Options of ``bivariate``."""

    fill: Fill = "interpolate"
    cos_power: Annotated[float, option("power P of the cos^P(theta_d) weight of the excess; default: chosen from "
                                       "the data", flag=None, attr="cos_power", gt=0.0)] | None = None


def reconstruct(s: Slice, opts: BivariateOptions, ctx: Context) -> Reconstruction:
    """f(theta_h, theta_d) interpolated between the measured lines of ``s``; a scanned hemisphere: every point
    placed by (theta_h, theta_d, phi_d) on a grid."""
    from reconstruction.core.samples import everywhere, points_anywhere, scans_hemisphere
    from reconstruction.methods.bivariate import reconstruct_bivariate

    pts = points_anywhere(s)  # a bench's sweeps out of the plane: the in-plane lines (the grid fills what a few
    if pts is not None and scans_hemisphere(pts):  # great circles leave by smoothing: worse than the lines,
        # docs/real-materials.md)
        from reconstruction.methods.scattered import reconstruct_scattered

        pts = everywhere(s)
        rec = reconstruct_scattered(pts)
        ignored = [k for k, v in (("--fill zero", opts.fill == "zero"), ("--cos-power", opts.cos_power is not None))
                   if v]
        if ignored:
            rec.info["notes"] = [f"{', '.join(ignored)}: for in-plane slices only; not used on points anywhere"]
        return with_samples_used(rec, s, pts, "bivariate")
    return with_samples_used(reconstruct_bivariate(s, fill=opts.fill, cos_power=opts.cos_power), s, None, "bivariate")


METHOD = Method("bivariate", "f(theta_h, theta_d) interpolated between the measured lines",
                reconstruct=reconstruct, options=BivariateOptions, modules=("reconstruction.methods.bivariate",))
