"""Reading inputs: slice files, generic CSV tables, quantities, blind-spot zeros and clear errors for bad input."""

import math

import numpy as np
import pytest

from reconstruction.core.slicedata import Slice
from reconstruction.formats.inputs import InputError, drop_blind_spot_zeros, load_inputs, parse_columns, read_table
from reconstruction.formats.slicefile import write_slice


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def slice_file(tmp_path, name="s.csv", ti=30.0, quantity="brdf", values=None, to=None):
    to = np.arange(-60.0, 61.0, 10.0) if to is None else np.asarray(to, dtype=float)
    v = np.linspace(0.1, 0.5, to.size)[:, None] if values is None else np.asarray(values, dtype=float)
    s = Slice(np.full(to.size, ti), to, v, ["value"], 0.01 * np.abs(v), meta={"quantity": quantity})
    p = tmp_path / name
    write_slice(p, s)
    return p


def test_slice_file_is_read_and_converted_to_brdf(tmp_path):
    p = slice_file(tmp_path, quantity="reflectance_factor")
    loaded = load_inputs([p])
    to = np.arange(-60.0, 61.0, 10.0)
    np.testing.assert_allclose(loaded.slice.values[:, 0], np.linspace(0.1, 0.5, to.size) / math.pi)
    np.testing.assert_allclose(loaded.slice.std[:, 0], 0.01 * np.linspace(0.1, 0.5, to.size) / math.pi)
    assert loaded.slice.quantity == "brdf"
    assert loaded.quantities == ["reflectance_factor"]


def test_generic_spectral_table_with_mapped_columns_and_brdf_cos(tmp_path):
    text = "# exported by SomeGonio 2.1\nInc;Det;450 nm;550nm;650nm;550nm_std\n"
    rows = []
    for to in (-40.0, -20.0, 0.0, 20.0, 40.0):
        c = math.cos(math.radians(to))
        rows.append(f"20;{to};{0.1 * c};{0.2 * c};{0.3 * c};0.001")
    p = write(tmp_path, "export.csv", text + "\n".join(rows) + "\n")
    s = read_table(p, quantity="brdf_cos", columns=parse_columns("theta_i=Inc,theta_o=Det"))
    assert s.channels == ["450nm", "550nm", "650nm"]
    np.testing.assert_allclose(s.theta_o_deg, [-40, -20, 0, 20, 40])
    f, sd = s.brdf()
    np.testing.assert_allclose(f, np.tile([0.1, 0.2, 0.3], (5, 1)), rtol=1e-12)
    assert np.all(sd[:, 1] > 0) and np.all(sd[:, 0] == 0)


def test_generic_rgb_columns_in_any_order_and_value_renamed(tmp_path):
    p = write(tmp_path, "rgb.csv", "theta_i,theta_o,B,R,G\n10,-5,3,1,2\n10,5,6,4,5\n10,15,9,7,8\n")
    s = read_table(p, quantity="brdf")
    assert s.channels == ["R", "G", "B"]
    np.testing.assert_allclose(s.values, [[1, 2, 3], [4, 5, 6], [7, 8, 9]])
    q = write(tmp_path, "grey.csv", "incidence,outgoing,Intensity\n10,-5,1\n10,5,2\n10,15,3\n")
    g = read_table(q, quantity="reflectance_factor", columns={"value": "Intensity"})
    assert g.channels == ["value"]
    np.testing.assert_allclose(g.brdf()[0][:, 0], np.array([1, 2, 3]) / math.pi)


def test_blind_spot_zero_rows_are_missing_not_zero(tmp_path):
    to = np.arange(-60.0, 61.0, 2.0)
    v = np.full((to.size, 1), 0.2)
    # the shadow around retro (-30) is exported as zeros, a little wider than the default half width
    v[np.abs(to + 30) <= 12] = 0.0
    v[to == 50.0] = 0.0  # an exact zero far from the blind spot is a measurement and stays
    p = slice_file(tmp_path, values=v, to=to)
    loaded = load_inputs([p], blind_spot_deg=10.0)
    kept = loaded.slice.theta_o_deg
    assert loaded.dropped_blind_spot == int(np.sum(np.abs(to + 30) <= 12))
    assert not np.any(np.abs(kept + 30) <= 12)  # the contiguous zero run at 11-12 deg went too
    assert 50.0 in kept and loaded.slice.values[kept == 50.0, 0] == 0.0
    assert any("blind spot" in n for n in loaded.notes)


