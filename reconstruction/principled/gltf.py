"""The principled material on a sphere as a glTF 2.0 file (``.gltf``, JSON with the mesh embedded as a base64
buffer): metallic-roughness plus KHR_materials_ior, KHR_materials_specular, KHR_materials_clearcoat and
KHR_materials_sheen where they apply.

Mapping (docs/formats.md): baseColorFactor = base_weight base_color; metallicFactor = base_metalness;
roughnessFactor = specular_roughness (glTF's alpha is roughness^2 too); KHR_materials_ior.ior = the index whose F0
is specular_weight F0(specular_ior) (so specularFactor stays 1 and f90 is 1, as in our model);
KHR_materials_specular.specularColorFactor = specular_color (tints F0 of the dielectric, as ours); clearcoat =
coat_weight, coat_roughness (glTF's clearcoat has a fixed index of 1.5); sheenColorFactor = fuzz_weight fuzz_color,
sheenRoughnessFactor = fuzz_roughness (glTF's Charlie sheen is our fuzz lobe). Lost: the diffuse roughness, the
metal's F82 tint (glTF metals go to white at grazing by Schlick), the coat's index and tint.
"""

from __future__ import annotations

import base64
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from reconstruction.atomic import atomic_open
from reconstruction.principled import albedo as alb
from reconstruction.principled.model import MODEL, MODEL_VERSION, PrincipledParams

__all__ = ["gltf_document", "write_gltf", "sphere_mesh", "APPLY_THRESHOLD", "not_carried"]

#: a layer whose weight is below this is left out of the file (its extension does not apply)
APPLY_THRESHOLD = 1e-3


