"""The instrument's angular response (reconstruction.instrument.response): readings against a brute-force cone
integral."""

import math

import numpy as np
import pytest

from reconstruction.core.geometry import inplane_to_dirs
from reconstruction.core.models import Colour, Lambert, Material, Microfacet
from reconstruction.instrument.response import Instrument, InstrumentError, instrument_average


def _mat(*lobes) -> Material:
    return Material("m", list(lobes))


def _brute(mat: Material, ti: float, to: float, half_deg: float, nr: int = 500, nphi: int = 1024) -> np.ndarray:
    """Dense midpoint quadrature of f cos over the cone (polar about its centre, on the sphere), / (Omega cos_c)."""
    a = math.radians(half_deg)
    wi, wc = inplane_to_dirs(math.radians(ti), math.radians(to))
    u = np.array([math.cos(math.radians(to)), 0.0, -math.sin(math.radians(to))])
    v = np.array([0.0, 1.0, 0.0])
    t = (np.arange(nr) + 0.5) * a / nr
    p = (np.arange(nphi) + 0.5) * 2 * np.pi / nphi
    tt, pp = np.meshgrid(t, p, indexing="ij")
    d = (np.cos(tt)[..., None] * wc
         + np.sin(tt)[..., None] * (np.cos(pp)[..., None] * u + np.sin(pp)[..., None] * v))
    w = np.sin(tt) * (a / nr) * (2 * np.pi / nphi)
    f = mat.eval(np.broadcast_to(wi, d.shape), d)
    omega = 2 * np.pi * (1 - math.cos(a))
    return (f * (w * d[..., 2])[..., None]).sum(axis=(0, 1)) / omega / wc[2]


# the peak at the centre, inside, just inside the edge, on it, just outside, in the tail, at grazing incidence, and
# beyond the 6 cone radii past which the smooth rule takes the lobe (near grazing, where the tail is steepest)
GEOMETRIES = [(0.0, 0.0), (30.0, 30.6), (30.0, 30.99), (30.0, 31.0), (30.0, 31.3), (80.0, 80.5), (60.0, 62.5),
              (70.0, 72.0), (70.0, 76.5), (30.0, 23.5)]


@pytest.mark.parametrize("alpha", [1e-3, 5e-3])
def test_sharp_ggx_in_a_1deg_cone_matches_a_brute_force_integral(alpha):
    mat = _mat(Microfacet(Colour(np.array([0.95])), alpha=alpha))
    inst = Instrument.from_half_angle(1.0)
    ti = np.array([g[0] for g in GEOMETRIES])
    to = np.array([g[1] for g in GEOMETRIES])
    got = instrument_average(mat.eval, ti, to, inst)[:, 0]
    ref = np.array([_brute(mat, a, b, 1.0)[0] for a, b in GEOMETRIES])
    np.testing.assert_allclose(got, ref, rtol=0.01)
    # and the point sample at the centre is far off wherever the lobe is narrower than the cone
    centre = mat.eval(*inplane_to_dirs(np.radians(ti), np.radians(to)))[:, 0]
    assert abs(centre[0] / got[0] - 1) > 0.5


def test_smooth_material_equals_f_at_the_centre_and_the_brute_force():
    mat = _mat(Lambert(Colour(np.array([0.5, 0.4, 0.3]))), Microfacet(Colour(np.array([0.04])), alpha=0.3))
    inst = Instrument.from_half_angle(1.0)
    geo = [(0.0, 10.0), (30.0, 30.0), (45.0, -20.0), (70.0, 75.0)]
    ti, to = np.array(geo).T
    got = instrument_average(mat.eval, ti, to, inst)
    centre = mat.eval(*inplane_to_dirs(np.radians(ti), np.radians(to)))
    np.testing.assert_allclose(got, centre, rtol=0.005)
    ref = np.array([_brute(mat, a, b, 1.0, nr=60, nphi=90) for a, b in geo])
    np.testing.assert_allclose(got, ref, rtol=0.01)


def test_a_point_instrument_returns_f_at_the_centre():
    mat = _mat(Lambert(Colour(np.array([0.02]))), Microfacet(Colour(np.array([0.95])), alpha=1e-3))
    ti = np.array([30.0, 30.0, 45.0])
    to = np.array([30.0, 30.05, -10.0])
    want = mat.eval(*inplane_to_dirs(np.radians(ti), np.radians(to)))
    for inst in (Instrument(), Instrument.from_meta(None), Instrument.from_meta({})):
        np.testing.assert_array_equal(instrument_average(mat.eval, ti, to, inst), want)


