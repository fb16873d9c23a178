"""The principled material as a MaterialX document: one ``open_pbr_surface`` node (OpenPBR Surface, MaterialX
1.39's standard library) and its ``surfacematerial``.

Written with the standard library's XML writer (no runtime dependency); the test suite loads every file with the
``materialx`` package and validates it against the standard data libraries. What OpenPBR holds that our model
leaves at its defaults: transmission, subsurface, thin film, emission, anisotropy; ``coat_darkening`` is written
as 0 because the fitted model has no darkening under the coat (docs/formats.md).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from reconstruction.atomic import atomic_open
from reconstruction.principled.model import COLOUR_FIELDS, MODEL, MODEL_VERSION, PrincipledParams

__all__ = ["MATERIALX_VERSION", "materialx_document", "write_materialx", "safe_name"]

MATERIALX_VERSION = "1.39"


def safe_name(name: str, default: str = "material") -> str:
    """A MaterialX / Blender / glTF friendly identifier: letters, digits and underscores, not starting with a
    digit."""
    s = re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9_]", "_", name)).strip("_") or default
    return f"M_{s}" if s[0].isdigit() else s


def materialx_document(params: PrincipledParams, name: str, comment: str = "") -> str:
    """The ``.mtlx`` text of ``params`` with node names derived from ``name``."""
    base = safe_name(name)
    root = ET.Element("materialx", version=MATERIALX_VERSION)
    if comment:
        root.append(ET.Comment(f" {comment.replace('--', '-')} "))
    shader = ET.SubElement(root, "open_pbr_surface", name=f"SR_{base}", type="surfaceshader")
    d: dict[str, Any] = params.to_dict()
    for key, value in d.items():
        if key in COLOUR_FIELDS:
            ET.SubElement(shader, "input", name=key, type="color3", value=", ".join(f"{v:.6g}" for v in value))
        else:
            ET.SubElement(shader, "input", name=key, type="float", value=f"{value:.6g}")
    ET.SubElement(shader, "input", name="coat_darkening", type="float", value="0")
    mat = ET.SubElement(root, "surfacematerial", name=f"M_{base}" if not base.startswith("M_") else base,
                        type="material")
    ET.SubElement(mat, "input", name="surfaceshader", type="surfaceshader", nodename=f"SR_{base}")
    ET.indent(root)
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def write_materialx(path: str | Path, params: PrincipledParams, name: str, comment: str = "") -> dict[str, Any]:
    """Write the document atomically; returns the report's entry."""
    text = materialx_document(params, name, comment or f"{MODEL} {MODEL_VERSION} fitted by gonio-brdf")
    with atomic_open(Path(path), "w", encoding="utf-8") as fh:
        fh.write(text)
    return {"file": str(path), "node": "open_pbr_surface", "materialx_version": MATERIALX_VERSION,
            "not_carried": []}  # open_pbr_surface holds every parameter of the fitted model
