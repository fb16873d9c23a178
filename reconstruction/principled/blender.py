"""The principled material as a Blender Python script that builds it as a Principled BSDF (Blender 4.x and 5.0:
run it in Blender's Text Editor or ``blender --python M.py``; it assigns the material to the selected objects).

Mapping (docs/formats.md; Cycles' Principled BSDF layers sheen, coat, metal, specular and diffuse by albedo
scaling as our model does): Base Color = base_weight base_color; Metallic = base_metalness; Roughness =
specular_roughness; IOR = specular_ior and Specular IOR Level = specular_weight / 2 (0.5 leaves the index's F0);
Specular Tint = specular_color (F0 of the dielectric and the metal's F82 tint, as ours); Diffuse Roughness =
base_diffuse_roughness (Blender 4.3 and later); Coat Weight / Roughness / IOR / Tint = coat_*; Sheen Weight /
Roughness / Tint = fuzz_* (Blender's sheen is Zeltner's microfiber lobe, ours glTF's Charlie: of similar shape).
The distribution is set to single-scattering GGX, the lobe that was fitted ("Multiscatter GGX", Blender's default,
adds the energy of multiple scattering on rough surfaces). The script itself needs only ``bpy``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from reconstruction.atomic import atomic_open
from reconstruction.principled.materialx import safe_name
from reconstruction.principled.model import MODEL, MODEL_VERSION, PrincipledParams

__all__ = ["blender_script", "write_blender", "blender_inputs"]

_TEMPLATE = '''"""{title}

Builds the material {name!r} as a Principled BSDF and assigns it to the selected objects. Run it in Blender's
Text Editor (Run Script) or as `blender --python {file}`; importable: build_material() returns the material.
{summary}
"""

import bpy

NAME = {name!r}
INPUTS = {inputs}


def build_material(name=NAME):
    """The material (created, or rebuilt if it exists) with its Principled BSDF set from INPUTS."""
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    bsdf = next((n for n in nodes if n.type == "BSDF_PRINCIPLED"), None)
    if bsdf is None:
        bsdf = nodes.new("ShaderNodeBsdfPrincipled")
        out = next(n for n in nodes if n.type == "OUTPUT_MATERIAL")
        mat.node_tree.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    bsdf.distribution = "GGX"  # the single-scattering lobe that was fitted
    for key, value in INPUTS.items():
        if key in bsdf.inputs:  # "Diffuse Roughness" exists from Blender 4.3 on
            bsdf.inputs[key].default_value = value
    return mat


if __name__ == "__main__":
    material = build_material()
    for obj in bpy.context.selected_objects:
        if getattr(obj, "data", None) is not None and hasattr(obj.data, "materials"):
            obj.data.materials.clear()
            obj.data.materials.append(material)
'''


def blender_inputs(p: PrincipledParams) -> dict[str, Any]:
    """The Principled BSDF's input values (by Blender's input names) for ``p``."""
    def rgba(c: tuple[float, float, float], k: float = 1.0) -> tuple[float, float, float, float]:
        return (round(k * c[0], 6), round(k * c[1], 6), round(k * c[2], 6), 1.0)

    return {
        "Base Color": rgba(p.base_color, p.base_weight), "Metallic": round(p.base_metalness, 6),
        "Roughness": round(p.specular_roughness, 6), "IOR": round(p.specular_ior, 6),
        "Specular IOR Level": round(p.specular_weight / 2.0, 6), "Specular Tint": rgba(p.specular_color),
        "Diffuse Roughness": round(p.base_diffuse_roughness, 6),
        "Coat Weight": round(p.coat_weight, 6), "Coat Roughness": round(p.coat_roughness, 6),
        "Coat IOR": round(p.coat_ior, 6), "Coat Tint": rgba(p.coat_color),
        "Sheen Weight": round(p.fuzz_weight, 6), "Sheen Roughness": round(p.fuzz_roughness, 6),
        "Sheen Tint": rgba(p.fuzz_color),
    }


def blender_script(p: PrincipledParams, name: str, file_name: str = "material.py", summary: str = "") -> str:
    """The script's text."""
    inputs = "{\n" + "".join(f"    {k!r}: {v!r},\n" for k, v in blender_inputs(p).items()) + "}"
    return _TEMPLATE.format(title=f"{MODEL} {MODEL_VERSION} material fitted by gonio-brdf, as a Blender Principled "
                                  f"BSDF.", name=safe_name(name), file=file_name, inputs=inputs,
                            summary=summary.replace('"""', "'''"))


def write_blender(path: str | Path, p: PrincipledParams, name: str, summary: str = "") -> dict[str, Any]:
    """Write the script atomically; returns the report's entry."""
    text = blender_script(p, name, Path(path).name, summary)
    with atomic_open(Path(path), "w", encoding="utf-8") as fh:
        fh.write(text)
    return {"file": str(path), "node": "Principled BSDF", "distribution": "GGX",
            "not_carried": [] if p.base_diffuse_roughness < 1e-3 else [
                f"base_diffuse_roughness {p.base_diffuse_roughness:.3g} before Blender 4.3 (no Diffuse Roughness "
                "input there)"]}
