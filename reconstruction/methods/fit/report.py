"""The fit's result and report: the fitted :class:`~reconstruction.core.models.Material` with the selection, residuals,
weights, convergence and the constraints that held."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from reconstruction.core.metrics import relative_rmse_cos_dirs
from reconstruction.core.models import Material, Microfacet
from reconstruction.core.slicedata import Slice
from reconstruction.methods.fit.model import FLOOR, IOR_MAX, IOR_MIN, Array, FitResult, LobeSpec, _Problem

#: a fitted microfacet alpha below this makes the table hold theta_h cell averages near the mirror direction
SHARP_ALPHA = 0.01
REPORT_MAX_SAMPLES = 5000  # per-sample residuals listed in the report (an evenly strided subset beyond)

__all__ = ["FitReconstruction", "fit_info"]


@dataclass
class FitReconstruction:
    """Result of :func:`~reconstruction.methods.fit.reconstruct_fit`: a fitted :class:`Material` and the fit's
    report."""

    material: Material
    channels: list[str]
    result: FitResult
    info: dict[str, Any] = field(default_factory=dict)
    method: str = "fit"
    #: fitted to the samples inside a scene's ranges only (a scene's budget chose a simpler model than BIC)
    fitted_to_scene: bool = False
    #: the BIC choice's structure when a scene's budget replaced it by a simpler model (None otherwise)
    bic_specs: tuple[LobeSpec, ...] | None = None

    def eval(self, wi: Array, wo: Array) -> Array:
        """f_r (N, C) in 1/sr at unit direction pairs (N, 3); 0 below the horizon."""
        return self.material.eval(wi, wo)

    def table(self) -> Array:
        """The MERL table (3, 90, 90, 180): bin-centre values, and below :attr:`sharp_theta_h_rad` the
        microfacet
        lobes' cell averages over theta_h (:func:`reconstruction.core.halfdiff.average_theta_h_half_diff`, 8 per
        cell) in the
        half-diff angles; the other lobes (Lambert, retro: constant in theta_h at fixed theta_d) keep their values,
        so this is ``merltable.average_theta_h_cells`` of :meth:`eval` at a fraction of the cost. NaN below the
        horizon."""
        from reconstruction.core import halfdiff, merlgrid

        t = self._centre_table()
        sharp = self.sharp_theta_h_rad
        if sharp is None:
            return t
        th, td, _ = merlgrid.cell_angles()
        m = self.material
        rows = int(min(merlgrid.N_TH, merlgrid.theta_h_index(sharp) + 1))
        cic, coc = (c[:rows] for c in merlgrid.cell_cosines())
        valid = (cic > 0) & (coc > 0)
        covered = np.ones_like(valid)
        for lb in m.lobes:
            if isinstance(lb, Microfacet):  # sharp (it sets the rows) or not: its average replaces its centre value
                _, avg, covered = halfdiff.average_theta_h_half_diff(lb.shape_half_diff, sharp, 8)
                delta = np.where(valid, avg - lb.shape_half_diff(th[:rows], td, cic, coc), 0.0)
                col = np.broadcast_to(lb.colour.on(m.n_channels, m.wavelengths_nm), (3,))
                t[:, :rows] += col[:, None, None, None] * delta[None]
        t[:, :rows][:, valid & ~covered] = 0.0  # no sub-sample above the horizon: 0, as merl's
        return t

    def _centre_table(self) -> Array:
        """The bin-centre table (3, 90, 90, 180), NaN below the horizon: ``merltable.tabulate(self.material.eval)``, in
        the half-diff angles when every lobe has a half-diff form (lambert, ggx, beckmann, retro: a tenth of the cost of
        evaluating 1.46 million direction pairs; the same values to rounding, tests/test_fit.py)."""
        from reconstruction.core import halfdiff, merlgrid, merltable

        m = self.material
        th, td, _ = merlgrid.cell_angles()
        ci, co = merlgrid.cell_cosines()
        shapes = [halfdiff.lobe_half_diff(lb, th, td, ci, co) for lb in m.lobes] if m.n_channels in (1, 3) else [None]
        if any(x is None for x in shapes):
            return merltable.tabulate(m.eval)
        out = np.zeros((3,) + ci.shape)
        for lb, shape in zip(m.lobes, shapes, strict=True):  # a handful
            col = np.broadcast_to(lb.colour.on(m.n_channels, m.wavelengths_nm), (3,))
            for c in range(3):
                out[c] += shape * col[c]
        out[:, ~merlgrid.valid_mask()] = np.nan
        return out

    @property
    def sharp_theta_h_rad(self) -> float | None:
        """theta_h (radians) below which the table holds theta_h cell averages: 5 alpha of the narrowest
        microfacet lobe when alpha < :data:`SHARP_ALPHA` (a lobe narrower than the table's cells), else None."""
        alphas = [lb.alpha for lb in self.material.lobes if isinstance(lb, Microfacet)]
        return 5.0 * min(alphas) if alphas and min(alphas) < SHARP_ALPHA else None

    @property
    def table_values(self) -> str:
        """What the table holds, for the report."""
        sharp = self.sharp_theta_h_rad
        if sharp is None:
            return "bin centres"
        return (f"cell averages over theta_h below {np.degrees(sharp):.3g} deg (automatic: a lobe narrower than "
                f"the table's cells), bin centres elsewhere")

    def report(self) -> dict[str, Any]:
        return {"method": self.method, "model": self.result.name, "material": self.material.to_dict(),
                "parameters": self.result.parameters(), **self.info}

    def fitted_parameters(self) -> list[dict[str, Any]]:
        """Per lobe, the fitted parameters with their standard deviations (``<key>_std``): the report's
        ``parameters`` (:class:`reconstruction.base.FittedParameters`)."""
        return list(self.result.parameters())

    def analytic_lobes(self) -> list[dict[str, Any]] | None:
        """The fitted lobes in the parameters schema's form (:class:`reconstruction.base.AnalyticLobes`): lambert
        (albedo), ggx / beckmann (alpha, specular colour, Fresnel none or Schlick's f0 and its index), retro
        (exponent, amount); None when a lobe has none of these forms."""
        from reconstruction.core.models import Lambert, Retro
        from reconstruction.methods.fit.model import ior_of_f0

        out: list[dict[str, Any]] = []
        for lb in self.material.lobes:  # a handful
            col = lb.colour.values.tolist()
            if isinstance(lb, Lambert):
                out.append({"type": "lambert", "albedo": col})
            elif isinstance(lb, Microfacet):
                d: dict[str, Any] = {"type": lb.distribution, "alpha": lb.alpha, "specular": col}
                d["fresnel"] = ({"kind": "none"} if lb.f0 is None
                                else {"kind": "schlick", "f0": lb.f0, "ior": ior_of_f0(lb.f0)})
                out.append(d)
            elif isinstance(lb, Retro):
                out.append({"type": "retro", "exponent": lb.exponent, "amount": col})
            else:
                return None
        return out


def fit_info(slices: Slice, full: _Problem, chosen: FitResult, material: Material, ranked: list[FitResult],
             reason: str, skipped: list[str], fit_mask: NDArray[np.bool_] | None, gaps: dict[str, float],
             loss: str, f_scale: float) -> dict[str, Any]:
    """The report of the fit (without the scene and notes sections): residuals on every sample, the summary
    figures on the samples the model is for (a scene's subset, when it was fitted to one)."""
    wi, wo, f = full.wi, full.wo, full.f
    # the model as the instrument reads it (cone averages near the mirror directions) against the data
    model = full.blur.reading(material) if full.blur is not None else material.eval(wi, wo)
    resid = (model - f) / full.sigma_of(model)  # every sample, whatever subset the model was fitted to
    used = fit_mask if fit_mask is not None else np.ones(len(slices), dtype=bool)
    ru = resid[used]
    every = max(1, -(-len(slices) // REPORT_MAX_SAMPLES))  # the report lists at most this many residuals
    return {
        "selection": {"criterion": "BIC = robust chi^2 + k ln(n)", "chosen": chosen.name, "reason": reason,
                      "candidates": [r.summary() for r in ranked], "skipped": skipped},
        "residuals": {
            "n_values": int(ru.size),
            "fitted_to_values": chosen.n,
            "chi2_reduced": round(float(np.sum(ru ** 2)) / max(ru.size - chosen.k, 1), 6),
            "rms_normalised": round(float(np.sqrt(np.mean(ru ** 2))), 6),
            "max_abs_normalised": round(float(np.max(np.abs(ru))), 6),
            "relative_rmse_cos": round(relative_rmse_cos_dirs(model[used], f[used], wi[used], wo[used]), 6),
            "relative_rmse_cos_all_samples": round(relative_rmse_cos_dirs(model, f, wi, wo), 6),
            "samples_used": int(used.sum()),
            "samples": {"theta_i_deg": slices.theta_i_deg[::every].tolist(),
                        "theta_o_deg": slices.theta_o_deg[::every].tolist(),
                        "normalised": np.round(resid[::every], 5).tolist(),
                        **({"every": every, "note": f"1 sample in {every} is listed"} if every > 1 else {})},
        },
        "weights": {"sigma": f"sqrt(std^2 + ({full.relative_sigma:g} f_model)^2 + ({FLOOR:g} peak)^2)",
                    "loss": loss, "f_scale_sigma": f_scale},
        "fit": {"converged": chosen.success, "message": chosen.message, "evaluations": chosen.nfev},
        "holes": "the blind spot and missing samples are covered by the fitted model",
        "constraints": {
            "amplitudes": "lambert albedo, microfacet specular and retro amount each in (0, 1]",
            "fresnel": "Schlick's approximation of a dielectric interface: f0 = ((ior - 1) / (ior + 1))^2, "
                       f"ior in [{IOR_MIN:.3f}, {IOR_MAX:.0f}]",
            "energy": "each channel's directional albedo held <= 1 at theta_i = 0-88 deg during the fit",
            "max_directional_albedo": [round(float(v), 5) for v in chosen.albedo().max(axis=0)],
            **{k: round(v, 6) for k, v in gaps.items()},
        },
    }
