"""hardware/bom.csv and hardware/bom.py: every variant's parts and total, and the guide quoting the totals."""

from __future__ import annotations

import contextlib
import importlib.util
import io
import re
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _bom():
    """hardware/bom.py as a module (hardware/ is no package: a lab runs its scripts)."""
    if "hardware_bom" not in sys.modules:
        spec = importlib.util.spec_from_file_location("hardware_bom", REPO / "hardware" / "bom.py")
        mod = importlib.util.module_from_spec(spec)
        sys.modules["hardware_bom"] = mod
        spec.loader.exec_module(mod)
    return sys.modules["hardware_bom"]


def _run(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = _bom().main(argv)
    return status, out.getvalue(), err.getvalue()


def test_every_variant_has_what_the_issue_lists():
    bom = _bom()
    lines = bom.load()
    roles = {v: " | ".join(f"{x.part} {x.role}".lower() for x in lines if v in x.variants and not x.optional)
             for v in bom.VARIANTS}
    common = ("led driver", "led supply", "collimat", "detector aperture", "enclosure", "kinematic", "sample spring",
              "alignment laser", "protoboard|prototyping", "cable", "profile|frame", r"white reference \(ptfe\)",
              "mcp6001", "74hc4051", "bpw34", "monitor photodiode", "feedback resistor 10 kohm",
              "feedback resistor 100 mohm", "feedback capacitor", "decoupling", "emergency stop",
              "first-surface mirror")
    for v, text in roles.items():
        for want in common:
            assert re.search(want, text), (v, want)
    assert re.search("xl430", roles["xl430"]) and re.search("xm430", roles["xm430"])
    assert "usb to dynamixel" in roles["xl430"] and "usb to dynamixel" not in roles["grbl"]
    for want in ("nema 17", "tmc2209", "cnc shield", "limit switch", "608", "gt2"):
        assert want in roles["grbl"], want
    spectralon = [x for x in lines if "Spectralon" in x.part]
    assert len(spectralon) == 1 and spectralon[0].optional and spectralon[0].unit_eur_min >= 400
    assert [x.quantity for x in lines if x.part.startswith("Feedback resistor")] == [1, 1, 1, 1, 1]


def test_the_totals_are_the_sums_of_the_lines():
    bom = _bom()
    lines = bom.load()
    tot = bom.totals(lines)
    xl = [x for x in lines if "xl430" in x.variants and not x.optional]
    assert tot["xl430"] == (pytest.approx(sum(x.quantity * x.unit_eur_min for x in xl)),
                            pytest.approx(sum(x.quantity * x.unit_eur_max for x in xl)))
    # the XM430 bench differs from the XL430 one by its servos only: 2 x (270..300 - 45..55)
    assert tot["xm430"][0] - tot["xl430"][0] == pytest.approx(2 * (270 - 45))
    assert tot["xm430"][1] - tot["xl430"][1] == pytest.approx(2 * (300 - 55))
    assert 350 <= tot["xl430"][0] and tot["xl430"][1] <= 900   # the engineer's 450-700 for an XL430 bench


def test_a_broken_parts_list_is_named_by_row_and_column(tmp_path):
    src = (REPO / "hardware" / "bom.csv").read_text().splitlines()
    for row, bad, good, want in ((3, ",2,", ",two,", "quantity"), (4, ",xl430 xm430,", ",xl430 mx64,", "variants")):
        lines = list(src)
        lines[row - 1] = lines[row - 1].replace(bad, good, 1)
        p = tmp_path / "bom.csv"
        p.write_text("\n".join(lines) + "\n")
        status, out, err = _run(["--csv", str(p)])
        assert status == 2 and out == ""
        assert f"row {row}: {want}:" in err and "Traceback" not in err


def test_the_guide_quotes_the_scripts_totals():
    status, out, _ = _run([])
    assert status == 0
    guide = (REPO / "docs" / "build-a-bench.md").read_text()
    assert out.strip() in guide, "docs/build-a-bench.md: paste the output of `python hardware/bom.py`"
    bom = _bom()
    tot = bom.totals(bom.load())
    for v, label in (("xl430", "XL430"), ("xm430", "XM430"), ("grbl", "GRBL")):
        lo, hi = tot[v]
        assert f"{label} bench: {lo:.0f}-{hi:.0f} EUR" in guide, v
    status, table, _ = _run(["--markdown"])
    assert status == 0 and table.count("\n") == len(bom.load()) + 2
    assert table in guide, "docs/build-a-bench.md: paste the output of `python hardware/bom.py --markdown`"
    lo, hi = tot["xl430"]
    assert f"an XL430 bench {lo:.0f}-{hi:.0f} EUR" in (REPO / "README.md").read_text()
