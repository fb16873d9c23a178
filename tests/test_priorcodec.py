"""The prior's compact cache (reconstruction.methods.priorcodec): tables come back within the stated tolerance of
ln f_r, zeros stay zeros, damaged streams are refused, and smooth tables take a fraction of their float32 size
(synthetic materials only)."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction.core.models import Material
from reconstruction.methods import prior, priorcodec

#: float32's rounding of ln f_r (|ln f| < 60 after the offset) and of exp: far below LN_STEP / 2
TOL = priorcodec.LN_STEP / 2 + 2e-5


@pytest.fixture(scope="module")
def cells():
    """The prior's training cells: (mask (90, 45, 45), wi, wo)."""
    g = prior._grid()
    tr = g["train"]
    return tr.reshape(prior.GRID), g["wi"][tr], g["wo"][tr]


def _material(albedo: list[float], alpha: float, f0: float = 0.04) -> Material:
    return Material.from_dict({"name": "m", "lobes": [{"type": "lambert", "albedo": albedo},
                                                      {"type": "ggx", "alpha": alpha, "specular": 1.0, "f0": f0}]})


def _roundtrip_errors(f: np.ndarray, g: np.ndarray) -> np.ndarray:
    """|ln g - ln f| over the cells above the floor."""
    peak = f.max(axis=1, keepdims=True)
    keep = f >= priorcodec.FLOOR * peak
    return np.abs(np.log(g[keep].astype(np.float64)) - np.log(f[keep]))


def test_a_smooth_material_round_trips_within_the_step_and_is_small(cells):
    mask, wi, wo = cells
    f = np.asarray(_material([0.6, 0.3, 0.05], 0.05, 0.5).eval(wi, wo), dtype=np.float64).T  # (3, M)
    f[:, ::997] = 0.0  # some cells without a value (a fit's negative output)
    low, high, lo = priorcodec.encode_rows(f, mask)
    g = priorcodec.decode_rows(low, high, lo, mask)
    assert g.shape == f.shape and g.dtype == np.float32
    np.testing.assert_array_equal(g == 0, f == 0)  # zeros exactly, nothing else
    err = _roundtrip_errors(f, g)
    assert err.max() <= TOL and 0.2 * priorcodec.LN_STEP < np.sqrt(np.mean(err**2)) < 0.4 * priorcodec.LN_STEP
    # a fraction of the float32 table: a smooth material codes to under 10 % (the real ones: about 7 %)
    assert len(low) + len(high) < 0.10 * f.size * 4


def test_rough_tables_and_any_channel_count_round_trip(cells):
    """Noise over the whole range of codes (steps of any size between cells: the 16-bit wrap), one, two or three
    channels, tiny and huge levels, cells below the floor."""
    mask, _, _ = cells
    rng = np.random.default_rng(3)
    m = int(mask.sum())
    for c in (1, 2, 3):
        f = np.exp(rng.uniform(-57.0, 0.0, size=(c, m))) * np.array([1e-8, 3.0, 5e4])[:c, None]
        f[:, 0] = np.array([1e-8, 3.0, 5e4])[:c]  # every row's peak
        f[:, 1] = 1e-40 * f[:, 0]  # below the floor: decoded as the floor
        f[:, 2] = 0.0
        f[:, 3] = np.nan  # read as 0
        g = priorcodec.decode_rows(*priorcodec.encode_rows(f, mask), mask)
        assert _roundtrip_errors(np.nan_to_num(f), g).max() <= TOL
        np.testing.assert_allclose(g[:, 1], priorcodec.FLOOR * f[:, 0], rtol=2 * TOL)
        assert np.all(g[:, 2:4] == 0) and np.all(g[:, 4:] > 0)
    # a row of zeros
    g = priorcodec.decode_rows(*priorcodec.encode_rows(np.zeros((3, m)), mask), mask)
    assert not g.any()


def test_pack_and_unpack_many_materials_in_threads_and_damage_is_refused(cells):
    mask, wi, wo = cells
    mats = [np.asarray(_material([0.1 * k, 0.2, 0.3], 0.02 + 0.1 * k).eval(wi, wo), dtype=np.float64).T
            for k in range(1, 5)]
    arrays = priorcodec.pack([priorcodec.encode_rows(f, mask) for f in mats], mask)
    one = priorcodec.unpack(arrays, mask, threads=1)
    two = priorcodec.unpack(arrays, mask, threads=2)
    np.testing.assert_array_equal(one, two)
    assert one.shape == (4, 3, int(mask.sum()))
    for f, g in zip(mats, one, strict=True):
        assert _roundtrip_errors(f, g).max() <= TOL
    lo, sizes, blob, head = arrays
    bad = blob.copy()
    bad[sizes[0, 0] // 2] ^= 0xFF
    with pytest.raises(ValueError):
        priorcodec.unpack((lo, sizes, bad, head), mask)
    for k in range(3):  # another version, step or floor: another coding
        other = head.copy()
        other[k] *= 2
        with pytest.raises(ValueError):
            priorcodec.unpack((lo, sizes, blob, other), mask)
    with pytest.raises(ValueError, match="expected"):  # other than the materials the caller expects
        priorcodec.unpack(arrays, mask, rows=(5, 3))
    with pytest.raises(ValueError):  # cut short
        priorcodec.unpack((lo, sizes, blob[:-10], head), mask)
    with pytest.raises(ValueError, match="prefix"):
        priorcodec.encode_rows(mats[0], ~mask)


def test_the_basis_of_a_coded_prior_is_the_float32_one(cells):
    """The prior's basis from coded tables and from the float32 tables they came from agree to the coding's
    step (mean and components of y = log(f cos cos / s + EPS))."""
    mask, wi, wo = cells
    mats = [np.asarray(_material([0.05 + 0.1 * a, 0.2, 0.5 - 0.1 * a], al, f0).eval(wi, wo), dtype=np.float32).T
            for a in range(4) for al in (0.03, 0.1, 0.3) for f0 in (0.04, 0.9)]
    exact = prior.PriorSet("exact", [f"m{k}" for k in range(len(mats))], np.asarray(mats))
    coded = prior.PriorSet("coded", exact.names, priorcodec.unpack(
        priorcodec.pack([priorcodec.encode_rows(f, mask) for f in mats], mask), mask))
    idx, w, _ = prior._design(_slice())
    (mu0, c0, s0), (mu1, c1, s1) = exact.basis(idx, w), coded.basis(idx, w)
    assert np.max(np.abs(mu1 - mu0)) < priorcodec.LN_STEP
    # the coding's noise (0.29 LN_STEP rms per cell: a norm of 0.2 over the cells) moves the spread of the leading
    # components by a few thousandths
    np.testing.assert_allclose(s1[:10], s0[:10], rtol=1e-3, atol=0.02)
    for k in range(5):  # the leading components, up to sign
        assert abs(abs(float(c0[k] @ c1[k])) - 1.0) < 1e-3


def _slice():
    from reconstruction.core.slicedata import Slice

    to = np.arange(-80.0, 81.0, 2.0)
    to = to[np.abs(to + 40.0) >= 4.0]
    return Slice(np.full(to.size, 40.0), to, np.ones((to.size, 3)), ["R", "G", "B"])
