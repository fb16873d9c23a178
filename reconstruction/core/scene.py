"""Scene files (``configs/scenes/*.toml``): what a capture or a reconstruction is for.

One format, read by ``gonio-capture --scene`` (restricts the capture plan, :meth:`acquisition.plans.plan.Plan.restrict`)
and by ``gonio-reconstruct --scene`` (model selection, :func:`reconstruction.methods.fit.reconstruct_fit`)::

    [scene]
    name = "glossy-product"              # optional label (default: the file name without .toml)
    theta_i_deg = [15.0, 45.0]           # range [min, max] of light polar angles from the normal the scene uses
                                         # (degrees, 0 <= min <= max < 90)
    theta_o_deg = [0.0, 75.0]            # range of view polar angles from the normal (unsigned: on the in-plane
                                         # slice both sides of the normal are kept)
    angular_resolution_deg = 1.0         # finest angular detail that matters. Capture: the outgoing step.
                                         # Fit: lobes narrower than this are not resolved, alpha >= radians(
                                         # resolution) / 2.6 (~ lobe FWHM), and candidates are compared on a grid
                                         # of this step (at least 1 deg)
    lobes = ["lambert", "ggx", "fresnel"]  # optional: the lobe kinds the reconstruction may use (lambert, ggx,
                                           # beckmann, retro, fresnel); ignored by the capture

    [scene.view]                         # optional: what a renderer will do, instead of the two ranges above
    geometry = "sphere"                  # "sphere": an object seen whole; "plane": a flat sample
    lights_deg = [[45.0, 0.0]]           # light directions [polar, azimuth] (deg): sphere: the angle from the
                                         # camera's direction and the azimuth about it; plane: from the normal,
                                         # azimuth from the camera's (180 = the mirror side)
    camera_deg = [30.0]                  # plane only: the camera's polar angles from the normal
    coverage = 0.9                       # sphere: the share of the lit, seen surface the ranges keep

    [scene.error_budget]                 # optional
    relative_rmse = 0.03                 # tolerated relative error. Capture: the adaptive refinement tolerance.
                                         # Fit: tolerated relative RMSE of f cos(theta_i) cos(theta_o) over the
                                         # scene's directions; the simplest candidate within it of the BIC choice
                                         # is used
    relative_sigma = 0.01                # relative measurement uncertainty aimed at (fit: used in the weights)

All keys are optional; unknown keys and tables other than ``[scene]`` are errors (they are probably typos). With
``[scene.view]``, the ranges the file does not give follow from the view (:func:`view_ranges`): for a plane, the
cameras' and lights' polar angles; for a sphere, the central ``coverage`` of theta_i and theta_o over its lit,
seen surface, each point weighted by its projected area and cos theta_i. A range the file does not give is None
in :class:`Scene`; each program says which default it uses with
:meth:`Scene.ranges` (the capture the whole hemisphere, the fit 0-85 deg).

Errors are :class:`SceneError`; their messages name the file and the key.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from reconstruction.base import ReconstructionError
from reconstruction.schema.files import MAX_TEXT_BYTES, UserFileError, read_user_text
from reconstruction.schema.scene import GEOMETRIES, LOBE_KINDS, ErrorBudget, SceneTable, View, keys

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["Scene", "SceneError", "view_ranges", "RECONSTRUCTION_DEFAULT_RANGE_DEG", "CAPTURE_DEFAULT_RANGE_DEG",
           "load_scene", "scene_from_dict", "ScenePairs", "scene_pairs"]

#: The keys of [scene] and [scene.error_budget]: the scene file's schema (reconstruction.schema.scene).
_SCENE_KEYS = keys(SceneTable)
_BUDGET_KEYS = keys(ErrorBudget)
_VIEW_KEYS = keys(View)

Range = tuple[float, float]


class SceneError(ReconstructionError):
    """A scene file is invalid; the message names the file and the key. (A :class:`ValueError`, through
    :class:`~reconstruction.base.ReconstructionError`.)"""


#: theta_i and theta_o range (degrees) that the reconstruction assumes for a range a scene file does not give:
#: what a fit is judged over (reconstruction.methods.fit, reconstruction.methods.crossval).
RECONSTRUCTION_DEFAULT_RANGE_DEG = (0.0, 85.0)
#: ... and that a capture plan assumes: the whole hemisphere (acquisition.plans.plan.Plan.restrict). The two differ on
#: purpose: a capture measures what it can reach; a fit is not asked to be judged at grazing angles.
CAPTURE_DEFAULT_RANGE_DEG = (0.0, 89.999)


@dataclass(frozen=True)
class Scene:
    """A scene file, validated (keys in the module docstring). Angles in degrees; None where the file is silent."""

    name: str = "scene"
    theta_i_deg: Range | None = None
    theta_o_deg: Range | None = None
    angular_resolution_deg: float | None = None
    lobes: tuple[str, ...] | None = None
    relative_rmse: float | None = None
    relative_sigma: float | None = None
    source: str = "<scene>"
    view: str | None = None  # [scene.view] described, with the ranges it gave
    view_geometry: str | None = None  # [scene.view]'s geometry, lights and cameras (deg) as given; None without
    view_lights_deg: tuple[tuple[float, float], ...] | None = None
    view_cameras_deg: tuple[float, ...] | None = None


    def ranges(self, default: Range) -> tuple[Range, Range]:
        """(theta_i_deg, theta_o_deg), each the file's range or ``default`` where the file gives none."""
        return (self.theta_i_deg or default, self.theta_o_deg or default)


