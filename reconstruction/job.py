"""What one reconstruction is asked to do (:class:`Job`: one ``gonio-reconstruct`` command line), the checks of
its outputs before any work, and its failure when a table is implausible. :mod:`reconstruction.pipeline` runs it."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from reconstruction.base import ReconstructionError
from reconstruction.formats import exports
from reconstruction.principled.outputs import wants

__all__ = ["ImplausibleError", "Job", "Progress", "check_output", "implausible_message", "check_outputs"]


class ImplausibleError(ReconstructionError):
    """The reconstruction fails a plausibility check; nothing was written."""


@dataclass(frozen=True)
class Job:
    """One reconstruction, from input files to outputs: what one ``gonio-reconstruct`` command line asks.

    ``inputs``: slice files or generic tables (merged); ``out``: the MERL table (``.binary``); ``preview``: an
    ``.exr`` (and the PNG beside it); ``report``: the JSON report. The other fields are the command's flags of the
    same names (angles in degrees): ``columns`` as ``"theta_i=NAME,theta_o=NAME"``, ``lobes`` as kinds,
    ``axis`` / ``smoothing`` for revolve, ``supersample`` as (nh, nd, np) or ``"adaptive"``. The methods' options
    (declared by each method, :mod:`reconstruction.methods.registry`): the fields named after their flags
    (``lobes``, ``fill``, ``axis``, ``smoothing``, ``prior``, ``prior_anchor``, ``prior_near``; None: the method's
    declared default), and ``options`` for any other, by :class:`~reconstruction.methods.Options` attribute
    (``{"toy_gain": 1.5}``).
    """

    inputs: tuple[str, ...]
    out: str
    method: str = "auto"
    preview: str | None = None
    report: str | None = None
    supersample: tuple[int, int, int] | str | None = None
    quantity: str | None = None
    columns: str | None = None
    blind_spot_deg: float | None = None
    angles_in: str = "degrees"  # --angles-in: the unit of the inputs' angle columns (reconstruction.formats.angleunits)
    illuminant: str = "D65"
    scene: str | None = None
    lobes: tuple[str, ...] | None = None
    fill: str | None = None  # --fill (None: the declared default, interpolate)
    axis: str | None = None  # --axis (None: the declared default, auto)
    smoothing: float | None = None
    allow_implausible: bool = False
    conservative: bool = True  # auto: bounded where no sample rests (reconstruction.assess.guard); --no-conservative
    html: str | None = None
    # other formats (reconstruction.formats.exports; README: Formats); ``out`` may be "" when one of them is asked for
    rgl: str | None = None
    zemax: str | None = None
    zemax_incidences: str | None = None
    zemax_azimuths: str | None = None
    zemax_radials: str | None = None
    export_mitsuba: str | None = None
    export_json: str | None = None
    preview_renderer: str = "builtin"
    prior: str | None = None  # --prior DIR: the folder of prior materials (method prior; auto tries it when given)
    prior_anchor: float | None = None  # --prior-anchor A: method prior's blend with bivariate (0..1; None: 0)
    prior_near: int | None = None  # --prior-near N: method prior's local basis of the N nearest materials (None: 0)
    uncertainty: str | None = None  # --uncertainty SIGMA.npy: sigma of ln f per cell (reconstruction.assess)
    advise: bool = False  # --advise: rank the incidences to measure next
    bench: str | None = None  # --bench CONFIG.toml: the bench whose limits and timing --advise uses
    budget_s: float | None = None  # --budget-s T: --advise plans further slices within T s of bench time
    # the closest principled material (reconstruction.principled; docs/formats.md)
    principled: str | None = None
    materialx: str | None = None
    gltf: str | None = None
    blender: str | None = None
    options: Mapping[str, Any] = field(default_factory=dict)  # other methods' options, by Options attribute

    def method_options(self) -> dict[str, Any]:
        """The methods' options this job sets, by :class:`~reconstruction.methods.Options` attribute: its fields
        named after a declared option's flag (when not None), then :attr:`options`."""
        from reconstruction.methods import option_specs

        out: dict[str, Any] = {}
        for spec in option_specs():
            value = getattr(self, spec.dest, None) if spec.dest in self.__dataclass_fields__ else None
            if value is not None:
                out[spec.attr] = value
        out.update(self.options)
        return out

    @property
    def steps(self) -> list[str]:
        """The steps ``pipeline.run`` reports to its ``progress`` (for a progress bar's total)."""
        return (["read", "colour", "reconstruct", "tabulate", "checks"]
                + (["conservative"] if self.bounds else [])
                + ["write"] + (["preview"] if self.preview else [])
                + (["uncertainty"] if self.assesses else []) + (["advice"] if self.advise else [])
                + (["principled"] if wants(self) else []) + (["html"] if self.html else []))

    @property
    def assesses(self) -> bool:
        """Whether the run computes the per-cell uncertainty (asked for, for the advice or the HTML page)."""
        return bool(self.uncertainty or self.advise or self.html)

    @property
    def bounds(self) -> bool:
        """Whether auto's table is bounded where no sample rests (``pipeline.bound_where_unmeasured``)."""
        return self.method == "auto" and self.conservative

    @property
    def posterior_early(self) -> bool:
        """Whether the built-in analytic family's posterior of the samples (the reference of the uncertainty and
        of the bound without a prior) is computed beside the reconstruction."""
        return (self.assesses or self.bounds) and not self.prior


