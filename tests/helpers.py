"""Plain helpers shared by several test modules (fixtures live in conftest.py); import as ``tests.helpers``."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

#: Dynamixel position units (and the simulated stepper's steps) per degree in configs/simulated.toml.
UNITS_PER_DEG = 4096 / 360


def deep_merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """A new dict: ``over`` merged into ``base`` table by table (nested dicts merged, everything else replaced);
    neither argument is modified."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def units(deg: float) -> int:
    """Controller position (Dynamixel units, stepper steps) of ``deg`` on the axes of configs/simulated.toml
    (zero offset 2048, 4096 units per turn)."""
    return round(2048 + deg * UNITS_PER_DEG)


def planned(cfg: str | Path) -> list[tuple[float, float]]:
    """The measurable points of the bench file's ``[plan]``, sorted and rounded to 1e-6 deg."""
    from acquisition import Bench

    b = Bench.from_config(cfg)
    return sorted((round(ti, 6), round(to, 6)) for ti, to in b.check(b.plan()).measurable)


#: Linux capabilities that let root ignore permission bits: CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH, CAP_FOWNER.
_DAC_CAPS = (1, 2, 3)


def unprivileged() -> dict[str, Any]:
    """``subprocess`` keyword arguments that make permission bits apply to the child (and its children) when the
    tests run as root: the capabilities that bypass them are dropped from its bounding set before it starts, so a
    read-only file or folder is read-only to it as to an operator. Nothing when the tests run unprivileged."""
    import ctypes
    import os

    if os.geteuid() != 0:
        return {}
    libc = ctypes.CDLL(None, use_errno=True)

    def drop() -> None:
        for cap in _DAC_CAPS:
            if libc.prctl(24, cap, 0, 0, 0) != 0:  # PR_CAPBSET_DROP
                raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP) failed")

    return {"preexec_fn": drop}
