"""Outputs beyond the MERL table: RGL ``.bsdf``, Zemax ``.bsdf``, a Mitsuba 3 BSDF fragment, the parameters as
JSON, and a preview rendered by Mitsuba 3; the ``gonio-reconstruct`` flags that ask for them.

Mitsuba 3 fragment (``--export-mitsuba MATERIAL.xml``): a ``<bsdf version="3.0.0" id="NAME">`` element a scene can
``<include>`` and ``<ref>``. Where the fitted model *maps*, i.e. a Mitsuba plugin evaluates the same function:

* ``lambert`` -> ``diffuse`` (reflectance = albedo);
* a microfacet lobe without Fresnel (``fit`` lobes ``ggx`` / ``beckmann``) -> ``roughconductor`` with
  ``material="none"`` (F = 1), the same ``distribution`` and ``alpha``, ``specular_reflectance`` = the lobe's
  specular colour (Mitsuba's separable Smith G1 is ours, Walter's rational approximation for Beckmann included);
* a GGX lobe with Schlick's Fresnel (``fit``'s ``ggx(F)``) and a grey specular colour ks -> ``principled`` with
  ``metallic`` 1 (its Fresnel is then Schlick's with F0 = ``base_color`` = f0, its D and G are GGX with separable
  Smith G1, alpha = ``roughness``^2; diffuse, sheen, clearcoat and transmission off), blended with a black
  ``diffuse`` for the scale ks (a principled lobe has no colour scale, so a coloured ks does not map);
* the ``microfacet`` method: every GGX term of its NDF mixture -> a ``roughconductor`` of its alpha with the
  fitted Fresnel (``none``; a dielectric of index eta as a conductor with k = 0, whose Fresnel equations are the
  dielectric's; a conductor eta + i kappa), ``specular_reflectance`` = ks w_j;
* a sum of lobes -> nested ``blendbsdf`` (weight = the share of the right branch's amplitudes), the leaves'
  colours scaled so the blend adds exactly to the sum; when the amplitudes add to more than 1 a leaf colour is an
  ``srgb`` spectrum with ``unbounded`` set, and a comment in the fragment says why (a blend weighs its branches
  by 1 - weight and weight, so a branch holds its lobes' amplitudes over its weight: the demo's albedo 0.14
  beside a GGX lobe of scale 0.91 is a diffuse reflectance of 0.14 / 0.09 = 1.58 in a blend of weight 0.91).
  The report's ``mitsuba.not_carried`` lists what the fragment cannot hold (empty where the model maps).

``roughplastic`` is not used: its diffuse term is Fresnel-transmitted and internally reflected, which none of
our lobes is. A Beckmann lobe with Schlick's Fresnel, a Schlick lobe with a coloured specular, amplitudes adding
to more than 1 with a Schlick lobe, a retro lobe or a data-driven method does not map: the fragment is then a
``measured`` BSDF referring to the RGL file (written beside it if ``--rgl`` is not given).

Parameters (``--export-json PARAMS.json``), schema ``gonio-brdf/parameters/1`` (docs/parameters.schema.json)::

    {"schema": "gonio-brdf/parameters/1", "method": "fit", "model": "lambert+ggx(F)", "channels": ["R", "G", "B"],
     "units": {"f": "1/sr", "angles": "deg"}, "analytic": true,
     "lobes": [{"type": "lambert", "albedo": [..]},
               {"type": "ggx", "alpha": 0.15, "specular": [..], "fresnel": {"kind": "schlick", "f0": 0.04, "ior": 1.5}},
               {"type": "retro", "exponent": 8.0, "amount": [..]},
               {"type": "ggx_mixture", "terms": [{"alpha": .., "weight": ..}], "specular": [..],
                "fresnel": {"kind": "none" | "dielectric" | "conductor", "eta": .., "kappa": ..}}],
     "uncertainties": {...}, "formula": "...", "mitsuba": {"maps": true, "plugins": [..]}}
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np
from numpy.typing import NDArray

from reconstruction.atomic import atomic_open
from reconstruction.base import Reconstruction, ReconstructionError, offers

Array = NDArray[np.float64]

__all__ = ["SCHEMA", "add_arguments", "check_arguments", "wants_outputs", "asks_output", "OTHER_OUTPUTS",
           "write_outputs", "parameters",
           "mitsuba_fragment", "render_mitsuba_preview", "MitsubaMissing", "require_mitsuba"]

SCHEMA = "gonio-brdf/parameters/1"
FORMULAS = {
    "lambert": "albedo / pi",
    "ggx": "specular F(theta_d) D(h) G1(wi) G1(wo) / (4 cos theta_i cos theta_o), GGX D and separable Smith G1; "
           "F = Schlick f0 + (1 - f0)(1 - cos theta_d)^5 or 1 without Fresnel",
    "beckmann": "as ggx with the Beckmann D and Walter's rational Smith G1",
    "retro": "amount (n + 2) / (2 pi) max(0, wi . wo)^n, n = exponent",
    "ggx_mixture": "specular F(theta_d) sum_j weight_j D_j(h) G1_j(wi) G1_j(wo) / (4 cos theta_i cos theta_o), "
                   "exact unpolarised Fresnel of eta (+ i kappa)",
}


class MitsubaMissing(ReconstructionError):
    """The mitsuba package is not installed; the message says how to install it."""


def require_mitsuba(flag: str) -> Any:
    """Import mitsuba with the scalar_rgb variant; :class:`MitsubaMissing` with one line if it is not installed."""
    try:
        import mitsuba as mi
    except ImportError:
        raise MitsubaMissing(f"{flag} needs Mitsuba 3, which is not installed: pip install 'gonio-brdf[mitsuba]' "
                             f"(or pip install mitsuba)") from None
    mi.set_variant("scalar_rgb")
    return mi


# --- command line ----------------------------------------------------------------------------------------


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The format flags of gonio-reconstruct."""
    g = ap.add_argument_group("other formats (docs/formats.md)")
    g.add_argument("--rgl", metavar="MATERIAL.bsdf",
                   help="also write an RGL tensor file (Dupuy & Jakob 2018) for Mitsuba 3's measured plugin")
    g.add_argument("--zemax", metavar="MATERIAL.bsdf",
                   help="also write a Zemax tabular BSDF (PlaneSymmetrical BRDF, TIS per incidence) on the grid of "
                        "--zemax-incidences / --zemax-azimuths / --zemax-radials")
    g.add_argument("--zemax-incidences", metavar="DEGREES", default=None,
                   help="Zemax output incidences, e.g. 0,15,30,45,60,75 (default: 0:45:5,50:87.5:2.5)")
    g.add_argument("--zemax-azimuths", metavar="DEGREES", default=None,
                   help="Zemax output azimuths about the specular direction, 0 to 180 (default 0:180:5)")
    g.add_argument("--zemax-radials", metavar="DEGREES", default=None,
                   help="Zemax output radial angles from the specular direction, from 0 (default: 0.25 deg steps "
                        "near 0, 5 deg beyond 20, to 180)")
    g.add_argument("--export-mitsuba", metavar="MATERIAL.xml",
                   help="a Mitsuba 3 <bsdf> fragment: diffuse / roughconductor / principled in a blendbsdf with the "
                        "fitted parameters where the model maps exactly, else a measured BSDF referring to the RGL "
                        "file (written beside the XML if --rgl is not given)")
    g.add_argument("--export-json", metavar="PARAMS.json",
                   help="the model's parameters in the documented schema gonio-brdf/parameters/1")
    g.add_argument("--preview-renderer", choices=("builtin", "mitsuba"), default="builtin",
                   help="--preview rendered by the built-in point-light renderer (default) or by Mitsuba 3 with "
                        "the RGL file under an environment map (pip install 'gonio-brdf[mitsuba]')")
    from reconstruction.principled.outputs import add_arguments as add_principled_arguments

    add_principled_arguments(ap)


