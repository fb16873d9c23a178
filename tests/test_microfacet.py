"""The microfacet method: a non-parametric NDF, Smith G from it and a physical Fresnel, fitted to slices."""

import numpy as np
import pytest

from reconstruction.base import Reconstruction, ReconstructionError
from reconstruction.core import merltable
from reconstruction.core.geometry import sph_to_vec
from reconstruction.core.metrics import directional_albedo, reciprocity_error, relative_rmse_cos
from reconstruction.core.models import Colour, Lambert, Material, Microfacet, ggx_d
from reconstruction.core.slicedata import Slice
from reconstruction.methods.microfacet import fresnel, reconstruct_microfacet
from reconstruction.synthetic import synthetic_slice


class DielectricGGX(Microfacet):
    """A GGX lobe with the exact dielectric Fresnel of index ``eta`` (the family the method assumes)."""

    eta: float = 1.5

    def shape(self, wi, wo):
        h = wi + wo
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        cd = np.clip(np.sum(wi * h, axis=-1), 0, 1)
        return super().shape(wi, wo) * fresnel(cd, "dielectric", self.eta)


def two_population_material(eta=1.5):
    """Diffuse + a non-GGX NDF: 70 % sharp facets (alpha 0.05) and 30 % rough ones (alpha 0.4), so D has a narrow
    core and a long tail that no single GGX or Beckmann lobe has."""
    sharp = DielectricGGX(colour=Colour(np.array([0.7])), alpha=0.05)
    rough = DielectricGGX(colour=Colour(np.array([0.3])), alpha=0.4)
    sharp.eta = rough.eta = eta
    return Material("two-population", [Lambert(colour=Colour(np.array([0.15, 0.25, 0.4]))), sharp, rough])


def true_ndf(theta_h):
    c = np.cos(theta_h)
    return 0.7 * ggx_d(c, 0.05) + 0.3 * ggx_d(c, 0.4)


@pytest.mark.parametrize("incidences", [(40.0,), (20.0, 40.0, 60.0)])
def test_recovers_a_two_population_ndf_and_the_index(incidences):
    mat = two_population_material(eta=1.5)
    rec = reconstruct_microfacet(synthetic_slice(mat, incidences, step_deg=1.0))
    assert isinstance(rec, Reconstruction)
    assert rec.fresnel_kind == "dielectric"
    assert rec.eta == pytest.approx(1.5, abs=0.05)
    th = np.radians(np.array([0.0, 1.0, 3.0, 6.0, 10.0, 20.0]))
    np.testing.assert_allclose(rec.ndf(th), true_ndf(th), rtol=0.2)  # the core and the shoulder, within 20 %
    # the far tail (35 deg, 1000 times below the peak) within 30 %; the sharp population alone is 10 times lower
    tail = np.radians(35.0)
    assert rec.ndf(tail) == pytest.approx(true_ndf(tail), rel=0.3)
    assert ggx_d(np.cos(tail), 0.05) < true_ndf(tail) / 10
    # the table is close to the truth everywhere, not only in the measured plane
    err = relative_rmse_cos(merltable.tabulate(rec.eval), merltable.tabulate(mat.eval))
    assert err < 0.1


def test_student_t_like_tail_is_kept():
    # a heavy tail: GGX mixture 0.5 alpha 0.02 + 0.5 alpha 0.2, no Fresnel; one slice
    lobes = [Microfacet(colour=Colour(np.array([0.5])), alpha=a) for a in (0.02, 0.2)]
    mat = Material("t", [Lambert(colour=Colour(np.array([0.1])))] + lobes)
    rec = reconstruct_microfacet(synthetic_slice(mat, (30.0,), step_deg=1.0))
    th = np.radians([0.0, 2.0, 8.0, 20.0, 40.0])
    np.testing.assert_allclose(rec.ndf(th) * rec.ks[0], 0.5 * ggx_d(np.cos(th), 0.02) + 0.5 * ggx_d(np.cos(th), 0.2),
                               rtol=0.2)


