"""Draw the rooms of the three packages into docs/architecture.md (between its ``rooms`` markers) and as a
picture, docs/architecture.png (the packages as buildings, their rooms, what each room may not import, and how
bytes, files and tables flow between the lab, the packages and the tools that read the tables).

Both are made from the tree itself: every package and room with its modules, and under each room what its import
contract (pyproject.toml, checked by lint-imports in the suite) forbids it. Run it after adding a module or a room;
``--check`` exits 1 when the page or the picture is out of date (the suite runs it: the picture carries the text
drawing it was made from in its PNG metadata, so the check does not depend on how matplotlib renders).

    .venv/bin/python scripts/draw_rooms.py [--check]
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "architecture.md"
PNG = REPO / "docs" / "architecture.png"
PNG_KEY = "gonio-rooms"
BEGIN, END = "<!-- rooms:begin (scripts/draw_rooms.py) -->", "<!-- rooms:end -->"
WIDTH = 116


def _modules(folder: Path) -> list[str]:
    return sorted(p.stem for p in folder.glob("*.py") if p.stem != "__init__")


def _rooms(folder: Path) -> list[Path]:
    return sorted(p.parent for p in folder.glob("*/__init__.py"))


def _forbidden(contracts: list[dict], module: str) -> list[str]:
    out: list[str] = []
    for c in contracts:
        if module in c.get("source_modules", []):
            out += [m.removeprefix(module.split(".")[0] + ".") for m in c.get("forbidden_modules", [])]
    return out


def _box(title: str, lines: list[str], width: int) -> list[str]:
    inner = width - 4
    body = [ln for text in lines for ln in (textwrap.wrap(text, inner) or [""])]
    return ([f"+-- {title} " + "-" * max(0, width - len(title) - 6) + "+"]
            + [f"| {ln.ljust(inner)} |" for ln in body] + ["+" + "-" * (width - 2) + "+"])


Room = tuple[str, list[str], list[str]]  # name, modules (sub-rooms end in "/"), what it may not import


def layout() -> list[tuple[str, list[str], list[Room], list[str]]]:
    """Each package: its name, its top-level modules, its rooms and what the whole package may not import."""
    contracts = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    out = []
    for pkg in ("acquisition", "simulator", "reconstruction"):
        rooms = [(room.name, _modules(room) + [r.name + "/" for r in _rooms(room)],
                  _forbidden(contracts, f"{pkg}.{room.name}")) for room in _rooms(REPO / pkg)]
        out.append((pkg, _modules(REPO / pkg), rooms, _forbidden(contracts, pkg)))
    return out


def drawing() -> str:
    """The text drawing of the three packages' rooms, modules and forbidden imports."""
    out: list[str] = []
    for pkg, top, rooms, pkg_banned in layout():
        lines = [f"{pkg}/: {', '.join(top)}"]
        for name, modules, banned in rooms:
            lines.append("")
            lines.append(f"{name}/: {', '.join(modules)}")
            if banned:
                lines.append(f"  may not import: {', '.join(banned)}")
        if pkg_banned:
            lines.append("")
            lines.append(f"the package may not import: {', '.join(pkg_banned)}")
        out += _box(pkg, lines, WIDTH) + [""]
    return "```text\n" + "\n".join(out).rstrip() + "\n```"


# The picture: three buildings (packages) with their rooms, the lab beside them, the flows between.
_COLOURS = {"acquisition": "#dbe9f6", "simulator": "#f6e7d4", "reconstruction": "#dff0dc", "lab": "#eeeeee"}
_EDGES = {"acquisition": "#2f6690", "simulator": "#b5651d", "reconstruction": "#3a7d44", "lab": "#555555"}


