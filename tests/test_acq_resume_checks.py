"""Issue 49: no silent wrong answer from a capture and its resume. What is counted safe is what is on disk (a
link lost right after a row was appended); a resume refuses rows that are not points of the plan or whose values
are impossible for their standard deviation (``--force`` sets them aside, said in the log); a resume whose slice
is gone while the run record names captured samples refuses, naming them."""

from __future__ import annotations

import json

import pytest

from acquisition.cli import main
from acquisition.errors import CommError
from acquisition.run.engine import Engine
from tests.test_acq_support import make_raw, read, write_config

PLAN = {"plan": {"theta_i_deg": [30.0, 50.0], "theta_o_step_deg": 10.0}}


def _rows(path) -> list[str]:
    return [ln for ln in path.read_text().splitlines() if ln[:1].isdigit() or ln[:1] == "-"]


@pytest.fixture(scope="module")
def done(tmp_path_factory):
    """A complete small capture (two incidences, 28 samples) and its config."""
    d = tmp_path_factory.mktemp("resume49")
    cfg = write_config(d / "fast.toml", make_raw(PLAN))
    assert main(["--config", str(cfg), "--out", str(d / "base"), "--no-progress"]) == 0
    return cfg, d / "base"


def test_a_link_lost_right_after_a_row_was_appended_counts_that_row_as_safe(tmp_path, monkeypatch, capsys):
    """The row is appended (and fsynced) before the controller's clock is read (TIME?); when that read fails the
    row is on disk, and the count of safely captured samples says so."""
    cfg = write_config(tmp_path / "c.toml", make_raw(PLAN))
    real = Engine._account
    calls = []

    def clock_read_fails_on_the_fifth_point(self):  # the bench clock's TIME? after the 5th row was appended
        if self.sink is not None:  # the capture's engine (not the dry run's estimate)
            calls.append(1)
        if len(calls) == 5 and self.sink is not None:
            raise CommError("no reply to TIME? (is the controller still connected?)")
        real(self)

    monkeypatch.setattr(Engine, "_account", clock_read_fails_on_the_fifth_point)
    code = main(["--config", str(cfg), "--out", str(tmp_path / "o"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 1
    on_disk = len(_rows(tmp_path / "o" / "slice.csv"))
    assert on_disk == 5
    assert f"{on_disk} sample(s) are safely in" in err, err
    record = json.loads((tmp_path / "o" / "capture.json").read_text())
    assert record["runs"][-1]["samples_total"] == on_disk


@pytest.mark.parametrize("how", ["deleted", "emptied"])
def test_a_resume_whose_slice_is_gone_but_recorded_refuses_naming_what_was_captured(done, tmp_path, capsys, how):
    cfg, base = done
    out = tmp_path / "o"
    out.mkdir()
    (out / "capture.json").write_bytes((base / "capture.json").read_bytes())
    if how == "emptied":
        (out / "slice.csv").write_text("")
    code = main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2
    assert "28 sample(s)" in err and "capture.json" in err and "slice.csv" in err, err
    assert len(err.strip().splitlines()) == 1
    assert not _rows(out / "slice.csv") if (out / "slice.csv").exists() else True
    assert how != "emptied" or (out / "slice.csv").exists()  # the evidence stays as it was
    record = json.loads((out / "capture.json").read_text())
    assert record["runs"] == json.loads((base / "capture.json").read_text())["runs"]  # no run was started


def _edit(path, find: str, replace: str) -> None:
    text = path.read_text()
    assert find in text
    path.write_text(text.replace(find, replace, 1))


def _copy(base, out):
    out.mkdir()
    for name in ("slice.csv", "capture.json"):
        (out / name).write_bytes((base / name).read_bytes())
    return out


def test_a_resume_refuses_a_row_that_is_not_a_point_of_the_plan(done, tmp_path, capsys):
    """The issue's reproduction: a row edited from theta_i 30 to 70 (a fourth incidence of one sample) resumed
    with exit 0. Now the resume names the row and refuses it; the file is left as it was."""
    cfg, base = done
    out = _copy(base, tmp_path / "o")
    _edit(out / "slice.csv", "\n30.0,50.0,", "\n70.0,50.0,")
    before = (out / "slice.csv").read_bytes()
    code = main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "(70, 50): not a point of the plan" in err and "--force" in err, err
    line = next(k for k, ln in enumerate(before.decode().splitlines(), 1) if ln.startswith("70.0,50.0,"))
    assert f"slice.csv:{line} " in err
    assert len(err.strip().splitlines()) == 1
    assert (out / "slice.csv").read_bytes() == before


def test_a_resume_refuses_values_impossibly_below_zero_for_their_std(done, tmp_path, capsys):
    cfg, base = done
    out = _copy(base, tmp_path / "o")
    row = next(ln for ln in (out / "slice.csv").read_text().splitlines() if ln.startswith("30.0,50.0,"))
    cells = row.split(",")
    _edit(out / "slice.csv", row, ",".join([*cells[:2], "-0.5", "7e-05", *cells[4:]]))
    code = main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "(30, 50): f_r -0.5 +- 7e-05 1/sr is 7143 standard deviations below zero" in err, err


def test_resume_force_sets_refused_rows_aside_says_so_in_the_log_and_completes(done, tmp_path, capsys):
    cfg, base = done
    out = _copy(base, tmp_path / "o")
    edited = next(ln for ln in (out / "slice.csv").read_text().splitlines() if ln.startswith("30.0,50.0,"))
    _edit(out / "slice.csv", "\n30.0,50.0,", "\n70.0,50.0,")
    code = main(["--config", str(cfg), "--out", str(out), "--resume", "--force", "--no-progress"])
    assert code == 0, capsys.readouterr().err
    s = read(out / "slice.csv")
    ref = read(base / "slice.csv")
    assert sorted(zip(s.theta_i_deg, s.theta_o_deg, strict=True)) == sorted(zip(ref.theta_i_deg, ref.theta_o_deg,
                                                                             strict=True))
    aside = (out / "slice.set-aside.csv").read_text()
    assert aside.startswith("# gonio-brdf slice\n") and "70.0," + edited[len("30.0,"):] in aside
    assert read(out / "slice.set-aside.csv").theta_i_deg.tolist() == [70.0]  # a slice file of its own
    log = (out / "capture.log").read_text()
    assert "set aside 1 row(s)" in log and "(70, 50): not a point of the plan" in log and "--force" in log


def test_a_flipped_digit_is_caught_by_the_rows_check_value(done, tmp_path, capsys):
    """Every row's CRC-32 is kept in slice.crc as it is appended: a value edited by one digit (still a point of
    the plan, still plausible) no longer matches and is refused; --force sets it aside and measures it again."""
    cfg, base = done
    out = _copy(base, tmp_path / "o")
    (out / "slice.crc").write_bytes((base / "slice.crc").read_bytes())
    row = next(ln for ln in (out / "slice.csv").read_text().splitlines() if ln.startswith("30.0,50.0,"))
    value = row.split(",")[2]
    flipped = value[:4] + str((int(value[4]) + 1) % 10) + value[5:]  # one digit of f_r
    _edit(out / "slice.csv", row, row.replace(value, flipped, 1))
    code = main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "(30, 50): edited or corrupted since it was written" in err, err
    assert main(["--config", str(cfg), "--out", str(out), "--resume", "--force", "--no-progress"]) == 0
    s = read(out / "slice.csv")
    assert len(s) == 28 and flipped not in (out / "slice.csv").read_text()
    assert flipped in (out / "slice.set-aside.csv").read_text()
    # the point measured again has its own check value: a further resume finds nothing to refuse
    assert main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"]) == 0


def test_a_slice_without_row_checks_still_resumes_and_gets_them(done, tmp_path, capsys):
    cfg, base = done
    out = _copy(base, tmp_path / "o")  # an older capture: no slice.crc
    rows = (out / "slice.csv").read_text().splitlines(keepends=True)
    (out / "slice.csv").write_text("".join(rows[:-3]))  # three points still to measure
    assert main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"]) == 0, capsys.readouterr().err
    checks = (out / "slice.crc").read_text().splitlines()
    assert len([c for c in checks if not c.startswith("#")]) == 28  # the 25 rows found, then the 3 new ones
    assert "# gonio-brdf slice" in (out / "slice.csv").read_text()  # the slice file itself is unchanged in form
    assert read(out / "slice.csv").channels == ["value"]


def test_a_row_whose_check_value_a_kill_cut_off_is_the_captures_on_every_later_resume(done, tmp_path, capsys):
    """kill -9 between a row's append (fsynced) and its check value's: the row is the capture's. The resume takes
    it, and its check value is written then, so that a later resume, after this run appended rows with theirs,
    does not call it a row the capture did not write (a failure of test_sigkill_at_random_moments_then_resume)."""
    cfg, base = done
    out = _copy(base, tmp_path / "o")
    (out / "slice.crc").write_bytes((base / "slice.crc").read_bytes())
    rows = (out / "slice.csv").read_text().splitlines(keepends=True)
    (out / "slice.csv").write_text("".join(rows[:-3]))  # 25 rows on disk, three points still to measure
    checks = (out / "slice.crc").read_text().splitlines(keepends=True)
    (out / "slice.crc").write_text("".join(checks[:-4]))  # the 25th row's check value never written
    assert main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"]) == 0, capsys.readouterr().err
    assert len([c for c in (out / "slice.crc").read_text().splitlines() if not c.startswith("#")]) == 28
    rows = (out / "slice.csv").read_text().splitlines(keepends=True)
    (out / "slice.csv").write_text("".join(rows[:-1]))  # the next resume finds the 25th row among checked ones
    assert main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"]) == 0, capsys.readouterr().err
    assert len(read(out / "slice.csv")) == 28