def test_vectorised_channels_broadcast_and_the_material_or_lobes_forms():
    mat = _mat(Lambert(Colour(np.array([0.1, 0.2, 0.3]))), Microfacet(Colour(np.array([0.9, 0.8, 0.7])), alpha=2e-3))
    inst = Instrument.from_half_angle(0.5)
    to = np.linspace(25.0, 35.0, 11)
    many = instrument_average(mat.eval, 30.0, to, inst)
    assert many.shape == (11, 3)
    one_by_one = np.vstack([instrument_average(mat.eval, 30.0, t, inst) for t in to])
    np.testing.assert_allclose(many, one_by_one, rtol=1e-12)
    np.testing.assert_allclose(instrument_average(mat, 30.0, to, inst), many, rtol=1e-12)
    # a plain callable that says which microfacet lobes it holds gives the same reading
    np.testing.assert_allclose(instrument_average(lambda wi, wo: mat.eval(wi, wo), 30.0, to, inst,
                                                  lobes=[mat.lobes[1]]), many, rtol=1e-9)
    # the lobe (about 0.2 deg wide) is narrower than the cone: the reading at its peak is well below f there
    assert many[5, 0] < mat.eval(*inplane_to_dirs(np.radians(30.0), np.radians(30.0)))[0] / 3


def test_500_samples_of_a_sharp_lobe_through_a_cone():
    mat = _mat(Lambert(Colour(np.array([0.02]))), Microfacet(Colour(np.array([0.97, 0.95, 0.9])), alpha=1e-3))
    inst = Instrument.from_half_angle(1.0)
    ti = np.repeat(np.linspace(0.0, 80.0, 10), 50)
    to = ti + np.tile(np.linspace(-3.0, 3.0, 50), 10)
    r = instrument_average(mat.eval, ti, to, inst)
    # its speed is a benchmark's figure, not a unit test's: benchmarks/bench_instrument.py and
    # benchmarks/bench_test_timings.py (this case: 0.05 s)
    assert r.shape == (500, 3) and np.all(np.isfinite(r)) and np.all(r > 0)


def test_source_divergence_averages_over_the_beam():
    smooth = _mat(Lambert(Colour(np.array([0.5]))), Microfacet(Colour(np.array([0.04])), alpha=0.3))
    inst = Instrument(0.0, source_divergence_deg=1.0)
    got = instrument_average(smooth.eval, [20.0, 50.0], [20.0, -30.0], inst)
    np.testing.assert_allclose(got, smooth.eval(*inplane_to_dirs(np.radians([20.0, 50.0]),
                                                                np.radians([20.0, -30.0]))), rtol=0.005)
    sharp = _mat(Microfacet(Colour(np.array([0.95])), alpha=1e-3))
    narrow = instrument_average(sharp.eval, 30.0, 30.0, Instrument.from_half_angle(0.3))
    wide = instrument_average(sharp.eval, 30.0, 30.0, Instrument.from_half_angle(0.3, source_divergence_deg=0.5))
    assert wide[0, 0] < 0.7 * narrow[0, 0]  # a divergent beam spreads the mirror image beyond the small cone


def test_meta_round_trip_and_clear_errors():
    inst = Instrument(1e-3, source_divergence_deg=0.2, beam_diameter_mm=5.0, sample_diameter_mm=25.0,
                      band="silicon x halogen-3000K")
    assert Instrument.from_meta(inst.to_meta()) == inst
    assert math.isclose(Instrument.from_half_angle(1.0).aperture_half_angle_deg, 1.0)
    assert math.isclose(Instrument(1e-3).aperture_half_angle_deg, 1.02224, rel_tol=1e-5)
    with pytest.raises(InstrumentError, match=r"instrument\.detector_solid_angle_sr"):
        Instrument.from_meta({"detector_solid_angle_sr": "big"})
    with pytest.raises(InstrumentError, match=r"instrument\.beam_diameter_mm"):
        Instrument.from_meta({"detector_solid_angle_sr": 1e-3, "beam_diameter_mm": -1})
    with pytest.raises(InstrumentError, match=r"instrument\.band"):
        Instrument.from_meta({"band": 3})
    with pytest.raises(InstrumentError, match="expected an object"):
        Instrument.from_meta([1, 2])


