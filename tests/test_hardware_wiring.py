"""hardware/wiring/draw.py: each bench's wiring drawing names every board, pin and wire the guide's tables list."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

DETECTOR = {"A0", "A1", "MONITOR OUT", "monitor (MONITOR=1)", "D7", "D8", "D9", "D10", "D6", "5V", "GND", "OUT",
            "S0 (pin 11)", "S1 (pin 10)", "S2 (pin 9)",
            "BPW34, shielded cable", "monitor BPW34", "DIM", "VIN", "G: 100 R; 100 k to GND",
            "coil: 1N4007 across it, cathode to +12 V", "D7 high = light on", "D6 high = reference in"}
WANT = {
    "dynamixel": DETECTOR | {"U2D2 (latency timer 1 ms)", "U2D2 Power Hub", "TTL in", "12 V in", "X3P",
                             "servo ID 1: light arm (XL430 / XM430)", "servo ID 2: detector arm",
                             "emergency stop (NC, latching)", "12 V after the stop"},
    "grbl": DETECTOR | {"X socket (D2/D5)", "Y socket (D3/D6)", "X limit (D9)", "Y limit (D10)",
                        "NEMA 17: light arm (5:1 belt)", "NEMA 17: detector arm (5:1 belt)", "NC to GND",
                        "emergency stop (NC, latching)", "motor supply after the stop", "12-36 V"},
}


def test_each_bench_is_drawn_with_every_board_pin_and_wire(tmp_path):
    r = subprocess.run([sys.executable, str(REPO / "hardware" / "wiring" / "draw.py"), "--out", str(tmp_path),
                        "--format", "svg"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    for name, want in WANT.items():
        svg = (tmp_path / f"wiring-{name}.svg").read_text()
        labels = set(re.findall(r"<tspan[^>]*>([^<]+)</tspan>", svg))
        assert want <= labels, (name, sorted(want - labels))
        assert len(re.findall(r"<path", svg)) >= 30, name    # boxes, leads and wires drawn
    # the guide shows the drawings the script makes
    guide = (REPO / "docs" / "build-a-bench.md").read_text()
    for name in WANT:
        assert f"](wiring-{name}.png)" in guide and (REPO / "docs" / f"wiring-{name}.png").is_file()
    assert "python hardware/wiring/draw.py" in guide