def _check_file(path: str, suffix: str, flag: str) -> None:
    p = Path(path)
    if p.suffix.lower() != suffix:
        raise ReconstructionError(f"{flag} {p}: expected a file name ending in {suffix}")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise ReconstructionError(f"{flag} {p}: the folder {parent} does not exist")


def wants_outputs(args: Any) -> bool:
    """True if any format field (``rgl``, ``zemax``, ``export_mitsuba``, ``export_json`` of a
    :class:`~reconstruction.job.Job` or parsed command line, or a principled material's) asks for a file."""
    from reconstruction.principled.outputs import wants

    return any(getattr(args, k, None) for k in ("rgl", "zemax", "export_mitsuba", "export_json")) or wants(args)


#: the outputs besides the MERL table (flags without the dashes): asking for any makes --out optional
OTHER_OUTPUTS = ("preview", "html", "report", "rgl", "zemax", "export_mitsuba", "export_json", "uncertainty",
                 "principled", "materialx", "gltf", "blender")


def asks_output(args: Any) -> bool:
    """True if a :class:`~reconstruction.job.Job` or parsed command line asks for any file besides the MERL
    table (:data:`OTHER_OUTPUTS`, each a file name: a bare ``--html`` is the batch's): then ``--out`` is
    optional, the table being computed for them either way."""
    return any(isinstance(getattr(args, k, None), str) and getattr(args, k) for k in OTHER_OUTPUTS)