def sphere_mesh(n_lat: int = 32, n_lon: int = 64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A unit UV sphere (glTF's y up): positions (V, 3) float32 (also its normals) and triangle indices (T*3,)
    uint16, counter-clockwise seen from outside."""
    lat = np.linspace(0.0, math.pi, n_lat + 1)
    lon = np.linspace(0.0, 2.0 * math.pi, n_lon + 1)
    th, ph = np.meshgrid(lat, lon, indexing="ij")
    pos = np.stack([np.sin(th) * np.sin(ph), np.cos(th), np.sin(th) * np.cos(ph)], axis=-1).reshape(-1, 3)
    pos = pos.astype(np.float32)
    pos /= np.linalg.norm(pos, axis=-1, keepdims=True)
    i, j = np.meshgrid(np.arange(n_lat), np.arange(n_lon), indexing="ij")
    a = (i * (n_lon + 1) + j).ravel()
    b = a + n_lon + 1
    tris = np.concatenate([np.stack([a, b, a + 1], -1)[i.ravel() > 0],
                           np.stack([a + 1, b, b + 1], -1)[i.ravel() < n_lat - 1]])
    return pos, pos.copy(), tris.astype(np.uint16).ravel()


def _material(p: PrincipledParams, name: str) -> tuple[dict[str, Any], list[str]]:
    base = [float(np.clip(p.base_weight * c, 0.0, 1.0)) for c in p.base_color]
    mat: dict[str, Any] = {"name": name, "pbrMetallicRoughness": {
        "baseColorFactor": [*base, 1.0], "metallicFactor": float(p.base_metalness),
        "roughnessFactor": float(p.specular_roughness)}}
    ext: dict[str, Any] = {}
    ior = float(alb.ior_from_f0(min(p.specular_f0, 0.999)))
    ext["KHR_materials_ior"] = {"ior": ior}
    if any(c != 1.0 for c in p.specular_color):
        ext["KHR_materials_specular"] = {"specularFactor": 1.0, "specularColorFactor": [float(c) for c in
                                                                                        p.specular_color]}
    if p.coat_weight >= APPLY_THRESHOLD:
        ext["KHR_materials_clearcoat"] = {"clearcoatFactor": float(p.coat_weight),
                                          "clearcoatRoughnessFactor": float(p.coat_roughness)}
    if p.fuzz_weight >= APPLY_THRESHOLD:
        ext["KHR_materials_sheen"] = {"sheenColorFactor": [float(p.fuzz_weight * c) for c in p.fuzz_color],
                                      "sheenRoughnessFactor": float(p.fuzz_roughness)}
    mat["extensions"] = ext
    return mat, sorted(ext)


def not_carried(p: PrincipledParams) -> list[str]:
    """What of ``p`` a glTF file cannot carry (module docstring: Lost), each said with its value: empty when the
    file holds the material as fitted."""
    lost = []
    if p.base_diffuse_roughness >= 0.02:  # below, Lambert within a fraction of a per cent
        lost.append(f"base_diffuse_roughness {p.base_diffuse_roughness:.3g} (glTF's diffuse is Lambert)")
    if p.base_metalness >= APPLY_THRESHOLD and any(c != 1.0 for c in p.specular_color):
        lost.append("the metal's F82 tint (specular_color "
                    + ", ".join(f"{c:.3g}" for c in p.specular_color) + "; glTF metals go to white at grazing)")
    if p.coat_weight >= APPLY_THRESHOLD and abs(p.coat_ior - 1.5) > 1e-3:
        lost.append(f"coat_ior {p.coat_ior:.3g} (glTF's clearcoat has a fixed index of 1.5)")
    if p.coat_weight >= APPLY_THRESHOLD and any(c != 1.0 for c in p.coat_color):
        lost.append("coat_color " + ", ".join(f"{c:.3g}" for c in p.coat_color) + " (glTF's clearcoat is clear)")
    return lost


def gltf_document(p: PrincipledParams, name: str, extras: dict[str, Any] | None = None) -> dict[str, Any]:
    """The glTF JSON (a dict) of a sphere of radius 1 at the origin with the material ``p``."""
    pos, nrm, idx = sphere_mesh()
    blobs = [pos.tobytes(), nrm.tobytes(), idx.tobytes()]
    offsets = np.cumsum([0] + [len(b) for b in blobs])
    data = b"".join(blobs)
    data += b"\0" * (-len(data) % 4)
    mat, used = _material(p, name)
    lost = not_carried(p)
    doc: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": "gonio-brdf (principled material fit)",
                  "extras": {"model": MODEL, "model_version": MODEL_VERSION, **(extras or {}),
                             **({"not_carried": lost} if lost else {})}},
        "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"name": f"{name}_sphere", "mesh": 0}],
        "meshes": [{"name": f"{name}_sphere", "primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1},
                                                                "indices": 2, "material": 0, "mode": 4}]}],
        "materials": [mat],
        "buffers": [{"byteLength": len(data),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode("ascii")}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": int(offsets[0]), "byteLength": len(blobs[0]), "target": 34962},
            {"buffer": 0, "byteOffset": int(offsets[1]), "byteLength": len(blobs[1]), "target": 34962},
            {"buffer": 0, "byteOffset": int(offsets[2]), "byteLength": len(blobs[2]), "target": 34963}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": int(pos.shape[0]), "type": "VEC3",
             "min": [float(v) for v in pos.min(axis=0)], "max": [float(v) for v in pos.max(axis=0)]},
            {"bufferView": 1, "componentType": 5126, "count": int(nrm.shape[0]), "type": "VEC3"},
            {"bufferView": 2, "componentType": 5123, "count": int(idx.size), "type": "SCALAR"}],
    }
    if used:
        doc["extensionsUsed"] = used
    return doc


def write_gltf(path: str | Path, p: PrincipledParams, name: str, extras: dict[str, Any] | None = None
               ) -> dict[str, Any]:
    """Write the ``.gltf`` atomically; returns the report's entry (the extensions used, and ``not_carried``: what
    of the fitted material the format could not hold, :func:`not_carried`; also in the file's asset extras)."""
    doc = gltf_document(p, name, extras)
    with atomic_open(Path(path), "w", encoding="utf-8") as fh:
        fh.write(json.dumps(doc, indent=1, allow_nan=False) + "\n")
    return {"file": str(path), "extensions": doc.get("extensionsUsed", []), "not_carried": not_carried(p)}
