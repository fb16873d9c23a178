"""The interface every reconstruction method implements (many small models behind one evaluate interface).

A method takes in-plane slices (already converted to f_r in 1/sr and to 1 grey or 3 linear-RGB channels) and
returns a :class:`Reconstruction`: a vectorised BRDF ``eval(wi, wo) -> (N, C)`` for any direction pairs, plus a
JSON-serialisable ``report()``. ``reconstruction.core.merltable.tabulate(rec.eval, ...)`` turns it into a MERL table.

What else a reconstruction can give, its outputs ask it (:func:`offers`), never its class: ``analytic_lobes()``
(:class:`AnalyticLobes`: ``eval`` is this sum of lobes in closed form, which the parameters JSON and the Mitsuba
fragment write), ``fitted_parameters()`` (:class:`FittedParameters`: the fitted parameters with their
uncertainties, which the parameters JSON carries and the principled fit starts from), ``table()`` (a faster MERL
table), ``samples_left_out``.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = ["Reconstruction", "ReconstructionError", "AnalyticLobes", "FittedParameters", "offers"]


class ReconstructionError(ValueError):
    """The input cannot be reconstructed; the message says what is wrong with which input."""


@runtime_checkable
class Reconstruction(Protocol):
    """A full isotropic BRDF reconstructed from slices."""

    method: str
    channels: list[str]  # ["value"] (grey) or ["R", "G", "B"] (linear sRGB)

    def eval(self, wi: Array, wo: Array) -> Array:
        """f_r (N, C) in 1/sr at unit direction pairs (N, 3), z = normal; finite and >= 0 above the horizon."""
        ...

    def report(self) -> dict[str, Any]:
        """JSON-serialisable description: method, parameters, residuals, coverage, notes."""
        ...


class AnalyticLobes(Protocol):
    """A reconstruction whose ``eval`` is a sum of lobes in closed form."""

    def analytic_lobes(self) -> list[dict[str, Any]]:
        """The lobes in the parameters schema's form (docs/parameters.schema.json, ``lobes``): ``{"type":
        "lambert", "albedo": [..]}``, ``{"type": "ggx" | "beckmann", "alpha", "specular", "fresnel"}``, ``{"type":
        "retro", "exponent", "amount"}``, ``{"type": "ggx_mixture", "terms", "specular", "fresnel"}``; None when a
        lobe has no such form."""
        ...


class FittedParameters(Protocol):
    """A reconstruction with fitted parameters and their uncertainties."""

    def fitted_parameters(self) -> list[dict[str, Any]]:
        """Per lobe: ``{"type", <parameter>: value, <parameter>_std: its standard deviation, ...}``."""
        ...


def offers(rec: Any, capability: str) -> Any:
    """The bound method ``capability`` of ``rec`` (``"analytic_lobes"``, ``"fitted_parameters"``), or None when it
    cannot give it: how an output asks a reconstruction what it can give, whichever method made it (a wrapper that
    changes ``eval``, such as :class:`reconstruction.assess.guard.Conservative`, sets what no longer holds to
    None)."""
    got = getattr(rec, capability, None)
    return got if callable(got) else None