def zemax_grid(args: Any) -> tuple[Array, Array, Array]:
    """(incidences, azimuths, radial angles) in degrees of the Zemax output: the ``zemax_*`` fields, validated,
    or the defaults."""
    from reconstruction.formats import zemax

    grid = (
        zemax.parse_angle_list(args.zemax_incidences, 0.0, 89.9, "--zemax-incidences")
        if getattr(args, "zemax_incidences", None) else zemax.DEFAULT_INCIDENCES_DEG,
        zemax.parse_angle_list(args.zemax_azimuths, 0.0, 180.0, "--zemax-azimuths")
        if getattr(args, "zemax_azimuths", None) else zemax.DEFAULT_AZIMUTHS_DEG,
        zemax.parse_angle_list(args.zemax_radials, 0.0, 180.0, "--zemax-radials")
        if getattr(args, "zemax_radials", None) else zemax.DEFAULT_RADIALS_DEG)
    az, rad = grid[1], grid[2]
    if az[0] != 0.0 or az[-1] != 180.0:
        raise ReconstructionError(f"--zemax-azimuths: a plane-symmetric grid runs from 0 to 180 deg, got {az[0]:g} "
                                  f"to {az[-1]:g}")
    if rad[0] != 0.0:
        raise ReconstructionError(f"--zemax-radials: the first radial angle must be 0 (the specular direction), "
                                  f"got {rad[0]:g}")
    return grid


def check_arguments(args: Any) -> None:
    """Validate the format fields before any work (file names, folders, grids, mitsuba when it is needed)."""
    for flag, key, suffix in (("--rgl", "rgl", ".bsdf"), ("--zemax", "zemax", ".bsdf"), ("--export-mitsuba",
                              "export_mitsuba", ".xml"), ("--export-json", "export_json", ".json")):
        v = getattr(args, key, None)
        if v:
            _check_file(v, suffix, flag)
    if getattr(args, "rgl", None) and getattr(args, "zemax", None) and Path(args.rgl) == Path(args.zemax):
        raise ReconstructionError(f"--rgl and --zemax name the same file {args.rgl}")
    zemax_grid(args)
    from reconstruction.principled.outputs import check_arguments as check_principled

    check_principled(args)
    if getattr(args, "preview_renderer", "builtin") == "mitsuba":
        if not getattr(args, "preview", None):
            raise ReconstructionError("--preview-renderer mitsuba renders --preview MATERIAL.exr; give --preview")
        require_mitsuba("--preview-renderer mitsuba")


