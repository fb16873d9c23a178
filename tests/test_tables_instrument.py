"""Data-driven tables from a mirror-like capture read through a 1 deg cone keep the lobe's energy (bivariate)."""

import numpy as np
import pytest

from reconstruction.core import merltable
from reconstruction.core.energy import microfacet_albedo
from reconstruction.core.metrics import halfvector_albedo
from reconstruction.core.models import Colour, Lambert, Material, Microfacet
from reconstruction.core.slicedata import Slice
from reconstruction.formats import merl
from reconstruction.instrument.response import Instrument, instrument_average
from reconstruction.methods.bivariate import reconstruct_bivariate

THETA_I = np.radians([0.0, 30.0, 60.0, 80.0])


def _capture(mat: Material, inst: Instrument, meta: bool = True) -> Slice:
    ti, to = np.meshgrid(np.arange(0.0, 81.0, 10.0), np.arange(-88.0, 89.0, 2.0), indexing="ij")
    ti, to = ti.ravel(), to.ravel()
    keep = np.abs(to + ti) > 4  # the blind spot around the retro direction
    v = instrument_average(mat, ti[keep], to[keep], inst)
    return Slice(ti[keep], to[keep], v, ["value"], 0.01 * v,
                 meta={"instrument": inst.to_meta()} if meta else {})


def _table_albedo(table: np.ndarray) -> np.ndarray:
    return halfvector_albedo(lambda wi, wo: merltable.lookup(table, wi, wo), THETA_I)[:, 0]


@pytest.fixture(scope="module")
def mirror():
    mat = Material("mirror", [Lambert(Colour(np.array([0.02]))), Microfacet(Colour(np.array([0.95])), alpha=1e-3)])
    exact = 0.02 + 0.95 * microfacet_albedo(THETA_I, 1e-3, None, "ggx")
    return mat, exact


def test_halfvector_albedo_resolves_a_mirror_lobe(mirror):
    mat, exact = mirror
    np.testing.assert_allclose(halfvector_albedo(mat.eval, THETA_I)[:, 0], exact, rtol=1e-3)


def test_bivariate_table_of_a_mirror_keeps_its_albedo_within_5_percent(mirror):
    mat, exact = mirror
    rec = reconstruct_bivariate(_capture(mat, Instrument.from_half_angle(1.0)))
    assert rec.cell_average_th and "cell averages" in rec.table_values
    rep = rec.report()
    assert {p["theta_i_deg"] for p in rep["instrument"]["plateaus"]} >= {30.0, 60.0, 80.0}
    assert any("narrower than the instrument's cone" in n for n in rep["notes"])
    np.testing.assert_allclose(_table_albedo(rec.table()), exact, rtol=0.05)


def test_microfacet_table_of_a_mirror_keeps_its_albedo_within_5_percent(mirror):
    from reconstruction.methods import Options
    from reconstruction.pipeline import reconstruct, tabulate

    mat, exact = mirror
    rec, _ = reconstruct(_capture(mat, Instrument.from_half_angle(1.0)), "microfacet", Options())
    assert rec.report()["instrument"]["cone_averaged_samples"] > 0
    assert rec.table_values.startswith("cell averages over theta_h")
    np.testing.assert_allclose(_table_albedo(tabulate(rec)), exact, rtol=0.05)
    # alpha 1e-3 is below what a 1 deg cone resolves: the lobe is written at the resolution, its energy kept
    from reconstruction.methods.fit.aperture import resolution_alpha

    merged = rec.report()["instrument"]["below_resolution"]
    assert merged["resolution_alpha"] == pytest.approx(resolution_alpha(1.0)) and merged["weight"] > 0.5
    assert rec.alphas[rec.weights > 0].min() == pytest.approx(resolution_alpha(1.0))
    point, _ = reconstruct(_capture(mat, Instrument.from_half_angle(1.0), meta=False), "microfacet", Options())
    assert np.all(_table_albedo(tabulate(point)) < 0.5 * exact)  # the readings taken as point values


def test_revolve_table_of_a_mirror_keeps_its_albedo_within_5_percent(mirror):
    from reconstruction.methods import Options
    from reconstruction.pipeline import reconstruct, tabulate

    mat, exact = mirror
    rec, _ = reconstruct(_capture(mat, Instrument.from_half_angle(1.0)), "revolve", Options())
    assert {p["theta_i_deg"] for p in rec.report()["instrument"]["plateaus"]} >= {30.0, 60.0, 80.0}
    assert rec.table_values.startswith("cell averages over theta_h")
    got = _table_albedo(tabulate(rec))
    # theta_i = 0: the normal-incidence slice has its mirror direction in the blind spot; the peak measured at
    # 10 deg fills that hole (at the same offsets from the mirror direction), so 0 deg holds too
    assert any("the peak measured at theta_i 10 deg fills it" in n for n in rec.report()["notes"])
    np.testing.assert_allclose(got, exact, rtol=0.05)


def test_without_the_instrument_the_same_readings_lose_the_lobe(mirror):
    mat, exact = mirror
    rec = reconstruct_bivariate(_capture(mat, Instrument.from_half_angle(1.0), meta=False))
    assert not rec.cell_average_th and "instrument" not in rec.report()
    assert np.all(_table_albedo(rec.table()) < 0.5 * exact)


def test_a_smooth_material_is_unchanged_by_the_instrument():
    mat = Material("plastic", [Lambert(Colour(np.array([0.5]))), Microfacet(Colour(np.array([0.04])), alpha=0.3)])
    inst = Instrument.from_half_angle(1.0)
    a = reconstruct_bivariate(_capture(mat, inst))
    b = reconstruct_bivariate(_capture(mat, inst, meta=False))
    assert not a.cell_average_th
    np.testing.assert_array_equal(a.table(), b.table())


def test_gonio_reconstruct_carries_the_instrument_to_the_methods(mirror, tmp_path):
    import json

    from reconstruction import cli
    from reconstruction.formats.slicefile import write_slice

    mat, exact = mirror
    src = tmp_path / "mirror.csv"
    write_slice(src, _capture(mat, Instrument.from_half_angle(1.0)))
    for method in ("bivariate", "fit"):
        out, rep = tmp_path / f"{method}.binary", tmp_path / f"{method}.json"
        assert cli.main([str(src), "--method", method, "--out", str(out), "--report", str(rep)]) == 0
        r = json.loads(rep.read_text())
        assert r["checks"]["all_pass"]
        assert r["table"]["values"].startswith("cell averages over theta_h")
        # (a mirror's grazing cells exceed the reader's default sanity bound of 1e8 1/sr, as its true table does)
        np.testing.assert_allclose(_table_albedo(merl.read(out, max_value=None)), exact, rtol=0.05)
        if method == "fit":
            assert any("below the instrument's angular resolution" in n for n in r["details"]["notes"])
