"""``gonio-compare A B``: two BRDFs compared as the field judges them (A = a reconstruction, B = the reference).

Any two BRDFs the project reads (:func:`reconstruction.formats.brdffile.load_brdf`): a MERL table (``.binary``),
an RGL-EPFL measured material (``.bsdf``, read as Mitsuba's ``measured`` plugin does), a Zemax tabular BSDF, a
neural-BRDF npy set (the published layout of asztr/Neural-BRDF: ``PREFIX`` or any ``PREFIX_fc1.npy`` ...
``PREFIX_b3.npy``, or a folder holding one such set) and a material TOML (``[material]``); spectral files in
linear sRGB. The figures (the metrics of
``../shared/realdata/README.md``; :func:`compare` returns them, ``--json`` writes them):

* ``image``: a sphere rendered with A and with B (:func:`reconstruction.core.render.render_sphere`) under the
  presets ``key`` (a sky-and-ground environment plus a sun in front) and ``rim`` (the same sky plus a sun behind
  the sphere: grazing light), pixels seen at a view angle above 80 deg left out: per lighting ``psnr_db`` of the
  tone-mapped images (exposure at B's 99.5th percentile, clipped, gamma 2.2; infinite, ``null`` in JSON, for
  identical images) and ``relative_rmse`` of the linear images, and ``relative_rmse_but_brightest_pixel``, the
  same with B's single brightest pixel left out (a glossy highlight's error is its one or two brightest pixels:
  f at a theta_h finer than a bench's step); ``psnr_db``, ``relative_rmse`` and
  ``relative_rmse_but_brightest_pixel`` at the top of ``image`` are the means over the two lightings. A MERL
  table is read with trilinear interpolation.
* ``cosl2``: relative cosine-weighted L2 of f over direction pairs drawn uniformly in solid angle, both angles
  <= 80 deg (:func:`reconstruction.core.metrics.cosl2`).
* ``log_error``: mean |ln((f_A cos ti + 1e-3) / (f_B cos ti + 1e-3))| over the same pairs.
* ``rmse80``: relative RMSE of f cos ti cos to over the MERL cells with both angles <= 80 deg (a BRDF that is not
  a table is tabulated first, at the bin centres), and ``rmse80_grazing_share``: the share of its square from
  the cells with theta_d >= 60 deg.

Grey against colour: when one side is grey (one channel, as a photodiode bench measures: every channel of a table
equal) and the other colour, the colour side is read in the photodiode's band (:func:`band_matched`: its R, G,
B weighted by the band over the Mallett-Yuksel spectra of R, G and B, as the simulator reads an RGB material;
``--band RESPONSIVITY,SOURCE``, default silicon,halogen-3000K, the bench's default) and the output says so
(``band`` in the JSON); ``--no-band`` compares them as they are, and says that it compares grey with colour.

Dimensionless errors are fractions (0.05 = 5 %). ``--png OUT`` writes the two spheres side by side with their
difference. Bad input: exit 2 and one line naming the file and what was expected.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from reconstruction.base import ReconstructionError
from reconstruction.core import merltable
from reconstruction.core.metrics import (
    IMAGE_MAX_VIEW_DEG,
    cosl2,
    image_exposure,
    image_psnr,
    image_relative_rmse,
    log_error,
    relative_rmse_cos_by_theta_d,
    tone_map,
    uniform_pairs,
)
from reconstruction.core.render import render_sphere, view_angle_mask

Array = NDArray[np.float64]
BRDF = Callable[[Array, Array], Any]

__all__ = ["Brdf", "Reference", "CompareError", "load_brdf", "reference", "judge", "compare", "main", "is_grey",
           "band_matched",
           "LIGHTINGS", "N_PAIRS", "MAX_THETA_DEG", "GRAZING_THETA_D_DEG"]

PROG = "gonio-compare"
LIGHTINGS = ("key", "rim")
N_PAIRS = 200_000  # direction pairs of cosl2 and the log error (their sampling noise is far below 1 %)
MAX_THETA_DEG = 80.0
GRAZING_THETA_D_DEG = 60.0


class CompareError(ReconstructionError):
    """A BRDF to compare cannot be read; the message names the file and what was expected."""


def _rgb(v: Any, n: int) -> Array:
    """(n, 3) f_r from a BRDF's (n, 1 | 3) values (grey repeated)."""
    a = np.asarray(v, dtype=np.float64).reshape(n, -1)
    return np.repeat(a, 3, axis=1) if a.shape[1] == 1 else a


