"""Draw the detector's front-end schematic from its netlist (hardware/frontend/frontend.cir) with schemdraw.

    python hardware/frontend/draw.py --out docs/frontend.png      # or .svg

Every part's reference and value is taken from the netlist (hardware/frontend/netlist.py), with the op-amps'
(MCP6001, SOT-23-5) and the multiplexer's (74HC4051, DIP/SO-16) pin numbers; :func:`drawing` returns the drawing
and the list of (reference, label) it drew, which tests/test_frontend_drawing.py compares with the netlist.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE.parents[1]) not in sys.path:  # run as a script from anywhere
    sys.path.insert(0, str(HERE.parents[1]))

from hardware.frontend.netlist import NETLIST, Part, parts  # noqa: E402

#: what each subcircuit is on the board
PART_NAMES = {"photodiode": "BPW34", "mcp6001": "MCP6001", "hc4051": "74HC4051"}
#: 74HC4051 pins (DIP/SO-16) by the subcircuit's pin names
HC4051_PINS = {"y0": "13", "y1": "14", "y2": "15", "y3": "12", "y4": "1", "z": "3", "s0": "11", "s1": "10",
               "s2": "9", "e": "6", "vcc": "16", "gnd": "8", "vee": "7"}
#: MCP6001 pins (SOT-23-5): VOUT 1, VSS 2, VIN+ 3, VIN- 4, VDD 5
MCP6001_PINS = {"out": "1", "vs": "2", "in2": "3", "in1": "4", "vd": "5"}
_UNITS = {"resistor": "Ω", "capacitor": "F"}
_PREFIX = ((1e9, "G"), (1e6, "M"), (1e3, "k"), (1.0, ""), (1e-3, "m"), (1e-6, "µ"), (1e-9, "n"), (1e-12, "p"))


def value_label(p: Part) -> str:
    """'10 kΩ', '100 nF', '1 pF' for a resistor or capacitor of the netlist."""
    v = float(p.value or 0.0)
    for scale, prefix in _PREFIX:
        if v >= scale * 0.999:
            return f"{v / scale:g} {prefix}{_UNITS[p.kind]}"
    return f"{v:g} {_UNITS[p.kind]}"


def label_value(text: str) -> float:
    """The value of a label made by :func:`value_label` (its number times its prefix)."""
    num, unit = text.split()
    scale = dict((p, s) for s, p in _PREFIX if p).get(unit[:-1], 1.0) if len(unit) > 1 else 1.0
    return float(num) * scale


class Sheet:
    """A schemdraw drawing plus the list of parts it labelled."""

    def __init__(self, by_ref: dict[str, Part]) -> None:
        import schemdraw

        self.d = schemdraw.Drawing(show=False)
        self.d.config(fontsize=11, unit=2.5)
        self.by_ref = by_ref
        self.drawn: list[tuple[str, str]] = []

    def part(self, element, ref: str, loc: str = "top", sep: str = "\n"):
        """Add ``element`` labelled with part ``ref``'s reference and value (from the netlist)."""
        p = self.by_ref[ref]
        text = value_label(p) if p.kind in _UNITS else PART_NAMES[p.kind]
        self.drawn.append((ref, text))
        return self.d.add(element.label(f"{ref}{sep}{text}", loc=loc, fontsize=10))

    def add(self, element):
        return self.d.add(element)


def _pin(sheet: Sheet, xy, text: str, ofst=(0.15, 0.15)) -> None:
    import schemdraw.elements as elm

    sheet.add(elm.Label().at((xy[0] + ofst[0], xy[1] + ofst[1])).label(text, fontsize=8, color="#555"))


def _ground(sheet: Sheet, xy) -> None:
    import schemdraw.elements as elm

    sheet.add(elm.Ground().at(xy))


def _supply_and_reference(s: Sheet, vref_xy) -> None:
    """+5 V with C1, the reference divider R1/R2 and C4, ending at ``vref_xy`` (the reference bus)."""
    import schemdraw.elements as elm

    x0, y0 = vref_xy[0] - 9.0, vref_xy[1]
    s.add(elm.Vdd().at((x0, y0 + 5.0)).label("+5 V (Arduino 5V)", fontsize=10))
    s.add(elm.Line().at((x0, y0 + 5.0)).down(1.0))
    s.part(elm.Capacitor().at((x0, y0 + 4.0)).down(2.0), "C1", loc="bottom")
    _ground(s, (x0, y0 + 2.0))
    s.add(elm.Line().at((x0, y0 + 4.0)).right(3.0))
    s.add(elm.Dot().at((x0, y0 + 4.0)))
    r1 = s.part(elm.Resistor().at((x0 + 3.0, y0 + 4.0)).down(4.0), "R1", loc="bottom")
    s.add(elm.Dot().at(r1.end))
    s.part(elm.Resistor().at(r1.end).down(2.5), "R2", loc="bottom")
    _ground(s, (x0 + 3.0, y0 - 2.5))
    s.add(elm.Line().at(r1.end).right(2.5))
    s.add(elm.Dot().at((x0 + 5.5, y0)))
    s.part(elm.Capacitor().at((x0 + 5.5, y0)).down(2.5), "C4", loc="bottom")
    _ground(s, (x0 + 5.5, y0 - 2.5))
    s.add(elm.Line().at((x0 + 5.5, y0)).to(vref_xy))
    s.add(elm.Label().at((x0 + 4.0, y0 + 0.4)).label("Vref 30 mV", fontsize=9))