def write_outputs(args: Any, rec: Reconstruction, timings: dict[str, float]) -> dict[str, Any]:
    """Write every file the format flags ask for; returns the report's entries (and fills ``timings``)."""
    import time

    from reconstruction.formats import rgl, zemax

    out: dict[str, Any] = {}
    channels = list(rec.channels)
    rgl_path = getattr(args, "rgl", None)
    if getattr(args, "export_mitsuba", None) and not rgl_path and not _maps(rec)[0]:
        beside = Path(args.export_mitsuba).with_suffix(".bsdf")  # the measured fallback needs one
        if getattr(args, "zemax", None) and Path(args.zemax).resolve() == beside.resolve():
            beside = beside.with_name(beside.stem + "-rgl.bsdf")
        rgl_path = str(beside)
    if rgl_path:
        t0 = time.perf_counter()
        out["rgl"] = rgl.write(rgl_path, rec.eval, description=f"gonio-brdf {rec.method}")
        timings["rgl"] = time.perf_counter() - t0
    if getattr(args, "zemax", None):
        t0 = time.perf_counter()
        inc, az, rad = zemax_grid(args)
        out["zemax"] = zemax.write(args.zemax, rec.eval, channels, incidence_deg=inc, azimuth_deg=az,
                                   radial_deg=rad, comments=[f"gonio-brdf {rec.method} reconstruction, BRDF in 1/sr",
                                                             "angles in degrees about the specular direction"])
        timings["zemax"] = time.perf_counter() - t0
    if getattr(args, "export_mitsuba", None):
        xml, info = mitsuba_fragment(rec, Path(args.export_mitsuba).stem,
                                     _relative(rgl_path, args.export_mitsuba) if rgl_path else None)
        with atomic_open(args.export_mitsuba, "w", encoding="utf-8") as fh:
            fh.write(xml)
        out["mitsuba"] = {"xml": str(args.export_mitsuba), **info}
    if getattr(args, "export_json", None):
        params = parameters(rec)
        with atomic_open(args.export_json, "w", encoding="utf-8") as fh:
            fh.write(json.dumps(params, indent=2, allow_nan=False) + "\n")
        out["parameters_json"] = str(args.export_json)
    return out


def _relative(target: str, beside: str) -> str:
    """``target`` relative to the folder of ``beside`` (Mitsuba resolves filenames against the XML's folder)."""
    return os.path.relpath(Path(target).resolve(), Path(beside).resolve().parent)


# --- parameters ------------------------------------------------------------------------------------------


def _lobes(rec: Reconstruction) -> list[dict[str, Any]] | None:
    """The model's lobes in the JSON schema's form, or None for a data-driven method (one that does not offer
    ``analytic_lobes``, :class:`reconstruction.base.AnalyticLobes`)."""
    lobes = offers(rec, "analytic_lobes")
    return lobes() if lobes is not None else None


def parameters(rec: Reconstruction) -> dict[str, Any]:
    """The reconstruction's parameters in schema :data:`SCHEMA` (JSON-ready)."""
    from reconstruction.report.summary import _json_safe

    lobes = _lobes(rec)
    rep = rec.report()
    maps, plugins, why = _maps(rec)
    out: dict[str, Any] = {"schema": SCHEMA, "method": rec.method, "model": rep.get("model"),
                           "channels": list(rec.channels), "units": {"f": "1/sr", "angles": "deg", "alpha": "GGX or "
                                                                     "Beckmann roughness (dimensionless)"},
                           "analytic": lobes is not None, "lobes": lobes or [],
                           "formula": "f(wi, wo) = sum of the lobes: " + "; ".join(
                               f"{k}: {FORMULAS[k]}" for k in dict.fromkeys(lb["type"] for lb in lobes or []))
                           if lobes else "data-driven: no closed form; use the MERL or RGL file",
                           "mitsuba": {"maps": maps, "plugins": plugins, "reason": why}}
    fitted = offers(rec, "fitted_parameters")
    if fitted is not None and fitted():
        out["uncertainties"] = fitted()  # per lobe, with <key>_std
    return _json_safe(out)


# --- Mitsuba 3 -------------------------------------------------------------------------------------------


def _maps(rec: Reconstruction) -> tuple[bool, list[str], str]:
    """(maps exactly, Mitsuba plugins used, why) for ``rec``."""
    lobes = _lobes(rec)
    if lobes is None:
        return False, ["measured"], f"{rec.method} is data-driven: no analytic BSDF"
    for lb in lobes:
        if lb["type"] == "retro":
            return False, ["measured"], "a retro lobe has no Mitsuba 3 counterpart"
        if lb.get("fresnel", {}).get("kind") == "schlick":
            col = _rgb(lb["specular"])
            if lb["type"] != "ggx":
                return False, ["measured"], ("Schlick's Fresnel on a Beckmann lobe has no Mitsuba 3 counterpart "
                                             "(principled is GGX only)")
            if float(np.ptp(col)) > 1e-6 * max(float(np.max(col)), 1e-300):
                return False, ["measured"], ("Schlick's Fresnel maps to principled (metallic 1) only with a grey "
                                             "specular colour; this lobe's is coloured")
    leaves = _leaves(lobes)
    schlick = [c for p, c, _ in leaves if p == "principled"]
    if len(schlick) > 1:
        return False, ["measured"], "two Schlick lobes cannot both take a blend weight as their scale"
    if schlick and len(leaves) > 1 and float(np.max(schlick[0])) >= 1.0 - 1e-12:
        return False, ["measured"], ("a Schlick lobe of specular 1 leaves no blend weight for the other lobes "
                                     "(principled has no colour scale)")
    plugins = {p for p, _, _ in leaves}
    if len(leaves) > 1 or (schlick and float(np.max(schlick[0])) < 1.0 - 1e-12):
        plugins.add("blendbsdf")
    if schlick and len(leaves) == 1 and float(np.max(schlick[0])) < 1.0 - 1e-12:
        plugins.add("diffuse")  # the scale of a lone principled lobe: a blend with a black diffuse
    plugins = sorted(plugins)
    return True, plugins, "the model maps exactly"