@dataclass
class Brdf:
    """A BRDF to compare: ``eval(wi, wo) -> (N, 1 | 3)`` (1/sr) and, for a MERL table, the ``table`` itself
    (3, 90, 90, 180), which is then what is rendered and evaluated (interpolated lookups)."""

    name: str
    kind: str  # "merl", "rgl", "nbrdf", "material"
    eval: BRDF
    table: Array | None = None
    _tabulated: Array | None = field(default=None, repr=False)

    def f(self) -> BRDF:
        """The BRDF as the renderer and the metrics read it: a table's interpolated lookup, else ``eval``."""
        return merltable.brdf_of(self.table) if self.table is not None else self.eval

    def values(self, wi: Array, wo: Array) -> Array:
        """f_r (N, 3) at pairs (N, 3): non-finite values (a table's empty cells) as 0."""
        return np.nan_to_num(_rgb(self.f()(wi, wo), wi.shape[0]), nan=0.0, posinf=0.0, neginf=0.0)

    def merl_table(self) -> Array:
        """The MERL table: the table itself, or this BRDF tabulated at the bin centres (once)."""
        if self.table is not None:
            return self.table
        if self._tabulated is None:
            self._tabulated = merltable.tabulate(self.eval)
        return self._tabulated


def load_brdf(path: str | Path) -> Brdf:
    """Read the BRDF at ``path`` (:func:`reconstruction.formats.brdffile.load_brdf`: every file the project reads);
    :class:`CompareError` naming the file otherwise."""
    from reconstruction.formats.brdffile import load_brdf as load

    try:
        b = load(path)
    except ReconstructionError as e:
        raise CompareError(str(e)) from None
    if b.table is not None:
        return Brdf(b.name, b.kind, merltable.brdf_of(b.table), b.table)
    return Brdf(b.name, b.kind, b.eval)


def is_grey(b: Brdf) -> bool:
    """True when ``b`` has one channel: a table whose three channels are equal (to 1e-5, NaN where NaN: the MERL
    format scales each channel by its own factor, so a grey table reads back equal to rounding), or a BRDF that
    evaluates to one channel (or three equal ones) at a few hundred direction pairs."""
    if b.table is not None:
        t = np.asarray(b.table)
        return bool(np.allclose(t[0], t[1], rtol=1e-5, atol=0.0, equal_nan=True)  # the format's scales: float64
                    and np.allclose(t[1], t[2], rtol=1e-5, atol=0.0, equal_nan=True))
    wi, wo = uniform_pairs(256, MAX_THETA_DEG)
    v = np.asarray(b.eval(wi, wo), dtype=np.float64).reshape(wi.shape[0], -1)
    return v.shape[1] == 1 or bool(np.allclose(v, v[:, :1], rtol=1e-9, atol=0.0, equal_nan=True))


def band_matched(a: Brdf, b: Brdf, band: tuple[str, str] | None) -> tuple[Brdf, Brdf, dict[str, Any] | None]:
    """(a, b, what was done) for a grey side against a colour side: the colour one read in the photodiode ``band``
    ((responsivity, source) names of :func:`reconstruction.schema.optics.spectrum_of`), so that both are the one
    channel a photodiode measures; as they are with ``band`` None (the note then says that grey is compared with
    colour). The note is None when both are grey or both colour."""
    grey_a, grey_b = is_grey(a), is_grey(b)
    if grey_a == grey_b:
        return a, b, None
    grey, colour = ("A", "B") if grey_a else ("B", "A")
    if band is None:
        return a, b, {"grey": grey, "colour": colour, "applied": False,
                      "note": f"{grey} is grey (one channel) and {colour} colour: compared as they are, grey against "
                              "each colour channel (--no-band)"}
    from reconstruction.schema.core import SchemaError
    from reconstruction.schema.optics import band_name, rgb_band_weights

    try:
        w = rgb_band_weights(*band)
    except SchemaError as e:
        raise CompareError(f"--band: {e}".replace(": : ", ": ")) from None
    src = b if grey_a else a
    name = band_name(*band)

    def banded(wi: Array, wo: Array) -> Array:
        return _rgb(src.eval(wi, wo), wi.shape[0]) @ w[:, None]

    table = None
    if src.table is not None:
        g = np.tensordot(w, np.asarray(src.table, dtype=np.float64), axes=1)
        table = np.broadcast_to(g[None], src.table.shape).copy()
    conv = Brdf(f"{src.name} in {name}", src.kind, merltable.brdf_of(table) if table is not None else banded, table)
    note = {"grey": grey, "colour": colour, "applied": True, "band": name,
            "rgb_weights": [round(float(x), 4) for x in w],
            "note": f"{grey} is grey (one channel, as a photodiode measures) and {colour} colour: {colour} read in the "
                    f"photodiode band {name} (R, G, B weighted {w[0]:.3f}, {w[1]:.3f}, {w[2]:.3f}); --band names "
                    "another, --no-band compares them as they are"}
    return (a, conv, note) if grey_a else (conv, b, note)