def _tia(s: Sheet, origin, pd: str, amp: str, out_name: str, decoupling: str) -> dict:
    """Photodiode ``pd`` into op-amp ``amp`` at ``origin`` (its inverting input), its supply decoupled by
    capacitor ``decoupling``: anchors of the amplifier."""
    import schemdraw.elements as elm

    op = s.part(elm.Opamp(leads=True).anchor("in1").at(origin), amp, loc="center")
    for anchor, pin in MCP6001_PINS.items():
        xy = op.absanchors[anchor]
        _pin(s, xy, pin, ofst=(-0.35, 0.15) if anchor.startswith("in") else (0.1, 0.15))
    vd, vs = op.absanchors["vd"], op.absanchors["vs"]
    s.add(elm.Line().at(vd).up(1.4))
    s.add(elm.Vdd().at((vd[0], vd[1] + 1.4)).label("+5 V", fontsize=9))
    s.add(elm.Line().at(vs).down(0.4))
    _ground(s, (vs[0], vs[1] - 0.4))
    s.add(elm.Dot().at((vd[0], vd[1] + 1.2)))
    s.add(elm.Line().at((vd[0], vd[1] + 1.2)).right(2.6))
    s.part(elm.Capacitor().at((vd[0] + 2.6, vd[1] + 1.2)).down(1.0), decoupling, loc="bottom")
    _ground(s, (vd[0] + 2.6, vd[1] + 0.2))
    inn = (origin[0] - 1.5, origin[1])
    s.add(elm.Line().at(origin).to(inn))
    s.add(elm.Dot().at(inn))
    vref = (inn[0], op.absanchors["in2"][1] - 2.5)
    s.part(elm.Photodiode().at(vref).to(inn), pd, loc="bottom")  # anode on Vref, cathode on VIN-
    s.add(elm.Line().at(op.absanchors["in2"]).left(0.8))
    s.add(elm.Line().at((op.absanchors["in2"][0] - 0.8, op.absanchors["in2"][1])).to((op.absanchors["in2"][0] - 0.8,
                                                                                       vref[1])))
    s.add(elm.Line().at((op.absanchors["in2"][0] - 0.8, vref[1])).to(vref))
    s.add(elm.Dot().at(vref))
    out = op.absanchors["out"]
    s.add(elm.Line().at(out).right(1.5))
    s.add(elm.Dot().at((out[0] + 1.5, out[1])))
    s.add(elm.Line().at((out[0] + 1.5, out[1])).down(1.2))
    s.add(elm.Line().at((out[0] + 1.5, out[1] - 1.2)).right(1.0).label(out_name, loc="right", fontsize=10))
    return {"inn": inn, "vref": vref, "out": (out[0] + 1.5, out[1]), "vd": vd}


