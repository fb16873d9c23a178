"""``gonio-align``: the arms' zero offsets, the sample's tilt and its surface's height from data.

With a first-surface mirror as the sample, short detector sweeps find the specular peak at several incidences;
a sweep over the white reference at normal incidence finds the detector arm's zero; the mirror turned 180 deg about
its normal (a second run, ``--turned``) separates the light arm's zero from the mirror's tilt. The fit and what it
can and cannot tell apart: :mod:`reconstruction.instrument.alignment`; the procedure: docs/build-a-bench.md, Alignment.

    gonio-align --config my-bench.toml --save align1.json     # mirror + white reference
    # turn the mirror 180 deg about its normal in the holder, then
    gonio-align --config my-bench.toml --turned align1.json --write

prints the ``[axes.*].zero_offset`` lines to paste (``--write`` puts them into the bench file). Exit status: 0
fitted; 1 the data do not determine the alignment (a peak outside the sweep, peaks that no fit explains: the
message says which) or a hardware failure; 2 bad arguments or bench file (nothing moved).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np

from reconstruction.instrument.alignment import (
    Alignment,
    AlignmentError,
    combine,
    fit_diffuse_zero,
    fit_specular,
    peak_centre,
    specular_peak_deg,
    zero_offset_for,
)

#: Where the detector arm stops on each side of the white reference's normal (deg), light arm at 0.
REFERENCE_THETA_O = tuple(float(x) for x in range(15, 80, 5))
#: The detector's distance from the axis when the bench file does not give [bench].detector_distance_mm (mm):
#: the printed bench's (hardware/cad/params.toml).
DEFAULT_DETECTOR_DISTANCE_MM = 70.0
#: A surface offset that moves the specular peak less than this at the highest incidence counts as on the axis.
ON_AXIS_DEG = 0.05

EPILOG = """\
examples:
  gonio-align --config configs/mirror-misaligned.toml --save out/align1.json
  gonio-align --config configs/mirror-misaligned-turned.toml --turned out/align1.json
  gonio-align --config my-bench.toml --turned align1.json --write     # the zero offsets into the bench file

exit status: 0 fitted, 1 the data do not determine the alignment (the message says why) or a hardware failure,
2 bad arguments or bench file (nothing moved).
"""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="gonio-align", epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Align the bench from data: specular peaks of a first-surface mirror at several incidences "
                    "and a sweep over the white reference give the arms' zero offsets, the mirror's tilt and how "
                    "far its surface is off the rotation axis; prints the bench-file lines to paste.")
    p.add_argument("--config", required=True, help="bench file (TOML), the mirror mounted as the sample")
    p.add_argument("--incidences", default="20,35,50,65", metavar="DEG,DEG,...",
                   help="light arm angles of the specular sweeps (default 20,35,50,65; 3 or more over 20 deg)")
    p.add_argument("--window", type=float, default=2.5, metavar="DEG",
                   help="the detector sweeps this far each side of the nominal specular (default 2.5)")
    p.add_argument("--step", type=float, default=0.1, metavar="DEG", help="detector step of a sweep (default 0.1)")
    p.add_argument("--repeats", type=int, default=2, help="detector repeats a point (default 2)")
    p.add_argument("--no-reference", action="store_true",
                   help="skip the white reference sweep (then only a - b + 2t and the surface offset are fitted)")
    p.add_argument("--turned", metavar="FILE",
                   help="the mirror is turned 180 deg about its normal since the run saved in FILE (--save): "
                        "sweep the mirror again and separate the light arm's zero from the tilt")
    p.add_argument("--save", metavar="FILE", help="write this run's measurements (JSON), for a later --turned run")
    p.add_argument("--detector-distance-mm", type=float, metavar="MM",
                   help="the detector's aperture from the axis (default [bench].detector_distance_mm, else 70)")
    p.add_argument("--write", action="store_true",
                   help="write the fitted zero_offset values into the bench file (the lines printed)")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object on stdout")
    return p


def _signal(reading: Any, dark: Any) -> float:
    """A reading's mean less the dark's, over the detector's channels (counts)."""
    return float(np.mean(np.asarray(reading.mean, float) - np.asarray(dark.mean, float)))


def sweep(bench: Any, theta_i: float, theta_o: list[float], repeats: int, dark: Any) -> dict[str, Any]:
    """The detector arm through ``theta_o`` (ascending, approached from below) with the light arm at ``theta_i``:
    the arms' positions as read back and the dark-subtracted signal at each."""
    lim = bench.cfg.det_axis
    first = max(theta_o[0] - 1.0, lim.min_deg)
    bench.move(theta_i, first)
    ti, to, sig = [], [], []
    for o in theta_o:
        bench.move(theta_i, o)
        bench.settle()
        pos = bench.positions()
        ti.append(pos[0])
        to.append(pos[1])
        sig.append(_signal(bench.read(repeats), dark))
    return {"theta_i_deg": float(np.mean(ti)), "theta_o_deg": to, "signal": sig}