@dataclass
class Reference:
    """What a comparison needs of the reference, computed once: its renders (per lighting, (size, size, 3)), its
    values at the uniform pairs and (on demand) its MERL table."""

    brdf: Brdf
    size: int
    images: dict[str, Array]
    wi: Array
    wo: Array
    values: Array


def render_images(b: Brdf, size: int) -> dict[str, Array]:
    """The sphere rendered with ``b`` under each of :data:`LIGHTINGS`, (size, size, 3) linear radiance each."""
    return {name: np.repeat(img, 3, axis=2) if img.shape[2] == 1 else img
            for name in LIGHTINGS for img in (render_sphere(b.f(), size, name),)}


def reference(b: Brdf, size: int = 128, n_pairs: int = N_PAIRS) -> Reference:
    """The reference ``b`` rendered and evaluated once (:func:`judge` compares any number of BRDFs with it)."""
    wi, wo = uniform_pairs(n_pairs, MAX_THETA_DEG)
    return Reference(b, size, render_images(b, size), wi, wo, b.values(wi, wo))


def rmse80(table: Array, truth: Array) -> tuple[float, float]:
    """(rmse80, the share of its square from theta_d >= 60 deg) of two MERL tables."""
    parts = relative_rmse_cos_by_theta_d(table, truth, MAX_THETA_DEG, (0.0, GRAZING_THETA_D_DEG, 90.0))
    tot = float(np.sum(parts ** 2))
    return float(np.sqrt(tot)), (float(parts[1] ** 2 / tot) if tot > 0 else 0.0)


def image_metrics(images: dict[str, Array], truth: dict[str, Array], size: int) -> dict[str, Any]:
    """Per lighting ``psnr_db`` and ``relative_rmse`` over the pixels seen at <= 80 deg, and their means."""
    mask = view_angle_mask(size, 1.0, IMAGE_MAX_VIEW_DEG)
    out: dict[str, Any] = {"size": size, "max_view_deg": IMAGE_MAX_VIEW_DEG}
    for name in LIGHTINGS:
        out[name] = {"psnr_db": image_psnr(images[name], truth[name], mask),
                     "relative_rmse": image_relative_rmse(images[name], truth[name], mask),
                     "relative_rmse_but_brightest_pixel": image_relative_rmse(images[name], truth[name], mask,
                                                                              leave_out_brightest=1)}
    for key in ("psnr_db", "relative_rmse", "relative_rmse_but_brightest_pixel"):
        out[key] = float(np.mean([out[n][key] for n in LIGHTINGS]))
    return out


def judge(a: Brdf, ref: Reference, with_rmse80: bool = True,
          images: dict[str, Array] | None = None) -> dict[str, Any]:
    """``a`` against the reference: the figures of the module docstring (``rmse80`` only ``with_rmse80``).
    ``images``: ``a``'s renders if already made (:func:`render_images`)."""
    imgs = images if images is not None else render_images(a, ref.size)
    va = a.values(ref.wi, ref.wo)
    out: dict[str, Any] = {"image": image_metrics(imgs, ref.images, ref.size),
                           "cosl2": cosl2(va, ref.values, ref.wi, ref.wo),
                           "log_error": log_error(va, ref.values, ref.wi),
                           "pairs": int(ref.wi.shape[0])}
    if with_rmse80:
        out["rmse80"], out["rmse80_grazing_share"] = rmse80(a.merl_table(), ref.brdf.merl_table())
    return out


def compare(a: Brdf, b: Brdf, size: int = 128) -> dict[str, Any]:
    """``a`` (a reconstruction) against ``b`` (the reference): :func:`judge` of ``a`` and ``reference(b)``."""
    return judge(a, reference(b, size))


