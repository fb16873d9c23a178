"""Synthetic in-plane slices of a known material: what the bench would measure, without a bench.

For checking a reconstruction against ground truth (which method suits a material, how much noise or how few
incidences it tolerates), as the tests and ``benchmarks/bench_reconstruct.py`` do::

    from reconstruction import pipeline
    from reconstruction.core import merltable
    from reconstruction.core.metrics import relative_rmse_cos
    from reconstruction.core.models import Material
    from reconstruction.synthetic import synthetic_slice

    mat = Material.from_toml("configs/simulated.toml")
    rec, _ = pipeline.reconstruct(synthetic_slice(mat, (30.0, 60.0), noise=0.01), "auto")
    print(relative_rmse_cos(pipeline.tabulate(rec), merltable.tabulate(mat.eval)))

Geometry as on the bench (README conventions): light at theta_i, detector at the signed theta_o; samples in the
retro blind spot, where the source arm shadows the detector (|theta_i + theta_o| <= ``blind_spot_deg``), are left
out. Values are f_r (quantity ``brdf``) on the material's channels: ``value``, ``R,G,B`` or wavelengths.
Unlike ``gonio-sim``, no bench is simulated (no angle quantisation, detector or calibration).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from reconstruction.core.geometry import inplane_to_dirs
from reconstruction.core.models import Material
from reconstruction.core.slicedata import Slice

__all__ = ["synthetic_slice"]


def synthetic_slice(material: Material, incidences_deg: Sequence[float] = (30.0,),
                    theta_o_deg: ArrayLike | None = None, *, step_deg: float = 2.0, blind_spot_deg: float = 4.0,
                    noise: float = 0.0, noise_floor: float = 0.0, seed: int = 0) -> Slice:
    """In-plane samples of ``material``, incidence by incidence, theta_o increasing within each.

    ``theta_o_deg``: the detector angles of every incidence (degrees); default -80 to 80 every ``step_deg``.
    ``noise``, ``noise_floor``: each value gets Gaussian noise of standard deviation ``noise * |f| +
    noise_floor`` (relative and absolute), recorded as the samples' std (zero without noise); ``seed`` makes it
    reproducible.
    """
    if theta_o_deg is None:
        theta_o_deg = np.arange(-80.0, 80.0 + 1e-9, step_deg)
    outgoing = np.asarray(theta_o_deg, dtype=np.float64).reshape(-1)
    ti, to = [], []
    for t in incidences_deg:
        o = outgoing[np.abs(outgoing + t) > blind_spot_deg]
        ti.append(np.full(o.size, float(t)))
        to.append(o)
    a, b = np.concatenate(ti), np.concatenate(to)
    f = material.eval(*inplane_to_dirs(np.radians(a), np.radians(b)))
    std = noise * np.abs(f) + noise_floor
    if np.any(std):
        f = f + np.random.default_rng(seed).normal(size=f.shape) * std
    if material.wavelengths_nm is not None:
        channels = [f"{w:g}nm" for w in np.asarray(material.wavelengths_nm)]
    else:
        channels = ["value"] if f.shape[1] == 1 else ["R", "G", "B"]
    return Slice(a, b, f, channels, std)
