"""The HTML report of a reconstruction: one self-contained file (images inline, no network) per material.

Sections (each a ``<section id=...>``): ``summary`` (method and why, checks, inputs, software), ``slices`` (the
measured samples with error bars, the blind spot and the skipped samples marked, every method's prediction at the
same angles, the chosen one highlighted, cross-validation's held-out predictions), ``polar`` (the slice as the
thesis draws it: the polar curve, its sub-curves and their axes), ``coverage`` (a (theta_h, theta_d) map of the
table with the measured lines on it: where the table rests on data and where it extrapolates), ``spheres`` (the
sphere under three point lights, and under a sky-and-ground environment alone, with a sun in front and with a sun
behind: :mod:`reconstruction.core.render`), ``cuts`` (in-plane cuts of the table
at other incidences), ``albedo`` (directional albedo against theta_i with the limit 1), ``checks``,
``parameters`` (with uncertainties), ``choice`` (cross-validation), ``timings``. The figures' values are
computed here (numpy) and drawn with matplotlib by a forked child as they arrive
(:class:`~reconstruction.report.figures.Drawer`); the spheres are PNGs of their own
(:mod:`reconstruction.report.spheres`); the page with the standard library. Written atomically.
"""

from __future__ import annotations

import html
import json
import warnings
from collections.abc import Callable, Mapping, Sequence
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.atomic import atomic_open
from reconstruction.base import Reconstruction
from reconstruction.core import merlgrid, merltable
from reconstruction.core.geometry import inplane_to_dirs, thesis_points_from_slice
from reconstruction.core.slicedata import Slice
from reconstruction.report.figures import Drawer
from reconstruction.report.figures import figure as _figure
from reconstruction.report.figures import log_grid as _log_grid
from reconstruction.report.figures import margins as _margins
from reconstruction.report.figures import plain_log_ticks as _plain_log_ticks
from reconstruction.report.figures import png as _png
from reconstruction.report.spheres import N_DIRS, sphere_images, sphere_pngs

Array = NDArray[np.float64]

__all__ = ["SECTIONS", "build_html", "write_html", "write_index", "draw_polar_figure", "draw_sample_figures",
           "draw_table_figures", "draw_sigma_figures", "slice_curves", "coverage_values", "sigma_values",
           "cut_lines"]

SECTIONS = ("summary", "slices", "polar", "coverage", "spheres", "cuts", "albedo", "checks", "parameters",
            "choice", "timings")
_CSS = """body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}
h1{font-size:1.6em}h2{font-size:1.25em;border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.8em}
table{border-collapse:collapse;font-size:.9em}td,th{border:1px solid #ddd;padding:.25em .6em;text-align:left}
.pass{color:#176b2c;font-weight:bold}.fail{color:#a31515;font-weight:bold}img{max-width:100%}
.note{color:#555;font-size:.9em}code{background:#f3f3f3;padding:0 .2em}
.spheres{display:grid;grid-template-columns:repeat(3,auto);justify-content:start;gap:.3em 1em}
.spheres figure{margin:0}.spheres img{width:224px;height:224px}.spheres figcaption{font-size:.85em;text-align:center}
"""  # the spheres shown at twice their SPHERE_SIZE pixels


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("gonio-brdf")
    except Exception:  # noqa: BLE001 - a source checkout without metadata
        return "unknown"


def _img(uri: str, alt: str) -> str:
    return f'<img src="{uri}" alt="{html.escape(alt)}">'


def _lum(v: ArrayLike) -> Array:
    a = np.asarray(v, dtype=np.float64)
    return a.mean(axis=-1) if a.ndim > 1 else a


#: most incidences drawn per figure (a hemispherical file has dozens): spread evenly over the measured ones
MAX_PANELS = 8
#: panels per row
PANELS_PER_ROW = 4


def shown_incidences(s: Slice) -> list[float]:
    """The incidences (deg) the per-incidence figures draw: all up to :data:`MAX_PANELS`, else that many spread
    evenly over them (first and last included)."""
    inc = [float(t) for t in s.incidences()]
    if len(inc) <= MAX_PANELS:
        return inc
    return [inc[k] for k in np.unique(np.round(np.linspace(0, len(inc) - 1, MAX_PANELS)).astype(int))]