def test_drop_blind_spot_zeros_keeps_nonzero_rows():
    s = Slice([30, 30, 30, 30], [-32, -30, -28, 0], [[0.0], [0.1], [0.0], [0.2]], ["value"])
    out, n = drop_blind_spot_zeros(s, 5.0)
    assert n == 2
    np.testing.assert_array_equal(out.theta_o_deg, [-30, 0])


def test_several_inputs_are_merged_and_overlap_is_an_error(tmp_path):
    a = slice_file(tmp_path, "a.csv", ti=20.0)
    b = slice_file(tmp_path, "b.csv", ti=40.0, quantity="reflectance_factor")
    loaded = load_inputs([a, b])
    assert sorted(set(loaded.slice.theta_i_deg.tolist())) == [20.0, 40.0]
    assert len(loaded.slice) == 26
    c = slice_file(tmp_path, "c.csv", ti=20.0)
    with pytest.raises(InputError, match=r"c\.csv.*also in.*a\.csv"):
        load_inputs([a, c])


BAD_TABLES = [
    # (name, text, quantity, columns, message pattern)
    ("empty.csv", "theta_i,theta_o,value\n", "brdf", None, r"empty\.csv: no samples"),
    ("one.csv", "theta_i,theta_o,value\n30,10,0.5\n", "brdf", None, r"one\.csv: 1 sample\(s\); .* at least 3"),
    ("zeros.csv", "theta_i,theta_o,value\n30,0,0\n30,10,0\n30,20,0\n30,40,0\n", "brdf", None,
     r"zeros\.csv: every value is zero"),
    ("nan.csv", "theta_i,theta_o,value\n30,0,0.1\n30,10,nan\n30,20,0.3\n", "brdf", None,
     r"nan\.csv:3, column value: value is 'nan'"),
    ("text.csv", "theta_i,theta_o,value\n30,0,0.1\n30,10,abc\n", "brdf", None,
     r"text\.csv:3, column value: expected a number, got 'abc'"),
    ("dup.csv", "theta_i,theta_o,value\n30,0,0.1\n30,10,0.2\n30,10,0.3\n", "brdf", None,
     r"dup\.csv:4, column theta_o: duplicate sample .* \(also at line 3\)"),
    ("dupapart.csv", "theta_i,theta_o,value\n30,0,0.1\n40,10,0.2\n30,20,0.3\n40,0,0.1\n30,0,0.2\n", "brdf",
     None, r"dupapart\.csv:6, column theta_o: duplicate sample theta_i = 30\.0, theta_o = 0\.0 \(also at line 2\)"),
    ("unknown.csv", "theta_i,theta_o,value,temperature\n30,0,0.1,20\n", "brdf", None,
     r"unknown\.csv:1, column temperature: unknown column"),
    ("mapped.csv", "Inc,Det,value\n30,0,0.1\n", "brdf", {"theta_i": "Inc", "theta_o": "Detector"},
     r"mapped\.csv:1: --columns theta_o=Detector: no such column; the columns are Inc, Det, value"),
    ("noangle.csv", "a,b,value\n30,0,0.1\n", "brdf", None, r"noangle\.csv:1: no theta_i column"),
    ("noquantity.csv", "theta_i,theta_o,value\n30,0,0.1\n", None, None,
     r"noquantity\.csv: a generic table does not say what its values are; pass --quantity"),
    ("fields.csv", "theta_i,theta_o,value\n30,0,0.1\n30,10\n", "brdf", None,
     r"fields\.csv:3: 2 fields, expected 3"),
    ("range.csv", "theta_i,theta_o,value\n30,0,0.1\n30,95,0.1\n", "brdf", None,
     r"range\.csv:3, column theta_o: 95\.0 is outside \(-90, 90\)"),
    ("negstd.csv", "theta_i,theta_o,value,value_std\n30,0,0.1,-1\n30,5,0.1,0\n30,9,0.1,0\n", "brdf", None,
     r"negstd\.csv:2, column value_std: a standard deviation must be >= 0"),
]


@pytest.mark.parametrize("name, text, quantity, columns, pattern", BAD_TABLES, ids=[b[0] for b in BAD_TABLES])
def test_bad_generic_tables_give_clear_errors(tmp_path, name, text, quantity, columns, pattern):
    p = write(tmp_path, name, text)
    with pytest.raises(InputError, match=pattern) as e:
        load_inputs([p], quantity=quantity, columns=columns)
    assert "\n" not in str(e.value)


