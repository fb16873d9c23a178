"""The registry of reconstruction methods: one entry per method, used by the CLI, batch, the study and ``auto``.

A method is a :class:`Method`: a name, a one-line summary, a ``build(slice, options, progress)`` function that
returns a :class:`~reconstruction.base.Reconstruction`, and its own options schema (a :mod:`msgspec` struct:
:class:`FitOptions`, :class:`RevolveOptions`, ...; ``docs/schema/method-options.json``). ``build`` receives the
common :class:`Options` of a command line and reads its own options from them (:meth:`Method.options_from`).
Adding a method is one module and one :func:`register` call here; ``gonio-reconstruct --method``, ``--batch``, the
study and ``auto``'s cross-validation pick it up from :data:`REGISTRY`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta

from reconstruction.base import Reconstruction, ReconstructionError
from reconstruction.core.scene import Scene
from reconstruction.core.slicedata import Slice

__all__ = ["Method", "Options", "REGISTRY", "register", "get", "names", "NoOptions", "FitOptions", "RevolveOptions",
           "BivariateOptions", "PriorOptions", "options_schema"]


@dataclass
class Options:
    """Method options. ``fill``: "interpolate" holes (default) or leave them "zero" (bivariate, revolve)."""

    scene: Scene | None = None
    fill: str = "interpolate"
    lobes: Sequence[str] | None = None
    revolve_axis: str = "auto"
    revolve_smoothing: float | None = None
    cos_power: float | None = None  # bivariate: None = chosen from the data
    prior: str | None = None  # prior: the folder of prior materials (--prior)
    prior_exclude: tuple[str, ...] = ()  # prior: materials of the folder left out (a benchmark's leave-one-out)
    prior_anchor: float = 0.0  # prior: weight of the samples' bivariate interpolation in a geometric blend
    prior_near: int = 0  # prior: a local basis of the N materials nearest to the samples (0: every material)


class NoOptions(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A method without options of its own."""


Fill = Annotated[Literal["interpolate", "zero"], Meta(
    description="holes (blind spot, missing samples): interpolated, or left at 0 as the thesis does (--fill)")]
LobeKind = Literal["lambert", "ggx", "beckmann", "retro", "fresnel"]