def test_slice_files_carry_the_instrument_and_refuse_a_malformed_one(tmp_path):
    from reconstruction.core.slicedata import Slice, SliceError
    from reconstruction.formats.slicefile import read_slice, write_slice

    inst = Instrument(1e-3, band="silicon x halogen-3000K")
    p = tmp_path / "s.csv"
    write_slice(p, Slice([30.0], [30.0], [[0.1]], ["value"], meta={"instrument": inst.to_meta()}))
    assert Instrument.from_meta(read_slice(p).meta.get("instrument")) == inst
    write_slice(p, Slice([30.0], [30.0], [[0.1]], ["value"]))
    assert Instrument.from_meta(read_slice(p).meta.get("instrument")).is_point  # earlier files: a point
    write_slice(p, Slice([30.0], [30.0], [[0.1]], ["value"], meta={"instrument": {"detector_solid_angle_sr": -1}}))
    with pytest.raises(SliceError, match=r"s\.csv: metadata instrument\.detector_solid_angle_sr: expected a number"):
        read_slice(p)


def test_grazing_light_and_empty_input(recwarn):
    mat = _mat(Lambert(Colour(np.array([0.5]))), Microfacet(Colour(np.array([0.95])), alpha=1e-3))
    inst = Instrument.from_half_angle(1.0, source_divergence_deg=0.3)  # part of the beam below the horizon
    r = instrument_average(mat, [89.5, 89.9, 85.0], [89.5, -89.9, 89.7], inst)
    assert r.shape == (3, 1) and np.all(np.isfinite(r)) and np.all(r >= 0)
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]
    assert instrument_average(mat, [], [], inst).shape == (0, 1)
    assert instrument_average(mat, [], [], Instrument()).shape == (0, 1)


def _near_mirror_pairs():
    """Direction pairs of three slices within 10 deg of their mirror directions (and two far from it)."""
    ti = np.repeat([20.0, 45.0, 70.0], 7)
    to = ti + np.tile([-10.0, -3.0, -0.7, 0.0, 0.4, 2.5, 9.0], 3)
    ti, to = np.r_[ti, 30.0, 50.0], np.r_[to, -60.0, 10.0]
    return inplane_to_dirs(np.radians(ti), np.radians(to))


@pytest.mark.parametrize("kind", ["ggx", "beckmann"])
def test_unit_lobe_averages_equal_one_lobe_at_a_time(kind):
    """The fits' tables (the cheaper peak rule, TABLE_RULE) are the simulator's readings of each lobe alone to
    within 1e-3 of the lobe's largest reading; one distribution alone or two in one pass give the same numbers."""
    from reconstruction.instrument.response import instrument_average_dirs, unit_lobe_averages, unit_lobe_tables

    wi, wo = _near_mirror_pairs()
    inst = Instrument(detector_solid_angle_sr=1e-3, source_divergence_deg=0.25)
    alphas = np.geomspace(1e-4, 1.5, 7)  # sharp lobes (the peak rule) and broad ones (the smooth rule)
    got = unit_lobe_averages(wi, wo, inst, alphas, kind)
    assert got.shape == (len(wi), alphas.size)
    for k, a in enumerate(alphas):
        one = instrument_average_dirs(_mat(Microfacet(Colour(np.ones(1)), alpha=float(a), distribution=kind)), wi, wo,
                                      inst)[:, 0]
        np.testing.assert_allclose(got[:, k], one, rtol=0.0, atol=1e-3 * one.max())
        far = one < 1e-3 * one.max()  # away from the peaks the rules agree closely too (the smooth rule is shared)
        np.testing.assert_allclose(got[far, k], one[far], rtol=1e-3, atol=1e-12)
    both = unit_lobe_tables(wi, wo, inst, alphas, ("beckmann", "ggx"))
    np.testing.assert_array_equal(both[kind], got)


def test_shared_cone_averages_compute_each_direction_pair_once(monkeypatch):
    from reconstruction.instrument import response as ins

    wi, wo = _near_mirror_pairs()
    inst = Instrument.from_half_angle(1.0)
    alphas = np.array([2e-3, 0.05, 0.3])
    fresh = ins.unit_lobe_averages(wi, wo, inst, alphas)
    computed: list[int] = []
    real = ins._average_dirs

    def counting(f, a, b, *args, **kw):
        computed.append(len(np.atleast_2d(a)))
        return real(f, a, b, *args, **kw)

    monkeypatch.setattr(ins, "_average_dirs", counting)
    with ins.shared_cone_averages():
        first = ins.unit_lobe_averages(wi[:10], wo[:10], inst, alphas)  # a fold's training samples
        with ins.shared_cone_averages():  # nested: the same memory
            both = ins.unit_lobe_averages(wi, wo, inst, alphas)  # all of them: only the 13 others computed
        again = ins.unit_lobe_averages(wi[5:15], wo[5:15], inst, alphas)  # all known: nothing computed
        other = ins.unit_lobe_averages(wi[:3], wo[:3], inst, alphas[:2])  # another alpha grid: computed
    assert computed == [10, len(wi) - 10, 3]
    np.testing.assert_array_equal(both[:10], first)
    np.testing.assert_array_equal(again, both[5:15])
    np.testing.assert_allclose(both, fresh, rtol=1e-12)
    np.testing.assert_allclose(other, fresh[:3, :2], rtol=1e-12)
    ins.unit_lobe_averages(wi[:4], wo[:4], inst, alphas)  # the block is over: its memory is gone
    assert computed[-1] == 4