def _panels(n: int, w: float, h: float) -> tuple[Any, list[Any]]:
    """A figure of ``n`` panels, :data:`PANELS_PER_ROW` a row, each about ``w`` x ``h`` inches (at most 16 wide)."""
    cols = min(n, PANELS_PER_ROW)
    rows = -(-n // cols)
    fig = _figure((min(w * cols, 16), h * rows))
    axes = fig.subplots(rows, cols, squeeze=False)
    flat = list(axes.ravel())
    for ax in flat[n:]:
        ax.set_visible(False)
    return fig, flat[:n]


def _shown_note(s: Slice) -> str:
    """A sentence for the figures' note when they draw only some of the incidences."""
    shown, n = shown_incidences(s), len(s.incidences())
    return "" if len(shown) == n else (f" {len(shown)} of the {n} incidences are drawn ("
                                       + ", ".join(f"{x:g}" for x in shown) + " deg).")


#: the outgoing angles (deg) at which the slices figure draws each method's prediction
DENSE_THETA_O_DEG = np.linspace(-89.0, 89.0, 357)


def slice_curves(s: Slice, preds: Mapping[str, Callable[[Array, Array], ArrayLike]]) -> dict[str, Array]:
    """Each method's prediction (channel mean, 1/sr) at the incidences the figures draw
    (:func:`shown_incidences`) and :data:`DENSE_THETA_O_DEG`: name -> (incidences, angles), in one evaluation
    each."""
    inc = np.asarray(shown_incidences(s), dtype=np.float64)
    n = DENSE_THETA_O_DEG.size
    wi, wo = inplane_to_dirs(np.radians(np.repeat(inc, n)), np.radians(np.tile(DENSE_THETA_O_DEG, inc.size)))
    return {name: _lum(np.asarray(fn(wi, wo), dtype=np.float64)).reshape(inc.size, n) for name, fn in preds.items()}


def _slices_figure(s: Slice, chosen: str, curves: Mapping[str, Array], held_out: Array | None,
                   blind_deg: float) -> str:
    """The slices figure: ``curves`` from :func:`slice_curves`; ``held_out`` (N, C) in the order of ``s``."""
    inc = shown_incidences(s)
    fig, axes = _panels(len(inc), 5.2, 3.8)
    f, std = s.brdf()
    lum, lstd = _lum(f), _lum(std)
    for k, (ax, t) in enumerate(zip(axes, inc, strict=True)):
        m = s.theta_i_deg == t
        to = s.theta_o_deg[m]
        ax.axvspan(-t - blind_deg, -t + blind_deg, color="0.85", label="blind spot")
        for name, y in curves.items():
            ax.plot(DENSE_THETA_O_DEG, np.maximum(y[k], 1e-12), lw=2.6 if name == chosen else 1.0,
                    color="k" if name == chosen else None, label=name + (" (chosen)" if name == chosen else ""),
                    zorder=3 if name == chosen else 2)
        ax.errorbar(to, lum[m], yerr=lstd[m], fmt="o", ms=3, color="tab:red", ecolor="tab:red", label="measured",
                    zorder=4)
        if held_out is not None:
            h = _lum(held_out[m])
            ok = np.isfinite(h)
            ax.plot(to[ok], np.maximum(h[ok], 1e-12), "x", color="tab:purple", ms=5, label="held-out prediction",
                    zorder=5)
        gaps = np.nonzero(np.diff(np.sort(to)) > 2.5 * np.median(np.diff(np.sort(to))))[0] if to.size > 2 else []
        srt = np.sort(to)
        for g in gaps:
            ax.axvspan(srt[g], srt[g + 1], color="gold", alpha=0.25, label="not measured" if g == gaps[0] else None)
        ax.set_yscale("log")
        _plain_log_ticks(ax.yaxis)
        ax.set_xlim(-90, 90)
        ax.set_xlabel("theta_o (deg, + = specular side)")
        ax.set_ylabel("f_r (1/sr), channel mean")
        ax.set_title(f"theta_i = {t:g} deg")
        _log_grid(ax)
        ax.grid(True, which="major", axis="x", alpha=0.2)
    axes[0].legend(fontsize=7)
    _margins(fig, 1.0, 0.15, 0.6, 0.37, wgap=1.1, hgap=1.0)
    return _png(fig)


def _polar_figure(s: Slice) -> str:
    from reconstruction.methods.revolve import split_subcurves, subcurve_axis

    inc = shown_incidences(s)
    fig, axes = _panels(len(inc), 4.6, 3.9)
    f, _ = s.brdf()
    for ax, t in zip(axes, inc, strict=True):
        m = s.theta_i_deg == t
        order = np.argsort(s.theta_o_deg[m])
        to = np.radians(s.theta_o_deg[m][order])
        lum = np.maximum(_lum(f[m][order]), 0.0)
        pts = thesis_points_from_slice(to, lum)
        try:
            ranges = split_subcurves(pts)
        except ValueError:
            ranges = [(0, pts.shape[0] - 1)]
        for k, (a, b) in enumerate(ranges):
            seg = pts[a:b + 1]
            ax.plot(seg[:, 0], seg[:, 1], "-o", ms=2, lw=1.5, label=f"sub-curve {k + 1}")
            try:
                axis = subcurve_axis(seg)
                d = np.asarray(axis.direction, dtype=np.float64)
                p0 = np.asarray(axis.point, dtype=np.float64)
                ext = 1.2 * float(np.max(np.linalg.norm(seg, axis=1)))
                ax.plot([p0[0] - d[0] * ext, p0[0] + d[0] * ext], [p0[1] - d[1] * ext, p0[1] + d[1] * ext], "--",
                        lw=0.8, color="0.3")
            except ValueError:
                pass
        ax.axhline(0, color="k", lw=0.6)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"theta_i = {t:g} deg: value x (sin, cos) theta_o")
        ax.set_xlabel("x (specular side +)")
        ax.set_ylabel("z (normal)")
        ax.legend(fontsize=7)
    _margins(fig, 0.8, 0.15, 0.6, 0.37, wgap=0.9, hgap=1.0)
    return _png(fig)


