"""The amplifier's schematic (hardware/frontend/draw.py, the image in docs/build-a-bench.md) is drawn from its
netlist: the drawing and the netlist name the same parts with the same values, a changed value shows in the
drawing, and the guide shows the image."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

pytest.importorskip("schemdraw", reason="schemdraw is in the test extra: pip install -e '.[test]'")

from hardware.frontend import draw, netlist  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def test_the_drawing_names_every_part_of_the_netlist_with_its_value():
    _, drawn = draw.drawing()
    parts = {p.ref: p for p in netlist.parts()}
    refs = [ref for ref, _ in drawn]
    assert sorted(refs) == sorted(parts) and len(refs) == len(set(refs))  # each part once, none invented
    for ref, label in drawn:
        p = parts[ref]
        if p.value is None:
            assert label == draw.PART_NAMES[p.kind], (ref, label)
        else:
            assert draw.label_value(label) == pytest.approx(p.value, rel=1e-9), (ref, label, p.value)
    kinds = {p.kind for p in parts.values()}
    assert {"photodiode", "mcp6001", "hc4051", "resistor", "capacitor"} <= kinds


def test_a_changed_value_in_the_netlist_shows_in_the_drawing(tmp_path):
    for p in netlist.NETLIST.parent.glob("*.lib"):
        shutil.copy(p, tmp_path / p.name)
    text = netlist.NETLIST.read_text()
    assert "R7 inn y4 100meg" in text
    (tmp_path / "frontend.cir").write_text(text.replace("R7 inn y4 100meg", "R7 inn y4 47meg"))
    drawn = dict(draw.drawing(tmp_path / "frontend.cir")[1])
    assert drawn["R7"] == "47 MΩ" and dict(draw.drawing()[1])["R7"] == "100 MΩ"


def test_the_pin_numbers_are_the_parts_datasheet_pins():
    assert draw.MCP6001_PINS == {"out": "1", "vs": "2", "in2": "3", "in1": "4", "vd": "5"}  # SOT-23-5
    assert {draw.HC4051_PINS[k] for k in ("z", "e", "vee", "gnd", "vcc")} == {"3", "6", "7", "8", "16"}
    assert [draw.HC4051_PINS[f"y{k}"] for k in range(5)] == ["13", "14", "15", "12", "1"]


def test_the_cli_draws_an_image_and_refuses_a_bad_one(tmp_path, capsys):
    assert draw.main(["--out", str(tmp_path / "f.png")]) == 0
    assert (tmp_path / "f.png").stat().st_size > 10_000
    assert draw.main(["--out", str(tmp_path / "f.txt")]) == 2
    assert draw.main(["--out", str(tmp_path / "g.png"), "--netlist", str(tmp_path / "none.cir")]) == 2
    err = capsys.readouterr().err
    assert "must end in .png or .svg" in err and "none.cir: no such file" in err


def test_the_guide_shows_the_schematic():
    guide = (REPO / "docs" / "build-a-bench.md").read_text()
    assert "](frontend.png)" in guide and (REPO / "docs" / "frontend.png").is_file()
    assert "python hardware/frontend/draw.py --out docs/frontend.png" in guide
