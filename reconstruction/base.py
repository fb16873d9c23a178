"""The interface every reconstruction method implements (many small models behind one evaluate interface).

A method takes in-plane slices (already converted to f_r in 1/sr and to 1 grey or 3 linear-RGB channels) and
returns a :class:`Reconstruction`: a vectorised BRDF ``eval(wi, wo) -> (N, C)`` for any direction pairs, plus a
JSON-serialisable ``report()``. ``reconstruction.core.merltable.tabulate(rec.eval, ...)`` turns it into a MERL table.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = ["Reconstruction", "ReconstructionError"]


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
