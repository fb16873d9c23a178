"""The benches' wiring drawn (schemdraw): every board, supply, motor, switch and wire between them.

    python hardware/wiring/draw.py                    # docs/wiring-dynamixel.png and docs/wiring-grbl.png
    python hardware/wiring/draw.py --out DIR --format svg

The detector board's side is the same on both benches: the Uno's A0 from the amplifier, D8-D10 to the
multiplexer's select lines, D7 to the source MOSFET, D6 to the (optional) sample changer. The amplifier itself
(photodiode, op-amp, multiplexer, feedback resistors) is drawn in docs/build-a-bench.md, The amplifier.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

#: Wire colours: supply, ground, signal, bus, motor phases, USB.
POWER, GROUND, SIGNAL, BUS, MOTOR, USB = "#c62828", "#212121", "#1565c0", "#6a1b9a", "#2e7d32", "#757575"


def _box(d, elm, xy: tuple[float, float], title: str, size: tuple[float, float], pins: list[tuple]):
    """A board at ``xy`` (its lower left corner) with pins (anchor, printed name, side L/R/T/B), listed from the
    bottom (left) up (right); a side's pins spread evenly along it."""
    ic = elm.Ic(pins=[elm.IcPin(name=q[1], anchorname=q[0], side=q[2]) for q in pins], size=size, lblsize=11)
    has = {side: sum(1 for q in pins if q[2] == side) for side in "LRTB"}
    for side, n in has.items():
        if n:
            length = size[0] if side in "TB" else size[1]
            if side in "LR" and has["T"]:  # clear of the labels of the pins on top
                length *= 0.8
            pad = length / (2 * n)
            ic = ic.side(side, spacing=length / n, pad=pad, pinlabel_size=10)
    ic = d.add(ic.theta(0).at(xy))   # its lower left corner at xy, upright whatever the last wire's direction
    d.add(elm.Label().at((xy[0] + size[0] / 2, xy[1] + size[1] + 0.35)).label(title, fontsize=11))
    return ic


def _wire(d, elm, a, b, colour: str, text: str = "", shape: str = "-", k: float = 1.0):
    w = elm.Wire(shape, k=k).at(a).to(b).color(colour)
    if text:
        w = w.label(text, fontsize=8, color=colour)
    d.add(w)


def detector_side(d, elm, x0: float, y0: float) -> dict:
    """The detector board, its front-end, the source and the sample changer, placed from (x0, y0)."""
    uno = _box(d, elm, (x0, y0), "detector board: Arduino Uno R3 (firmware/detector)", (6, 4),
               [("usb", "USB", "L"), ("a0", "A0", "R"), ("d8", "D8", "R"), ("d9", "D9", "R"), ("d10", "D10", "R"),
                ("a1", "A1", "R"), ("v5", "5V", "T"), ("gnd", "GND", "T"), ("d7", "D7", "B"), ("d6", "D6", "B")])
    amp = _box(d, elm, (x0 + 11, y0), "front-end (see The amplifier); 74HC4051 E pin 6, VEE pin 7 to GND", (8, 4),
               [("out", "OUT", "L"), ("sa", "S0 (pin 11)", "L"), ("sb", "S1 (pin 10)", "L"), ("sc", "S2 (pin 9)", "L"),
                ("mout", "MONITOR OUT", "L"), ("pd", "BPW34, shielded cable", "R"), ("mon", "monitor BPW34", "R"),
                ("v5", "5V", "T"),
                ("gnd", "GND", "T")])
    fet = _box(d, elm, (x0 + 11, y0 - 5.5), "source MOSFET IRLZ44N", (6, 2),
               [("g", "G: 100 R; 100 k to GND", "L"), ("dr", "D", "R"), ("s", "S to GND", "B")])
    psu = _box(d, elm, (x0 + 21, y0 - 2.6), "12 V 1 A supply (the LED's own)", (5, 1.2), [("out", "+12 V / GND", "B")])
    led = _box(d, elm, (x0 + 21, y0 - 6.1), "LED driver LDD-350H", (5, 2.2),
               [("dim", "DIM", "L"), ("vin", "VIN", "T"), ("out", "LED+ / LED-", "R")])
    lamp = _box(d, elm, (x0 + 29, y0 - 5.9), "1 W white LED (collimator)", (3, 1.6), [("in", "+ / -", "L")])
    sol = _box(d, elm, (x0 + 11, y0 - 10), "sample changer (optional): MOSFET + 12 V solenoid", (15, 2),
               [("g", "G: 100 R; 100 k to GND", "L"), ("coil", "coil: 1N4007 across it, cathode to +12 V", "R")])
    _wire(d, elm, uno.a0, amp.out, SIGNAL, "0-5 V")
    for pin, mux in (("d8", "sa"), ("d9", "sb"), ("d10", "sc")):
        _wire(d, elm, getattr(uno, pin), getattr(amp, mux), SIGNAL)
    _wire(d, elm, uno.a1, amp.mout, SIGNAL, "monitor (MONITOR=1)")
    _wire(d, elm, uno.d7, fet.g, SIGNAL, "D7 high = light on", "|-")
    _wire(d, elm, uno.d6, sol.g, SIGNAL, "D6 high = reference in", "|-")
    _wire(d, elm, fet.dr, led.dim, SIGNAL, "", "-|")
    _wire(d, elm, psu.out, led.vin, POWER, "", "-")
    _wire(d, elm, led.out, lamp["in"], POWER, "350 mA", "-|")
    _wire(d, elm, uno.v5, amp.v5, POWER, "5 V; 100 nF + 10 uF at the op-amp and the 4051", "n", k=1.6)
    _wire(d, elm, uno.gnd, amp.gnd, GROUND, "star ground (the source's return apart)", "n", k=0.8)
    return {"uno": uno}


