"""Slice files: round trip, durable appends, torn lines, and errors that name file, line and column."""

import json

import numpy as np
import pytest

from reconstruction.core.slicedata import Slice, SliceError, to_brdf
from reconstruction.formats.slicefile import SliceWriter, read_slice, write_slice

META = {"quantity": "brdf", "material": "test", "bench": "configs/simulated.toml", "software_version": "0.1.0"}


def make_slice(channels=("R", "G", "B"), n=5):
    to = np.linspace(-60, 60, n)
    vals = np.abs(np.random.default_rng(0).normal(size=(n, len(channels))))
    return Slice(np.full(n, 30.0), to, vals, list(channels), std=vals * 0.01, repeats=np.full(n, 4),
                 unix_time_s=1.7e9 + np.arange(n), meta=META)


@pytest.mark.parametrize("channels", [("value",), ("R", "G", "B"), ("450nm", "550nm", "650.5nm")])
def test_round_trip(tmp_path, channels):
    s = make_slice(channels)
    p = tmp_path / "s.csv"
    write_slice(p, s)
    r = read_slice(p)
    assert r.channels == list(channels)
    np.testing.assert_array_equal(r.values, s.values)
    np.testing.assert_array_equal(r.std, s.std)
    np.testing.assert_array_equal(r.theta_o_deg, s.theta_o_deg)
    assert r.repeats.tolist() == [4] * 5
    assert r.meta["material"] == "test" and r.meta["format_version"] == 1
    if channels[0].endswith("nm"):
        np.testing.assert_array_equal(r.wavelengths_nm, [450, 550, 650.5])


def test_file_layout_is_documented_csv(tmp_path):
    p = tmp_path / "s.csv"
    write_slice(p, make_slice(("value",), n=1))
    lines = p.read_text().splitlines()
    assert lines[0] == "# gonio-brdf slice"
    assert json.loads(lines[1].removeprefix("# meta: "))["quantity"] == "brdf"
    assert lines[2] == "theta_i_deg,theta_o_deg,value,value_std,repeats,unix_time_s"
    assert lines[3].startswith("30.0,-60.0,")


def test_writer_appends_durably_and_resumes(tmp_path):
    p = tmp_path / "s.csv"
    with SliceWriter(p, ["value"], META) as w:
        w.append(30, -10, [0.1], [0.001], 4, 1.0)
        w.append(30, 0, [0.2], [0.002], 4, 2.0)
        # visible to a reader before close: flushed after every row
        assert len(read_slice(p)) == 2
    with SliceWriter(p, ["value"], META) as w:  # resume
        w.append(30, 10, [0.3], [0.003], 4, 3.0)
    r = read_slice(p)
    assert r.theta_o_deg.tolist() == [-10, 0, 10]
    with pytest.raises(SliceError, match="cannot append"):
        SliceWriter(p, ["R", "G", "B"], META)


def test_torn_last_line_is_dropped_with_warning_and_cut_on_resume(tmp_path):
    p = tmp_path / "s.csv"
    with SliceWriter(p, ["value"], META) as w:
        w.append(30, -10, [0.1], [0.001], 4, 1.0)
    with open(p, "a") as fh:
        fh.write("30.0,0.0,0.2")  # crash mid-row
    with pytest.warns(UserWarning, match="torn last line"):
        r = read_slice(p)
    assert len(r) == 1
    w = SliceWriter(p, ["value"], META)  # no Python warning: the note is the caller's to log (a capture's log)
    assert len(w.notes) == 1 and "torn last line" in w.notes[0]
    w.append(30, 0, [0.2], [0.002], 4, 2.0)
    w.close()
    r = read_slice(p)  # no warning now, both rows intact
    assert r.theta_o_deg.tolist() == [-10, 0]


def write_text(tmp_path, body, meta=None, header="theta_i_deg,theta_o_deg,value,value_std,repeats,unix_time_s"):
    m = {"format_version": 1, "quantity": "brdf"} if meta is None else meta
    p = tmp_path / "bad.csv"
    p.write_text(f"# gonio-brdf slice\n# meta: {json.dumps(m)}\n{header}\n{body}")
    return p


