"""What a method used of its input: the report's ``samples_left_out`` set on a plugin's reconstruction."""

from __future__ import annotations

from reconstruction.base import Reconstruction
from reconstruction.core.slicedata import Slice

__all__ = ["with_samples_used"]


def with_samples_used(rec: Reconstruction, s: Slice, used: Slice | None, method: str) -> Reconstruction:
    """``rec`` with ``samples_left_out`` (the report's key of that name: what it used and left out, and why)."""
    from reconstruction.core.samples import samples_used

    rec.samples_left_out = samples_used(s, used, method)  # type: ignore[attr-defined]
    return rec