def test_physically_plausible_by_construction_even_on_unphysical_data():
    # values far above any albedo: the fit must still conserve energy, be reciprocal and non-negative
    base = synthetic_slice(two_population_material(), (30.0,), step_deg=2.0)
    s = Slice(base.theta_i_deg, base.theta_o_deg, base.values * 40.0, base.channels)
    rec = reconstruct_microfacet(s)
    alb = directional_albedo(rec.eval, np.radians(np.arange(0.0, 89.0, 4.0)), 128, 256)
    assert alb.max() <= 1.0 + 1e-3
    assert reciprocity_error(rec.eval) < 1e-9
    rng = np.random.default_rng(0)
    wi = sph_to_vec(np.arccos(rng.uniform(0.01, 1, 2000)), rng.uniform(0, 2 * np.pi, 2000))
    wo = sph_to_vec(np.arccos(rng.uniform(0.01, 1, 2000)), rng.uniform(0, 2 * np.pi, 2000))
    v = rec.eval(wi, wo)
    assert np.all(np.isfinite(v)) and np.all(v >= 0)
    assert np.all(np.asarray(rec.report()["parameters"]["specular"]) <= 1.0)


def test_conductor_fresnel_is_chosen_for_a_metal():
    class Conductor(Microfacet):
        def shape(self, wi, wo):
            h = wi + wo
            h = h / np.linalg.norm(h, axis=-1, keepdims=True)
            return super().shape(wi, wo) * fresnel(np.sum(wi * h, axis=-1), "conductor", 0.2, 3.5)

    mat = Material("metal", [Conductor(colour=Colour(np.array([0.9])), alpha=0.1)])
    rec = reconstruct_microfacet(synthetic_slice(mat, (10.0, 40.0, 70.0), step_deg=1.0))
    assert rec.fresnel_kind == "conductor"
    f0 = rec.report()["parameters"]["fresnel"]["f0"]
    assert f0 * rec.ks[0] == pytest.approx(float(fresnel(1.0, "conductor", 0.2, 3.5)) * 0.9, rel=0.05)


def test_bad_input():
    with pytest.raises(ReconstructionError, match="at least 4"):
        reconstruct_microfacet(Slice([30, 30, 30], [0, 10, 20], np.ones((3, 1)), ["value"]))
    wl = Slice([30] * 5, [0, 10, 20, 30, 40], np.ones((5, 2)), ["450nm", "550nm"])
    with pytest.raises(ReconstructionError, match="convert spectra"):
        reconstruct_microfacet(wl)


@pytest.mark.parametrize("alphas, kind, channels", [
    ((0.002, 0.05, 0.4), "dielectric", 3),  # a term sharper than the cells: theta_h cell averages near 0
    ((0.03, 0.3), "conductor", 1),  # bin centres only, one grey channel
])
def test_table_is_the_tabulated_eval(alphas, kind, channels):
    # the half-diff table must hold what tabulating eval gives (and, with a sharp term, its theta_h averages)
    from reconstruction import pipeline
    from reconstruction.core import sharprows
    from reconstruction.methods.microfacet import MicrofacetReconstruction

    a = np.array(alphas)
    rec = MicrofacetReconstruction(a, np.full(a.size, 1.0 / a.size), kind, 1.6, 2.5 if kind == "conductor" else 0.0,
                                   np.linspace(0.2, 0.4, channels), np.linspace(0.3, 0.5, channels),
                                   ["R", "G", "B"][:channels] if channels == 3 else ["value"])
    slow = merltable.tabulate(rec.eval)
    sharp = rec.sharp_theta_h_rad
    assert (sharp is not None) == (min(alphas) < 0.01)
    if sharp:
        slow, rows = merltable.average_theta_h_cells(rec.eval, slow, sharp, n=8)
        assert rows >= 2
    fast = rec.table()
    assert np.array_equal(np.isnan(fast), np.isnan(slow))
    ok = np.isfinite(slow)
    assert np.max(np.abs(fast[ok] - slow[ok]) / np.maximum(np.abs(slow[ok]), 1e-12)) < 1e-9
    # what gonio-reconstruct writes: with a sharp term, those rows renormalised to its energy (sharprows)
    written = sharprows.renormalise(rec.eval, fast, sharp)[0] if sharp else fast
    np.testing.assert_array_equal(pipeline.tabulate(rec), written)
