"""The printed bench's parameters (``hardware/cad/params.toml``) and the optics they make: the numbers the CAD
builds from and the bench files' optics keys are checked against (no CAD library needed here).

Collimator: the LED lights a pinhole of diameter p at the focus of a lens of focal length f; the beam leaves
through the output aperture (the beam's diameter D) with a half angle of divergence ``atan(p / 2f)``.
Detector: an aperture of diameter a at distance R from the rotation axis (on the photodiode) sees the solid angle
``2 pi (1 - cos atan(a / 2R))``; a field stop of diameter s, L in front of it, limits what it sees on the sample
to a disk of radius ``a/2 + (s/2 - a/2) R / L`` seen whole (and ``-a/2 + (s/2 + a/2) R / L`` in part).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

HERE = Path(__file__).resolve().parent
PARAMS_TOML = HERE / "params.toml"
CONFIGS = HERE.parents[1] / "configs"


def load(path: str | Path = PARAMS_TOML) -> dict[str, Any]:
    """The parameters as a nested dict (mm)."""
    with open(path, "rb") as fh:
        return tomllib.load(fh)


def divergence_deg(p: dict[str, Any]) -> float:
    """The collimated beam's half angle of divergence (deg)."""
    c = p["optics"]["collimator"]
    return math.degrees(math.atan(0.5 * c["pinhole_mm"] / c["lens_focal_mm"]))


def beam_diameter_mm(p: dict[str, Any]) -> float:
    """The beam's diameter (mm): the collimator's output aperture."""
    return float(p["optics"]["collimator"]["beam_mm"])


def solid_angle_sr(p: dict[str, Any]) -> float:
    """The detector's acceptance (sr) seen from the axis: its aperture's cone."""
    d = p["optics"]["detector"]
    return 2.0 * math.pi * (1.0 - math.cos(math.atan(0.5 * d["aperture_mm"] / d["distance_mm"])))


def field_of_view_mm(p: dict[str, Any]) -> tuple[float, float]:
    """(radius seen whole, radius seen at all) on the sample at normal view (mm)."""
    d = p["optics"]["detector"]
    a, s, r, l = 0.5 * d["aperture_mm"], 0.5 * d["field_stop_mm"], d["distance_mm"], d["field_stop_to_aperture_mm"]
    return a + (s - a) * r / l, -a + (s + a) * r / l


def bench_file_optics(p: dict[str, Any]) -> dict[str, float]:
    """The bench-file keys this printed bench stands for: ``[bench]``'s source_divergence_deg, beam_diameter_mm,
    sample_diameter_mm, detector_distance_mm and ``[detector]``'s solid_angle_sr."""
    return {"source_divergence_deg": divergence_deg(p), "beam_diameter_mm": beam_diameter_mm(p),
            "sample_diameter_mm": float(p["sample"]["diameter_mm"]),
            "detector_distance_mm": float(p["optics"]["detector"]["distance_mm"]), "solid_angle_sr": solid_angle_sr(p)}


def config_optics(path: str | Path) -> dict[str, float]:
    """The same keys as a bench file states them (solid_angle_sr also from aperture_half_angle_deg); keys it
    leaves out are left out."""
    with open(path, "rb") as fh:
        raw = tomllib.load(fh)
    out = {k: float(raw["bench"][k]) for k in ("source_divergence_deg", "beam_diameter_mm", "sample_diameter_mm",
                                              "detector_distance_mm") if k in raw.get("bench", {})}
    det = raw.get("detector", {})
    if "solid_angle_sr" in det:
        out["solid_angle_sr"] = float(det["solid_angle_sr"])
    elif "aperture_half_angle_deg" in det:
        out["solid_angle_sr"] = 2 * math.pi * (1 - math.cos(math.radians(det["aperture_half_angle_deg"])))
    return out


def mismatches(p: dict[str, Any], configs: str | Path = CONFIGS) -> list[str]:
    """Each printed bench file's (in ``configs``) optics key that differs from the parameters' by more than the
    tolerance."""
    want = bench_file_optics(p)
    tol = float(p["bench_files"]["tolerance"])
    bad = []
    for name in p["bench_files"]["printed"]:
        for k, v in config_optics(Path(configs) / name).items():
            if abs(v - want[k]) > tol * abs(want[k]):
                bad.append(f"configs/{name}: {k} = {v:.6g}, the printed bench's is {want[k]:.6g} "
                           f"(hardware/cad/params.toml)")
    return bad


if __name__ == "__main__":
    prm = load()
    for key, val in bench_file_optics(prm).items():
        print(f"{key} = {val:.6g}")
    whole, part = field_of_view_mm(prm)
    print(f"field of view on the sample: radius {whole:.2f} mm seen whole, {part:.2f} mm in part")
    problems = mismatches(prm)
    print("\n".join(problems) or "the printed bench files agree")
    sys.exit(1 if problems else 0)