def _positive(src: str, key: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
        raise SceneError(f"{src}: {key}: expected a positive number, got {v!r}")
    return float(v)


def _range(src: str, key: str, v: Any) -> Range:
    ok = (isinstance(v, list) and len(v) == 2
          and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v))
    if not ok or not 0.0 <= v[0] <= v[1] < 90.0:
        raise SceneError(f"{src}: {key}: expected [min, max] degrees with 0 <= min <= max < 90, got {v!r}")
    return float(v[0]), float(v[1])


def _unknown(src: str, table: str, keys: Mapping[str, Any], allowed: tuple[str, ...]) -> None:
    bad = [k for k in keys if k not in allowed]
    if bad:
        more = f" (and {', '.join(bad[1:])})" if len(bad) > 1 else ""
        raise SceneError(f"{src}: {table}.{bad[0]}: unknown key{more}; allowed keys: {', '.join(allowed)}")


def scene_from_dict(d: Mapping[str, Any], source: str = "<scene>") -> Scene:
    """Validate a parsed scene file (the whole TOML document, with its ``[scene]`` table); ``source`` names it
    in errors and gives the default name."""
    s = d.get("scene")
    if not isinstance(s, Mapping):
        raise SceneError(f"{source}: no [scene] table (every scene file has one)")
    others = [k for k in d if k != "scene"]
    if others:
        raise SceneError(f"{source}: [{others[0]}]: unknown section; a scene file has only [scene]")
    _unknown(source, "[scene]", s, _SCENE_KEYS)
    kw: dict[str, Any] = {"source": source, "name": Path(source).stem}
    if "name" in s:
        if not isinstance(s["name"], str):
            raise SceneError(f"{source}: [scene].name: expected a string, got {s['name']!r}")
        kw["name"] = s["name"]
    for key in ("theta_i_deg", "theta_o_deg"):
        if key in s:
            kw[key] = _range(source, f"[scene].{key}", s[key])
    if "angular_resolution_deg" in s:
        kw["angular_resolution_deg"] = _positive(source, "[scene].angular_resolution_deg",
                                                 s["angular_resolution_deg"])
    if "lobes" in s:
        lobes = s["lobes"]
        if not isinstance(lobes, list) or not lobes or any(x not in LOBE_KINDS for x in lobes):
            raise SceneError(f"{source}: [scene].lobes: expected a list of {', '.join(LOBE_KINDS)}, got {lobes!r}")
        kw["lobes"] = tuple(lobes)
    eb = s.get("error_budget", {})
    if not isinstance(eb, Mapping):
        raise SceneError(f"{source}: [scene.error_budget]: expected a table ({', '.join(_BUDGET_KEYS)})")
    _unknown(source, "[scene.error_budget]", eb, _BUDGET_KEYS)
    for key in _BUDGET_KEYS:
        if key in eb:
            kw[key] = _positive(source, f"[scene.error_budget].{key}", eb[key])
    if "view" in s:
        kw.update(_view(source, s["view"], kw))
    return Scene(**kw)