def _leaves(lobes: list[dict[str, Any]]) -> list[tuple[str, Array, dict[str, Any]]]:
    """(plugin, colour (3,), properties) of every additive term of the model."""
    out: list[tuple[str, Array, dict[str, Any]]] = []
    for lb in lobes:
        if lb["type"] == "lambert":
            out.append(("diffuse", _rgb(lb["albedo"]), {}))
        elif lb["type"] in ("ggx", "beckmann") and lb["fresnel"]["kind"] == "schlick":
            out.append(("principled", _rgb(lb["specular"]), {"alpha": lb["alpha"], "f0": lb["fresnel"]["f0"]}))
        elif lb["type"] in ("ggx", "beckmann"):
            out.append(("roughconductor", _rgb(lb["specular"]),
                        {"distribution": lb["type"], "alpha": lb["alpha"], "fresnel": {"kind": "none"}}))
        elif lb["type"] == "ggx_mixture":
            for t in lb["terms"]:
                out.append(("roughconductor", _rgb(lb["specular"]) * t["weight"],
                            {"distribution": "ggx", "alpha": t["alpha"], "fresnel": lb["fresnel"]}))
    return [leaf for leaf in out if float(np.max(leaf[1])) > 0]


def _rgb(v: Any) -> Array:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    return np.repeat(a, 3) if a.size == 1 else a


def _colour_xml(name: str, c: Array, pad: str) -> str:
    val = ", ".join(f"{x:.9g}" for x in c)
    if np.all(c <= 1.0) and np.all(c >= 0.0):
        return f'{pad}<rgb name="{name}" value="{val}"/>'
    return (f'{pad}<spectrum type="srgb" name="{name}"><rgb name="color" value="{val}"/>'
            f'<boolean name="unbounded" value="true"/></spectrum>')


def _leaf_xml(plugin: str, colour: Array, props: dict[str, Any], pad: str) -> list[str]:
    if plugin == "principled":  # grey colour: its value is the lobe's scale, applied by a blend with black
        scale = float(np.max(colour))
        f0 = props["f0"]
        lobe = [f'{pad}<bsdf type="principled">',
                f'{pad}    <rgb name="base_color" value="{f0:.9g}, {f0:.9g}, {f0:.9g}"/>',
                f'{pad}    <float name="metallic" value="1"/>',
                f'{pad}    <float name="roughness" value="{math.sqrt(props["alpha"]):.9g}"/>', f"{pad}</bsdf>"]
        if scale >= 1.0 - 1e-12:
            return lobe
        inner = ["    " + x for x in lobe]
        return [f'{pad}<bsdf type="blendbsdf">', f'{pad}    <float name="weight" value="{scale:.12g}"/>',
                f'{pad}    <bsdf type="diffuse"><rgb name="reflectance" value="0, 0, 0"/></bsdf>', *inner,
                f"{pad}</bsdf>"]
    if plugin == "diffuse":
        return [f'{pad}<bsdf type="diffuse">', _colour_xml("reflectance", colour, pad + "    "), f"{pad}</bsdf>"]
    lines = [f'{pad}<bsdf type="roughconductor">',
             f'{pad}    <string name="distribution" value="{props["distribution"]}"/>',
             f'{pad}    <float name="alpha" value="{props["alpha"]:.9g}"/>']
    fr = props["fresnel"]
    if fr["kind"] == "none":
        lines.append(f'{pad}    <string name="material" value="none"/>')
    else:
        lines.append(f'{pad}    <float name="eta" value="{fr["eta"]:.9g}"/>')
        lines.append(f'{pad}    <float name="k" value="{fr.get("kappa", 0.0):.9g}"/>')
    lines += [_colour_xml("specular_reflectance", colour, pad + "    "), f"{pad}</bsdf>"]
    return lines