def _room_boxes(ax, x: float, y_top: float, w: float, rooms: list[Room], pkg: str, cols: int = 1,
                line_h: float = 0.0098) -> float:
    """Draw rooms as boxes in ``cols`` columns from ``y_top`` down (axes units); return the lowest y used."""
    from matplotlib.patches import FancyBboxPatch

    col_w = (w - 0.01 * (cols - 1)) / cols
    chars = max(20, int(col_w * 265))
    y_cols = [y_top] * cols
    for name, modules, banned in rooms:
        c = y_cols.index(max(y_cols))
        body = textwrap.wrap(", ".join(modules), chars) or [""]
        ban = textwrap.wrap("may not import: " + ", ".join(banned), int(chars * 1.05)) if banned else []
        h = line_h * (1.5 + len(body) + len(ban)) + 0.012
        x0, y0 = x + c * (col_w + 0.01), y_cols[c] - h
        ax.add_patch(FancyBboxPatch((x0, y0), col_w, h, boxstyle="round,pad=0.002,rounding_size=0.006",
                                    fc="white", ec=_EDGES[pkg], lw=1.0, zorder=2))
        ax.text(x0 + 0.006, y0 + h - 0.005, f"{name}/", va="top", ha="left", fontsize=8.5, weight="bold",
                color=_EDGES[pkg], zorder=3)
        ax.text(x0 + 0.006, y0 + h - 0.006 - 1.4 * line_h, "\n".join(body), va="top", ha="left", fontsize=7,
                family="monospace", linespacing=1.25, zorder=3)
        if ban:
            ax.text(x0 + 0.006, y0 + 0.005, "\n".join(ban), va="bottom", ha="left", fontsize=6.5,
                    color="#a12a2a", style="italic", linespacing=1.25, zorder=3)
        y_cols[c] = y0 - 0.008
    return min(y_cols)


def _building(ax, x: float, y: float, w: float, h: float, pkg: str, subtitle: str) -> None:
    from matplotlib.patches import FancyBboxPatch, Polygon

    ax.add_patch(FancyBboxPatch((x, y), w, h, boxstyle="round,pad=0.003,rounding_size=0.01", fc=_COLOURS[pkg],
                                ec=_EDGES[pkg], lw=2, zorder=0))
    ax.add_patch(Polygon([(x - 0.004, y + h), (x + w / 2, y + h + 0.032), (x + w + 0.004, y + h)],
                         closed=True, fc=_EDGES[pkg], ec=_EDGES[pkg], alpha=0.85, zorder=0))
    ax.text(x + w / 2, y + h + 0.011, pkg, ha="center", va="center", fontsize=12, weight="bold", color="white")
    ax.text(x + 0.008, y + h - 0.008, subtitle, ha="left", va="top", fontsize=8, style="italic", color="#333333")


def _arrow(ax, xy_from: tuple[float, float], xy_to: tuple[float, float], label: str, colour: str = "#333333",
           dashed: bool = False, both: bool = False, at: tuple[float, float] | None = None,
           style: str = "arc3,rad=0") -> None:
    ax.annotate("", xy=xy_to, xytext=xy_from, zorder=4, arrowprops=dict(
        arrowstyle="<|-|>" if both else "-|>", color=colour, lw=1.6, ls="--" if dashed else "-",
        connectionstyle=style, mutation_scale=14, shrinkA=0, shrinkB=0))
    mx, my = at or ((xy_from[0] + xy_to[0]) / 2, (xy_from[1] + xy_to[1]) / 2)
    ax.text(mx, my, label, ha="center", va="center", fontsize=7.5, color=colour, zorder=5,
            bbox=dict(boxstyle="round,pad=0.25", fc="white", ec=colour, lw=0.6))