def dynamixel(d, elm) -> None:
    pc = _box(d, elm, (0, 8), "PC (gonio-capture)", (3, 3.2), [("u1", "USB", "R"), ("u2", "USB", "R")])
    u2d2 = _box(d, elm, (6, 12), "U2D2 (latency timer 1 ms)", (4, 2), [("usb", "USB", "L"), ("ttl", "TTL", "R")])
    hub = _box(d, elm, (13, 11.4), "U2D2 Power Hub", (4.5, 3.2),
               [("ttl", "TTL in", "L"), ("pwr", "12 V in", "B"), ("o1", "TTL/12 V out", "R")])
    s1 = _box(d, elm, (21, 12.8), "servo ID 1: light arm (XL430 / XM430)", (5, 2),
              [("a", "X3P", "L"), ("b", "X3P", "R")])
    s2 = _box(d, elm, (29, 12.8), "servo ID 2: detector arm", (5, 2), [("a", "X3P", "L")])
    psu = _box(d, elm, (13, 6.2), "12 V 5 A supply (in the box)", (4.5, 1.6), [("out", "+12 V / GND", "R")])
    estop = _box(d, elm, (20, 6.2), "emergency stop (NC, latching)", (4.5, 1.6), [("i", "in", "L"), ("o", "out", "T")])
    _wire(d, elm, pc.u1, u2d2.usb, USB, "/dev/serial/by-id/usb-FTDI...", "-|")
    _wire(d, elm, u2d2.ttl, hub.ttl, BUS, "TTL bus", "-|")
    _wire(d, elm, hub.o1, s1.a, BUS, "1 Mbaud", "-|")
    _wire(d, elm, s1.b, s2.a, BUS, "daisy chain", "-")
    _wire(d, elm, psu.out, estop.i, POWER)
    _wire(d, elm, estop.o, hub.pwr, POWER, "12 V after the stop", "n", k=1.2)
    det = detector_side(d, elm, 8, -2)
    _wire(d, elm, pc.u2, det["uno"].usb, USB, "/dev/serial/by-id/usb-Arduino...", "-|")


def grbl(d, elm) -> None:
    pc = _box(d, elm, (0, 8), "PC (gonio-capture)", (3, 3.2), [("u1", "USB", "R"), ("u2", "USB", "R")])
    uno = _box(d, elm, (6, 10), "GRBL 1.1: Uno + CNC shield v3 (drivers' EN on D8)", (6, 6),
               [("usb", "USB", "L"), ("x", "X socket (D2/D5)", "R"), ("y", "Y socket (D3/D6)", "R"),
                ("lx", "X limit (D9)", "R"), ("ly", "Y limit (D10)", "R"), ("pwr", "12-36 V", "B")])
    ends = {}
    for pin, title, label in (("x", "NEMA 17: light arm (5:1 belt)", "A+ A- B+ B-"),
                              ("y", "NEMA 17: detector arm (5:1 belt)", "A+ A- B+ B-"),
                              ("lx", "switch at the light arm's max_deg", "NC to GND"),
                              ("ly", "switch at the detector arm's max_deg", "NC to GND")):
        y = getattr(uno, pin)[1]
        x = 19.0 if pin in ("x", "y") else 27.0
        ends[pin] = _box(d, elm, (x, y - 0.35), title, (5, 0.7), [("a", label, "L")])
    _wire(d, elm, uno.x, ends["x"].a, MOTOR, "TMC2209 (Vref set first)")
    _wire(d, elm, uno.y, ends["y"].a, MOTOR, "TMC2209")
    _wire(d, elm, uno.lx, ends["lx"].a, SIGNAL, "$5=1: a broken wire reads pressed")
    _wire(d, elm, uno.ly, ends["ly"].a, SIGNAL)
    psu = _box(d, elm, (6, 4.6), "24 V 4.5 A supply (in the box)", (4.5, 1.6), [("out", "+24 V / GND", "R")])
    estop = _box(d, elm, (13, 4.6), "emergency stop (NC, latching)", (4.5, 1.6), [("i", "in", "L"), ("o", "out", "T")])
    _wire(d, elm, pc.u1, uno.usb, USB, "/dev/serial/by-id/usb-1a86...", "-|")
    _wire(d, elm, psu.out, estop.i, POWER, "", "-")
    _wire(d, elm, estop.o, uno.pwr, POWER, "motor supply after the stop", "|-")
    det = detector_side(d, elm, 8, -4)
    _wire(d, elm, pc.u2, det["uno"].usb, USB, "/dev/serial/by-id/usb-Arduino...", "-|")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python hardware/wiring/draw.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(REPO / "docs"), metavar="DIR", help="folder of the drawings (docs/)")
    ap.add_argument("--format", choices=("png", "svg"), default="png")
    args = ap.parse_args(argv)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import schemdraw
        import schemdraw.elements as elm
    except ImportError as e:
        print(f"draw: needs schemdraw ({e.name} is missing): pip install 'gonio-brdf[cad]'", file=sys.stderr)
        return 2
    schemdraw.use("matplotlib" if args.format == "png" else "svg")  # svg: the labels stay text
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, fn in (("dynamixel", dynamixel), ("grbl", grbl)):
        path = out / f"wiring-{name}.{args.format}"
        with schemdraw.Drawing(show=False) as d:
            d.config(fontsize=9, unit=2)
            fn(d, elm)
        d.save(str(path), dpi=110)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