def measure(bench: Any, incidences: list[float], window: float, step: float, repeats: int,
            reference: bool) -> dict[str, Any]:
    """The specular sweeps (and the white reference's sweep): the measurements :func:`analyse` fits."""
    lim = bench.cfg.det_axis
    out: dict[str, Any] = {"specular": []}
    with bench:
        dark = bench.dark()
        bench.detector.set_sample("TARGET")
        for ti in incidences:
            grid = np.arange(ti - window, ti + window + 0.5 * step, step)
            grid = [float(x) for x in grid if lim.min_deg <= x <= lim.max_deg]
            out["specular"].append(sweep(bench, ti, grid, repeats, dark))
        if reference:
            bench.detector.set_sample("REF")
            grid = sorted([-x for x in REFERENCE_THETA_O] + list(REFERENCE_THETA_O))
            grid = [x for x in grid if lim.min_deg <= x <= lim.max_deg]
            out["reference"] = sweep(bench, 0.0, grid, max(repeats, 4), dark)
            bench.detector.set_sample("TARGET")
        bench.park()
    return out


def peaks(data: dict[str, Any]) -> tuple[list[float], list[float]]:
    """(incidences, peak centres) of the specular sweeps; :class:`AlignmentError` names the incidence whose peak
    the sweep does not hold."""
    ti, pk = [], []
    for s in data["specular"]:
        ti.append(s["theta_i_deg"])
        pk.append(peak_centre(s["theta_o_deg"], s["signal"], where=f"theta_i = {s['theta_i_deg']:.2f} deg: "))
    return ti, pk


def analyse(data: dict[str, Any], distance_mm: float, first: dict[str, Any] | None = None) -> Alignment:
    """The alignment from one run's measurements (``data``), or from a first run (``first``) and this one with the
    mirror turned."""
    base = first if first is not None else data
    ti, pk = peaks(base)
    fit1 = fit_specular(ti, pk, distance_mm)
    b = fit_diffuse_zero(base["reference"]["theta_o_deg"], base["reference"]["signal"])[0] \
        if "reference" in base else None
    turned = None
    if first is not None:
        ti2, pk2 = peaks(data)
        turned = fit_specular(ti2, pk2, distance_mm)
    al = combine(fit1, b, turned)
    if al.light_zero_deg is not None and al.tilt_deg is not None:  # the light arm's offset moves delta a little
        alpha = al.light_zero_deg + al.tilt_deg
        fit1 = fit_specular(ti, pk, distance_mm, alpha)
        if turned is not None:
            turned = fit_specular(ti2, pk2, distance_mm, al.light_zero_deg - al.tilt_deg)
        al = combine(fit1, b, turned)
    return al


def _zero_line(cfg: Any, name: str, arm_zero: float) -> tuple[float, str]:
    ax = cfg.axes[name]
    new = zero_offset_for(ax.zero_offset, ax.direction, ax.units_per_deg, arm_zero)
    return new, (f"zero_offset = {new:.6g}    # was {ax.zero_offset:.6g}: the {name} arm stood {arm_zero:+.3f} deg "
                 "past its readings")


def report(cfg: Any, al: Alignment, distance_mm: float, incidences: list[float]) -> tuple[str, dict[str, float]]:
    """What gonio-align prints, and the zero offsets it may write ({axis: value})."""
    worst = max(abs(x) for x in incidences)
    shift = abs(float(specular_peak_deg(worst, 0.0, al.surface_offset_mm, distance_mm)) - worst)
    where = "above" if al.surface_offset_mm > 0 else "below"
    surface = (f"the surface is on the axis ({al.surface_offset_mm:+.2f} mm: it moves the specular by {shift:.3f} "
               f"deg at {worst:g} deg)") if shift < ON_AXIS_DEG else \
        (f"the surface is {abs(al.surface_offset_mm):.2f} mm {where} the rotation axis (it moves the specular by "
         f"{shift:.2f} deg at {worst:g} deg): {'lower' if where == 'above' else 'raise'} the sample holder's seat by "
         "that much (shims under its three balls) and align again")
    lines = [f"specular peaks: a - b + 2t = {al.c_deg:+.3f} deg (rms {al.rms_deg:.3f} deg); {surface}"]
    writes: dict[str, float] = {}
    if al.detector_zero_deg is None:
        lines.append("no white reference sweep: the arms' zeros and the tilt stay unknown (only a - b + 2t)")
    else:
        lines.append(f"white reference: the detector arm stands {al.detector_zero_deg:+.3f} deg past its readings (b)")
    if al.tilt_deg is not None:
        lines.append(f"mirror turned: its tilt is {al.tilt_deg:+.3f} deg (t, towards the detector's side)")
    if al.light_zero_deg is not None:
        lines.append(f"the light arm stands {al.light_zero_deg:+.3f} deg past its readings (a)")
    elif al.light_plus_2tilt_deg is not None:
        lines.append(f"a + 2t = {al.light_plus_2tilt_deg:+.3f} deg: turn the mirror 180 deg about its normal and "
                     "run again with --turned FILE (this run's --save) to tell the light arm's zero from the tilt")
    paste = []
    if al.light_zero_deg is not None:
        writes["light"], line = _zero_line(cfg, "light", al.light_zero_deg)
        paste += ["[axes.light]", line]
    if al.detector_zero_deg is not None:
        writes["detector"], line = _zero_line(cfg, "detector", al.detector_zero_deg)
        paste += ["[axes.detector]", line]
    if paste:
        lines += ["", f"bench-file lines (paste into {cfg.path}, or run again with --write):", *paste]
    return "\n".join(lines), writes