def write_png(path: str | Path, images: dict[str, Array], truth: dict[str, Array], labels: tuple[str, str]) -> None:
    """A, B and 4 |A - B| (tone-mapped with B's exposure), a row per lighting, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(LIGHTINGS), 3, figsize=(7.5, 2.6 * len(LIGHTINGS)), squeeze=False)
    for row, name in zip(axes, LIGHTINGS, strict=True):
        size = truth[name].shape[0]
        e = image_exposure(truth[name], view_angle_mask(size, 1.0, IMAGE_MAX_VIEW_DEG))
        ta, tb = tone_map(images[name], e), tone_map(truth[name], e)
        for ax, img, title in zip(row, (ta, tb, np.clip(4.0 * np.abs(ta - tb), 0, 1)),
                                  (f"A: {labels[0]}", f"B: {labels[1]}", "4 |A - B|"), strict=True):
            ax.imshow(img, interpolation="nearest")
            ax.set_title(f"{title} ({name})", fontsize=7)
            ax.axis("off")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _fmt_pct(x: float) -> str:
    return f"{x * 100:.2f} %" if np.isfinite(x) else "inf"


def _fmt_db(x: float) -> str:
    return f"{x:.2f} dB" if np.isfinite(x) else "inf dB (identical)"


def format_lines(res: dict[str, Any]) -> list[str]:
    """The figures of :func:`judge` as lines for a terminal."""
    im = res["image"]
    lines = [f"image ({im['size']}x{im['size']}, view <= {im['max_view_deg']:g} deg): PSNR {_fmt_db(im['psnr_db'])}"
             f" (key {_fmt_db(im['key']['psnr_db'])}, rim {_fmt_db(im['rim']['psnr_db'])}); linear error "
             f"{_fmt_pct(im['relative_rmse'])} (key {_fmt_pct(im['key']['relative_rmse'])}, rim "
             f"{_fmt_pct(im['rim']['relative_rmse'])}); without the reference's brightest pixel "
             f"{_fmt_pct(im['relative_rmse_but_brightest_pixel'])}",
             f"cosl2 {_fmt_pct(res['cosl2'])}; log error {res['log_error']:.4f} ({res['pairs']} pairs uniform in "
             f"solid angle, both angles <= {MAX_THETA_DEG:g} deg)"]
    if "rmse80" in res:
        lines.append(f"rmse80 {_fmt_pct(res['rmse80'])} ({res['rmse80_grazing_share'] * 100:.0f} % of its square at "
                     f"theta_d >= {GRAZING_THETA_D_DEG:g} deg)")
    return lines


def build_parser() -> argparse.ArgumentParser:
    from reconstruction.cliutil import OneLineParser

    ap = OneLineParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="examples:\n  gonio-compare out/demo/material.binary truth.binary --json cmp.json\n"
                              "  gonio-compare material.binary ../shared/realdata/nbrdf-merl/chrome_fc1.npy "
                              "--png cmp.png")
    ap.add_argument("a", metavar="A", help="the BRDF to judge (a reconstruction)")
    ap.add_argument("b", metavar="B", help="the reference (the truth, a reference measurement)")
    ap.add_argument("--json", metavar="OUT", help="write the figures as JSON (non-finite values as null)")
    ap.add_argument("--png", metavar="OUT", help="write A, B and their difference, rendered, as a PNG")
    ap.add_argument("--size", type=int, default=128, metavar="N", help="image size in pixels (default 128)")
    ap.add_argument("--band", default="silicon,halogen-3000K", metavar="RESPONSIVITY,SOURCE",
                    help="when one side is grey (a photodiode's one channel) and the other colour: read the colour "
                         "side in this photodiode band (default silicon,halogen-3000K, the bench's default; "
                         "responsivity silicon or a CSV, source halogen-<T>K, D65 or a CSV)")
    ap.add_argument("--no-band", action="store_true",
                    help="compare a grey side with a colour side as they are (the output says so)")
    return ap


def _band(spec: str) -> tuple[str, str]:
    """``--band RESPONSIVITY,SOURCE`` as the two names."""
    parts = [x.strip() for x in spec.split(",")]
    if len(parts) != 2 or not all(parts):
        raise CompareError(f"--band: expected RESPONSIVITY,SOURCE (e.g. silicon,halogen-3000K), got {spec!r}")
    return parts[0], parts[1]


def main(argv: Sequence[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if not 8 <= args.size <= 2048:
        ap.error(f"--size: expected 8..2048 pixels, got {args.size}")
    from reconstruction.cliutil import plain_warnings

    t0 = time.perf_counter()
    try:
        with plain_warnings(PROG), np.errstate(all="ignore"):
            a, b = load_brdf(args.a), load_brdf(args.b)
            a, b, banded = band_matched(a, b, None if args.no_band else _band(args.band))
            ref = reference(b, args.size)
            imgs = render_images(a, args.size)
            res = judge(a, ref, images=imgs)
            res["a"] = {"path": str(args.a), "kind": a.kind}
            res["b"] = {"path": str(args.b), "kind": b.kind}
            if banded is not None:
                res["band"] = banded
            if args.png:
                try:
                    write_png(args.png, imgs, ref.images, (a.name, b.name))
                except OSError as e:
                    raise CompareError(f"{args.png}: cannot write ({e.strerror or e})") from None
    except CompareError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    print(f"{PROG}: A = {args.a} ({a.kind}), B = {args.b} ({b.kind})")
    if banded is not None:
        print(f"{PROG}: {banded['note']}")
    print("\n".join(format_lines(res)))
    if args.json:
        from reconstruction.report.summary import write_json

        try:
            write_json(args.json, res)
        except OSError as e:
            print(f"{PROG}: error: {args.json}: cannot write ({e.strerror or e})", file=sys.stderr)
            return 2
    print(f"{PROG}: {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
