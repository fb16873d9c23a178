"""MERL binary tables: exact bytes, round trips, index functions, lookups, tabulation, errors."""

import os
import struct

import numpy as np
import pytest

from reconstruction.core import merlgrid, merltable
from reconstruction.core.geometry import dirs_from_half_diff
from reconstruction.formats import merl

RNG = np.random.default_rng(3)


def test_exact_bytes_of_a_hand_computed_table(tmp_path):
    f = np.zeros(merltable.SHAPE)
    f[0] = 1.0 / 1500.0  # stored red = f * 1500 = 1
    f[1] = 2.3 / 1500.0  # stored green = f * 1500 / 1.15 = 2
    f[2] = 4.98 / 1500.0  # stored blue = f * 1500 / 1.66 = 3
    f[:, 0, 0, 1] = np.nan  # an invalid cell, stored as -1
    p = tmp_path / "tiny.binary"
    merl.write(p, f)
    data = p.read_bytes()
    assert len(data) == 34_992_012
    assert data[:12] == bytes.fromhex("5a000000" "5a000000" "b4000000")  # int32 LE 90 90 180
    first = {"r": 12, "g": 12 + 8 * 1_458_000, "b": 12 + 16 * 1_458_000}
    assert struct.unpack("<d", data[first["r"]:first["r"] + 8])[0] == pytest.approx(1.0, rel=1e-15)
    assert struct.unpack("<d", data[first["g"]:first["g"] + 8])[0] == pytest.approx(2.0, rel=1e-15)
    assert struct.unpack("<d", data[first["b"]:first["b"] + 8])[0] == pytest.approx(3.0, rel=1e-15)
    # cell (0, 0, 1) is the second value of each channel (phi_d is the fastest index)
    assert struct.unpack("<d", data[first["r"] + 8:first["r"] + 16])[0] == -1.0
    assert data[first["b"] + 8:first["b"] + 16] == struct.pack("<d", -1.0)
    # linear index i = k + 180 j + 180 * 90 i: cell (2, 3, 4) -> 4 + 540 + 32400
    f2 = np.zeros(merltable.SHAPE)
    f2[1, 2, 3, 4] = 1.15 / 1500.0 * 7.0
    merl.write(p, f2)
    data = p.read_bytes()
    off = 12 + 8 * (1_458_000 + 4 + 180 * 3 + 180 * 90 * 2)
    assert struct.unpack("<d", data[off:off + 8])[0] == pytest.approx(7.0, rel=1e-15)


def test_random_table_round_trip(tmp_path):
    f = RNG.uniform(0, 50, merltable.SHAPE)
    f[RNG.uniform(size=merltable.SHAPE) < 0.05] = np.nan
    p = tmp_path / "r.binary"
    merl.write(p, f)
    g = merl.read(p)
    assert g.shape == merltable.SHAPE and g.dtype == np.float64
    np.testing.assert_array_equal(np.isnan(g), np.isnan(f))
    np.testing.assert_allclose(g, f, rtol=1e-15)


def test_cell_to_directions_to_cell_for_every_cell():
    i, j, k = np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij")
    wi, wo = merlgrid.cell_to_dirs(i, j, k)
    a, b, c = merlgrid.dirs_to_cell(wi, wo)
    assert np.array_equal(a, i) and np.array_equal(b, j) and np.array_equal(c, k)


def test_reference_index_functions_by_hand():
    deg = np.radians
    # theta_h: boundaries at (i / 90)^2 * 90 deg; i = 1 starts at 0.0111.. deg, i = 10 at 1.111.. deg
    assert merlgrid.theta_h_index(deg([0.0, 0.0110, 0.0112, 1.1110, 1.1112, 89.99, 95.0])).tolist() == [
        0, 0, 1, 9, 10, 89, 89]
    assert merlgrid.theta_h_index(-0.1) == 0
    assert merlgrid.theta_d_index(deg([0.0, 9.9999, 10.0001, 89.9999, 90.0])).tolist() == [0, 9, 10, 89, 89]
    # phi_d: negative values fold by +pi (reciprocity)
    assert merlgrid.phi_d_index(deg([0.0, 0.9999, 1.0001, 179.9999, -0.5, -179.5])).tolist() == [
        0, 0, 1, 179, 179, 0]


def coded_table():
    i, j, k = np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij")
    code = i * 1e5 + j * 1e3 + k
    return np.stack([code, code + 0.25, code + 0.5])