def _tree(leaves: list[tuple[str, Array, dict[str, Any]]], total: float, pad: str, attrs: str = "") -> list[str]:
    """Nested blendbsdf adding the leaves exactly: each blend weighs its branches by their amplitude shares, and a
    leaf of amplitude a (its largest channel) is written with colour * total / a."""
    if len(leaves) == 1:
        plugin, col, props = leaves[0]
        lines = _leaf_xml(plugin, col * total / float(np.max(col)), props, pad)
        if attrs:
            lines[0] = lines[0].replace("<bsdf ", f"<bsdf {attrs} ", 1)
        return lines
    half = len(leaves) // 2
    left, right = leaves[:half], leaves[half:]
    amp_l = sum(float(np.max(c)) for _, c, _ in left)
    amp_r = sum(float(np.max(c)) for _, c, _ in right)
    w = amp_r / (amp_l + amp_r)
    head = f'{pad}<bsdf type="blendbsdf"' + (f" {attrs}" if attrs else "") + ">"
    return ([head, f'{pad}    <float name="weight" value="{w:.12g}"/>'] + _tree(left, total, pad + "    ")
            + _tree(right, total, pad + "    ") + [f"{pad}</bsdf>"])


def _unbounded_comment(leaves: list[tuple[str, Array, dict[str, Any]]]) -> str:
    """The fragment's note on its colours above 1: exact, not a bug (module docstring)."""
    amps = ", ".join(f"{p} {float(np.max(c)):.3g}" for p, c, _ in leaves)
    return ("<!-- Colours above 1 (srgb spectra with unbounded = true) are exact, not a bug: a blendbsdf weighs its "
            "two branches by (1 - weight) and weight, so to add the fitted lobes (amplitudes: " + amps + ") each "
            "branch holds its lobes' amplitudes divided by its weight, and the surface reflects the fitted "
            "amounts. -->")


def mitsuba_fragment(rec: Reconstruction, name: str, rgl_file: str | None) -> tuple[str, dict[str, Any]]:
    """(XML text, info) of a Mitsuba 3 ``<bsdf>`` for ``rec``: analytic where it maps, else ``measured`` with
    ``rgl_file`` (a path relative to the XML file)."""
    maps, plugins, why = _maps(rec)
    ident = quoteattr(name)
    head = ['<?xml version="1.0" encoding="utf-8"?>',
            f"<!-- gonio-brdf {rec.method} reconstruction ({rec.report().get('model') or rec.method}): {why}. "
            f"Include it in a scene with <include filename=\"...\"/> and use <ref id={ident}/>. -->"]
    attrs = f'version="3.0.0" id={ident}'
    if maps:
        lobes = _lobes(rec)
        assert lobes is not None
        leaves = _leaves(lobes)
        others = [lf for lf in leaves if lf[0] != "principled"]
        schlick = [lf for lf in leaves if lf[0] == "principled"]
        amp = sum(float(np.max(c)) for _, c, _ in others)
        if not leaves:  # a black surface: every amplitude is zero
            body = [f'<bsdf type="diffuse" {attrs}>', '    <rgb name="reflectance" value="0, 0, 0"/>', "</bsdf>"]
        elif not schlick:
            body = _tree(others, amp, "", attrs)
        elif not others:
            body = _leaf_xml(*schlick[0], "")
            body[0] = body[0].replace("<bsdf ", f"<bsdf {attrs} ", 1)
        else:  # the Schlick lobe's scale ks is the blend weight; the rest is amplified by 1 / (1 - ks)
            ks = float(np.max(schlick[0][1]))
            body = ([f'<bsdf type="blendbsdf" {attrs}>', f'    <float name="weight" value="{ks:.12g}"/>']
                    + _tree(others, amp / (1.0 - ks), "    ")
                    + _leaf_xml("principled", np.ones(3), schlick[0][2], "    ") + ["</bsdf>"])
        unbounded = 'name="unbounded" value="true"' in "\n".join(body)
        if unbounded:
            head.append(_unbounded_comment(leaves))
        info = {"maps": True, "plugins": plugins, "leaves": len(leaves), "unbounded_colours": unbounded,
                "not_carried": []}
    else:
        if rgl_file is None:
            raise ReconstructionError("the model does not map to a Mitsuba BSDF and no RGL file was written for the "
                                      "measured fallback")
        body = [f'<bsdf type="measured" {attrs}>', f"    <string name=\"filename\" value={quoteattr(rgl_file)}/>",
                "</bsdf>"]
        info = {"maps": False, "plugins": ["measured"], "filename": rgl_file, "reason": why,
                "not_carried": [f"the fitted model as parameters ({why}): the fragment renders the RGL file's "
                                "tabulated samples"]}
    return "\n".join(head + body) + "\n", info


