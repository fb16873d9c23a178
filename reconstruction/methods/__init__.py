"""The registry of reconstruction methods: one line per method, used by the CLI, batch, the study and ``auto``.

A method is one module (the built-in ones: ``reconstruction/methods/plugins/``) that declares its options once,
as a msgspec struct with descriptions and bounds, and its ``reconstruct(slice, options, context)`` function,
bundled as a :class:`Method` (:mod:`reconstruction.methods.registry`). Registering it here is the one other line
(the plugins are imported under private names: ``reconstruction.methods.fit`` is the method's implementation):
``gonio-reconstruct --method`` and its flags (:mod:`reconstruction.methods.flags`), ``--help``, the common
:class:`Options`, ``docs/schema/method-options.json`` (:func:`options_schema`), ``--batch``, the study and
``auto``'s cross-validation all come from :data:`REGISTRY`.
"""

from __future__ import annotations

from reconstruction.methods.plugins import bivariate as _bivariate
from reconstruction.methods.plugins import fit as _fit
from reconstruction.methods.plugins import microfacet as _microfacet
from reconstruction.methods.plugins import prior as _prior
from reconstruction.methods.plugins import revolve as _revolve
from reconstruction.methods.plugins.bivariate import BivariateOptions
from reconstruction.methods.plugins.fit import FitOptions
from reconstruction.methods.plugins.prior import PriorOptions
from reconstruction.methods.plugins.revolve import RevolveOptions
from reconstruction.methods.registry import (
    REGISTRY,
    Context,
    Method,
    NoOptions,
    Options,
    OptionSpec,
    get,
    names,
    option,
    option_specs,
    options_schema,
    register,
)

__all__ = ["Method", "Context", "Options", "OptionSpec", "REGISTRY", "register", "get", "names", "option",
           "option_specs", "NoOptions", "FitOptions", "RevolveOptions", "BivariateOptions", "PriorOptions",
           "options_schema"]

register(_fit.METHOD)
register(_microfacet.METHOD)
register(_revolve.METHOD)
register(_bivariate.METHOD)
register(_prior.METHOD)