def pair(th_deg, td_deg, pd_deg, ph=0.7):
    return dirs_from_half_diff(np.radians(th_deg), ph, np.radians(td_deg), np.radians(pd_deg))


def test_nearest_lookup_at_bin_boundaries():
    t = coded_table()
    # just either side of the (i=1 | i=2) theta_h boundary at (2/90)^2*90 = 0.04444 deg, theta_d = 10 deg
    v = merltable.lookup(t, *pair([0.0444, 0.0445], [20.5, 20.5], [10.5, 10.5]))
    assert v[:, 0].tolist() == [1 * 1e5 + 20e3 + 10, 2 * 1e5 + 20e3 + 10]
    v = merltable.lookup(t, *pair([30.0, 30.0], [9.999, 10.001], [-0.5, 0.5]))
    i30 = int(np.sqrt(30 / 90) * 90)  # 51
    assert v[:, 0].tolist() == [i30 * 1e5 + 9e3 + 179, i30 * 1e5 + 10e3 + 0]
    np.testing.assert_allclose(v[:, 2] - v[:, 0], 0.5)


def test_interpolated_lookup_by_hand():
    t = coded_table()
    # at a bin centre: exactly that cell
    th = ((10 + 0.5) / 90) ** 2 * 90
    v = merltable.lookup(t, *pair(th, 20.5, 40.5), interpolate=True)
    assert v[0] == pytest.approx(10e5 + 20e3 + 40)
    # halfway between phi_d centres 40.5 and 41.5 -> mean of k = 40 and 41
    v = merltable.lookup(t, *pair(th, 20.5, 41.0), interpolate=True)
    assert v[0] == pytest.approx(10e5 + 20e3 + 40.5)
    # phi_d = 0 lies halfway between the centres of k = 179 (179.5 deg) and k = 0 (0.5 deg): wraps
    v = merltable.lookup(t, *pair(th, 20.5, 0.0), interpolate=True)
    assert v[0] == pytest.approx(10e5 + 20e3 + (179 + 0) / 2)
    # halfway between theta_d centres 20.5 and 21.5
    v = merltable.lookup(t, *pair(th, 21.0, 40.5), interpolate=True)
    assert v[0] == pytest.approx(10e5 + 20.5e3 + 40)
    # a NaN neighbour is skipped, not propagated
    t2 = t.copy()
    t2[:, 10, 20, 41] = np.nan
    v = merltable.lookup(t2, *pair(th, 20.5, 41.0), interpolate=True)
    assert v[0] == pytest.approx(10e5 + 20e3 + 40)
    # below the horizon -> NaN
    assert np.isnan(merltable.lookup(t, [0, 0, 1.0], [1.0, 0, -0.1])).all()


def test_tabulate_constant_and_horizon():
    albedo = np.array([0.2, 0.5, 0.8])

    def lambert(wi, wo):
        up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        return np.where(up[:, None], albedo / np.pi, 0.0)

    t = merltable.tabulate(lambert)
    valid = merlgrid.valid_mask()
    assert 0.5 < valid.mean() < 0.95
    np.testing.assert_allclose(t[:, valid], np.broadcast_to((albedo / np.pi)[:, None], t[:, valid].shape), rtol=1e-15)
    assert np.isnan(t[:, ~valid]).all()
    # cells with theta_d + theta_h well past 90 deg at phi_d = 0 are below the horizon
    assert np.isnan(t[0, 89, 89, 0])
    assert np.isfinite(t[0, 0, 0, 0])
    # cell averages of a constant are that constant in every valid cell, also near the horizon where some
    # sub-samples fall below it (they get no weight); with an even count no sub-sample is the centre
    ts = merltable.tabulate(lambert, supersample=(2, 2, 2))
    np.testing.assert_array_equal(np.isnan(ts), np.isnan(t))
    np.testing.assert_allclose(ts[:, valid], t[:, valid], rtol=1e-12)


def test_tabulate_grey_function_broadcasts_to_rgb():
    t = merltable.tabulate(lambda wi, wo: np.full((wi.shape[0], 1), 0.25))
    v = merlgrid.valid_mask()
    assert np.all(t[:, v] == 0.25)


