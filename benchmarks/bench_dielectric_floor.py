"""How close a plain OpenPBR dielectric can come to the demo's material in image (issue 41, item 12).

The demo's true material is lambert (albedo 0.14) + GGX (alpha 0.15, Schlick F0 0.04 = IOR 1.5, scale 0.9), added,
not layered. ``fit_principled`` writes it as a plain dielectric (metalness 0, no coat); with metalness and a coat
it reaches a lower image error by imitating the unlayered sum. This prints, as image error (the mean relative RMSE
of the key and rim renders at 64 pixels, :func:`reconstruction.principled.fit.judge_images`):

* the material ``fit_principled`` writes, and the layered candidate it leaves in the JSON;
* the plain dielectric straight from the analytic lobes (IOR 1.5, alpha 0.15, albedo 0.14, specular tint 0.9);
* the best plain dielectric a search of the image error itself finds (Nelder-Mead over base colour, diffuse
  roughness, F0, specular tint and roughness, from the written material, three starts of diffuse roughness), and
  the best with the IOR held at 1.5 (base colour, specular tint, roughness).

Usage: ``.venv/bin/python benchmarks/bench_dielectric_floor.py`` (about 60 s).
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruction.core.models import Material  # noqa: E402
from reconstruction.principled import albedo as alb  # noqa: E402
from reconstruction.principled.fit import analytic_start, fit_principled, judge_images, params_from_vector  # noqa: E402
from reconstruction.principled.model import PrincipledParams  # noqa: E402

LOBES = [{"type": "lambert", "albedo": [0.14]}, {"type": "ggx", "alpha": 0.15, "ior": 1.5, "f0": 0.04,
                                                 "specular": [0.9]}]
DEMO = Material.from_dict({"name": "demo", "lobes": [{"type": "lambert", "albedo": 0.14},
                                                     {"type": "ggx", "alpha": 0.15, "specular": 0.9, "f0": 0.04}]})


def image_error(p: PrincipledParams) -> float:
    """Mean relative RMSE of the key and rim renders (64 pixels) against the demo's material."""
    return float(np.mean([v["relative_rmse"] for v in judge_images(p.eval, DEMO.eval).values()]))


def grey(p: PrincipledParams, **kw: float) -> PrincipledParams:
    """``p`` with grey colours ``base`` and ``tint`` and the other fields of ``kw``."""
    base, tint = kw.pop("base", None), kw.pop("tint", None)
    if base is not None:
        kw["base_color"] = (float(np.clip(base, 0, 1)),) * 3
    if tint is not None:
        kw["specular_color"] = (float(np.clip(tint, 0, 1)),) * 3
    return dataclasses.replace(p, **kw)


def search(fn, v0: np.ndarray, steps: tuple[float, ...], nfev: int = 250) -> tuple[float, np.ndarray]:
    simplex = np.array([v0] + [v0 + np.eye(v0.size)[k] * s for k, s in enumerate(steps)])
    r = minimize(lambda v: image_error(fn(v)), v0, method="Nelder-Mead",
                 options={"maxfev": nfev, "initial_simplex": simplex, "xatol": 1e-4, "fatol": 1e-6})
    return float(r.fun), r.x


def main() -> int:
    fit = fit_principled(DEMO.eval, start=analytic_start(LOBES))
    p = fit.params
    layered = PrincipledParams.from_dict(fit.layers["parameters_with_layers"])
    print(f"written (plain dielectric): {fit.image_relative_rmse:.2%}  IOR {p.specular_ior:.3f}  "
          f"roughness {p.specular_roughness:.3f}  base {p.base_color[0]:.4f}")
    print(f"layered candidate:          {image_error(layered):.2%}  metalness {layered.base_metalness:.3f}  "
          f"coat {layered.coat_weight:.3f} of IOR {layered.coat_ior:.3f}  specular IOR {layered.specular_ior:.3f}")
    print(f"analytic lobes as a dielectric (IOR 1.5): {image_error(params_from_vector(analytic_start(LOBES))):.2%}")

    def five(v: np.ndarray) -> PrincipledParams:
        b, dr, f0, tint, rough = v
        ior = float(np.clip(alb.ior_from_f0(float(np.clip(f0, 1e-4, alb.F0_MAX))), 1.0, 3.0))
        return grey(p, base=b, base_diffuse_roughness=float(np.clip(dr, 0, 1)), specular_ior=ior, tint=tint,
                    specular_roughness=float(np.clip(rough, 0, 1)))

    best = None
    for dr in (0.0, 0.3, 0.6):
        v0 = np.array([p.base_color[0], dr, p.specular_f0, p.specular_color[0], p.specular_roughness])
        e, x = search(five, v0, (0.03, 0.3, 0.01, 0.1, 0.05))
        print(f"  image search from diffuse roughness {dr}: {e:.2%}")
        best = (e, x) if best is None or e < best[0] else best
    q = five(best[1])
    print(f"best plain dielectric by image search: {best[0]:.2%}  IOR {q.specular_ior:.3f}  "
          f"diffuse roughness {q.base_diffuse_roughness:.3f}")

    def at_15(v: np.ndarray) -> PrincipledParams:
        b, tint, rough = v
        return grey(p, base=b, specular_ior=1.5, tint=tint, specular_roughness=float(np.clip(rough, 0, 1)))

    e15, _ = search(at_15, np.array([p.base_color[0], 0.9, p.specular_roughness]), (0.03, 0.1, 0.05))
    print(f"best plain dielectric with IOR 1.5: {e15:.2%}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
