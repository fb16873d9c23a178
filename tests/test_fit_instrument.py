"""fit with the instrument's angular response: synthetic slices read through a 1e-3 sr cone (instrument_average)."""

import numpy as np
import pytest

from reconstruction.core.energy import microfacet_albedo
from reconstruction.core.models import Colour, Lambert, Material, Microfacet
from reconstruction.core.slicedata import Slice
from reconstruction.instrument.response import Instrument, instrument_average
from reconstruction.methods.fit import reconstruct_fit


def _capture(alpha: float, inst: Instrument, seed: int = 1) -> tuple[Material, Slice]:
    """A mirror-like material read by ``inst`` at 2 deg steps, 1 % noise (and its std) plus a small floor."""
    mat = Material("m", [Lambert(Colour(np.array([0.02]))), Microfacet(Colour(np.array([0.95])), alpha=alpha)])
    ti, to = np.meshgrid([0.0, 20.0, 40.0, 60.0], np.arange(-80.0, 81.0, 2.0), indexing="ij")
    ti, to = ti.ravel(), to.ravel()
    keep = np.abs(to + ti) > 4  # the blind spot around the retro direction
    ti, to = ti[keep], to[keep]
    v = instrument_average(mat, ti, to, inst)
    std = 0.01 * v + 1e-4
    meas = v + np.random.default_rng(seed).normal(size=v.shape) * std
    return mat, Slice(ti, to, meas, ["value"], std, meta={"instrument": inst.to_meta()})


def exact_albedo(mat: Material, theta_i: np.ndarray) -> np.ndarray:
    """The directional albedo (n, C) of a lambert + microfacet material, exact (energy's tabulated integrals)."""
    out = np.zeros((len(theta_i), mat.n_channels))
    for lb in mat.lobes:
        col = lb.colour.on(mat.n_channels, None)
        if isinstance(lb, Lambert):
            out += col
        else:
            out += microfacet_albedo(theta_i, lb.alpha, lb.f0, lb.distribution)[:, None] * col
    return out


def _ggx(rec):
    return next(p for p in rec.report()["parameters"] if p["type"] == "ggx")


def test_alpha_0_005_through_a_1e3_sr_cone_comes_back_within_25_percent():
    mat, s = _capture(0.005, Instrument(1e-3))
    rec = reconstruct_fit(s)  # its time is benchmarks/bench_test_timings.py's figure (0.4 s)
    p = _ggx(rec)
    assert abs(p["alpha"] / 0.005 - 1) < 0.25
    assert p["alpha_std"] is not None and abs(p["alpha"] - 0.005) < 4 * p["alpha_std"] + 0.0005
    assert abs(p["specular"][0] / 0.95 - 1) < 0.05
    lobe = rec.report()["instrument"]["lobes"][0]
    assert lobe["resolved"] and "note" not in lobe
    # the same data taken as point samples (no instrument in the metadata) give a wrong, wider and weaker lobe
    point = reconstruct_fit(Slice(s.theta_i_deg, s.theta_o_deg, s.values, ["value"], s.std))
    pp = next(q for q in point.report()["parameters"] if q["type"] in ("ggx", "beckmann"))
    assert abs(pp["alpha"] / 0.005 - 1) > 0.25 or abs(pp["specular"][0] / 0.95 - 1) > 0.25


def test_alpha_1e3_comes_back_as_an_upper_bound_with_its_energy_kept():
    mat, s = _capture(0.001, Instrument(1e-3))
    rec = reconstruct_fit(s)
    rep = rec.report()
    lobe = rep["instrument"]["lobes"][0]
    assert not lobe["resolved"] and lobe["alpha_upper_bound"] > 0.001
    assert lobe["alpha_upper_bound"] < 0.005  # the bound still says something
    assert any("below the instrument's angular resolution, alpha < " in n for n in rep["notes"])
    assert abs(_ggx(rec)["specular"][0] / 0.95 - 1) < 0.05  # the lobe's energy
    ti = np.radians([0.0, 30.0, 60.0])
    np.testing.assert_allclose(exact_albedo(rec.material, ti), exact_albedo(mat, ti), rtol=0.05)


def test_a_point_instrument_fits_as_before():
    _, s = _capture(0.005, Instrument(1e-3))
    rep = reconstruct_fit(Slice(s.theta_i_deg, s.theta_o_deg, s.values, ["value"], s.std)).report()
    assert "instrument" not in rep


def test_a_malformed_instrument_is_a_clear_error():
    from reconstruction.base import ReconstructionError

    _, s = _capture(0.005, Instrument(1e-3))
    bad = Slice(s.theta_i_deg, s.theta_o_deg, s.values, ["value"], s.std, meta={"instrument": {"band": ""}})
    with pytest.raises(ReconstructionError, match=r"instrument\.band"):
        reconstruct_fit(bad)
