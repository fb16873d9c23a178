"""The prior's coefficients under the basis's own misfit: correlated, not independent (issue 50).

:mod:`reconstruction.methods.prior` fits the coefficients c of K components to the mapped samples y (n, C) as a
Gaussian posterior mean. Treating the samples' misfit as independent noise of one variance ``lam`` makes every
sample a new piece of evidence, while what the K components cannot hold is the same at neighbouring samples: a sweep
of 80 samples 2 deg apart along a part of the material the basis cannot follow counts as 80 observations, and the
coefficients bend to it, trading the cells no sample rests on for the ones that are seen (with a tilted sweep of a
metal, a rim 10-100 times too bright; from one more in-plane slice a table worse than from one slice). The prior's
own materials say how that misfit is correlated: the part of each of their rows (T) beyond the K components, read at
the samples, ``E`` (T, n). The noise covariance is then

    N = lam I + E^T E / (T - 1),

and the posterior mean c = (A^T N^-1 A + diag(1 / sig^2))^-1 A^T N^-1 y, with A the components at the samples. N
is inverted through its rank-T part (Woodbury): O(n T K), never an n x n matrix. Samples along a direction the
basis cannot follow then carry the weight of about one observation however many there are, and more samples only
add what the basis can use. With E = 0 it is the independent-noise posterior the prior used before.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = ["NoiseModel", "posterior_coefficients", "NOISE_SCALE"]

#: The weight of the prior materials' misfit covariance in N (module doc): N = lam I + NOISE_SCALE E^T E / (T - 1).
NOISE_SCALE = 0.3


class NoiseModel:
    """The misfit's covariance beyond ``k`` components at the samples: ``E30`` (T, n), the rows' part beyond every
    component of the basis; ``coef`` (T, Kmax) the rows' coefficients; ``sb`` (n, Kmax) the components at the
    samples; ``scale`` the weight of that covariance (:data:`NOISE_SCALE`). :meth:`inverse_times` gives N^-1 x for
    any ``lam`` from one eigendecomposition per ``k``."""

    def __init__(self, e_all: Array, coef: Array, sb: Array, k: int, sig: Array, scale: float | None = None) -> None:
        w = (NOISE_SCALE if scale is None else scale) / max(e_all.shape[0] - 1, 1)  # 0: independent misfit
        beyond = np.nonzero(_held(sig))[0]
        beyond = beyond[beyond >= k]  # the components after k that hold anything (others are round-off)
        u = (e_all + coef[:, beyond] @ sb[:, beyond].T).T * np.sqrt(w)  # (n, T): the rows' misfit beyond k
        d, v = np.linalg.eigh(u.T @ u)  # (T,), (T, T)
        self.uv = u @ v  # (n, T)
        self.d = np.maximum(d, 0.0)

    def inverse_times(self, x: Array, lam: float) -> Array:
        """N^-1 x (x: (n, m)) with N = lam I + U U^T (Woodbury through the eigenvectors of U^T U)."""
        # (lam I + U U^T)^-1 = (I - U (lam I + U^T U)^-1 U^T) / lam, and U^T U = V D V^T
        return (x - self.uv @ ((self.uv.T @ x) / (lam + self.d)[:, None])) / lam


def posterior_coefficients(sb: Array, y: Array, sig: Array, k: int, lam: float,
                           noise: NoiseModel | None = None) -> Array:
    """The posterior mean (k, C) of the first ``k`` coefficients given the mapped samples ``y`` (n, C), the
    components at the samples ``sb`` (n, >= k), their prior standard deviations ``sig`` and the noise ``lam`` I plus,
    with ``noise``, the basis's correlated misfit (module doc)."""
    keep = np.nonzero(_held(sig)[:k])[0]  # components of no variance (fewer rows than k) stay at 0
    a = sb[:, keep]
    na = a if noise is None else noise.inverse_times(a, lam) * lam  # lam N^-1 a (N = lam I: a itself)
    out = np.zeros((k, y.shape[1]))
    out[keep] = np.linalg.solve(a.T @ na + lam * np.diag(1.0 / sig[keep] ** 2), na.T @ y)
    return out


def _held(sig: Array) -> NDArray[np.bool_]:
    """The components whose prior standard deviation is more than round-off of the largest's."""
    return np.asarray(sig) > 1e-6 * float(np.max(sig))