class FitOptions(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Options of ``fit`` (the scene, common to every method, is passed beside them)."""

    lobes: Annotated[list[LobeKind] | None, Meta(
        description="lobe kinds the fit may use (--lobes); default all, or the scene's list")] = None


class RevolveOptions(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Options of ``revolve``."""

    axis: Annotated[Literal["auto", "vertical", "pca"], Meta(
        description="axis of each sub-curve: vertical through its top, first principal component, or chosen per "
                    "sub-curve (--axis)")] = "auto"
    smoothing: Annotated[float, Meta(ge=0.0, description="Gaussian sigma (deg of theta_o) before the sub-curve "
                                                         "split (--smoothing); default 5")] | None = None
    fill: Fill = "interpolate"


class PriorOptions(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Options of ``prior``."""

    prior: Annotated[str, Meta(description="folder of prior materials: NBRDF npy sets, MERL .binary tables or "
                                           "material TOML files (--prior)")] | None = None
    anchor: Annotated[float, Meta(ge=0.0, le=1.0, description="weight a of the samples' bivariate interpolation: "
                                  "f = f_prior^(1-a) f_bivariate^a (--prior-anchor; 0: the prior alone)")] = 0.0
    near: Annotated[int, Meta(ge=0, description="a local prior: the basis of the N prior materials nearest to the "
                              "samples (--prior-near; 0: of every material)")] = 0


class BivariateOptions(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Options of ``bivariate``."""

    fill: Fill = "interpolate"
    cos_power: Annotated[float, Meta(gt=0.0, description="power P of the cos^P(theta_d) weight of the excess; "
                                                         "default: chosen from the data")] | None = None


@dataclass(frozen=True)
class Method:
    """One reconstruction method: ``build(slice, options, progress)`` -> Reconstruction.

    ``options``: the method's own options schema (a msgspec struct); ``common``: which of them come from which
    field of the common :class:`Options` (the command line's flags). ``build`` takes its options from the common
    ones itself; the method's function checks their values with its own messages.
    """

    name: str
    summary: str
    build: Callable[[Slice, Options, Callable[[str], None] | None], Reconstruction]
    options: type[msgspec.Struct] = NoOptions
    common: Mapping[str, str] = field(default_factory=dict)
    available: Callable[[Options], bool] | None = None  # None: always; else whether ``auto`` may try it
    #: the modules ``build`` imports (scipy's among them): what a run that builds it may import ahead
    #: (:func:`reconstruction.methods.auto.import_methods`, while its forked child works)
    modules: tuple[str, ...] = ()

    def usable(self, opts: Options) -> bool:
        """Whether this method can run with ``opts`` (``auto`` skips the others, e.g. ``prior`` without --prior)."""
        return self.available is None or self.available(opts)

    def options_from(self, opts: Options) -> Any:
        """This method's options, taken from the common ``opts`` and validated against its schema."""
        return self.parse_options({k: getattr(opts, v) for k, v in self.common.items()})

    def parse_options(self, raw: Mapping[str, Any]) -> Any:
        """Validate ``raw`` (e.g. a table of a study or a script) against the method's schema;
        :class:`ReconstructionError` naming the method and the option otherwise."""
        try:
            return msgspec.convert(dict(raw), self.options)
        except msgspec.ValidationError as e:
            raise ReconstructionError(f"method {self.name}: options: {e}") from None


def options_schema() -> dict[str, Any]:
    """JSON Schema of every registered method's options (``docs/schema/method-options.json``)."""
    _, defs = msgspec.json.schema_components([m.options for m in REGISTRY.values()],
                                             ref_template="#/$defs/{name}")
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": "gonio-brdf method options",
            "description": "The options of each reconstruction method (reconstruction.methods), by method name.",
            "type": "object", "additionalProperties": False,
            "properties": {m.name: {"$ref": f"#/$defs/{m.options.__name__}", "description": m.summary}
                           for m in REGISTRY.values()}, "$defs": defs}


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


def _used(rec: Reconstruction, s: Slice, used: Slice | None, method: str) -> Reconstruction:
    """``rec`` with ``samples_left_out`` (the report's key of that name: what it used and left out, and why)."""
    from reconstruction.core.samples import samples_used

    rec.samples_left_out = samples_used(s, used, method)  # type: ignore[attr-defined]
    return rec


def _fit(s: Slice, o: Options, progress: Callable[[str], None] | None) -> Reconstruction:
    from reconstruction.core.samples import everywhere
    from reconstruction.methods.fit import reconstruct_fit

    opt = FitOptions(lobes=o.lobes)  # type: ignore[arg-type] # checked by reconstruct_fit, with its own message
    pts = everywhere(s)
    return _used(reconstruct_fit(pts, scene=o.scene, lobes=opt.lobes, progress=progress), s, pts, "fit")


def _microfacet(s: Slice, o: Options, progress: Callable[[str], None] | None) -> Reconstruction:
    from reconstruction.core.samples import everywhere
    from reconstruction.methods.microfacet import reconstruct_microfacet

    pts = everywhere(s)
    return _used(reconstruct_microfacet(pts), s, pts, "microfacet")


def _revolve(s: Slice, o: Options, progress: Callable[[str], None] | None) -> Reconstruction:
    from reconstruction.methods.revolve import reconstruct_revolve

    opt = RevolveOptions(axis=o.revolve_axis, smoothing=o.revolve_smoothing, fill=o.fill)  # type: ignore[arg-type]
    # reciprocal: f(wi, wo) and f(wo, wi) averaged, so the BRDF passes the reciprocity check
    kw: dict[str, Any] = {"axis": opt.axis, "fill": opt.fill, "reciprocal": True}
    if opt.smoothing is not None:
        kw["smoothing"] = opt.smoothing
    return _used(reconstruct_revolve(s, **kw), s, None, "revolve")


def _bivariate(s: Slice, o: Options, progress: Callable[[str], None] | None) -> Reconstruction:
    from reconstruction.core.samples import everywhere, points_anywhere, scans_hemisphere
    from reconstruction.methods.bivariate import reconstruct_bivariate

    opt = BivariateOptions(fill=o.fill, cos_power=o.cos_power)  # type: ignore[arg-type]
    pts = points_anywhere(s)  # a scanned hemisphere: every point placed by (theta_h, theta_d, phi_d) on a grid; a
    if pts is not None and scans_hemisphere(pts):  # bench's sweeps out of the plane: the in-plane lines (the grid
        # fills what a few great circles leave by smoothing: worse than the lines, docs/real-materials.md)
        from reconstruction.methods.scattered import reconstruct_scattered

        pts = everywhere(s)
        rec = reconstruct_scattered(pts)
        ignored = [k for k, v in (("--fill zero", opt.fill == "zero"), ("--cos-power", opt.cos_power is not None))
                   if v]
        if ignored:
            rec.info["notes"] = [f"{', '.join(ignored)}: for in-plane slices only; not used on points anywhere"]
        return _used(rec, s, pts, "bivariate")
    return _used(reconstruct_bivariate(s, fill=opt.fill, cos_power=opt.cos_power), s, None, "bivariate")


def _prior(s: Slice, o: Options, progress: Callable[[str], None] | None) -> Reconstruction:
    from reconstruction.methods.prior import reconstruct_prior

    if not 0.0 <= o.prior_anchor <= 1.0:
        raise ReconstructionError(f"method prior: --prior-anchor {o.prior_anchor:g}: expected a weight from 0 (the "
                                  "prior alone) to 1 (the bivariate interpolation alone)")
    opt = PriorOptions(prior=o.prior, anchor=o.prior_anchor, near=o.prior_near)
    if not opt.prior:
        raise ReconstructionError("method prior needs --prior DIR: a folder of measured materials (NBRDF npy sets, "
                                  "MERL .binary tables or material TOML files) whose structure the slice is "
                                  "completed with")
    from reconstruction.core.samples import everywhere

    if opt.near > 0:  # a local prior (reconstruction.methods.prior_local), on every point as below
        from reconstruction.methods.prior_local import reconstruct_local

        rec = reconstruct_local(s, opt.prior, exclude=tuple(o.prior_exclude), n_near=opt.near)
    else:
        rec = reconstruct_prior(s, opt.prior, exclude=tuple(o.prior_exclude))  # on every point (everywhere(s))
    if opt.anchor <= 0.0:
        return _used(rec, s, everywhere(s), "prior")
    from reconstruction.methods.prior import AnchoredPrior

    return _used(AnchoredPrior(rec, _bivariate(s, o, None), opt.anchor), s, everywhere(s), "prior")


register(Method("fit", "analytic lobes (lambert, ggx/beckmann with Fresnel, retro) chosen by BIC, energy-constrained",
                _fit, FitOptions, {"lobes": "lobes"}, modules=("reconstruction.methods.fit",)))
register(Method("microfacet", "non-parametric microfacet: tabulated NDF, Smith G from it, physical Fresnel",
                _microfacet, modules=("reconstruction.methods.microfacet",)))
register(Method("revolve", "the thesis's solids of revolution, extended to every incidence", _revolve,
                RevolveOptions, {"axis": "revolve_axis", "smoothing": "revolve_smoothing", "fill": "fill"},
                modules=("reconstruction.methods.revolve",)))
register(Method("bivariate", "f(theta_h, theta_d) interpolated between the measured lines", _bivariate,
                BivariateOptions, {"fill": "fill", "cos_power": "cos_power"},
                modules=("reconstruction.methods.bivariate",)))
register(Method("prior", "completed from a basis of measured materials (--prior DIR), fitted to the slices",
                _prior, PriorOptions, {"prior": "prior", "anchor": "prior_anchor", "near": "prior_near"},
                available=lambda o: bool(o.prior),
                modules=("reconstruction.methods.prior",)))
