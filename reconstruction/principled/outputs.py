"""``gonio-reconstruct --principled PARAMS.json --materialx M.mtlx --gltf M.gltf --blender M.py``: fit the closest
principled material to the reconstruction once, write each file asked for, and give the report its
``principled`` entry (the parameters, the model and how far it stays from the measurement)."""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

from reconstruction.atomic import atomic_open
from reconstruction.base import Reconstruction, ReconstructionError, offers

__all__ = ["FLAGS", "add_arguments", "check_arguments", "wants", "write_outputs"]

#: (flag, field of the Job / parsed command line, file suffix)
FLAGS = (("--principled", "principled", ".json"), ("--materialx", "materialx", ".mtlx"),
         ("--gltf", "gltf", ".gltf"), ("--blender", "blender", ".py"))


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The principled material's flags of gonio-reconstruct."""
    g = ap.add_argument_group("the closest principled material (OpenPBR Surface; docs/formats.md)")
    g.add_argument("--principled", metavar="PARAMS.json",
                   help="fit OpenPBR Surface parameters to the reconstruction (bounded, each in its documented "
                        "range) and write them with the model's name and version and how far the material stays "
                        "from the measurement (image error over the default views, cosl2)")
    g.add_argument("--materialx", metavar="MATERIAL.mtlx",
                   help="the fitted material as a MaterialX 1.39 document (an open_pbr_surface node)")
    g.add_argument("--gltf", metavar="MATERIAL.gltf",
                   help="a glTF 2.0 file of a sphere with the fitted material (metallic-roughness + "
                        "KHR_materials_ior/_specular/_clearcoat/_sheen where they apply)")
    g.add_argument("--blender", metavar="MATERIAL.py",
                   help="a Blender Python script that builds the fitted material as a Principled BSDF")


def wants(args: Any) -> bool:
    """True if a Job or parsed command line asks for any of the principled material's files."""
    return any(isinstance(getattr(args, key, None), str) and getattr(args, key) for _, key, _ in FLAGS)


def check_arguments(args: Any) -> None:
    """Each asked file: the right suffix, in an existing writable folder, not a folder itself; no two the same."""
    seen: dict[Path, str] = {}
    for flag, key, suffix in FLAGS:
        v = getattr(args, key, None)
        if not v:
            continue
        p = Path(v)
        if p.suffix.lower() != suffix:
            raise ReconstructionError(f"{flag} {p}: expected a file name ending in {suffix}")
        if p.is_dir():
            raise ReconstructionError(f"{flag} {p}: is a folder; give a file name ending in {suffix}")
        parent = p.parent if str(p.parent) else Path(".")
        if not parent.is_dir():
            raise ReconstructionError(f"{flag} {p}: the folder {parent} does not exist")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise ReconstructionError(f"{flag} {p}: the folder {parent} is not writable")
        r = p.resolve()
        if r in seen:
            raise ReconstructionError(f"{seen[r]} and {flag} name the same file {p}")
        seen[r] = flag


def write_outputs(args: Any, rec: Reconstruction, name: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """Fit the principled material to ``rec`` and write the files asked for. Returns (the report's ``outputs``
    entries, the report's ``principled`` entry)."""
    from reconstruction.principled.blender import write_blender
    from reconstruction.principled.fit import analytic_start, fit_principled
    from reconstruction.principled.gltf import write_gltf
    from reconstruction.principled.materialx import write_materialx

    # fitted analytic lobes (fit's lambert + GGX of a dielectric): a start the principled fit refines
    fitted = offers(rec, "fitted_parameters")
    fit = fit_principled(rec.eval, start=analytic_start(fitted()) if fitted is not None else None)
    entry = fit.to_dict()
    entry["fitted_to"] = f"the {rec.method} reconstruction"
    files: dict[str, Any] = {}
    t0 = time.perf_counter()
    if getattr(args, "principled", None):
        with atomic_open(Path(args.principled), "w", encoding="utf-8") as fh:
            fh.write(json.dumps(entry, indent=2, allow_nan=False) + "\n")
        files["principled"] = str(args.principled)
    if getattr(args, "materialx", None):
        files["materialx"] = write_materialx(args.materialx, fit.params, name, fit.sentence)
    if getattr(args, "gltf", None):
        files["gltf"] = write_gltf(args.gltf, fit.params, name, {"summary": fit.sentence})
    if getattr(args, "blender", None):
        files["blender"] = write_blender(args.blender, fit.params, name, fit.sentence)
    entry["export_seconds"] = round(time.perf_counter() - t0, 3)
    return files, entry