def write_zero_offsets(path: Path, values: dict[str, float]) -> None:
    """Set ``zero_offset`` in the bench file's ``[axes.<name>]`` tables, keeping every other line and comment."""
    text = path.read_text(encoding="utf-8")
    for name, value in values.items():
        head = re.search(rf"^\[axes\.{name}\][ \t]*(#.*)?$", text, re.M)
        if head is None:
            raise ValueError(f"{path}: no [axes.{name}] table to write zero_offset into")
        nxt = re.search(r"^\[", text[head.end():], re.M)
        end = head.end() + (nxt.start() if nxt else len(text) - head.end())
        body = text[head.end():end]
        new, n = re.subn(r"^(zero_offset[ \t]*=[ \t]*)[^#\n]*?([ \t]*(#.*)?)$",
                         lambda m, v=value: f"{m.group(1)}{v!r}{m.group(2)}", body, count=1, flags=re.M)
        if n == 0:
            raise ValueError(f"{path}: [axes.{name}] has no zero_offset line")
        text = text[:head.end()] + new + text[end:]
    path.write_text(text, encoding="utf-8")


def _fail(msg: str, status: int) -> int:
    print(f"gonio-align: {msg}", file=sys.stderr)
    return status


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``gonio-align`` console script (and of ``gonio-capture --align``)."""
    args = build_parser().parse_args(argv)
    from acquisition.bench import Bench
    from acquisition.errors import CommError, ConfigError, DeviceError, PlanError

    try:
        incidences = [float(x) for x in args.incidences.split(",") if x.strip()]
    except ValueError:
        return _fail(f"--incidences: expected degrees separated by commas, got {args.incidences!r}", 2)
    if not (0 < args.step <= 1.0 and 0 < args.window <= 10.0 and 1 <= args.repeats <= 1000):
        return _fail("--step must lie in (0, 1] deg, --window in (0, 10] deg, --repeats in [1, 1000]", 2)
    first = None
    if args.turned:
        try:
            first = json.loads(Path(args.turned).read_text(encoding="utf-8"))
            first["specular"]
        except (OSError, ValueError, KeyError, TypeError) as e:
            return _fail(f"--turned {args.turned}: not a measurement saved by gonio-align --save ({e})", 2)
    try:
        bench = Bench.from_config(args.config)
    except ConfigError as e:
        return _fail(f"{e}; nothing was moved", 2)
    dist = args.detector_distance_mm or bench.cfg.bench.detector_distance_mm or DEFAULT_DETECTOR_DISTANCE_MM
    try:
        data = measure(bench, incidences, args.window, args.step, args.repeats,
                       reference=not args.no_reference and first is None)
    except (ConfigError, PlanError) as e:
        return _fail(f"{e}; nothing was moved", 2)
    except (CommError, DeviceError) as e:
        return _fail(str(e), 1)
    if args.save:
        Path(args.save).parent.mkdir(parents=True, exist_ok=True)
        Path(args.save).write_text(json.dumps(data), encoding="utf-8")
    try:
        al = analyse(data, dist, first)
    except AlignmentError as e:
        return _fail(str(e), 1)
    text, writes = report(bench.cfg, al, dist, incidences)
    if args.json:
        print(json.dumps({k: getattr(al, k) for k in Alignment.__dataclass_fields__} | {"zero_offset": writes}))
    else:
        print(text)
    if args.write and writes:
        write_zero_offsets(Path(args.config), writes)
        print(f"gonio-align: wrote zero_offset of {', '.join(sorted(writes))} into {args.config}", file=sys.stderr)
    return 0


__all__ = ["main", "measure", "analyse", "report", "write_zero_offsets"]

if __name__ == "__main__":
    sys.exit(main())