def picture(path: Path = PNG) -> None:
    """Draw the packages, their rooms, the lab and the flows between them into ``path`` (PNG, 1800 px wide)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    packs = {pkg: (top, rooms, banned) for pkg, top, rooms, banned in layout()}
    fig = plt.figure(figsize=(18, 13), dpi=100)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.axis("off")
    ax.text(0.5, 0.99, "gonio-brdf: the packages, their rooms and what flows between them", ha="center",
            va="top", fontsize=15, weight="bold")
    ax.text(0.5, 0.968, "made from the tree and pyproject.toml's import contracts by scripts/draw_rooms.py; "
            "red: what a room may not import", ha="center", va="top", fontsize=9, color="#555555")

    top_y, gap = 0.905, 0.075
    # the lab: what a lab builds and flashes
    lab = [(name, sorted(p.name for p in (REPO / name).iterdir() if not p.name.startswith((".", "__"))), [])
           for name in ("hardware", "firmware")]
    _room_boxes(ax, 0.022, top_y - 0.03, 0.156, lab, "lab")
    ax.text(0.1, 0.70, "the bench itself:\nlight arm and detector arm\n(Dynamixel servos or GRBL steppers),\n"
            "photodiode board on an Arduino\nor a spectrometer, a flat sample", ha="center", va="center",
            fontsize=8, color="#333333")
    bottoms = {}
    for pkg, (x, w, cols) in {
        "acquisition": (0.235, 0.345, 2),
        "simulator": (0.635, 0.35, 2),
    }.items():
        top, rooms, banned = packs[pkg]
        bottoms[pkg] = _room_boxes(ax, x + 0.008, top_y - 0.03, w - 0.016, [("(top)", top, banned)] + rooms,
                                   pkg, cols=cols)
    low = min(bottoms.values()) - 0.004
    _building(ax, 0.015, low, 0.17, top_y - low, "lab", "what a lab builds and flashes")
    _building(ax, 0.235, low, 0.345, top_y - low, "acquisition", "gonio-capture, gonio-align: drive the bench, "
              "capture slices")
    _building(ax, 0.635, low, 0.35, top_y - low, "simulator", "gonio-sim: the bench's bytes on pseudo-terminals, "
              "its physics")
    r_top = low - gap - 0.032
    top, rooms, banned = packs["reconstruction"]
    r_low = _room_boxes(ax, 0.243, r_top - 0.03, 0.734, [("(top)", top, banned)] + rooms, "reconstruction", cols=3)
    _building(ax, 0.235, r_low - 0.004, 0.75, r_top - r_low + 0.004, "reconstruction",
              "gonio-reconstruct: the base; imports neither of the others")

    _arrow(ax, (0.185, 0.80), (0.235, 0.80), "serial bytes\n(USB, RS-485)", both=True, at=(0.21, 0.835))
    _arrow(ax, (0.635, 0.80), (0.58, 0.80), "the same bytes\non pseudo-\nterminals", colour=_EDGES["simulator"],
           both=True, at=(0.6075, 0.845))
    band = low - gap / 2
    ax.plot([0.10, 0.10, 0.70], [low - 0.003, band, band], color="#777777", lw=1.6, ls="--", zorder=4)
    _arrow(ax, (0.70, band), (0.70, low), "firmware/detector's hex runs on simavr; hardware/frontend's ngspice "
           "table is the amplifier the emulated ADC reads", colour="#777777", dashed=True, at=(0.50, band))
    _arrow(ax, (0.30, low), (0.30, r_top), "slice CSV\n+ capture.json", colour=_EDGES["acquisition"],
           at=(0.30, band + 0.018))
    _arrow(ax, (0.93, low), (0.93, r_top), "imports the base\n(models, timing,\nschema)", colour=_EDGES["simulator"],
           dashed=True, at=(0.93, band + 0.005))
    _arrow(ax, (0.235, r_low + 0.12), (0.14, r_low + 0.12), "MERL, EXR, RGL, Zemax,\nMaterialX, glTF, "
           "Mitsuba,\nreports", colour=_EDGES["reconstruction"], at=(0.10, r_low + 0.17))
    ax.text(0.12, r_low + 0.12, "renderers, BRDF viewers,\noptics tools,\nartists' tools", ha="right",
            va="center", fontsize=9)
    floor = r_low - 0.03  # crop what the rooms did not use, keeping the scale
    ax.set_ylim(floor, 1)
    fig.set_size_inches(18, 13 * (1 - floor))
    fig.savefig(path, metadata={"Description": f"{PNG_KEY}\n{drawing()}"})
    plt.close(fig)


def _picture_source(path: Path) -> str | None:
    """The text drawing a picture was made from (its PNG metadata), or None."""
    from PIL import Image

    if not path.exists():
        return None
    desc = Image.open(path).info.get("Description", "")
    return desc.removeprefix(f"{PNG_KEY}\n") if desc.startswith(PNG_KEY) else None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="exit 1 if docs/architecture.md is out of date")
    args = ap.parse_args(argv)
    text = DOC.read_text(encoding="utf-8")
    if BEGIN not in text or END not in text:
        print(f"{DOC}: no {BEGIN} ... {END} markers", file=sys.stderr)
        return 2
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    new = f"{head}{BEGIN}\n{drawing()}\n{END}{tail}"
    if args.check:
        stale = [str(p) for p, ok in ((DOC, new == text), (PNG, _picture_source(PNG) == drawing())) if not ok]
        if stale:
            print(f"{' and '.join(stale)} out of date: run .venv/bin/python scripts/draw_rooms.py", file=sys.stderr)
            return 1
        return 0
    DOC.write_text(new, encoding="utf-8")
    picture(PNG)
    print(f"wrote the rooms into {DOC} and {PNG}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