def test_two_distributions_that_know_different_pairs_each_keep_the_pairs_once():
    """A table of ggx and beckmann where ggx knows some pairs already: both come out whole (ggx's known rows as they
    were), and each distribution's memory holds every pair once (the pass computes the union for both)."""
    from reconstruction.instrument import response as ins

    wi, wo = _near_mirror_pairs()
    inst = Instrument.from_half_angle(1.0)
    alphas = np.array([2e-3, 0.05, 0.3])
    fresh = ins.unit_lobe_tables(wi, wo, inst, alphas, ("ggx", "beckmann"))
    with ins.shared_cone_averages():
        first = ins.unit_lobe_averages(wi[:10], wo[:10], inst, alphas, "ggx")
        both = ins.unit_lobe_tables(wi, wo, inst, alphas, ("ggx", "beckmann"))
        memory = ins.shared_cone_entries()
    np.testing.assert_array_equal(both["ggx"][:10], first)
    for dn in ("ggx", "beckmann"):
        np.testing.assert_allclose(both[dn], fresh[dn], rtol=1e-12)
        (pairs, vals), = [v for k, v in memory.items() if k[1] == dn]
        assert len(pairs) == len(np.unique(pairs, axis=0)) == len(np.unique(np.concatenate([wi, wo], axis=1),
                                                                            axis=0))


def test_fit_tables_prefetched_in_another_process_seed_the_shared_cone_averages(monkeypatch):
    """aperture.prefetch_tables computes fit's cone tables of a slice's near-mirror samples as fit does; seeded into
    a shared_cone_averages block (as auto's forked child's answer is), fit's tables are then looked up, not
    computed, with the same values. A point instrument has none to prefetch."""
    from reconstruction.core.slicedata import Slice
    from reconstruction.instrument import response as ins
    from reconstruction.methods.fit.aperture import Blur, prefetch_tables

    ti = np.repeat([20.0, 45.0], 9)
    to = ti + np.tile([-30.0, -6.0, -1.0, -0.4, 0.0, 0.5, 1.2, 5.0, 25.0], 2)
    meta = {"instrument": {"detector_solid_angle_sr": 1e-3, "source_divergence_deg": 0.25}}
    s = Slice(ti, to, np.ones((ti.size, 1)), ["value"], meta=meta)
    entries = prefetch_tables(s)
    assert len(entries) == 2  # ggx and beckmann
    wi, wo = inplane_to_dirs(np.radians(ti), np.radians(to))
    inst = Instrument.from_meta(meta["instrument"])
    fresh = Blur(inst, wi, wo)
    want = {k: fresh._table(k) for k in ("ggx", "beckmann")}
    computed: list[int] = []
    real = ins._average_dirs
    monkeypatch.setattr(ins, "_average_dirs", lambda *a, **k: computed.append(1) or real(*a, **k))
    with ins.shared_cone_averages():
        ins.seed_shared_cone_averages(entries)
        seeded = Blur(inst, wi, wo)
        for k in ("ggx", "beckmann"):
            x = np.linspace(np.log(1e-4), np.log(1.5), 7)
            np.testing.assert_array_equal(seeded._table(k)(x), want[k](x))
    assert computed == []
    assert prefetch_tables(Slice(ti, to, np.ones((ti.size, 1)), ["value"])) == {}


def test_reading_a_slice_and_bivariate_import_no_scipy_optimize(tmp_path):
    """A run of bivariate on a slice file imports neither scipy.optimize nor scipy.interpolate (half a second of a
    one-second run); auto's forked child starts on fit's cone tables before the run imports them."""
    import subprocess
    import sys

    from tests.test_cli_reconstruct import BLUE_PLASTIC, slice_file

    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC)
    code = ("import sys; from reconstruction import cli; "
            f"rc = cli.main([{str(src)!r}, '--method', 'bivariate', '--out', {str(tmp_path / 'b.binary')!r}, "
            "'--quiet']); print(rc, 'scipy.optimize' in sys.modules, 'scipy.interpolate' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.split() == ["0", "False", "False"], out.stderr