def coverage_values(table: Array) -> Array:
    """The coverage map's values: log10 f cos_i cos_o on the table's in-plane sheet (phi_d ~ 0), (theta_h,
    theta_d) = (90, 90)."""
    th, td, _ = merlgrid.cell_angles()
    cc = np.cos(td[0, :, 0])[None, :] ** 2 - np.sin(th[:, 0, 0])[:, None] ** 2  # in-plane cos_i cos_o
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # cells without a value in any channel: NaN, drawn blank
        g = np.nanmean(table[:, :, :, 0], axis=0)  # phi_d ~ 0: the in-plane configurations
    return np.log10(np.maximum(g * np.clip(cc, 0, None), 1e-6))


def _coverage_figure(val: Array, s: Slice) -> str:
    """The coverage figure from :func:`coverage_values`."""
    return _png(_coverage_draw(val, s))


def _coverage_plot(table: Array, s: Slice) -> Any:
    """The figure of the coverage section: the in-plane sheet of the table with the measured samples on it
    (white dots edged in black, so the legend's marker shows on its grey frame)."""
    return _coverage_draw(coverage_values(table), s)


def _coverage_draw(val: Array, s: Slice) -> Any:
    fig = _figure((6.4, 4.8))
    ax = fig.subplots()
    _margins(fig, 0.65, 0.15, 0.6, 0.37)
    im = ax.imshow(val.T, origin="lower", aspect="auto", extent=[0, 90, 0, 90], cmap="viridis")
    fig.colorbar(im, ax=ax, label="log10 f cos(theta_i) cos(theta_o), in-plane")
    _samples_on_map(ax, s, "where the table rests on data")
    return fig


def _samples_on_map(ax: Any, s: Slice, title: str) -> None:
    """The measured samples (white dots edged in black) on a (theta_h index, theta_d) map, its axes, title and
    legend (its marker visible on a grey frame)."""
    hh = np.abs(s.theta_o_deg - s.theta_i_deg) / 2.0
    dd = np.abs(s.theta_o_deg + s.theta_i_deg) / 2.0
    ax.plot(np.sqrt(hh / 90.0) * 90.0, dd, "o", ms=2.5, mfc="w", mec="k", mew=0.4, label="measured samples")
    ax.set_xlabel("theta_h index (sqrt-spaced bins, as in the table)")
    ax.set_ylabel("theta_d (deg)")
    ax.set_title(title)
    ax.legend(fontsize=7, loc="upper right", markerscale=2.0, facecolor="0.75", framealpha=0.9)