def test_threaded_tabulation_fills_every_chunk_as_one_thread_does(monkeypatch):
    # a function of the directions that differs in every cell: a chunk written to the wrong rows, or left out,
    # changes the table
    def f(wi, wo):
        return np.stack([wi[:, 0] + 2 * wo[:, 1], wi[:, 2] * wo[:, 2], wo[:, 0] - wi[:, 1]], axis=1)

    monkeypatch.setenv("GONIO_THREADS", "1")
    one = merltable.tabulate(f, chunk_cells=150_001)
    monkeypatch.setenv("GONIO_THREADS", "3")
    assert merltable._threads() == 3
    many = merltable.tabulate(f, chunk_cells=150_001)
    assert np.array_equal(one, many, equal_nan=True)
    with pytest.raises(ZeroDivisionError):  # an error in any chunk reaches the caller
        merltable.tabulate(lambda wi, wo: 1 // 0)


def test_supersampling_resolves_a_lobe_narrower_than_a_cell():
    # a narrow bump in theta_h inside cell i = 40: point samples at the bin centre miss it, averages don't
    lo, hi = (40 / 90) ** 2 * (np.pi / 2), (41 / 90) ** 2 * (np.pi / 2)
    mid = ((40.5 / 90) ** 2) * (np.pi / 2)

    def bump(wi, wo):
        h = wi + wo
        th = np.arctan2(np.hypot(h[:, 0], h[:, 1]), h[:, 2])
        return (np.abs(th - (mid + 0.3 * (hi - mid))) < 0.1 * (hi - lo)).astype(float)[:, None]

    c = merltable.tabulate(bump)
    s = merltable.tabulate(bump, supersample=(10, 1, 1))
    assert np.nanmax(c[0, 40]) == 0.0
    assert np.nanmean(s[0, 40, 10:30]) == pytest.approx(0.2, rel=0.05)


def test_read_errors(tmp_path):
    with pytest.raises(merltable.MerlError, match="no such file"):
        merl.read(tmp_path / "missing.binary")
    good = tmp_path / "good.binary"
    merl.write(good, np.ones(merltable.SHAPE))
    data = good.read_bytes()
    (tmp_path / "trunc.binary").write_bytes(data[:-8])
    with pytest.raises(merltable.MerlError, match="truncated"):
        merl.read(tmp_path / "trunc.binary")
    (tmp_path / "big.binary").write_bytes(data + b"\0")
    with pytest.raises(merltable.MerlError, match="oversized"):
        merl.read(tmp_path / "big.binary")
    (tmp_path / "hdr.binary").write_bytes(struct.pack("<3i", 90, 90, 360) + data[12:])
    with pytest.raises(merltable.MerlError, match=r"header says \(90, 90, 360\)"):
        merl.read(tmp_path / "hdr.binary")
    bad = bytearray(data)
    bad[12 + 8 * 5:12 + 8 * 6] = struct.pack("<d", float("nan"))
    (tmp_path / "nan.binary").write_bytes(bytes(bad))
    with pytest.raises(merltable.MerlError, match=r"1 cell\(s\) \(r\[0,0,5\]\)"):
        merl.read(tmp_path / "nan.binary")


def test_write_errors_name_cells(tmp_path):
    f = np.ones(merltable.SHAPE)
    f[2, 1, 2, 3] = np.inf
    with pytest.raises(merltable.MerlError, match=r"infinite value in 1 cell\(s\) \(b\[1,2,3\]\)"):
        merl.write(tmp_path / "x.binary", f)
    f[2, 1, 2, 3] = -0.5
    with pytest.raises(merltable.MerlError, match="negative"):
        merl.write(tmp_path / "x.binary", f)
    f = np.ones(merltable.SHAPE)
    f[:, 0, 0, 0] = np.nan  # above the horizon
    with pytest.raises(merltable.MerlError, match=r"3 cell\(s\)"):
        merl.write(tmp_path / "x.binary", f, require_above_horizon=True)
    with pytest.raises(merltable.MerlError, match="shape"):
        merl.write(tmp_path / "x.binary", np.ones((3, 90, 90, 90)))
    assert not (tmp_path / "x.binary").exists()


def test_failed_write_leaves_no_half_file(tmp_path, monkeypatch):
    target = tmp_path / "m.binary"
    merl.write(target, np.full(merltable.SHAPE, 0.5))
    before = target.read_bytes()

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(os, "fsync", boom)
    with pytest.raises(OSError, match="disk full"):
        merl.write(target, np.full(merltable.SHAPE, 0.25))
    assert target.read_bytes() == before  # the old file is untouched
    assert [p.name for p in tmp_path.iterdir()] == ["m.binary"]  # no temporary left behind


def test_written_file_has_ordinary_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        merl.write(tmp_path / "p.binary", np.ones(merltable.SHAPE))
    finally:
        os.umask(old)
    assert (tmp_path / "p.binary").stat().st_mode & 0o777 == 0o644  # not mkstemp's 0600


def test_half_diff_cosines_and_theta_h_averages_match_the_direction_pairs():
    # the closed-form cosines are the z of the cells' direction pairs, and the half-diff theta_h averages are
    # merltable.average_theta_h_cells of the same function evaluated on direction pairs
    from reconstruction.core import halfdiff
    from reconstruction.core.models import Microfacet

    ci, co = merlgrid.cell_cosines()
    wi, wo = merlgrid._cell_dirs()
    assert np.array_equal(ci, wi[..., 2]) and np.array_equal(co, wo[..., 2])
    assert np.array_equal((ci > 0) & (co > 0), merlgrid.valid_mask())
    lobe = Microfacet(alpha=0.003, f0=0.05)
    rows, avg, covered = halfdiff.average_theta_h_half_diff(lobe.shape_half_diff, 0.015, n=8)
    ref, rows_ref = merltable.average_theta_h_cells(lambda a, b: lobe.shape(a, b)[:, None], np.zeros(merltable.SHAPE),
                                                    0.015, n=8)
    assert rows == rows_ref >= 3 and covered[merlgrid.valid_mask()[:rows]].all()
    ok = merlgrid.valid_mask()[:rows]
    np.testing.assert_allclose(avg[ok], ref[0, :rows][ok], rtol=1e-9)


def test_the_reciprocal_table_of_a_mirror_symmetric_function_comes_from_one_evaluation_per_cell():
    """g depends on wi's and wo's heights and |wo_y| (symmetric about the plane of incidence) but is not
    reciprocal: the phi_d-reversed average is the table of 0.5 (g(wi, wo) + g(wo, wi))."""
    calls = []

    def g(wi, wo):
        calls.append(len(wi))
        v = 0.1 + wi[:, 2] ** 3 * (1.0 + np.abs(wo[:, 1])) + 0.5 * wo[:, 2]
        return np.stack([v, 2 * v, 3 * v], axis=1)

    fast = merltable.tabulate_reciprocal(g)
    n_fast = sum(calls)
    calls.clear()
    slow = merltable.tabulate(lambda i, o: 0.5 * (g(i, o) + g(o, i)))
    assert n_fast == sum(calls) // 2  # half the evaluations
    v = merlgrid.valid_mask()
    np.testing.assert_allclose(fast[:, v], slow[:, v], rtol=1e-12)
    assert np.isnan(fast[:, ~v]).all()
    assert not np.allclose(merltable.tabulate(g)[:, v], slow[:, v], rtol=1e-3)  # g alone is not reciprocal


def test_a_float32_table_is_looked_up_as_its_float64_copy():
    """merltable.lookup reads a float32 table (the uncertainty's sigma) as it is: the float64 copy's values."""
    from reconstruction.core.geometry import inplane_to_dirs

    rng = np.random.default_rng(5)
    t32 = rng.uniform(0.0, 3.0, merltable.SHAPE).astype(np.float32)
    wi, wo = inplane_to_dirs(np.radians(rng.uniform(0, 80, 500)), np.radians(rng.uniform(-80, 80, 500)))
    for interp in (False, True):
        np.testing.assert_array_equal(merltable.lookup(t32, wi, wo, interpolate=interp),
                                      merltable.lookup(t32.astype(np.float64), wi, wo, interpolate=interp))


def test_cell_cosines_are_the_cell_directions_z_components_bit_for_bit():
    """valid_mask and cell_cosines come from the closed form without the 70 MB of direction vectors: the same bits
    as the bin-centre directions' z components, and read-only (a caller cannot change the cached copy)."""
    wi, wo = merlgrid._cell_dirs()
    ci, co = merlgrid.cell_cosines()
    np.testing.assert_array_equal(ci, wi[..., 2])
    np.testing.assert_array_equal(co, wo[..., 2])
    m = merlgrid.valid_mask()
    np.testing.assert_array_equal(m, (wi[..., 2] > 0) & (wo[..., 2] > 0))
    assert int(m.sum()) == merltable.N_CELLS - 361784  # the doctest of tabulate: 361,784 cells below the horizon
    with pytest.raises(ValueError):
        m[0, 0, 0] = False
