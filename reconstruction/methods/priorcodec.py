"""A prior's tables, compact on disk: ln f_r quantised per row, predicted from neighbouring cells, deflated.

The prior (:mod:`reconstruction.methods.prior`) only reads its materials' f_r at the training cells, through
y = log(f cos cos / s + EPS): a relative error of f is what matters, and one of 0.1 % is far below anything the
basis or a slice resolves. Each material (C rows of M cells: a boolean ``mask`` of the reduced grid (theta_h,
theta_d, phi_d), true on a prefix of every theta_d column) is coded on its own:

* q = 1 + round((ln f - lo) / :data:`LN_STEP`), clipped at 1 (the floor: ``lo`` = ln of :data:`FLOOR` x the row's
  largest value), and q = 0 where f = 0 (decoded exactly to 0). |ln f_decoded - ln f| <= LN_STEP / 2 above the
  floor; codes fit in int16 (at most 1 + ln(1 / FLOOR) / LN_STEP = 28,784), and so do the channels' differences;
* three channels: the first and the third as their difference from the second (a material's channels share their
  shape);
* each cell's code less the code of the cell before it along theta_d (the mask is a prefix along theta_d: that
  cell is always there), then less the previous cell's such difference (cells in grid order, so mostly a step of
  phi_d); modulo 2^16 (the cumulative sums that decode it wrap the same way, and every code is in int16's range);
* zigzag-mapped to uint16 (small magnitudes -> small numbers); the low bytes compressed by zlib's Huffman coding
  alone (fast, near their entropy), the high bytes (almost all 0) by its run-length coding.

Decoding is two cumulative sums and an exponential per cell (vectorised, one material per thread). Every material
is encoded on its own: no basis shared across materials, which would let a benchmark's left-out material leak into
the prior of the others. About 100 kB per NBRDF material (3 x 115,710 cells) against 1.4 MB as float32, or 2.2 MB
on the whole grid.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

__all__ = ["LN_STEP", "FLOOR", "encode_rows", "decode_rows", "pack", "unpack"]

#: quantisation step of ln f_r (dimensionless): every cell above the floor is decoded within +-LN_STEP / 2 of its
#: ln f_r (a relative error of at most 0.1 %)
LN_STEP = 0.002
#: cells below FLOOR x their row's largest value are decoded as that floor: far below any cell of the 141 real
#: materials (the faintest is 2e-13 of its row's peak). A floor relative to the peak must be that low: a row's scale s
#: (the median at a slice's samples) can be 1e-7 of its peak (a mirror-like RGL material), and a floor of 1e-9
#: moved y = log(f cos cos / s + EPS) by up to 0.77 there
FLOOR = 1e-25
_QMAX = int(np.ceil(np.log(1.0 / FLOOR) / LN_STEP)) + 1  # the largest code: 28,784
assert _QMAX < 2**15  # codes and the channels' differences in int16; the steps between cells wrap in 16 bits


def _check_mask(mask: NDArray[np.bool_]) -> None:
    if mask.ndim != 3 or np.any(mask[:, 1:] & ~mask[:, :-1]):
        raise ValueError("the cells' mask must be 3-d and a prefix along its second axis (theta_d)")


def _deflate(data: bytes, strategy: int) -> bytes:
    co = zlib.compressobj(1, zlib.DEFLATED, 15, 9, strategy)
    return co.compress(data) + co.flush()


def encode_rows(f: NDArray[np.floating], mask: NDArray[np.bool_]) -> tuple[bytes, bytes, NDArray[np.float64]]:
    """One material's rows ``f`` (C, M) f_r in 1/sr at the M cells of ``mask`` (grid order; >= 0; NaN, inf and
    negatives read as 0) -> (the low bytes' stream, the high bytes' stream, the rows' offsets ``lo`` (C,): ln f_r of
    each row's floor)."""
    _check_mask(mask)
    f = np.nan_to_num(np.asarray(f, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    if f.ndim != 2 or f.shape[1] != int(mask.sum()):
        raise ValueError(f"expected rows (C, {int(mask.sum())}), got shape {f.shape}")
    pos = f > 0
    peak = np.max(np.where(pos, f, 0.0), axis=1)
    lo = np.where(peak > 0, np.log(np.where(peak > 0, peak, 1.0) * FLOOR), 0.0)
    q = np.clip(np.rint((np.log(np.where(pos, f, 1.0)) - lo[:, None]) / LN_STEP), 0, _QMAX - 1) + 1
    q = np.where(pos, q, 0).astype(np.int32)
    if q.shape[0] == 3:  # the first and third channels relative to the second
        q[0] -= q[1]
        q[2] -= q[1]
    dense = np.zeros((q.shape[0], *mask.shape), dtype=np.int32)
    dense[:, mask] = q
    e = np.diff(dense, axis=2, prepend=0)[:, mask]  # less the cell before along theta_d (0 before the first)
    r = np.diff(e, axis=1, prepend=0).astype(np.int16)  # less the previous cell's; modulo 2^16
    z = ((r << 1) ^ (r >> 15)).view(np.uint16)  # zigzag
    return (_deflate((z & 0xFF).astype(np.uint8).tobytes(), zlib.Z_HUFFMAN_ONLY),
            _deflate((z >> 8).astype(np.uint8).tobytes(), zlib.Z_RLE), lo)


def _inflate(blob: bytes | NDArray[np.uint8], n: int) -> NDArray[np.uint8]:
    try:
        raw = zlib.decompress(blob)
    except zlib.error as e:
        raise ValueError(f"damaged prior codes: {e}") from None
    if len(raw) != n:
        raise ValueError(f"damaged prior codes: {len(raw)} bytes, expected {n}")
    return np.frombuffer(raw, dtype=np.uint8)


def decode_rows(low: bytes | NDArray[np.uint8], high: bytes | NDArray[np.uint8], lo: NDArray[np.floating],
                mask: NDArray[np.bool_], out: NDArray[np.float32] | None = None) -> NDArray[np.float32]:
    """f_r (C, M) float32 in 1/sr of one material from :func:`encode_rows`' output (``lo``: (C,); ``mask``: the
    same cells), into ``out`` when given. Raises ValueError on streams that are damaged or of the wrong size."""
    _check_mask(mask)
    lo = np.asarray(lo, dtype=np.float64)
    return _decode(low, high, lo, mask.shape, _flat_cells(mask, lo.shape[0]), out)


def _flat_cells(mask: NDArray[np.bool_], c: int) -> NDArray[np.intp]:
    """Flat indices (C M,) of the mask's cells in a (C, *mask.shape) array (a flat index: 3 to 6 times faster to
    scatter and gather with than the mask)."""
    return (np.arange(c)[:, None] * mask.size + np.flatnonzero(mask)).ravel()


def _decode(low: bytes | NDArray[np.uint8], high: bytes | NDArray[np.uint8], lo: NDArray[np.float64],
            shape: tuple[int, ...], cells: NDArray[np.intp], out: NDArray[np.float32] | None
            ) -> NDArray[np.float32]:
    c = lo.shape[0]
    m = cells.size // c
    z = _inflate(high, c * m).astype(np.uint16) << 8
    z |= _inflate(low, c * m)
    r = (z >> 1).astype(np.int16) ^ -(z & 1).astype(np.int16)  # zigzag undone
    dense = np.zeros(c * int(np.prod(shape)), dtype=np.int16)
    dense[cells] = np.cumsum(r.reshape(c, m), axis=1, dtype=np.int16).ravel()  # modulo 2^16, as encoded
    q = np.cumsum(dense.reshape(c, *shape), axis=2, dtype=np.int16).ravel().take(cells).reshape(c, m)  # theta_d
    if c == 3:
        q[0] += q[1]
        q[2] += q[1]
    if out is None:
        out = np.empty((c, m), dtype=np.float32)
    x = (q - 1).astype(np.float32)
    x *= np.float32(LN_STEP)
    x += lo.astype(np.float32)[:, None]
    np.exp(x, out=out)
    out[q == 0] = 0.0
    return out


def pack(encoded: Sequence[tuple[bytes, bytes, NDArray[np.float64]]], mask: NDArray[np.bool_]
         ) -> tuple[NDArray, ...]:
    """Arrays to save for N materials' :func:`encode_rows` outputs: (the offsets (N, C) float64, the streams' sizes
    (N, 2) int64, every stream (uint8, concatenated: each material's low then high bytes), the header [LN_STEP,
    FLOOR, M])."""
    lo = np.asarray([e[2] for e in encoded], dtype=np.float64).reshape(len(encoded), -1)
    sizes = np.asarray([(len(e[0]), len(e[1])) for e in encoded], dtype=np.int64).reshape(len(encoded), 2)
    blob = np.frombuffer(b"".join(e[0] + e[1] for e in encoded), dtype=np.uint8)
    return lo, sizes, blob, np.array([LN_STEP, FLOOR, float(mask.sum())])


def unpack(arrays: Sequence[NDArray], mask: NDArray[np.bool_], threads: int = 1) -> NDArray[np.float32]:
    """The tables (N, C, M) float32 f_r in 1/sr from :func:`pack`'s arrays (``mask``: the same cells), ``threads``
    materials at a time. Raises ValueError when the arrays are not :func:`pack`'s of this coding or are damaged."""
    if len(arrays) != 4:
        raise ValueError(f"expected 4 arrays of prior codes, got {len(arrays)}")
    lo, sizes, blob, head = (np.asarray(a) for a in arrays)
    if (head.shape != (3,) or head[0] != LN_STEP or head[1] != FLOOR or head[2] != mask.sum() or lo.ndim != 2
            or sizes.shape != (lo.shape[0], 2) or int(sizes.sum()) != blob.size):
        raise ValueError("prior codes of another coding, or damaged")
    _check_mask(mask)
    out = np.empty((*lo.shape, int(mask.sum())), dtype=np.float32)
    ends = np.cumsum(sizes.ravel()).reshape(sizes.shape)
    starts = ends - sizes
    cells = _flat_cells(mask, lo.shape[1])

    def one(k: int) -> None:
        _decode(blob[starts[k, 0]:ends[k, 0]], blob[starts[k, 1]:ends[k, 1]], lo[k], mask.shape, cells, out[k])

    if threads > 1 and len(sizes) > 1:
        with ThreadPoolExecutor(max_workers=min(threads, len(sizes))) as ex:
            list(ex.map(one, range(len(sizes))))
    else:
        for k in range(len(sizes)):
            one(k)
    return out
