"""The parts of hardware/frontend/frontend.cir as a list: what the board is built from (the lines before the
netlist's ``--- simulation stimuli (not built) ---`` marker), each with its reference, kind, nodes and value.

Used by draw.py (the schematic is drawn from this list) and by tests/test_frontend_spice.py (the drawing and the
netlist name the same parts and values)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
NETLIST = HERE / "frontend.cir"
STIMULI_MARKER = "--- simulation stimuli (not built) ---"
_SUFFIX = {"t": 1e12, "g": 1e9, "meg": 1e6, "k": 1e3, "m": 1e-3, "u": 1e-6, "n": 1e-9, "p": 1e-12, "f": 1e-15}
_VALUE = re.compile(r"^([-+]?\d+(?:\.\d*)?(?:e[-+]?\d+)?)(meg|[tgkmunpf])?", re.IGNORECASE)


def spice_value(text: str) -> float:
    """A SPICE number with its scale suffix (``10k``, ``1meg``, ``100p``) as a float; ValueError if none."""
    m = _VALUE.match(text.strip())
    if not m:
        raise ValueError(f"not a SPICE number: {text!r}")
    return float(m.group(1)) * _SUFFIX.get((m.group(2) or "").lower(), 1.0)


@dataclass(frozen=True)
class Part:
    """One built part: ``ref`` (R3, C5, XU1, ...), ``kind`` (resistor, capacitor, photodiode, mcp6001, hc4051),
    ``nodes`` in the netlist's order and ``value`` (ohm or farad; None for a subcircuit)."""

    ref: str
    kind: str
    nodes: tuple[str, ...]
    value: float | None


def parts(path: Path = NETLIST) -> list[Part]:
    """The built parts of the netlist ``path`` in order (comments, directives and stimuli left out)."""
    out: list[Part] = []
    for raw in path.read_text(encoding="utf-8").splitlines():
        if STIMULI_MARKER in raw:
            break
        line = raw.split(";")[0].strip()
        if not line or line[0] in "*." or line.startswith("+"):
            continue
        words = line.split()
        ref = words[0]
        if ref[0] in "RrCc":
            out.append(Part(ref.upper(), "resistor" if ref[0] in "Rr" else "capacitor", tuple(words[1:3]),
                            spice_value(words[3])))
        elif ref[0] in "Xx":
            args = [w for w in words[1:] if "=" not in w and w != "params:"]
            out.append(Part(ref.upper(), args[-1].lower(), tuple(args[:-1]), None))
        else:
            raise ValueError(f"{path}: part {ref}: not a resistor, capacitor or subcircuit")
    return out


def feedback(path: Path = NETLIST) -> list[tuple[Part, Part]]:
    """The five ranges' (resistor, capacitor) pairs by range index: the parts between ``inn`` and ``y<k>``."""
    ps = parts(path)
    out = []
    for k in range(5):
        pair = {p.kind: p for p in ps if set(p.nodes) == {"inn", f"y{k}"}}
        if set(pair) != {"resistor", "capacitor"}:
            raise ValueError(f"{path}: range {k} has no resistor and capacitor between inn and y{k}")
        out.append((pair["resistor"], pair["capacitor"]))
    return out
