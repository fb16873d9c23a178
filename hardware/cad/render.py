"""Pictures of the assembled bench from the CAD (matplotlib's 3D of the tessellated parts; no display needed).

    python hardware/cad/render.py                       # docs/bench-assembly.png (theta_i = 45, theta_o = 30)
    python hardware/cad/render.py --out x.png --theta-i 60 --theta-o 60
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import params  # noqa: E402

COLOURS = {"sample-holder": "#9e9e9e", "light-arm": "#4f7cac", "collimator-mount": "#d99a3d",
           "detector-arm": "#4f7cac", "detector-tube": "#5b9e5b"}


def _mesh(solid, tol: float = 0.3) -> np.ndarray:
    """(n, 3, 3) triangles of a solid (mm)."""
    verts, tris = solid.tessellate(tol, 0.3)
    v = np.array([[p.X, p.Y, p.Z] for p in verts])
    return v[np.asarray(tris)]


def draw(ax, parts: dict, p: dict, theta_i: float, theta_o: float, elev: float, azim: float) -> None:
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    light_dir = np.array([-np.sin(np.radians(theta_i)), 0.0, np.cos(np.radians(theta_i))])
    det_dir = np.array([np.sin(np.radians(theta_o)), 0.0, np.cos(np.radians(theta_o))])
    for name, solid in parts.items():
        tri = _mesh(solid)
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        shade = 0.55 + 0.45 * np.abs(n @ np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8]))
        base = np.array([int(COLOURS[name][k:k + 2], 16) / 255 for k in (1, 3, 5)])
        ax.add_collection3d(Poly3DCollection(tri, facecolors=np.clip(base * shade[:, None], 0, 1), linewidths=0))
    c = p["optics"]["collimator"]
    d = p["optics"]["detector"]
    beam = np.array([light_dir * c["output_aperture_from_axis_mm"], [0, 0, 0]])
    ax.plot(beam[:, 0], beam[:, 1], beam[:, 2], color="#e8c31a", lw=2.5, label="beam (8 mm)")
    view = np.array([[0, 0, 0], det_dir * (d["distance_mm"] - d["field_stop_to_aperture_mm"])])
    ax.plot(view[:, 0], view[:, 1], view[:, 2], color="#3a8f3a", lw=1.5, ls="--", label="detector's axis")
    ax.plot([-60, 60], [0, 0], [0, 0], color="k", lw=0.6)
    ax.plot([0, 0], [-45, 55], [0, 0], color="k", lw=0.8, ls=":", label="rotation axis")
    ax.set_xlim(-140, 140)
    ax.set_ylim(-140, 140)
    ax.set_zlim(-60, 220)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=elev, azim=azim)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python hardware/cad/render.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(params.HERE.parents[1] / "docs" / "bench-assembly.png"))
    ap.add_argument("--theta-i", type=float, default=45.0)
    ap.add_argument("--theta-o", type=float, default=30.0)
    ap.add_argument("--actuator", default="xm430", choices=("xl430", "xm430", "nema17"))
    args = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import parts as cad

    p = params.load()
    asm = cad.assembly(p, args.theta_i, args.theta_o, args.actuator)
    fig = plt.figure(figsize=(12, 6.2))
    for k, (elev, azim, title) in enumerate(((22, -58, "the bench"),
                                             (0, -90, "along the rotation axis (the plane of incidence)"))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        draw(ax, asm, p, args.theta_i, args.theta_o, elev, azim)
        ax.set_title(title)
        if k == 0:
            ax.legend(loc="upper left", fontsize=8)
        else:
            ax.set_yticks([])
            ax.set_ylabel("")
    fig.suptitle(f"hardware/cad: {args.actuator.upper()} arms, theta_i = {args.theta_i:g} deg, theta_o = "
                 f"{args.theta_o:g} deg (servos, frame and enclosure not drawn)", fontsize=11)
    fig.subplots_adjust(left=0.02, right=0.98, top=0.9, bottom=0.04, wspace=0.05)
    fig.savefig(args.out, dpi=90)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
