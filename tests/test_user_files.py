"""One way to open a user's file (issue 51 item 5): reconstruction.schema.files checks the path, the size and the
encoding once; every reader (bench files, slice files, CSV tables, MERL tables, scene files) raises the refusal as
its own error, in its own words."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from reconstruction.schema.files import UserFileError, check_user_file, read_user_bytes, read_user_text

REPO = Path(__file__).resolve().parents[1]


def test_each_refusal_has_its_kind_and_names_the_file(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    big = tmp_path / "big.toml"
    big.write_bytes(b"x" * 101)
    latin = tmp_path / "latin.toml"
    latin.write_bytes(b"a = 1\nb = '\xe9'\n")
    cases = [(tmp_path / "none.toml", "missing", "none.toml: no such file"),
             (tmp_path, "directory", "is a directory, expected a bench file"),
             (fifo, "special", "pipe: not a regular file (a device or a pipe), expected a bench file"),
             (big, "too_big", "big.toml: 101 bytes; a bench file is at most 100 bytes"),
             (latin, "not_utf8", "latin.toml:2: not a UTF-8 text file (invalid continuation byte at byte 11)")]
    for path, kind, words in cases:
        with pytest.raises(UserFileError) as e:
            read_user_text(path, "a bench file", 100)
        assert e.value.kind == kind and words in str(e.value) and e.value.path == path, (kind, str(e.value))
    assert isinstance(e.value, ValueError)
    assert e.value.line == 2 and e.value.byte == 11
    assert check_user_file(big, "a bench file").st_size == 101  # no limit: any size passes the check


def test_a_byte_order_mark_is_not_text_and_a_peek_reads_only_what_it_asks(tmp_path):
    p = tmp_path / "bom.csv"
    p.write_bytes(b"\xef\xbb\xbftheta_i_deg,theta_o_deg\n" + b"1,2\n" * 1000)
    assert read_user_text(p, "a CSV file", 1 << 20).startswith("theta_i_deg,")
    assert read_user_bytes(p, "a CSV file", read=8) == b"\xef\xbb\xbftheta"
    with pytest.raises(UserFileError) as e:
        read_user_text(p, "a CSV file", 100)
    assert e.value.kind == "too_big" and e.value.size == p.stat().st_size


def _readers():
    from acquisition.errors import ConfigError
    from acquisition.plans.plan import load_scene
    from reconstruction.core import merltable
    from reconstruction.core.slicedata import SliceError
    from reconstruction.formats import merl
    from reconstruction.formats.inputs import InputError, read_input
    from reconstruction.formats.slicefile import read_slice
    from reconstruction.schema.core import SchemaError
    from reconstruction.schema.files import open_text
    from simulator.config import ConfigError as SimConfigError
    from simulator.config import load_config as sim_load_config

    return [("bench file (schema)", lambda p: open_text(p, "a TOML bench file"), SchemaError, "a TOML bench file"),
            ("slice file", read_slice, SliceError, "a slice file"),
            ("input table", read_input, InputError, "a slice file or a CSV table"),
            ("MERL table", merl.read, merltable.MerlError, "a .binary file"),
            ("simulator bench file", sim_load_config, SimConfigError, "a TOML bench file"),
            ("scene file", load_scene, ConfigError, None)]


@pytest.mark.parametrize("reader", range(6))
def test_every_reader_refuses_a_directory_a_pipe_and_a_missing_file_through_the_one_check(tmp_path, reader):
    """Each reader raises its own error type, with the words of the one check (the scene file keeps its own: it
    says "not a regular file" for a directory too)."""
    name, read, error, what = _readers()[reader]
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)  # a reader that opened it would block here for ever instead of failing
    with pytest.raises(error, match="no such"):
        read(tmp_path / "missing")
    for path, words in ((tmp_path, f"is a directory, expected {what}"),
                        (fifo, f"not a regular file (a device or a pipe), expected {what}")):
        with pytest.raises(error) as e:
            read(path)
        msg = str(e.value)
        assert msg.startswith(str(path)), (name, msg)
        assert (words in msg) if what else ("not a regular file, expected a scene file (TOML)" in msg), (name, msg)


def test_no_reader_checks_a_files_type_by_itself():
    """The file-type checks (stat.S_ISREG / S_ISDIR) live in reconstruction/schema/files.py only: a new reader
    uses check_user_file / read_user_text instead of writing them a ninth time. The live view's server is the one
    other place, and not a reader of a user's file: it serves the files its own capture writes, opened without
    following links (O_NOFOLLOW) and refused when hard-linked or owned by another user (issue 49)."""
    found = sorted(str(p.relative_to(REPO)) for pkg in ("acquisition", "reconstruction", "simulator")
                   for p in (REPO / pkg).rglob("*.py") if re.search(r"S_ISREG|S_ISDIR", p.read_text(encoding="utf-8")))
    assert found == ["acquisition/live/server.py", "reconstruction/schema/files.py"]


#: The CSV parsers of the three packages: the one reader (reconstruction/schema/files.py: open_user_csv, which slice
#: files, generic tables and spectra read through), and the study's own results file, a table of text records
#: (material names, methods, statuses) that simulator/study.py writes and reads back, not a user's numeric table.
CSV_PARSERS = ["reconstruction/schema/files.py", "simulator/study.py"]


def test_no_reader_parses_csv_by_itself():
    """The CSV parsing (csv.reader / DictReader, numpy's loadtxt / genfromtxt) lives in the one reader: a new
    format that reads a CSV goes through open_user_csv instead of writing a fourth parser."""
    pattern = re.compile(r"csv\.(reader|DictReader)|\b(loadtxt|genfromtxt)\(")
    found = sorted(str(p.relative_to(REPO)) for pkg in ("acquisition", "reconstruction", "simulator")
                   for p in (REPO / pkg).rglob("*.py") if pattern.search(p.read_text(encoding="utf-8")))
    assert found == CSV_PARSERS


def test_the_three_csv_formats_read_through_the_one_reader_and_word_a_bad_cell_alike(tmp_path):
    """A slice file, a generic table and a reference spectrum: comment lines skipped, the header read, a bad cell
    named by file, line and column in the same words, whatever each reader's error type."""
    from reconstruction.core.slicedata import SliceError
    from reconstruction.formats.inputs import InputError, read_table
    from reconstruction.formats.slicefile import read_slice
    from reconstruction.schema.core import SchemaError
    from reconstruction.schema.files import open_user_csv, read_spectrum_csv

    slice_head = '# gonio-brdf slice\n# meta: {"format_version": 1, "quantity": "brdf"}\n# a comment\n' \
                 "theta_i_deg,theta_o_deg,value,value_std,repeats,unix_time_s\n"
    cases = [
        (slice_head + "30,0,0.1,0.01,4,1\n30,5,x,0.01,4,1\n", read_slice, SliceError, 6, "value"),
        ("# exported\n\ntheta_i,theta_o,value\n30,0,0.1\n# a note\n30,5,x\n",
         lambda p: read_table(p, quantity="brdf"), InputError, 6, "value"),
        ("# panel\nwavelength_nm,reflectance\n400,0.9\n500,x\n", lambda p: read_spectrum_csv(p, "[calibration]"),
         SchemaError, 4, "reflectance"),
    ]
    for k, (text, read, error, line, column) in enumerate(cases):
        path = tmp_path / f"f{k}.csv"
        path.write_text(text)
        with pytest.raises(error) as e:
            read(path)
        assert f"{path}:{line}, column {column}: expected a number, got 'x'" in str(e.value), str(e.value)
        path.write_text(text.replace(",x", ",0.2"))
        got = read(path)
        assert len(got[0] if k == 2 else got) == 2  # the comments and the header are not rows
    table = open_user_csv(tmp_path / "f1.csv", "a CSV file", delimiters=(",", ";"), quoted=True)
    data, line_of = table.rows()
    assert table.head == ["# exported", ""] and table.header == ["theta_i", "theta_o", "value"]
    assert table.header_line == 3 and line_of.tolist() == [4, 6] and data.tolist() == [[30, 0, 0.1], [30, 5, 0.2]]