def sigma_values(sigma: ArrayLike) -> Array:
    """The sigma map's values: sigma of ln f over (theta_h, theta_d), the median over phi_d of the channels'
    mean, (90, 90); NaN where no cell of a row lies above the horizon."""
    sg = np.asarray(sigma).mean(axis=0, dtype=np.float32)  # (90, 90, 180); single precision: a map to look at
    valid = merlgrid.valid_mask() & np.isfinite(sg)
    srt = np.sort(np.where(valid, sg, np.inf), axis=2)  # the cells below the horizon sorted last
    n = valid.sum(axis=2)
    lo = np.take_along_axis(srt, np.maximum((n - 1) // 2, 0)[..., None], axis=2)[..., 0]
    hi = np.take_along_axis(srt, np.maximum(n // 2, 0)[..., None], axis=2)[..., 0]
    return np.where(n > 0, 0.5 * (lo.astype(np.float64) + hi), np.nan)


def _sigma_figure(val: Array, s: Slice) -> str:
    """The sigma figure from :func:`sigma_values`, with the samples on it."""
    from matplotlib.colors import LogNorm

    fig = _figure((6.4, 4.8))
    ax = fig.subplots()
    _margins(fig, 0.65, 0.22, 0.6, 0.37)
    im = ax.imshow(np.clip(val.T, 0.01, 5.0), origin="lower", aspect="auto", extent=[0, 90, 0, 90], cmap="magma",
                   norm=LogNorm(0.01, 5.0))
    cb = fig.colorbar(im, ax=ax, label="sigma of ln f_r (median over phi_d; 0.1 = 10 %, 1 = a factor e)")
    _plain_log_ticks(cb.ax.yaxis)
    _log_grid(cb.ax, grid=False)
    _samples_on_map(ax, s, "how sure the table is (sigma of ln f)")
    return _png(fig)


def _spheres_html(pngs: Sequence[tuple[str, str]]) -> str:
    """The spheres as a grid of captioned images (three a row, each shown at twice its pixels)."""
    cells = "".join(f'<figure>{_img(uri, name)}<figcaption>{html.escape(name)}</figcaption></figure>'
                    for name, uri in pngs)
    return f'<div class="spheres">{cells}</div>'


def cut_lines(table: Array, s: Slice, sigma: Array | None = None) -> list[tuple[float, Array, Array | None, bool]]:
    """The cuts figure's lines: (theta_i in deg, the table's channel mean at :data:`CUT_THETA_O_DEG`, sigma of ln
    f there or None, whether measured) for 0, 20, 40, 60, 75 deg and the measured incidences (with many measured,
    :data:`MAX_PANELS` of them spread evenly); sigma only at the incidences not measured."""
    measured = set(float(x) for x in s.incidences())
    cuts = {0.0, 20.0, 40.0, 60.0, 75.0} | measured if len(measured) <= MAX_PANELS else set(shown_incidences(s))
    to = CUT_THETA_O_DEG
    out: list[tuple[float, Array, Array | None, bool]] = []
    for t in sorted(cuts):
        wi, wo = inplane_to_dirs(np.radians(np.full(to.size, t)), np.radians(to))
        v = _lum(np.nan_to_num(merltable.lookup(table, wi, wo, interpolate=True)))
        sg = (_lum(np.nan_to_num(merltable.lookup(sigma, wi, wo, interpolate=True)))
              if sigma is not None and t not in measured else None)
        out.append((t, v, sg, t in measured))
    return out


#: the outgoing angles (deg) of the cuts figure
CUT_THETA_O_DEG = np.linspace(-85.0, 85.0, 341)


def _cuts_figure(lines: Sequence[tuple[float, Array, Array | None, bool]]) -> str:
    """The cuts figure from :func:`cut_lines` (a band of +- 1 sigma where sigma is given)."""
    fig = _figure((8.5, 4.2))
    ax = fig.subplots()
    to = CUT_THETA_O_DEG
    for t, v, sg, measured in lines:
        line = ax.plot(to, np.maximum(v, 1e-9), lw=2.0 if measured else 1.0, ls="-" if measured else "--",
                       label=f"theta_i {t:g}" + (" (measured)" if measured else ""))[0]
        if sg is not None:  # +- 1 sigma of ln f at the incidences not measured
            ax.fill_between(to, np.maximum(v * np.exp(-sg), 1e-9), np.maximum(v * np.exp(sg), 1e-9),
                            color=line.get_color(), alpha=0.12, lw=0)
    ax.set_yscale("log")
    _plain_log_ticks(ax.yaxis)
    ax.set_xlabel("theta_o (deg)")
    ax.set_ylabel("table f_r (1/sr), channel mean")
    ax.set_title("in-plane cuts of the written table")
    _log_grid(ax)
    ax.grid(True, which="major", axis="x", alpha=0.2)
    ax.legend(fontsize=7, ncol=2)
    _margins(fig, 0.9, 0.15, 0.6, 0.37)
    return _png(fig)


def _albedo_figure(checks: Mapping[str, Any]) -> str:
    return _png(_albedo_plot(checks))


def _albedo_plot(checks: Mapping[str, Any]) -> Any:
    """The figure of the albedo section: one curve per channel (one for grey data) and the limit 1."""
    a = checks["albedo"]
    alb = np.asarray(a["albedo"], dtype=np.float64)
    fig = _figure((6.0, 3.6))
    ax = fig.subplots()
    grey = alb.shape[1] == 1 or bool(np.allclose(alb, alb[:, :1], rtol=1e-9, atol=0.0))
    if grey:  # one curve for grey data (the table holds the same value in its three channels)
        ax.plot(a["theta_i_deg"], alb[:, 0], "o-", ms=3, color="k", label="grey (every channel)")
    for k in range(0 if grey else alb.shape[1]):
        ax.plot(a["theta_i_deg"], alb[:, k], "o-", ms=3, color=("tab:red", "tab:green", "tab:blue")[k % 3],
                label=("R", "G", "B")[k % 3])
    ax.axhline(1.0, color="k", ls="--", lw=1, label="limit 1 (energy conservation)")
    ax.set_xlabel("theta_i (deg)")
    ax.set_ylabel("directional albedo")
    ax.set_ylim(0, max(1.1, float(alb.max()) * 1.1))
    ax.legend(fontsize=7)
    _margins(fig, 0.67, 0.15, 0.6, 0.15)
    return fig


def _kv_table(d: Mapping[str, Any]) -> str:
    rows = "".join(f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(_fmt(v))}</td></tr>" for k, v in d.items())
    return f"<table>{rows}</table>"


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (list, tuple)) and v and all(isinstance(x, (int, float)) or x is None for x in v):
        return ", ".join("-" if x is None else (f"{x:.6g}" if isinstance(x, float) else str(x)) for x in v)
    if isinstance(v, Mapping):
        return "; ".join(f"{k} = {_fmt(x)}" for k, x in v.items())
    if isinstance(v, list):
        return json.dumps(v)[:400]
    return str(v)


def _with_std(p: Mapping[str, Any]) -> dict[str, Any]:
    """Parameters with their ``*_std`` folded in: "value +- std" (per channel for lists)."""
    out: dict[str, Any] = {}
    for k, v in p.items():
        if k.endswith("_std"):
            continue
        sd = p.get(f"{k}_std")
        if isinstance(v, (int, float)) and isinstance(sd, (int, float)):
            out[k] = f"{v:.6g} +- {sd:.2g}"
        elif isinstance(v, list) and isinstance(sd, list) and len(v) == len(sd):
            out[k] = ", ".join(f"{a:.6g}" + (f" +- {b:.2g}" if isinstance(b, (int, float)) else "")
                               for a, b in zip(v, sd, strict=True))
        else:
            out[k] = v
    return out


def draw_polar_figure(drawer: Drawer, working: Slice) -> None:
    """Send the ``polar`` figure (the samples alone) to ``drawer``: a run sends it as soon as it has read them."""
    drawer.draw("polar", _polar_figure, working.sorted())


def draw_sample_figures(drawer: Drawer, working: Slice, rec: Reconstruction,
                        alternatives: Mapping[str, Reconstruction] | None = None, held_out: Array | None = None,
                        blind_deg: float = 4.0) -> None:
    """Send the ``slices`` figure (the samples and every method's prediction; ``held_out`` (N, C) in the order
    of ``working``) to ``drawer``, and ``polar`` unless sent. A run sends them as soon as its methods are built,
    while it goes on to tabulate; :func:`build_html` sends them when they were not."""
    order = np.lexsort((working.theta_o_deg, working.theta_i_deg))
    s = working.take(order)
    held = None if held_out is None else np.asarray(held_out, dtype=np.float64)[order]
    preds: dict[str, Callable[[Array, Array], ArrayLike]] = {rec.method: rec.eval}
    for name, other in (alternatives or {}).items():
        if name != rec.method:
            preds[name] = other.eval
    if "polar" not in drawer.sent:
        draw_polar_figure(drawer, working)
    drawer.draw("slices", _slices_figure, s, rec.method, slice_curves(s, preds), held, float(blind_deg))


def draw_table_figures(drawer: Drawer, working: Slice, table: Array, checks: Mapping[str, Any]) -> None:
    """Send the figures of the written ``table`` alone to ``drawer``: ``albedo`` and ``coverage``, their values
    computed here (numpy). A run sends them once its table is final, while it writes it and assesses it."""
    drawer.draw("albedo", _albedo_figure, {"albedo": checks["albedo"]})
    drawer.draw("coverage", _coverage_figure, coverage_values(np.asarray(table, dtype=np.float64)), working)


def draw_sigma_figures(drawer: Drawer, working: Slice, table: Array, sigma: Array | None = None) -> None:
    """Send the figures that show the uncertainty to ``drawer``: ``cuts`` (with bands of +- 1 sigma of ln f
    where ``sigma`` is given) and, with it, ``sigma``."""
    if sigma is not None:
        drawer.draw("sigma", _sigma_figure, sigma_values(sigma), working)
    drawer.draw("cuts", _cuts_figure, cut_lines(np.asarray(table, dtype=np.float64), working, sigma))


def build_html(*, report: Mapping[str, Any], working: Slice, rec: Reconstruction, table: ArrayLike,
               alternatives: Mapping[str, Reconstruction] | None = None, held_out: Array | None = None,
               title: str | None = None, sigma: ArrayLike | None = None,
               spheres: Callable[[], Any] | None = None, drawer: Drawer | None = None) -> str:
    """The page (a string). ``report`` is the JSON report; ``alternatives`` the other methods' reconstructions
    of the same samples (their predictions are drawn); ``held_out`` (N, C), in the order of ``working``:
    cross-validation's prediction of each sample from the fold that left it out (NaN where it was never held
    out); ``sigma``: the --uncertainty array (sigma of ln f per cell), drawn as a map and as bands on the cuts;
    ``spheres``: the sphere renders under way (a function giving :func:`sphere_images` of ``table``; rendered
    here when None); ``drawer``: a :class:`~reconstruction.report.figures.Drawer` the run made at its start
    and has sent the sample figures to (:func:`draw_sample_figures`), and the table's
    (:func:`draw_table_figures`) of this ``table``; without it one is made here (a forked child draws the
    figures while this process renders the spheres)."""
    t = np.asarray(table, dtype=np.float64)
    sg = None if sigma is None else np.asarray(sigma)  # float32 as written: read as it is
    with Drawer() if drawer is None else nullcontext(drawer) as d:
        if "slices" not in d.sent:
            draw_sample_figures(d, working, rec, alternatives, held_out,
                                float(report.get("inputs", {}).get("blind_spot_deg") or 4.0))
        if "coverage" not in d.sent:
            draw_table_figures(d, working, t, report["checks"])
        draw_sigma_figures(d, working, t, sg)
        pngs = sphere_pngs(spheres() if spheres is not None  # while the child draws
                           else sphere_images(t, report["checks"]["albedo"]))
        fig = d.results()
    return _page(report, working, title, fig, pngs, sg)


def _page(report: Mapping[str, Any], working: Slice, title: str | None, fig: Mapping[str, str],
          pngs: Sequence[tuple[str, str]], sg: Array | None) -> str:
    """:func:`build_html`'s page from the figures' data URIs ``fig`` and the spheres' ``pngs``."""
    s = working.sorted()
    checks = report["checks"]
    name = title or str(working.meta.get("material") or Path(str(working.source)).stem or "material")
    sec: dict[str, str] = {}
    status = "pass" if checks["all_pass"] else "fail"
    summary = {"method used": report["method"], "method requested": report.get("method_requested"),
               "why": report.get("method_reason", ""), "plausibility checks": "passed" if checks["all_pass"]
               else "FAILED", "inputs": ", ".join(map(str, report.get("inputs", {}).get("files", []))),
               "samples": len(working), "incidences (deg)": ", ".join(f"{x:g}" for x in working.incidences()),
               "software": f"gonio-brdf {_version()}"}
    if isinstance(report.get("principled"), Mapping):  # --principled / --materialx / --gltf / --blender
        summary["principled material"] = report["principled"].get("summary", "")
    sec["summary"] = (f'<p class="{status}">Checks {"passed" if checks["all_pass"] else "failed"}.</p>'
                      + _kv_table(summary))
    sec["slices"] = (_img(fig["slices"], "measured slices and predictions")
                     + '<p class="note">Points: the measured samples with their standard deviations; grey: the '
                       "blind spot around the retro direction; gold: stretches with no samples; lines: each "
                       "method's prediction at the same angles (the chosen one thick and black); crosses: "
                       "cross-validation's prediction of each sample from the folds that left it out."
                     + _shown_note(s) + "</p>")
    sec["polar"] = (_img(fig["polar"], "polar curve with sub-curves and axes")
                    + '<p class="note">The slice as the thesis draws it: each sample as value x (sin, cos) '
                      "theta_o, split into sub-curves where the curve's turning changes sign, each with its axis "
                      "of revolution (dashed).</p>")
    sec["coverage"] = (_img(fig["coverage"], "theta_h theta_d map of the table")
                       + '<p class="note">The in-plane (phi_d = 0) sheet of the table; white dots are the '
                         "measured samples. Away from them the table extrapolates; the rings and bands a "
                         "data-driven method shows in previews come from these interpolations between measured "
                         "lines and from its phi_d-independent approximation.</p>")
    if sg is not None:
        u = report.get("uncertainty", {})
        ms = u.get("median_sigma", {})
        sec["coverage"] += (_img(fig["sigma"], "theta_h theta_d map of sigma")
                            + '<p class="note">sigma of ln f_r per cell (the --uncertainty array): median '
                              + ", ".join(f"{ms[k]:.3f} over {k}" for k in ms if ms[k] is not None)
                              + " cells. Expected against the truth: PSNR "
                              + f"{u.get('expected_psnr_db', float('nan')):.1f} dB, linear image error "
                              + f"{u.get('expected_linear_image_error', float('nan')):.1%}, cosl2 "
                              + f"{u.get('expected_cosl2', float('nan')):.1%}." + _expected_vs_held_out(report)
                              + "</p>")
    sec["spheres"] = (_spheres_html(pngs)
                      + '<p class="note">The written table on a sphere (linear radiance, each image exposed on its '
                        "own 99.5th percentile, sRGB). Top: a point light and a dim uniform environment, as the "
                        f"preview. Bottom: a sky-and-ground environment (integrated over a fixed set of {N_DIRS} "
                        "directions per pixel, importance-sampled around the mirror direction, so the grazing "
                        "rim is resolved), alone, with a sun in front and with a sun behind the sphere (grazing "
                        "light): reconstruction.core.render.</p>")
    sec["cuts"] = _img(fig["cuts"], "in-plane cuts of the table")
    sec["albedo"] = _img(fig["albedo"], "directional albedo")
    rows = []
    for k in ("non_negative", "albedo", "reciprocity"):
        c = checks[k]
        figures = {kk: vv for kk, vv in c.items() if kk not in ("pass", "albedo", "theta_i_deg")}
        rows.append(f'<tr><th>{k}</th><td class="{"pass" if c["pass"] else "fail"}">'
                    f'{"pass" if c["pass"] else "FAIL"}</td><td>{html.escape(_fmt(figures))}</td></tr>')
    sec["checks"] = "<table>" + "".join(rows) + "</table>"
    params = report.get("parameters")
    if isinstance(params, list):
        sec["parameters"] = "".join(_kv_table(_with_std(p)) for p in params)
    elif isinstance(params, Mapping):
        sec["parameters"] = _kv_table(_with_std(params))
    else:
        sec["parameters"] = "<p>none</p>"
    cv = report.get("cross_validation")
    if cv:
        rows = ""
        for c in cv["scores"]:
            err, img = c["held_out_relative_rmse_cos"], c.get("held_out_image_error")
            label = c.get("label", c["method"])
            cls = ' class="pass"' if label == cv.get("chosen_label", cv["chosen"]) else ""
            rows += (f"<tr{cls}><td>{html.escape(label)}</td><td>{'-' if img is None else f'{img:.4f}'}</td>"
                     f"<td>{'-' if err is None else f'{err:.4%}'}</td><td>{c['seconds']:.2f}</td></tr>")
        sec["choice"] = (f"<p>{html.escape(report.get('method_reason', ''))}</p><p>Scheme: "
                         f"{html.escape(cv['scheme'])}; metric: {html.escape(cv['metric'])}.</p><table><tr><th>"
                         "method</th><th>held-out image error</th><th>held-out relative RMSE</th><th>seconds</th>"
                         "</tr>" + rows + "</table>")
    else:
        sec["choice"] = f"<p>{html.escape(report.get('method_reason', ''))}</p>"
    sec["timings"] = _kv_table({k: f"{v:.3f} s" for k, v in report.get("timings_s", {}).items()})
    body = "".join(f'<section id="{k}"><h2>{k.capitalize()}</h2>{sec[k]}</section>' for k in SECTIONS)
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>{html.escape(name)}: '
            f'gonio-brdf report</title><style>{_CSS}</style></head><body><h1>{html.escape(name)}</h1>'
            f"{body}</body></html>\n")


def _expected_vs_held_out(report: Mapping[str, Any]) -> str:
    """The sentence that sets the uncertainty's expected errors beside cross-validation's held-out error: they
    measure different things, and the first is usually the larger."""
    cv = report.get("cross_validation") or {}
    chosen = cv.get("chosen_label", cv.get("chosen"))
    held = next((c.get("held_out_relative_rmse_cos") for c in cv.get("scores", [])
                 if c.get("label", c.get("method")) == chosen), None)
    than = f" (here {held:.2%} for {chosen})" if isinstance(held, float) else ""
    return (" These are over the whole table as a renderer sees it, mostly directions out of the plane of "
            "incidence and incidences no slice measured, where the table extrapolates; cross-validation's "
            f"held-out error{than} is the error at the measured samples' own angles, in the plane, so it is "
            "usually far smaller: both are right, about different directions.")


def write_html(path: str | Path, **kwargs: Any) -> None:
    """:func:`build_html` written to ``path`` atomically (temporary file, fsync, rename)."""
    text = build_html(**kwargs)
    with atomic_open(Path(path), "w", encoding="utf-8") as fh:
        fh.write(text)


def write_index(path: str | Path, entries: Sequence[Mapping[str, Any]]) -> None:
    """An index page of a batch: one row per material (name, method, checks, link to its page or the error)."""
    rows = []
    for e in entries:
        link = (f'<a href="{html.escape(Path(e["html"]).name)}">{html.escape(e["name"])}</a>' if e.get("html")
                else html.escape(e["name"]))
        rows.append(f"<tr><td>{link}</td><td>{html.escape(str(e.get('method', '-')))}</td>"
                    f"<td>{html.escape(str(e.get('error', 'ok')))}</td></tr>")
    text = (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>gonio-brdf batch</title>'
            f"<style>{_CSS}</style></head><body><h1>Batch reconstruction</h1><table><tr><th>material</th><th>"
            f"method</th><th>result</th></tr>{''.join(rows)}</table></body></html>\n")
    with atomic_open(Path(path), "w", encoding="utf-8") as fh:
        fh.write(text)