class Progress(Protocol):
    """What ``pipeline.run`` tells about its progress: a step (or a sub-step, a method being fitted) begins; one of
    :attr:`Job.steps` is done."""

    def begin(self, label: str) -> None: ...

    def done(self, step: str) -> None: ...


def check_output(path: Path, suffix: str | None, flag: str) -> None:
    """An output path must name a file (``suffix``) in an existing, writable folder; checked before any work."""
    if suffix is not None and path.suffix.lower() != suffix:
        raise ReconstructionError(f"{flag} {path}: expected a file name ending in {suffix}")
    if path.is_dir():
        raise ReconstructionError(f"{flag} {path}: is a folder; give a file name"
                                  + (f" ending in {suffix}" if suffix else ""))
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise ReconstructionError(f"{flag} {path}: the folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ReconstructionError(f"{flag} {path}: the folder {parent} is not writable")
    if path.exists() and not path.is_file():
        raise ReconstructionError(f"{flag} {path}: exists and is not a regular file")


def implausible_message(method: str, checks: dict[str, Any]) -> str:
    """One line: which plausibility checks of ``checks`` failed, with figures, and what to try."""
    why = []
    if not checks["non_negative"]["pass"]:
        c = checks["non_negative"]
        why.append(f"non_negative: {c['missing_cells']} cell(s) without a value, minimum {c['min_1_per_sr']:.3g} 1/sr")
    if not checks["albedo"]["pass"]:
        c = checks["albedo"]
        alb = np.asarray(c["albedo"], dtype=np.float64)
        k = int(np.argmax(alb.max(axis=1)))
        why.append(f"albedo: the table reflects more light than it receives (directional albedo {alb.max():.3g} > "
                   f"1 + {c['tolerance']:g} at theta_i = {c['theta_i_deg'][k]:g} deg)")
    if not checks["reciprocity"]["pass"]:
        why.append(f"reciprocity: relative error {checks['reciprocity']['relative_error']:.3g}")
    return (f"method {method}: the table fails the plausibility check(s) " + "; ".join(why)
            + "; nothing written. Try --method fit or microfacet (energy-conserving by construction), slices at "
              "more incidences, or --allow-implausible to write it anyway")


def check_outputs(job: Job) -> None:
    """Every output path of ``job`` checked (and the exports' arguments) before any work."""
    if job.out:
        check_output(Path(job.out), ".binary", "--out")
    elif not exports.asks_output(job):
        raise ReconstructionError("give --out MATERIAL.binary (or another output: --preview, --html, --report, --rgl, "
                                  "--zemax, --export-mitsuba, --export-json, --uncertainty, --principled, "
                                  "--materialx, --gltf, --blender)")
    exports.check_arguments(job)
    if job.preview:
        check_output(Path(job.preview), ".exr", "--preview")
        png = Path(job.preview).with_suffix(".png")
        if png.is_dir():
            raise ReconstructionError(f"--preview {job.preview}: {png} (the PNG beside it) is a folder")
    if job.report:
        check_output(Path(job.report), None, "--report")
    if job.html:
        check_output(Path(job.html), ".html", "--html")
    if job.uncertainty:
        check_output(Path(job.uncertainty), ".npy", "--uncertainty")
    if job.bench and not Path(job.bench).is_file():
        raise ReconstructionError(f"--bench {job.bench}: no such file (expected a bench file, configs/*.toml)")
    if (job.bench or job.budget_s is not None) and not job.advise:
        raise ReconstructionError("--bench and --budget-s are for --advise")
