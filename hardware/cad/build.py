"""Build the bench's printed parts from ``hardware/cad/params.toml``: one STL (to print) and one STEP (to edit in
any CAD program) a part.

    python hardware/cad/build.py --out out/cad              # every part, STL and STEP
    python hardware/cad/build.py --out out/cad --only detector-tube --format stl
    python hardware/cad/build.py --list                     # the parts and what they are

Needs build123d (``pip install 'gonio-brdf[cad]'``). Exit status 2 (one line) without it or for a bad argument.
Print in black PETG, 0.2 mm layers, 4 perimeters; drill the detector aperture to 2.5 mm and the pinhole shim to
0.65 mm (docs/build-a-bench.md, Mechanics).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import params  # noqa: E402  (hardware/cad/params.py, beside this script)

DESCRIPTIONS = {
    "arm-xl430-light": "light arm on an XL430's horn (the collimator at 126/156 mm)",
    "arm-xl430-detector": "detector arm on an XL430's horn (the tube at 50/64 mm)",
    "arm-xm430-light": "light arm on an XM430's horn",
    "arm-xm430-detector": "detector arm on an XM430's horn",
    "arm-nema17-light": "light arm on a NEMA 17's 5 mm D shaft (set screw)",
    "arm-nema17-detector": "detector arm on a NEMA 17's 5 mm D shaft",
    "detector-tube": "field stop 13.5 mm, two baffles, aperture 2.5 mm at 70 mm from the axis, BPW34 pocket",
    "collimator-mount": "8 mm output aperture, seat of the f = 75 mm lens, pinhole plane at its focus, LED pocket",
    "laser-adapter": "holds the 12 mm alignment laser in the LED's pocket, on the beam's axis",
    "sample-holder": "three points in the rotation axis' plane; the sample pushed up against them; V grooves",
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python hardware/cad/build.py", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", metavar="DIR", help="folder for the files (made if missing)")
    ap.add_argument("--format", choices=("stl", "step", "both"), default="both")
    ap.add_argument("--only", metavar="PART", action="append", help="only this part (repeatable); see --list")
    ap.add_argument("--params", default=str(params.PARAMS_TOML),
                    help="the parameters (default hardware/cad/params.toml)")
    ap.add_argument("--list", action="store_true", help="list the parts and exit")
    args = ap.parse_args(argv)
    if args.list:
        for name, what in DESCRIPTIONS.items():
            print(f"{name:<22} {what}")
        return 0
    if not args.out:
        print("build: --out DIR is required (or --list)", file=sys.stderr)
        return 2
    unknown = sorted(set(args.only or ()) - set(DESCRIPTIONS))
    if unknown:
        print(f"build: --only: unknown part(s) {', '.join(unknown)}; see --list", file=sys.stderr)
        return 2
    try:
        import parts
        from build123d import export_step, export_stl
    except ImportError as e:
        print(f"build: needs build123d ({e.name} is missing): pip install 'gonio-brdf[cad]'", file=sys.stderr)
        return 2
    p = params.load(args.params)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, solid in parts.parts(p).items():
        if args.only and name not in args.only:
            continue
        written = []
        if args.format in ("stl", "both"):
            export_stl(solid, str(out / f"{name}.stl"), tolerance=0.02, angular_tolerance=0.2)
            written.append(f"{name}.stl")
        if args.format in ("step", "both"):
            export_step(solid, str(out / f"{name}.step"))
            written.append(f"{name}.step")
        bb = solid.bounding_box()
        print(f"{out}/{' '.join(written)}: {solid.volume / 1000:.1f} cm3, {bb.size.X:.0f} x {bb.size.Y:.0f} x "
              f"{bb.size.Z:.0f} mm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
