"""Draw the rooms of the three packages into docs/architecture.md (between its ``rooms`` markers).

The drawing is made from the tree itself: every package and room with its modules, and under each room what
its import contract (pyproject.toml, checked by lint-imports in the suite) forbids it. Run it after adding a
module or a room; ``--check`` exits 1 when the page is out of date (the suite runs it).

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


def drawing() -> str:
    """The text drawing of the three packages' rooms, modules and forbidden imports."""
    contracts = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    out: list[str] = []
    for pkg in ("acquisition", "simulator", "reconstruction"):
        top = _modules(REPO / pkg)
        lines = [f"{pkg}/: {', '.join(top)}"]
        for room in _rooms(REPO / pkg):
            name = f"{pkg}.{room.name}"
            sub = [r.name + "/" for r in _rooms(room)]
            lines.append("")
            lines.append(f"{room.name}/: {', '.join(_modules(room) + sub)}")
            banned = _forbidden(contracts, name)
            if banned:
                lines.append(f"  may not import: {', '.join(banned)}")
        banned = _forbidden(contracts, pkg)
        if banned:
            lines.append("")
            lines.append(f"the package may not import: {', '.join(banned)}")
        out += _box(pkg, lines, WIDTH) + [""]
    return "```text\n" + "\n".join(out).rstrip() + "\n```"


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
        if new != text:
            print(f"{DOC} is out of date: run .venv/bin/python scripts/draw_rooms.py", file=sys.stderr)
            return 1
        return 0
    DOC.write_text(new, encoding="utf-8")
    print(f"wrote the rooms into {DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
