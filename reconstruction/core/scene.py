"""Scene files (``configs/scenes/*.toml``): what a capture or a reconstruction is for.

One format, read by ``gonio-capture --scene`` (restricts the capture plan, :meth:`acquisition.plan.Plan.restrict`)
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

    [scene.error_budget]                 # optional
    relative_rmse = 0.03                 # tolerated relative error. Capture: the adaptive refinement tolerance.
                                         # Fit: tolerated relative RMSE of f cos(theta_i) cos(theta_o) over the
                                         # scene's directions; the simplest candidate within it of the BIC choice
                                         # is used
    relative_sigma = 0.01                # relative measurement uncertainty aimed at (fit: used in the weights)

All keys are optional; unknown keys and tables other than ``[scene]`` are errors (they are probably typos). A
range the file does not give is None in :class:`Scene`; each program says which default it uses with
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
from reconstruction.schema.scene import LOBE_KINDS, ErrorBudget, SceneTable, keys

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["Scene", "SceneError", "LOBE_KINDS", "RECONSTRUCTION_DEFAULT_RANGE_DEG", "CAPTURE_DEFAULT_RANGE_DEG",
           "load_scene", "scene_from_dict"]

#: The keys of [scene] and [scene.error_budget]: the scene file's schema (reconstruction.schema.scene).
_SCENE_KEYS = keys(SceneTable)
_BUDGET_KEYS = keys(ErrorBudget)

Range = tuple[float, float]


class SceneError(ReconstructionError):
    """A scene file is invalid; the message names the file and the key. (A :class:`ValueError`, through
    :class:`~reconstruction.base.ReconstructionError`.)"""


#: theta_i and theta_o range (degrees) that the reconstruction assumes for a range a scene file does not give:
#: what a fit is judged over (reconstruction.methods.fit, reconstruction.methods.crossval).
RECONSTRUCTION_DEFAULT_RANGE_DEG = (0.0, 85.0)
#: ... and that a capture plan assumes: the whole hemisphere (acquisition.plan.Plan.restrict). The two differ on
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
    return Scene(**kw)


def load_scene(path: str | Path) -> Scene:
    """Read and validate the scene file at ``path`` (keys in the module docstring)."""
    p = Path(path)
    try:
        d = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SceneError(f"{p}: no such scene file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise SceneError(f"{p}: invalid TOML: {e}") from None
    return scene_from_dict(d, str(p))