def _angles(src: str, key: str, v: Any, pairs: bool) -> list[Any]:
    def num(x: Any) -> bool:
        return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)

    ok = isinstance(v, list) and len(v) > 0 and all(
        (isinstance(x, list) and len(x) == 2 and all(num(y) for y in x) and 0.0 <= x[0] <= 180.0) if pairs
        else (num(x) and 0.0 <= x < 90.0) for x in v)
    if not ok:
        want = ("a list of [polar, azimuth] pairs in degrees (polar 0-180)" if pairs
                else "a list of polar angles in degrees, 0 <= angle < 90")
        raise SceneError(f"{src}: [scene.view].{key}: expected {want}, got {v!r}")
    return [tuple(float(y) for y in x) for x in v] if pairs else [float(x) for x in v]


def _view(src: str, v: Any, given: Mapping[str, Any]) -> dict[str, Any]:
    """The ranges (those the file does not give) and the description of ``[scene.view]``."""
    if not isinstance(v, Mapping):
        raise SceneError(f"{src}: [scene.view]: expected a table ({', '.join(_VIEW_KEYS)})")
    _unknown(src, "[scene.view]", v, _VIEW_KEYS)
    geometry = v.get("geometry", "sphere")
    if geometry not in GEOMETRIES:
        raise SceneError(f"{src}: [scene.view].geometry: expected one of {', '.join(GEOMETRIES)}, got {geometry!r}")
    if "lights_deg" not in v:
        raise SceneError(f"{src}: [scene.view].lights_deg: missing (the light directions the renderer uses)")
    lights = _angles(src, "lights_deg", v["lights_deg"], pairs=True)
    cameras = _angles(src, "camera_deg", v["camera_deg"], pairs=False) if "camera_deg" in v else None
    if geometry == "plane" and cameras is None:
        raise SceneError(f"{src}: [scene.view].camera_deg: missing (a plane's camera polar angles)")
    if geometry == "plane" and any(t >= 90.0 for t, _ in lights):
        raise SceneError(f"{src}: [scene.view].lights_deg: a plane's lights are above it (polar < 90 deg)")
    coverage = v.get("coverage", 0.9)
    if isinstance(coverage, bool) or not isinstance(coverage, (int, float)) or not 0.0 < coverage <= 1.0:
        raise SceneError(f"{src}: [scene.view].coverage: expected a share in (0, 1], got {coverage!r}")
    ti, to = view_ranges(geometry, lights, cameras, float(coverage))
    out: dict[str, Any] = {}
    derived = []
    for key, r in (("theta_i_deg", ti), ("theta_o_deg", to)):
        if key not in given:
            out[key] = r
            derived.append(f"{key} {r[0]:.1f}-{r[1]:.1f}")
    out.update(view_geometry=geometry, view_lights_deg=tuple(lights),
               view_cameras_deg=tuple(cameras) if cameras else None)
    out["view"] = (f"{geometry}, lights {[list(x) for x in lights]} deg"
                   + (f", cameras {cameras} deg" if cameras else "")
                   + (f": {', '.join(derived)}" if derived else ": ranges as the file gives them"))
    return out


