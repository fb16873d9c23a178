"""The registry of reconstruction methods: one entry per method, used by the CLI, batch, the study and ``auto``.

A method is a :class:`Method`: a name, a one-line summary and a ``build(slice, options)`` function that returns a
:class:`~reconstruction.base.Reconstruction`. Adding a method is one module and one :func:`register` call here;
``gonio-reconstruct --method`` and ``auto``'s cross-validation pick it up from :data:`REGISTRY`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from .base import Reconstruction, ReconstructionError
from .scene import Scene
from .slicefile import Slice

__all__ = ["Method", "Options", "REGISTRY", "register", "get", "names"]


@dataclass
class Options:
    """Method options. ``fill``: "interpolate" holes (default) or leave them "zero" (bivariate, revolve)."""

    scene: Scene | None = None
    fill: str = "interpolate"
    lobes: Sequence[str] | None = None
    revolve_axis: str = "auto"
    revolve_smoothing: float | None = None
    cos_power: float | None = None  # bivariate: None = chosen from the data


@dataclass(frozen=True)
class Method:
    """One reconstruction method: ``build(slice, options, progress)`` -> Reconstruction."""

    name: str
    summary: str
    build: Callable[[Slice, Options, Callable[[str], None] | None], Reconstruction]


REGISTRY: dict[str, Method] = {}


def register(method: Method) -> Method:
    """Add ``method`` to :data:`REGISTRY` (its name must be new)."""
    if method.name in REGISTRY or method.name == "auto":
        raise ValueError(f"a method named {method.name!r} is already registered")
    REGISTRY[method.name] = method
    return method


def get(name: str) -> Method:
    """The registered method ``name``; :class:`ReconstructionError` naming the choices otherwise."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise ReconstructionError(f"unknown method {name!r}; expected one of auto, {', '.join(REGISTRY)}") from None


def names() -> tuple[str, ...]:
    """Registered method names, in registration order."""
    return tuple(REGISTRY)


def _fit(s: Slice, o: Options, progress: Callable[[str], None] | None) -> Reconstruction:
    from .fit import reconstruct_fit
    from .samples import everywhere

    return reconstruct_fit(everywhere(s), scene=o.scene, lobes=o.lobes, progress=progress)


def _microfacet(s: Slice, o: Options, progress: Callable[[str], None] | None) -> Reconstruction:
    from .microfacet import reconstruct_microfacet
    from .samples import everywhere

    return reconstruct_microfacet(everywhere(s))


def _revolve(s: Slice, o: Options, progress: Callable[[str], None] | None) -> Reconstruction:
    from .revolve import reconstruct_revolve

    # reciprocal: f(wi, wo) and f(wo, wi) averaged, so the BRDF passes the reciprocity check
    kw: dict[str, Any] = {"axis": o.revolve_axis, "fill": o.fill, "reciprocal": True}
    if o.revolve_smoothing is not None:
        kw["smoothing"] = o.revolve_smoothing
    return reconstruct_revolve(s, **kw)


def _bivariate(s: Slice, o: Options, progress: Callable[[str], None] | None) -> Reconstruction:
    from .bivariate import reconstruct_bivariate

    return reconstruct_bivariate(s, fill=o.fill, cos_power=o.cos_power)


register(Method("fit", "analytic lobes (lambert, ggx/beckmann with Fresnel, retro) chosen by BIC, energy-constrained",
                _fit))
register(Method("microfacet", "non-parametric microfacet: tabulated NDF, Smith G from it, physical Fresnel",
                _microfacet))
register(Method("revolve", "the thesis's solids of revolution, extended to every incidence", _revolve))
register(Method("bivariate", "f(theta_h, theta_d) interpolated between the measured lines", _bivariate))