@pytest.mark.parametrize(
    "body, header, meta, pattern",
    [
        ("30,0,0.1,0.01,4,1\n", "theta_i_deg,value,value_std,repeats,unix_time_s", None,
         r"bad.csv:3: missing column 'theta_o_deg'"),
        ("30,0,0.1,0.01,4,1\n", "theta_i_deg,theta_o_deg,value,repeats,unix_time_s", None,
         r"bad.csv:3: missing column 'value_std'"),
        ("30,0,abc,0.01,4,1\n", None, None, r"bad.csv:4, column value: expected a number, got 'abc'"),
        ("30,0,0.1,0.01,4,1\n30,5,nan,0.01,4,1\n", None, None, r"bad.csv:5, column value: value is 'nan'"),
        ("30,95,0.1,0.01,4,1\n", None, None, r"bad.csv:4, column theta_o_deg: 95.0 is outside"),
        ("-90,5,0.1,0.01,4,1\n", None, None, r"bad.csv:4, column theta_i_deg: -90.0 is outside"),
        ("30,5,0.1,0.01,4,1\n30,6,0.1,0.01,4,1\n30,5,0.2,0.01,4,1\n", None, None,
         r"bad.csv:6: duplicate sample theta_i_deg = 30.0, theta_o_deg = 5.0 \(first at line 4\)"),
        ("30,5,0.1,0.01,4,1\n", None, {"format_version": 1, "quantity": "radiance"}, "unknown quantity 'radiance'"),
        ("30,5,0.1,0.01,4,1\n", None, {"format_version": 7, "quantity": "brdf"}, "unsupported format_version 7"),
        ("30,5,0.1\n30,6,0.1,0.01,4,1\n", None, None, r"bad.csv:4: 3 fields, expected 6"),
        ("30,5,0.1,0.01,0,1\n", None, None, r"bad.csv:4, column repeats: expected a positive integer"),
    ],
)
def test_reader_errors_name_file_line_and_column(tmp_path, body, header, meta, pattern):
    kw = {} if header is None else {"header": header}
    p = write_text(tmp_path, body, meta, **kw)
    with pytest.raises(SliceError, match=pattern):
        read_slice(p)


def test_missing_file_and_bad_magic(tmp_path):
    with pytest.raises(SliceError, match="no such file"):
        read_slice(tmp_path / "nope.csv")
    (tmp_path / "x.csv").write_text("a,b\n1,2\n")
    with pytest.raises(SliceError, match=r"x.csv:1: expected the first line"):
        read_slice(tmp_path / "x.csv")


def test_quantity_conversion():
    v = np.array([[np.pi], [1.0]])
    to = np.array([0.0, 60.0])
    np.testing.assert_allclose(to_brdf(v, to, "reflectance_factor"), [[1.0], [1 / np.pi]])
    np.testing.assert_allclose(to_brdf(v, to, "brdf_cos"), [[np.pi], [2.0]])
    s = Slice([30, 30], to, v, ["value"], meta={"quantity": "reflectance_factor"})
    np.testing.assert_allclose(s.brdf()[0], [[1.0], [1 / np.pi]])


def test_in_memory_validation():
    s = Slice([30, 30], [5, 5], [[1.0], [2.0]], ["value"])
    with pytest.raises(SliceError, match="duplicate sample"):
        s.validate()
    s = Slice([30], [5], [[np.nan]], ["value"])
    with pytest.raises(SliceError, match="column value"):
        s.validate()
    with pytest.raises(SliceError, match="value columns"):
        Slice([30], [5], [[1.0]], ["X"])


def test_header_only_file_reads_as_empty_and_can_be_appended(tmp_path):
    # a capture killed before its first sample leaves just the header
    p = tmp_path / "s.csv"
    SliceWriter(p, ["R", "G", "B"], META).close()
    s = read_slice(p)
    assert len(s) == 0 and s.values.shape == (0, 3)
    with SliceWriter(p, ["R", "G", "B"], META) as w:
        w.append(30, 5, [0.1, 0.2, 0.3], [0.0, 0.0, 0.0], 1, 1.0)
    assert len(read_slice(p)) == 1


def test_mismatched_sizes_are_a_slice_error():
    with pytest.raises(SliceError, match="do not make 2 samples"):
        Slice([30, 30], [5, 6], [[1.0, 2.0, 3.0]], ["R", "G", "B"])
