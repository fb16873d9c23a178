"""The bench's parts list (``hardware/bom.csv``) checked and summed per variant.

    python hardware/bom.py                 # each variant's total (EUR, min-max), and the optional extras
    python hardware/bom.py --variant grbl  # that variant's lines, then its total
    python hardware/bom.py --markdown      # every line as a Markdown table (docs/build-a-bench.md's)
    python hardware/bom.py --csv FILE      # another parts list

Columns of the CSV: ``part``, ``role``, ``quantity``, ``example_part_number``, ``unit_eur_min``,
``unit_eur_max`` (a unit's price range, EUR), ``variants`` (space-separated: ``xl430``, ``xm430``, ``grbl``),
``optional`` (``yes``/``no``: an upgrade, summed apart), ``notes``. A line's cost is quantity x unit price.
Exit status 2 (one line naming the file, the row and the column) for a list that does not read.
"""

from __future__ import annotations

import argparse
import csv
import sys
from dataclasses import dataclass
from pathlib import Path

#: The bench variants: Dynamixel XL430 arms, Dynamixel XM430 arms, NEMA 17 steppers on GRBL.
VARIANTS = ("xl430", "xm430", "grbl")
COLUMNS = ("part", "role", "quantity", "example_part_number", "unit_eur_min", "unit_eur_max", "variants",
           "optional", "notes")
BOM_CSV = Path(__file__).resolve().parent / "bom.csv"


class BomError(ValueError):
    """A parts list that does not read; the message names the file, the row and the column."""


@dataclass(frozen=True)
class Line:
    """One line of the parts list; prices in EUR per unit."""

    part: str
    role: str
    quantity: int
    example_part_number: str
    unit_eur_min: float
    unit_eur_max: float
    variants: tuple[str, ...]
    optional: bool
    notes: str

    @property
    def eur_min(self) -> float:
        return self.quantity * self.unit_eur_min

    @property
    def eur_max(self) -> float:
        return self.quantity * self.unit_eur_max


def _number(src: str, row: int, col: str, text: str, kind: type) -> float:
    try:
        v = kind(text)
    except ValueError:
        raise BomError(f"{src}: row {row}: {col}: expected a{'n integer' if kind is int else ' number'}, "
                       f"got {text!r}") from None
    if v < 0 or (kind is int and v == 0):
        raise BomError(f"{src}: row {row}: {col}: must be {'>= 1' if kind is int else '>= 0'}, got {text!r}")
    return v


def load(path: str | Path = BOM_CSV) -> list[Line]:
    """The lines of the parts list at ``path``; raises :class:`BomError` naming the row and the column."""
    src = str(path)
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
            header = tuple(rows[0].keys()) if rows else ()
    except OSError as e:
        raise BomError(f"{src}: cannot read: {e.strerror or e}") from None
    if header != COLUMNS:
        raise BomError(f"{src}: row 1: expected the columns {','.join(COLUMNS)}, got {','.join(header) or 'none'}")
    out = []
    for k, r in enumerate(rows, start=2):
        if None in r or any(v is None for v in r.values()):
            raise BomError(f"{src}: row {k}: expected {len(COLUMNS)} columns")
        variants = tuple(r["variants"].split())
        bad = [v for v in variants if v not in VARIANTS]
        if not variants or bad:
            raise BomError(f"{src}: row {k}: variants: expected some of {' '.join(VARIANTS)}, got {r['variants']!r}")
        if r["optional"] not in ("yes", "no"):
            raise BomError(f"{src}: row {k}: optional: expected yes or no, got {r['optional']!r}")
        lo = _number(src, k, "unit_eur_min", r["unit_eur_min"], float)
        hi = _number(src, k, "unit_eur_max", r["unit_eur_max"], float)
        if hi < lo:
            raise BomError(f"{src}: row {k}: unit_eur_max: {hi:g} is below unit_eur_min {lo:g}")
        if not r["part"].strip() or not r["role"].strip():
            raise BomError(f"{src}: row {k}: part and role must not be empty")
        out.append(Line(r["part"], r["role"], int(_number(src, k, "quantity", r["quantity"], int)),
                        r["example_part_number"], lo, hi, variants, r["optional"] == "yes", r["notes"]))
    return out


def totals(lines: list[Line], optional: bool = False) -> dict[str, tuple[float, float]]:
    """{variant: (min, max) EUR} over the lines that variant uses: the required ones, or (``optional``) the
    optional upgrades."""
    return {v: (sum(x.eur_min for x in lines if v in x.variants and x.optional == optional),
                sum(x.eur_max for x in lines if v in x.variants and x.optional == optional)) for v in VARIANTS}


def summary(lines: list[Line]) -> str:
    """What ``python hardware/bom.py`` prints: one line a variant (the guide quotes it)."""
    req, opt = totals(lines), totals(lines, optional=True)
    out = ["variant  lines  total EUR      optional extras EUR"]
    for v in VARIANTS:
        n = sum(1 for x in lines if v in x.variants and not x.optional)
        out.append(f"{v:<8} {n:>5}  {req[v][0]:>5.0f} - {req[v][1]:<5.0f}  {opt[v][0]:>4.0f} - {opt[v][1]:.0f}")
    return "\n".join(out)


def markdown(lines: list[Line]) -> str:
    """Every line as a Markdown table (what docs/build-a-bench.md shows under Parts from bom.csv)."""
    out = ["| part | role | qty | example | EUR each | benches |", "|---|---|---|---|---|---|"]
    for x in lines:
        benches = "all" if set(x.variants) == set(VARIANTS) else ", ".join(x.variants)
        opt = " (optional)" if x.optional else ""
        out.append(f"| {x.part}{opt} | {x.role} | {x.quantity} | {x.example_part_number} | "
                   f"{x.unit_eur_min:g}-{x.unit_eur_max:g} | {benches} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python hardware/bom.py", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--csv", default=str(BOM_CSV), help="the parts list (default: hardware/bom.csv)")
    p.add_argument("--variant", choices=VARIANTS, help="list that variant's lines before the totals")
    p.add_argument("--markdown", action="store_true", help="print every line as a Markdown table (the guide's)")
    args = p.parse_args(argv)
    try:
        lines = load(args.csv)
    except BomError as e:
        print(f"bom: {e}", file=sys.stderr)
        return 2
    if args.markdown:
        print(markdown(lines))
        return 0
    if args.variant:
        for x in lines:
            if args.variant in x.variants:
                opt = " (optional)" if x.optional else ""
                print(f"{x.quantity:>3} x {x.part}{opt}: {x.role}; e.g. {x.example_part_number}; "
                      f"{x.eur_min:g}-{x.eur_max:g} EUR")
        print()
    print(summary(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