def _environment(width: int = 128) -> NDArray[np.float32]:
    """A procedural latitude-longitude environment (width x width/2, linear RGB): a blue sky over a dark ground,
    a warm horizon band and a small bright sun, so highlights and the diffuse colour both show."""
    h = width // 2
    v = (np.arange(h) + 0.5) / h  # 0 at the zenith
    u = (np.arange(width) + 0.5) / width
    elev = (0.5 - v) * np.pi
    sky = np.where(elev[:, None, None] > 0,
                   np.array([0.35, 0.55, 1.0]) * (0.4 + 0.6 * np.sin(np.clip(elev, 0, None)))[:, None, None],
                   np.array([0.12, 0.1, 0.08]) * np.ones((h, 1, 1)))
    band = np.exp(-np.square(elev / 0.12))[:, None, None] * np.array([1.0, 0.75, 0.45])
    img = np.broadcast_to(sky + band, (h, width, 3)).copy()
    phi = (u - 0.5) * 2 * np.pi
    sun_e, sun_p = math.radians(40.0), math.radians(-140.0)
    d = (np.sin(elev)[:, None] * math.sin(sun_e)
         + np.cos(elev)[:, None] * math.cos(sun_e) * np.cos(phi[None, :] - sun_p))
    img += (d > math.cos(math.radians(4.0)))[..., None] * np.array([60.0, 55.0, 45.0])
    return img.astype(np.float32)


def render_mitsuba_preview(rgl_path: str | Path, exr_path: str | Path, size: int = 256, spp: int = 32
                           ) -> dict[str, Any]:
    """Render a sphere with the RGL file under the procedural environment with Mitsuba 3 (scalar_rgb, path
    tracer); write ``exr_path`` (linear float RGB) and the PNG beside it, as the built-in preview does."""
    from reconstruction.report.preview import write_exr, write_png

    mi = require_mitsuba("--preview-renderer mitsuba")
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 4},
        "sensor": {"type": "perspective", "fov": 34.0,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                   "sampler": {"type": "independent", "sample_count": spp},
                   "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"}}},
        "emitter": {"type": "envmap", "bitmap": mi.Bitmap(_environment())},  # +y up, as the camera
        "sphere": {"type": "sphere", "bsdf": {"type": "measured", "filename": str(rgl_path)}},
    })
    img = np.array(mi.render(scene), dtype=np.float32)[..., :3]
    exr_path = Path(exr_path)
    write_exr(exr_path, img)
    png = exr_path.with_suffix(".png")
    exposure = write_png(png, img)
    return {"exr": str(exr_path), "png": str(png), "size": size, "renderer": f"Mitsuba {mi.__version__} scalar_rgb, "
            f"path tracer, {spp} samples per pixel, procedural environment map", "rgl": str(rgl_path),
            "png_exposure": exposure, "max_linear": float(img.max())}


def mitsuba_preview(args: Any, rec: Reconstruction, outputs: dict[str, Any]) -> dict[str, Any]:
    """--preview with --preview-renderer mitsuba: render the RGL file written (or a temporary one)."""
    from reconstruction.formats import rgl

    if "rgl" in outputs:
        return render_mitsuba_preview(outputs["rgl"]["rgl"], args.preview)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "preview.bsdf"
        rgl.write(path, rec.eval, description=f"gonio-brdf {rec.method} (preview)")
        return render_mitsuba_preview(path, args.preview)
