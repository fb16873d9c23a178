"""Draw docs/demo.png, the README's picture: the demo capture's slices (with error bars), the reconstruction's
in-plane prediction at the same incidences, and the sphere rendered from the written table.

It reads what the README's first command writes (the capture, then ``gonio-reconstruct ... --method auto``):

    .venv/bin/gonio-capture --config configs/simulated.toml --out out/demo
    .venv/bin/gonio-reconstruct out/demo/slice.csv --method auto --out out/demo/material.binary \\
        --preview out/demo/material.exr --report out/demo/material.json
    .venv/bin/python scripts/readme_figure.py [--demo out/demo] [--out FILE.png]   # out/demo/demo.png
    .venv/bin/python scripts/readme_figure.py --update-docs                        # docs/demo.png, the README's

The prediction is read from the written MERL table (trilinear between bin centres, as ``merltable.lookup`` does), so
the figure shows the file a renderer gets, not the method's internal model; the sphere is
``reconstruction.report.preview.render_preview`` of that table (a point light and a dim uniform environment), exposed as
``gonio-reconstruct --preview`` exposes its PNG. Bad or missing input: exit 2 and one line.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from reconstruction.core import merltable  # noqa: E402
from reconstruction.core.geometry import inplane_to_dirs  # noqa: E402
from reconstruction.core.slicedata import SliceError  # noqa: E402
from reconstruction.formats import merl  # noqa: E402
from reconstruction.formats.slicefile import read_slice  # noqa: E402
from reconstruction.report.preview import PREVIEW_RADIUS, render_preview, srgb_encode  # noqa: E402

COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")


def _channel_mean(v: np.ndarray) -> np.ndarray:
    return v.mean(axis=-1) if v.ndim > 1 else v


def _title(report: dict | None) -> str:
    """One line naming the method and its main parameters, from the report (if there is one)."""
    if not report:
        return "reconstruction"
    method, model = report.get("method", "?"), report.get("details", {}).get("model")
    parts = [f"{method} ({model})" if model else str(method)]
    for lobe in report.get("parameters") or []:
        if lobe.get("type") in ("ggx", "beckmann") and "alpha" in lobe:
            parts.append(f"alpha {lobe['alpha']:.3f}")
            if "f0" in lobe:
                parts.append(f"f0 {lobe['f0']:.3f}")
        if lobe.get("type") == "lambert":
            parts.append(f"albedo {np.mean(lobe['albedo']):.3f}")
    return ", ".join(parts)


def draw(demo: Path, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = read_slice(demo / "slice.csv")
    table = merl.read(demo / "material.binary")
    report_path = demo / "material.json"
    report = json.loads(report_path.read_text(encoding="utf-8")) if report_path.exists() else None
    f, std = s.brdf()
    lum, lstd = _channel_mean(f), _channel_mean(std)

    fig = plt.figure(figsize=(11.0, 4.2), dpi=100)
    grid = fig.add_gridspec(1, 2, width_ratios=(2.15, 1.0), wspace=0.08)
    ax = fig.add_subplot(grid[0])
    dense = np.linspace(-89.0, 89.0, 713)
    for k, t in enumerate(s.incidences()):
        colour = COLOURS[k % len(COLOURS)]
        m = s.theta_i_deg == t
        wi, wo = inplane_to_dirs(np.radians(np.full(dense.size, t)), np.radians(dense))
        pred = _channel_mean(merltable.lookup(table, wi, wo, interpolate=True))
        ax.plot(dense, pred, color=colour, lw=1.6, zorder=2)
        ax.errorbar(s.theta_o_deg[m], lum[m], yerr=lstd[m], fmt="o", ms=3.2, mfc="white", mew=1.0, color=colour,
                    ecolor=colour, elinewidth=1.0, capsize=1.5, zorder=3,
                    label=f"theta_i = {t:g} deg")
    ax.plot([], [], color="0.3", lw=1.6, label="reconstruction (the written table)")
    ax.errorbar([], [], yerr=[], fmt="o", ms=3.2, mfc="white", color="0.3", label="captured, +- 1 std")
    ax.set_yscale("log")
    ax.set_xlim(-90, 90)
    ax.set_xticks(np.arange(-80, 81, 20))
    ax.set_xlabel("theta_o (deg; + = specular side, - = back-scatter side)")
    ax.set_ylabel("f_r (1/sr)")
    ax.grid(True, which="both", alpha=0.2)
    ax.legend(fontsize=8, loc="upper left", frameon=False)
    ax.set_title(f"captured slices and the reconstruction: {_title(report)}", fontsize=9.5)

    sx = fig.add_subplot(grid[1])
    img = render_preview(merltable.brdf_of(table), 320).astype(np.float64)
    size = img.shape[0]
    c = ((np.arange(size) + 0.5) / size * 2.0 - 1.0) / PREVIEW_RADIUS
    x, y = np.meshgrid(c, -c)
    lum_img = (img @ np.array([0.2126, 0.7152, 0.0722]))[x * x + y * y < 1.0]
    peak = float(np.percentile(lum_img[lum_img > 0], 99.5)) if np.any(lum_img > 0) else 1.0
    sx.imshow(srgb_encode(img / peak), interpolation="lanczos")
    sx.set_axis_off()
    sx.set_title("the table rendered (--preview)", fontsize=9.5)

    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100, bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--demo", type=Path, default=REPO / "out" / "demo",
                    help="the folder of the demo capture and reconstruction (default: out/demo)")
    ap.add_argument("--out", type=Path, default=None,
                    help="PNG to write (default: demo.png in the --demo folder; the tracked docs/demo.png only with "
                         "--update-docs)")
    ap.add_argument("--update-docs", action="store_true", help="write the README's picture, docs/demo.png")
    args = ap.parse_args(argv)
    if args.out is None:
        args.out = REPO / "docs" / "demo.png" if args.update_docs else args.demo / "demo.png"
    for name in ("slice.csv", "material.binary"):
        if not (args.demo / name).is_file():
            print(f"readme_figure: {args.demo / name} not found: run the README's first command first",
                  file=sys.stderr)
            return 2
    try:
        draw(args.demo, args.out)
    except (SliceError, merltable.MerlError, OSError, ValueError) as exc:
        print(f"readme_figure: {exc}", file=sys.stderr)
        return 2
    print(f"readme_figure: wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