def view_ranges(geometry: str, lights_deg: list[tuple[float, float]], cameras_deg: list[float] | None = None,
                coverage: float = 0.9) -> tuple[Range, Range]:
    """(theta_i range, theta_o range) in degrees that a renderer's view uses (module docstring): a plane's
    cameras and lights, or the central ``coverage`` over a sphere's lit, seen surface."""
    import numpy as np

    if geometry == "plane":
        ti = [t for t, _ in lights_deg]
        to = list(cameras_deg or [0.0])
        return (min(ti), max(ti)), (min(to), max(to))
    # the sphere seen from +z: normals over the visible disk (uniform in projected area), lights about +z
    n1 = 400
    x, y = np.meshgrid((np.arange(n1) + 0.5) / n1 * 2 - 1, (np.arange(n1) + 0.5) / n1 * 2 - 1)
    inside = x**2 + y**2 < 1.0
    n = np.stack([x[inside], y[inside], np.sqrt(1.0 - x[inside] ** 2 - y[inside] ** 2)], axis=-1)
    cos_o = n[:, 2]
    ti_all, to_all, w_all = [], [], []
    for a, b in lights_deg:
        a, b = math.radians(a), math.radians(b)
        lvec = np.array([math.sin(a) * math.cos(b), math.sin(a) * math.sin(b), math.cos(a)])
        cos_i = n @ lvec
        lit = (cos_i > 0) & (cos_o > 0)
        ti_all.append(np.degrees(np.arccos(cos_i[lit])))
        to_all.append(np.degrees(np.arccos(cos_o[lit])))
        w_all.append(cos_i[lit])
    if not any(t.size for t in ti_all):
        raise SceneError(f"[scene.view].lights_deg {lights_deg}: no light reaches the part of the sphere the camera "
                         "sees")
    ti, to, w = (np.concatenate(v) for v in (ti_all, to_all, w_all))
    lo, hi = (1.0 - coverage) / 2.0, (1.0 + coverage) / 2.0

    def quantiles(v: Any) -> Range:
        order = np.argsort(v)
        c = np.cumsum(w[order]) / np.sum(w)
        q = np.interp([lo, hi], c, v[order])
        return float(np.clip(q[0], 0.0, 89.0)), float(np.clip(q[1], 0.0, 89.0))

    return quantiles(ti), quantiles(to)


@dataclass(frozen=True)
class ScenePairs:
    """The direction pairs a scene's renderer evaluates the BRDF at, in the surface's local frame (+z the normal):
    ``wi``, ``wo`` (P, L, 3) unit vectors of P pixels under L lights, and ``weight`` (P, L) each pair's share of
    its pixel's radiance (cos theta_i x the light's irradiance; 0 where the light does not reach or the camera
    does not see). A pixel's radiance is sum_l f(wi, wo) weight."""

    wi: Any
    wo: Any
    weight: Any
    kind: str

    @property
    def theta_i_deg(self) -> Any:
        """(P, L) incidence angles in degrees."""
        import numpy as np

        return np.degrees(np.arccos(np.clip(self.wi[..., 2], -1.0, 1.0)))


#: pixels across a sphere scene's image, and pairs drawn for a scene of ranges
SCENE_PIXELS = 48
SCENE_RANGE_PAIRS = 4000