def _ranges(s: Sheet, a: dict, feedback: list[tuple[str, str]]) -> None:
    """Five Rf || Cf from the inverting input to the 74HC4051's channels; COM to the output."""
    import schemdraw.elements as elm

    inn, out = a["inn"], a["out"]
    x_bus, x_mux = inn[0], out[0] + 6.0
    base = inn[1] + 3.5
    order = ("y4", "y3", "y2", "y1", "y0")  # the 100 M range nearest the op-amp: its short trace
    pins = [elm.IcPin(name=f"Y{k[1]}", pin=HC4051_PINS[k], side="left") for k in reversed(order)]
    pins += [elm.IcPin(name="Z (COM)", pin="3", side="right"), elm.IcPin(name="S0", pin="11", side="right"),
             elm.IcPin(name="S1", pin="10", side="right"), elm.IcPin(name="S2", pin="9", side="right"),
             elm.IcPin(name="E", pin="6", side="bottom"), elm.IcPin(name="VEE", pin="7", side="bottom"),
             elm.IcPin(name="GND", pin="8", side="bottom"), elm.IcPin(name="VCC", pin="16", side="top")]
    mux = s.part(elm.Ic(pins=pins, size=(6.5, 13.0), pinspacing=2.6, edgepadH=0.8).anchor("Y0")
                 .at((x_mux, base)), "XU2", loc="center")
    s.add(elm.Line().at(inn).to((x_bus, mux.absanchors["Y4"][1])))
    for k, (r_ref, c_ref) in zip(range(5), feedback, strict=True):
        y = mux.absanchors[f"Y{k}"][1]
        s.add(elm.Dot().at((x_bus, y)))
        s.part(elm.Resistor().at((x_bus, y)).right(3.2), r_ref, loc="top", sep="  ")
        s.add(elm.Line().at((x_bus + 0.4, y)).down(0.9))
        s.part(elm.Capacitor().at((x_bus + 0.4, y - 0.9)).right(2.4), c_ref, loc="bottom", sep="  ")
        s.add(elm.Line().at((x_bus + 2.8, y - 0.9)).up(0.9))
        s.add(elm.Line().at((x_bus + 3.2, y)).to(mux.absanchors[f"Y{k}"]))
    z = mux.absanchors["Z (COM)"]
    s.add(elm.Line().at(z).right(1.0))
    s.add(elm.Line().at((z[0] + 1.0, z[1])).down(z[1] - out[1] + 0.0 if z[1] > out[1] else 0.1))
    s.add(elm.Line().at((z[0] + 1.0, out[1])).to(out))
    for name, pin in (("S0", "D8"), ("S1", "D9"), ("S2", "D10")):
        xy = mux.absanchors[name]
        s.add(elm.Line().at(xy).right(1.6).label(pin, loc="right", fontsize=9))
    for name in ("E", "VEE", "GND"):
        xy = mux.absanchors[name]
        s.add(elm.Line().at(xy).down(0.5))
        _ground(s, (xy[0], xy[1] - 0.5))
    vcc = mux.absanchors["VCC"]
    s.add(elm.Line().at(vcc).up(0.8))
    s.add(elm.Vdd().at((vcc[0], vcc[1] + 0.8)).label("+5 V", fontsize=9))
    s.add(elm.Dot().at((vcc[0], vcc[1] + 0.4)))
    s.add(elm.Line().at((vcc[0], vcc[1] + 0.4)).left(2.0))
    s.part(elm.Capacitor().at((vcc[0] - 2.0, vcc[1] + 0.4)).down(1.2), "C3", loc="bottom")
    _ground(s, (vcc[0] - 2.0, vcc[1] - 0.8))


def drawing(netlist: Path = NETLIST):
    """(schemdraw Drawing, [(reference, label)] drawn) of the netlist's board."""
    import schemdraw.elements as elm

    ps = parts(netlist)
    by_ref = {p.ref: p for p in ps}
    s = Sheet(by_ref)
    feedback = []
    for k in range(5):
        pair = {p.kind: p.ref for p in ps if set(p.nodes) == {"inn", f"y{k}"}}
        feedback.append((pair["resistor"], pair["capacitor"]))
    main = _tia(s, (0.0, 0.0), "XD1", "XU1", "out → A0 (ADC0)", "C2")
    _ranges(s, main, feedback)
    _supply_and_reference(s, main["vref"])
    # the monitor: a second photodiode on a fixed 1 M, below
    mon = _tia(s, (0.0, -10.0), "XD2", "XU3", "monitor → A1 (ADC1)", "C11")
    x_link = mon["vref"][0] - 1.5
    s.add(elm.Line().at(mon["vref"]).to((x_link, mon["vref"][1])))
    s.add(elm.Line().at((x_link, mon["vref"][1])).to((x_link, main["vref"][1])))
    s.add(elm.Dot().at((x_link, main["vref"][1])))
    top = (mon["inn"][0], mon["inn"][1] + 3.0)
    s.add(elm.Line().at(mon["inn"]).to(top))
    s.part(elm.Resistor().at(top).right(mon["out"][0] - top[0]), "R8", loc="top", sep="  ")
    s.add(elm.Line().at((mon["out"][0], top[1])).to(mon["out"]))
    s.add(elm.Line().at((top[0], top[1])).up(1.2))
    s.part(elm.Capacitor().at((top[0], top[1] + 1.2)).right(mon["out"][0] - top[0]), "C10", loc="top", sep="  ")
    s.add(elm.Line().at((mon["out"][0], top[1] + 1.2)).down(1.2))
    return s.d, s.drawn


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Draw the front-end schematic from hardware/frontend/frontend.cir.",
                                 epilog="example: python hardware/frontend/draw.py --out docs/frontend.png")
    ap.add_argument("--out", type=Path, required=True, help="the image to write (.png or .svg)")
    ap.add_argument("--netlist", type=Path, default=NETLIST, help="the netlist to draw")
    a = ap.parse_args(argv)
    if a.out.suffix.lower() not in (".png", ".svg"):
        print(f"draw.py: {a.out}: the image must end in .png or .svg", file=sys.stderr)
        return 2
    try:
        import schemdraw  # noqa: F401
    except ImportError:
        print("draw.py: schemdraw is not installed (pip install -e '.[test]')", file=sys.stderr)
        return 2
    if not a.netlist.is_file():
        print(f"draw.py: {a.netlist}: no such file", file=sys.stderr)
        return 2
    try:
        d, drawn = drawing(a.netlist)
    except (KeyError, ValueError) as e:
        print(f"draw.py: {a.netlist}: cannot draw it: {e}", file=sys.stderr)
        return 2
    a.out.parent.mkdir(parents=True, exist_ok=True)
    d.save(str(a.out), dpi=110)
    print(f"wrote {a.out} ({len(drawn)} parts)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
