"""Fault injection, deterministic for a given seed (one random stream per port / subsystem)."""

from __future__ import annotations

import numpy as np

from reconstruction.schema.simulator import FaultsSection


class FaultInjector:
    """Draws fault decisions from its own seeded generator.

    ``comm``: apply reply drops and byte corruption (false for a port the faults do not target).
    """

    def __init__(self, cfg: FaultsSection, rng: np.random.Generator, comm: bool = True) -> None:
        self.cfg = cfg
        self.rng = rng
        self.comm = comm
        self.counts = {"dropped": 0, "corrupted": 0, "overload": 0, "stall": 0, "saturate": 0}

    def drop_reply(self) -> bool:
        """True if this reply (status packet / reply line block) is to be lost."""
        if not self.comm or self.cfg.drop_reply_rate <= 0:
            return False
        hit = bool(self.rng.random() < self.cfg.drop_reply_rate)
        self.counts["dropped"] += hit
        return hit

    def corrupt(self, data: bytes) -> bytes:
        """Flip bits in each byte of ``data`` with probability ``corrupt_byte_rate`` (XOR with a non-zero mask)."""
        rate = self.cfg.corrupt_byte_rate
        if not self.comm or rate <= 0 or not data:
            return data
        hits = self.rng.random(len(data)) < rate
        if not hits.any():
            return data
        arr = np.frombuffer(data, dtype=np.uint8).copy()
        masks = self.rng.integers(1, 256, size=int(hits.sum()), dtype=np.uint8)
        arr[hits] ^= masks
        self.counts["corrupted"] += int(hits.sum())
        return arr.tobytes()

    def _move_fault(self, rate: float, kind: str) -> float | None:
        """With probability ``rate``: the fraction of the move (0.1 .. 0.9) at which the fault ``kind`` occurs."""
        if rate <= 0:
            return None
        if self.rng.random() < rate:
            self.counts[kind] += 1
            return float(self.rng.uniform(0.1, 0.9))
        return None

    def overload_fraction(self) -> float | None:
        """Per move: fraction of the move at which an overload occurs, or None."""
        return self._move_fault(self.cfg.overload_rate, "overload")

    def stall_fraction(self) -> float | None:
        """Per move: fraction of the move at which the axis stalls, or None."""
        return self._move_fault(self.cfg.stall_rate, "stall")

    def saturate(self, n: int) -> np.ndarray:
        """Per reading: boolean mask of ``n`` readings forced to saturate."""
        if self.cfg.saturate_rate <= 0:
            return np.zeros(n, dtype=bool)
        hits = self.rng.random(n) < self.cfg.saturate_rate
        self.counts["saturate"] += int(hits.sum())
        return hits