def scene_pairs(scene: Scene, default: Range = RECONSTRUCTION_DEFAULT_RANGE_DEG,
                max_view_deg: float = 80.0) -> ScenePairs:
    """The distribution of (wi, wo) a scene's renderer uses (:class:`ScenePairs`): with ``[scene.view]``, a
    sphere seen from +z (:data:`SCENE_PIXELS` pixels across, pixels seen above ``max_view_deg`` left out as the
    image metrics do) under its lights, or a plane's cameras x lights; without, pairs uniform in solid angle
    within the scene's theta_i and theta_o ranges (``default`` where the file gives none) at uniform relative
    azimuths, each weighted by cos theta_i. Deterministic."""
    import numpy as np

    def local(ct: Any, st: Any, cp: Any, sp: Any) -> Any:
        return np.stack([st * cp, st * sp, ct], axis=-1)

    if scene.view_geometry == "sphere" and scene.view_lights_deg:
        n1 = SCENE_PIXELS
        x, y = np.meshgrid((np.arange(n1) + 0.5) / n1 * 2 - 1, (np.arange(n1) + 0.5) / n1 * 2 - 1)
        inside = x**2 + y**2 < np.sin(np.radians(max_view_deg)) ** 2
        n = np.stack([x[inside], y[inside], np.sqrt(1.0 - x[inside] ** 2 - y[inside] ** 2)], axis=-1)  # (P, 3)
        a, b = np.radians(np.array(scene.view_lights_deg)).T
        lv = np.stack([np.sin(a) * np.cos(b), np.sin(a) * np.sin(b), np.cos(a)], axis=-1)  # (L, 3)
        cos_i = n @ lv.T  # (P, L)
        cos_o = np.broadcast_to(n[:, 2:3], cos_i.shape)
        lt = lv[None] - cos_i[..., None] * n[:, None]  # the light and the camera projected on the tangent plane
        vt = np.array([0.0, 0.0, 1.0])[None, None] - cos_o[..., None] * n[:, None]
        norm = np.linalg.norm(lt, axis=-1) * np.linalg.norm(vt, axis=-1)
        cp = np.where(norm > 1e-12, np.einsum("plk,plk->pl", lt, vt) / np.maximum(norm, 1e-300), 1.0)
        cp = np.clip(cp, -1.0, 1.0)
        ci = np.clip(cos_i, 1e-6, 1.0)
        wi = local(ci, np.sqrt(1.0 - ci**2), np.ones_like(ci), np.zeros_like(ci))
        wo = local(cos_o, np.sqrt(1.0 - cos_o**2), cp, np.sqrt(1.0 - cp**2))
        return ScenePairs(wi, wo, np.where(cos_i > 0, cos_i, 0.0), "sphere")
    if scene.view_geometry == "plane" and scene.view_lights_deg:
        t, az = np.radians(np.array(scene.view_lights_deg)).T  # (L,)
        c = np.radians(np.array(scene.view_cameras_deg or (0.0,)))  # (P,)
        shape = (c.size, t.size)
        wi = np.broadcast_to(local(np.cos(t), np.sin(t), np.cos(az), np.sin(az))[None], (*shape, 3))
        wo = np.broadcast_to(local(np.cos(c), np.sin(c), np.ones_like(c), np.zeros_like(c))[:, None], (*shape, 3))
        return ScenePairs(np.array(wi), np.array(wo), np.broadcast_to(np.cos(t)[None], shape).copy(), "plane")
    (i0, i1), (o0, o1) = scene.ranges(default)
    rng = np.random.default_rng(11)

    def cap(lo: float, hi: float) -> Any:
        ct = rng.uniform(np.cos(np.radians(hi)), np.cos(np.radians(lo)), SCENE_RANGE_PAIRS)
        return ct, np.sqrt(1.0 - ct**2)

    ci, si = cap(i0, i1)
    co, so = cap(o0, o1)
    ph = rng.uniform(0.0, 2 * np.pi, SCENE_RANGE_PAIRS)
    wi = local(ci, si, np.ones_like(ci), np.zeros_like(ci))[:, None]
    wo = local(co, so, np.cos(ph), np.sin(ph))[:, None]
    return ScenePairs(wi, wo, ci[:, None], "ranges")


def load_scene(path: str | Path) -> Scene:
    """Read and validate the scene file at ``path`` (keys in the module docstring)."""
    p = Path(path)
    try:
        text = read_user_text(p, "a scene file (TOML)", MAX_TEXT_BYTES)  # the one check: type, size, UTF-8
    except UserFileError as e:
        if e.kind == "missing":
            raise SceneError(f"{p}: no such scene file") from None
        if e.kind in ("directory", "special"):  # a device or a pipe would block the read
            raise SceneError(f"{p}: not a regular file, expected a scene file (TOML)") from None
        raise SceneError(f"{p}: invalid TOML: {e.why} at byte {e.byte}" if e.kind == "not_utf8" else str(e)) from None
    try:
        d = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{p}: invalid TOML: {e}") from None
    return scene_from_dict(d, str(p))