def test_bad_slice_files_and_paths(tmp_path):
    with pytest.raises(InputError, match=r"nothere\.csv: no such file"):
        load_inputs([tmp_path / "nothere.csv"])
    p = slice_file(tmp_path)
    text = p.read_text().splitlines()
    text[4] = text[4].replace(text[4].split(",")[2], "nan", 1)
    p.write_text("\n".join(text) + "\n")
    with pytest.raises(InputError, match=r"s\.csv:5, column value: value is 'nan'"):
        load_inputs([p])
    q = slice_file(tmp_path, "q.csv")
    with pytest.raises(InputError, match=r"q\.csv: the file says quantity 'brdf'; --quantity reflectance_factor"):
        load_inputs([q], quantity="reflectance_factor")
    with pytest.raises(InputError, match=r"--columns applies to generic tables"):
        load_inputs([q], columns={"theta_i": "x"})


@pytest.mark.parametrize("spec, pattern", [("theta_i", r"KEY=NAME"), ("phi=Az", r"unknown key 'phi'"),
                                           ("theta_i=A,theta_i=B", r"theta_i given twice")])
def test_parse_columns_errors(spec, pattern):
    with pytest.raises(InputError, match=pattern):
        parse_columns(spec)
    assert parse_columns("theta_i = Inc , theta_o=Det") == {"theta_i": "Inc", "theta_o": "Det"}


def test_decreasing_blocks_and_tabs_are_accepted(tmp_path):
    p = write(tmp_path, "tabs.tsv", "theta_i_deg\ttheta_o_deg\tvalue\n"
              "10\t40\t0.3\n10\t20\t0.2\n10\t0\t0.1\n50\t-10\t0.1\n50\t30\t0.4\n")
    s = read_table(p, quantity="brdf")
    np.testing.assert_allclose(s.theta_o_deg, [40, 20, 0, -10, 30])


def test_all_zero_and_empty_inputs_say_so(tmp_path):
    from reconstruction.core.slicedata import Slice
    from reconstruction.formats.inputs import InputError, load_inputs
    from reconstruction.formats.slicefile import write_slice

    p = tmp_path / "zero.csv"
    write_slice(p, Slice(np.full(20, 30.0), np.linspace(-80, 80, 20), np.zeros((20, 1)), ["value"]))
    with pytest.raises(InputError, match="every value is zero; nothing was measured"):
        load_inputs([p])
    (tmp_path / "empty.csv").write_text("\n")
    with pytest.raises(InputError, match="empty.csv: empty file"):
        load_inputs([tmp_path / "empty.csv"])


def test_rows_in_any_order_are_read_as_the_sorted_table(tmp_path):
    """A capture's own order (incidences interleaved, angles back and forth: an adaptive plan's refinement) reads
    as the same samples as the table sorted by incidence and angle (issue 41, item 8)."""
    rng = np.random.default_rng(3)
    ti = np.repeat([20.0, 50.0], 7)
    to = np.tile(np.arange(-30.0, 40.0, 10.0), 2)
    v = 0.1 + 0.01 * np.arange(ti.size)
    perm = rng.permutation(ti.size)
    rows = "".join(f"{a},{b},{c}\n" for a, b, c in zip(ti[perm], to[perm], v[perm], strict=True))
    p = write(tmp_path, "capture-order.csv", "Inc,Det,value\n" + rows)
    s = read_table(p, quantity="brdf", columns=parse_columns("theta_i=Inc,theta_o=Det"))
    got = sorted(zip(s.theta_i_deg.tolist(), s.theta_o_deg.tolist(), s.values[:, 0].tolist(), strict=True))
    assert got == sorted(zip(ti.tolist(), to.tolist(), v.tolist(), strict=True))


def test_own_slice_rows_in_capture_order_read_back_through_columns(tmp_path):
    """The rows of our slice file, in the capture's order, without its header lines, read through --columns."""
    to = np.array([30.0, 40.0, 20.0, 50.0, 10.0, 35.0, 25.0, -20.0])
    p = slice_file(tmp_path, to=to, values=np.linspace(0.1, 0.8, to.size)[:, None])
    body = [ln for ln in p.read_text().splitlines() if not ln.startswith("#")]
    q = write(tmp_path, "rows.csv", "\n".join(body).replace("theta_i_deg", "Inc") + "\n")
    loaded = load_inputs([q], quantity="brdf", columns=parse_columns("theta_i=Inc"))
    assert sorted(loaded.slice.theta_o_deg.tolist()) == sorted(to.tolist())
