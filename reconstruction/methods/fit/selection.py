"""The fit's model selection: candidate lobe structures fitted stepwise and ranked by BIC."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from reconstruction.base import ReconstructionError
from reconstruction.methods.fit.model import FitResult, LobeSpec, _Problem, fit_model, model_name

__all__ = ["Selection", "select_model"]


def _candidates_stage1(allowed: set[str]) -> list[tuple[LobeSpec, ...]]:
    out: list[tuple[LobeSpec, ...]] = []
    if "lambert" in allowed:
        out.append((LobeSpec("lambert"),))
    for d in ("ggx", "beckmann"):
        if d in allowed:
            out.append((LobeSpec(d),))
            if "lambert" in allowed:
                out.append((LobeSpec("lambert"), LobeSpec(d)))
    return out


def _extensions(best: tuple[LobeSpec, ...], allowed: set[str]) -> list[tuple[LobeSpec, ...]]:
    """Richer variants of ``best``: Fresnel on its microfacet lobe, a retro lobe, both, a lambert lobe."""
    out: list[tuple[LobeSpec, ...]] = []
    has_mf = any(s.kind in ("ggx", "beckmann") for s in best)
    with_f = tuple(LobeSpec(s.kind, True) if s.kind in ("ggx", "beckmann") else s for s in best)
    if has_mf and "fresnel" in allowed:
        out.append(with_f)
    if "retro" in allowed:
        out.append(best + (LobeSpec("retro"),))
        if has_mf and "fresnel" in allowed:
            out.append(with_f + (LobeSpec("retro"),))
    if "lambert" in allowed and not any(s.kind == "lambert" for s in best):
        out.append((LobeSpec("lambert"),) + best)
        if has_mf and "fresnel" in allowed:  # a stage-1 lambert + lobe may have stopped short of a Fresnel rise
            out.append((LobeSpec("lambert"),) + with_f)
    return out


@dataclass
class Selection:
    """Every candidate fitted (by name), ranked by BIC, the choice and why; ``skipped``: candidates with more
    parameters than values."""

    fitted: dict[str, FitResult]
    ranked: list[FitResult]
    chosen: FitResult
    reason: str
    skipped: list[str] = field(default_factory=list)


def select_model(prob: _Problem, allowed: set[str], n_channels: int, source: str, n_samples: int, *,
                 loss: str, f_scale: float, progress: Callable[[str], None] | None = None,
                 specs: Sequence[LobeSpec] | None = None) -> Selection:
    """Fit the candidates (``specs``: this structure only) to ``prob`` and choose the lowest BIC.

    Stage 1: lambert, ggx, beckmann, lambert + ggx, lambert + beckmann (those ``allowed``); stage 2: the best
    stage-1 model of each distribution (and the best overall) with Fresnel, a retro lobe, both, a lambert lobe.
    """
    fitted: dict[str, FitResult] = {}
    skipped: list[str] = []

    def run(cand: tuple[LobeSpec, ...]) -> None:
        name = model_name(cand)
        if name in fitted:
            return
        k = sum(len(s.nonlinear) for s in cand) + len(cand) * n_channels
        if k >= prob.n:
            skipped.append(f"{name}: {k} parameters for {prob.n} values")
            return
        if progress:
            progress(name)
        fitted[name] = fit_model(cand, prob, loss=loss, f_scale=f_scale)

    fixed = tuple(specs) if specs is not None else None
    for cand in [fixed] if fixed else _candidates_stage1(allowed):
        run(cand)
    if not fitted:
        raise ReconstructionError(f"{source}: too few samples ({n_samples}) for any candidate model")
    # stage 2: the best stage-1 model of each distribution (and the best overall), made richer
    bases = [] if fixed else [min(fitted.values(), key=lambda r: r.bic)]
    for d in ("ggx", "beckmann") if not fixed else ():
        of_d = [r for r in fitted.values() if any(s.kind == d for s in r.specs)]
        if of_d:
            bases.append(min(of_d, key=lambda r: r.bic))
    for base in bases:
        for cand in _extensions(base.specs, allowed):
            run(cand)
    ranked = sorted(fitted.values(), key=lambda r: r.bic)
    chosen = ranked[0]
    why = (f"lowest BIC ({chosen.bic:.1f}) of {len(ranked)} candidates; the next, {ranked[1].name}, has "
           f"{ranked[1].bic:.1f}" if len(ranked) > 1 else "the only candidate")
    return Selection(fitted, ranked, chosen, why, skipped)
