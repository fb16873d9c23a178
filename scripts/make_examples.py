"""Make the small example inputs of the README's tour (``examples/data/``), from the simulator:

* ``captures/matte-grey.csv``, ``captures/glossy-red.csv``: slice files of two materials, each captured by
  ``gonio-capture`` on the simulated bench (configs/simulated.toml with the material and a small plan changed),
  for ``gonio-reconstruct --batch examples/data/captures/``;
* ``other.csv``: a generic in-plane table as another instrument's software writes one (columns ``inc``, ``det``,
  ``value``, the reflectance factor pi f_r), converted from a simulated capture of a satin material;
* ``scan.bsdf``: a Zemax tabular BSDF (PlaneSymmetrical, XYZ) of a green paint on a coarse grid (what a scanning
  instrument gives: points anywhere on the hemisphere), tabulated from the simulator's material model;
* ``reference.bsdf``: the same paint as an RGL tensor file at a reduced resolution, the truth that
  ``gonio-compare`` judges the scan's reconstruction against.

Run from the repository root: ``.venv/bin/python scripts/make_examples.py [--out examples/data]`` (about 15 s).
The captures are seeded (the simulator's time jumps), so the values come out the same; only the wall-clock
column ``unix_time_s`` and the capture dates differ between runs.
"""

from __future__ import annotations

import argparse
import copy
import csv
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import tomli_w

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from reconstruction.core.models import Material  # noqa: E402
from reconstruction.formats import rgl, zemax  # noqa: E402
from reconstruction.formats.slicefile import read_slice  # noqa: E402

#: the materials: name -> [material] table
MATERIALS: dict[str, dict[str, Any]] = {
    "matte-grey": {"name": "matte-grey", "lobes": [{"type": "lambert", "albedo": [0.5, 0.5, 0.5]}]},
    "glossy-red": {"name": "glossy-red", "lobes": [
        {"type": "lambert", "albedo": [0.40, 0.05, 0.04]},
        {"type": "ggx", "alpha": 0.2, "specular": [0.9, 0.9, 0.9], "f0": 0.04}]},
    "satin": {"name": "satin", "lobes": [
        {"type": "lambert", "albedo": [0.30, 0.30, 0.25]},
        {"type": "ggx", "alpha": 0.3, "specular": [0.9, 0.9, 0.9], "f0": 0.04}]},
    "green-paint": {"name": "green-paint", "lobes": [
        {"type": "lambert", "albedo": [0.05, 0.30, 0.08]},
        {"type": "ggx", "alpha": 0.25, "specular": [0.9, 0.9, 0.9], "f0": 0.04}]},
}
#: the captures' plan: two incidences, 4 deg steps (a few seconds each on the simulated bench)
PLAN = {"theta_i_deg": [30.0, 60.0], "theta_o_min_deg": -80.0, "theta_o_max_deg": 80.0, "theta_o_step_deg": 4.0,
        "repeats": 2}
#: the scan's Zemax grid (degrees) and the reference's RGL resolution: small files
SCAN_GRID = {"incidence_deg": [0, 15, 30, 45, 60, 75], "azimuth_deg": list(range(0, 181, 15)),
             "radial_deg": [0, 2, 4, 6, 8, 10, 13, 16, 20, 25, 30, 40, 50, 60, 75, 90, 110, 130, 150, 170]}
REFERENCE_RESOLUTION = rgl.Resolution(n_theta_i=8, n_sample=24, n_vndf=24, n_ndf=64)


def capture(material: str, work: Path) -> Path:
    """Capture ``material`` on the simulated bench with :data:`PLAN` into ``work/material``; the slice file."""
    with open(REPO / "configs" / "simulated.toml", "rb") as fh:
        cfg = tomllib.load(fh)
    cfg = copy.deepcopy(cfg)
    cfg["material"] = MATERIALS[material]
    cfg["plan"] = {**cfg["plan"], **PLAN}
    config = work / f"{material}.toml"
    config.write_text(tomli_w.dumps(cfg), encoding="utf-8")
    folder = work / material
    r = subprocess.run([sys.executable, "-m", "acquisition.cli", "--config", config.name, "--out", material],
                       capture_output=True, text=True, cwd=work,  # the slice names the bench file as given
                       env={**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get(
                           "PYTHONPATH")]))})
    if r.returncode != 0:
        raise SystemExit(f"make_examples: the capture of {material} failed:\n{r.stdout}\n{r.stderr[-2000:]}")
    return folder / "slice.csv"


def write_generic(slice_path: Path, path: Path) -> None:
    """``slice_path`` as another instrument's table: incidence ``inc``, detector angle ``det``, and the
    reflectance factor pi f_r as ``value`` (one block per incidence, as such software writes it)."""
    s = read_slice(slice_path)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["inc", "det", "value"])
        rows = zip(s.theta_i_deg, s.theta_o_deg, s.values.reshape(len(s.theta_i_deg), -1)[:, 0], strict=True)
        for ti, to, v in sorted(rows, key=lambda r: (float(r[0]), float(r[1]))):
            w.writerow([f"{ti:g}", f"{to:g}", f"{math.pi * float(v):.6g}"])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=REPO / "examples" / "data", help="folder (default examples/data)")
    args = ap.parse_args(argv)
    out: Path = args.out
    (out / "captures").mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="gonio-examples-") as tmp:
        work = Path(tmp)
        for name in ("matte-grey", "glossy-red"):
            (out / "captures" / f"{name}.csv").write_bytes(capture(name, work).read_bytes())
        write_generic(capture("satin", work), out / "other.csv")
    paint = Material.from_dict(MATERIALS["green-paint"])
    note = ["green-paint (lambert + ggx alpha 0.25, f0 0.04): made by scripts/make_examples.py"]
    zemax.write(out / "scan.bsdf", paint.eval, ["R", "G", "B"], comments=note, **SCAN_GRID)
    rgl.write(out / "reference.bsdf", paint.eval, resolution=REFERENCE_RESOLUTION, description=note[0])
    for p in sorted(out.rglob("*")):
        if p.is_file():
            print(f"{p.relative_to(out)}: {p.stat().st_size:,} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
