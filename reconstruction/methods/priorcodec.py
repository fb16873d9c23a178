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
* the residual of a two-dimensional predictor (each cell's code less its neighbours': the one before along theta_d
  plus the one before along phi_d less the one before along both; the grid's other cells given the values that make
  their residuals 0, so only the mask's cells are stored), modulo 2^16 (the cumulative sums that decode it wrap the
  same way, and every code is in int16's range);
* zigzag-mapped to uint16 (small magnitudes -> small numbers); the low bytes compressed by zlib's Huffman coding
  alone (fast, near their entropy), the few high bytes that are not 0 (about 0.4 % of the cells: steps to and from a
  zero cell) listed with their positions.

Decoding is two cumulative sums over the grid and an exponential per cell (vectorised, one material per thread).
Every material is encoded on its own: no basis shared across materials, which would let a benchmark's left-out
material leak into the prior of the others. About 100 kB per NBRDF material (3 x 115,710 cells) against 1.4 MB as
float32, or 2.2 MB on the whole grid.
"""

from __future__ import annotations

import hashlib
import zlib
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["CODEC_VERSION", "LN_STEP", "FLOOR", "encode_rows", "decode_rows", "pack", "unpack"]

#: the coding's version, in :func:`pack`'s header: arrays of any other are refused (and a cache built again)
CODEC_VERSION = 1

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


def _residuals(q: NDArray[np.int32], mask: NDArray[np.bool_]) -> NDArray[np.int32]:
    """The predictor's residuals (C M,) of the codes ``q`` (C, M) at the mask's cells: on the whole grid the codes
    Q, with Q elsewhere such that R = D_d D_p Q (differences along theta_d and phi_d, 0 before the first) is 0
    there; R at the mask's cells, in :class:`_Layout`'s order (phi_d, theta_d, theta_h)."""
    c = q.shape[0]
    lay = _layout(mask, c)
    full = np.zeros(c * mask.size, dtype=np.int32)
    full[lay.cells] = q.ravel()
    full = full.reshape(c, *lay.shape)  # (C, phi_d, theta_d, theta_h): a phi_d step is a contiguous slice
    inside = mask.transpose(2, 1, 0)
    n = inside.sum(axis=1)  # (phi_d, theta_h): the mask's cells along theta_d, a prefix
    last = np.maximum(n - 1, 0)[:, None, None, :]
    g = np.empty_like(full)  # D_p Q
    prev = np.zeros((c, *lay.shape[1:]), dtype=np.int32)
    for p in range(lay.shape[0]):  # beyond a column's prefix, D_p Q repeats its last value (D_d D_p Q = 0 there)
        gp = full[:, p] - prev
        ext = np.take_along_axis(gp, last[p], axis=1) * (n[p] > 0)
        g[:, p] = np.where(inside[p], gp, ext)
        prev += g[:, p]
    return np.diff(g, axis=2, prepend=0).ravel().take(lay.stored)  # D_d


def encode_rows(f: NDArray[np.floating], mask: NDArray[np.bool_]) -> tuple[bytes, bytes, NDArray[np.float64]]:
    """One material's rows ``f`` (C, M) f_r in 1/sr at the M cells of ``mask`` (grid order; >= 0; NaN, inf and
    negatives read as 0) -> (the low bytes' stream, the high bytes' stream: positions and values, the rows' offsets
    ``lo`` (C,): ln f_r of each row's floor)."""
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
    r = _residuals(q, mask).astype(np.int16)  # modulo 2^16
    z = ((r << 1) ^ (r >> 15)).view(np.uint16)  # zigzag
    big = np.flatnonzero(z > 0xFF)
    steps = np.diff(big, prepend=0).astype("<u4")
    return (_deflate((z & 0xFF).astype(np.uint8).tobytes(), zlib.Z_HUFFMAN_ONLY),
            zlib.compress(steps.tobytes() + (z[big] >> 8).astype(np.uint8).tobytes()), lo)


def _inflate(blob: bytes | NDArray[np.uint8], n: int | None = None) -> NDArray[np.uint8]:
    try:
        raw = zlib.decompress(blob)
    except zlib.error as e:
        raise ValueError(f"damaged prior codes: {e}") from None
    if (n is not None and len(raw) != n) or (n is None and len(raw) % 5):
        raise ValueError(f"damaged prior codes: {len(raw)} bytes, expected {n if n is not None else 'a multiple of 5'}")
    return np.frombuffer(raw, dtype=np.uint8)


def decode_rows(low: bytes | NDArray[np.uint8], high: bytes | NDArray[np.uint8], lo: NDArray[np.floating],
                mask: NDArray[np.bool_], out: NDArray[np.float32] | None = None) -> NDArray[np.float32]:
    """f_r (C, M) float32 in 1/sr of one material from :func:`encode_rows`' output (``lo``: (C,); ``mask``: the
    same cells), into ``out`` when given. Raises ValueError on streams that are damaged or of the wrong size."""
    _check_mask(mask)
    lo = np.asarray(lo, dtype=np.float64)
    return _decode(low, high, lo, _layout(mask, lo.shape[0]), out)


class _Layout:
    """Where the coder works: a grid (C, phi_d, theta_d, theta_h), so that the sums along theta_d and phi_d add
    slices of contiguous runs of theta_h (3 times faster than along the grid's own last axis); ``stored``: the flat
    index in it of every stored residual (C M,: that grid's order), ``cells``: of every cell in the mask's own
    (grid) order (flat indices: 3 to 8 times faster to scatter and gather with than a mask)."""

    def __init__(self, mask: NDArray[np.bool_], c: int) -> None:
        nh, nd, npd = mask.shape
        self.c, self.m, self.shape = c, int(mask.sum()), (npd, nd, nh)
        base = np.arange(c)[:, None] * mask.size
        self.stored = (base + np.flatnonzero(mask.transpose(2, 1, 0))).ravel()
        h, d, p = np.nonzero(mask)
        self.cells = (base + (p * nd + d) * nh + h).ravel()


def _layout(mask: NDArray[np.bool_], c: int) -> _Layout:
    """The :class:`_Layout` of ``mask`` and ``c`` channels (the last few kept: every material of a prior has the same
    mask)."""
    key = (mask.shape, hashlib.sha1(np.packbits(mask).tobytes()).hexdigest(), c)
    if key not in _LAYOUTS:
        if len(_LAYOUTS) >= 4:
            _LAYOUTS.pop(next(iter(_LAYOUTS)))
        _LAYOUTS[key] = _Layout(mask, c)
    return _LAYOUTS[key]


_LAYOUTS: dict[tuple[Any, ...], _Layout] = {}


def _decode(low: bytes | NDArray[np.uint8], high: bytes | NDArray[np.uint8], lo: NDArray[np.float64],
            layout: _Layout, out: NDArray[np.float32] | None) -> NDArray[np.float32]:
    c, m = layout.c, layout.m
    low_bytes = _inflate(low, c * m)
    exc = _inflate(high)
    k = exc.size // 5
    at = np.cumsum(exc[: 4 * k].view("<u4"), dtype=np.intp)
    if k and at[-1] >= low_bytes.size:
        raise ValueError("damaged prior codes: a high byte beyond the cells")
    grid = np.zeros(c * int(np.prod(layout.shape)), dtype=np.int16)
    z = low_bytes.astype(np.int16)
    grid[layout.stored] = (z >> 1) ^ -(z & 1)  # the residuals whose high byte is 0 (zigzag undone) ...
    z = low_bytes[at].astype(np.uint16) | (exc[4 * k:].astype(np.uint16) << 8)
    grid[layout.stored[at]] = (z >> 1).astype(np.int16) ^ -(z & 1).astype(np.int16)  # ... and the others
    g = grid.reshape(c, *layout.shape)
    for i in range(1, layout.shape[1]):  # the sums along theta_d, then along phi_d (modulo 2^16, as encoded)
        g[:, :, i] += g[:, :, i - 1]
    for i in range(1, layout.shape[0]):
        g[:, i] += g[:, i - 1]
    q = grid.take(layout.cells).reshape(c, m)
    if c == 3:
        q[0] += q[1]
        q[2] += q[1]
    if out is None:
        out = np.empty((c, m), dtype=np.float32)
    np.multiply(q, np.float32(LN_STEP), out=out)
    out += (lo - LN_STEP).astype(np.float32)[:, None]
    np.exp(out, out=out)
    out[q == 0] = 0.0
    return out


def pack(encoded: Sequence[tuple[bytes, bytes, NDArray[np.float64]]], mask: NDArray[np.bool_]
         ) -> tuple[NDArray, ...]:
    """Arrays to save for N materials' :func:`encode_rows` outputs: (the offsets (N, C) float64, the streams' sizes
    (N, 2) int64, every stream (uint8, concatenated: each material's low bytes, then its high ones), the header
    [CODEC_VERSION, LN_STEP, FLOOR, M])."""
    lo = np.asarray([e[2] for e in encoded], dtype=np.float64).reshape(len(encoded), -1)
    sizes = np.asarray([(len(e[0]), len(e[1])) for e in encoded], dtype=np.int64).reshape(len(encoded), 2)
    blob = np.frombuffer(b"".join(e[0] + e[1] for e in encoded), dtype=np.uint8)
    return lo, sizes, blob, np.array([CODEC_VERSION, LN_STEP, FLOOR, float(mask.sum())])


def unpack(arrays: Sequence[NDArray], mask: NDArray[np.bool_], threads: int = 1,
           rows: tuple[int, int] | None = None) -> NDArray[np.float32]:
    """The tables (N, C, M) float32 f_r in 1/sr from :func:`pack`'s arrays (``mask``: the same cells), ``threads``
    materials at a time. Raises ValueError when the arrays are not :func:`pack`'s of this coding, are damaged, or
    hold other than ``rows`` (N, C) when given."""
    if len(arrays) != 4:
        raise ValueError(f"expected 4 arrays of prior codes, got {len(arrays)}")
    lo, sizes, blob, head = (np.asarray(a) for a in arrays)
    if (head.shape != (4,) or head[0] != CODEC_VERSION or head[1] != LN_STEP or head[2] != FLOOR
            or head[3] != mask.sum() or lo.ndim != 2 or sizes.shape != (lo.shape[0], 2)
            or int(sizes.sum()) != blob.size):
        raise ValueError("prior codes of another coding, or damaged")
    if rows is not None and lo.shape != rows:
        raise ValueError(f"prior codes of {lo.shape} materials x channels, expected {rows}")
    _check_mask(mask)
    out = np.empty((*lo.shape, int(mask.sum())), dtype=np.float32)
    ends = np.cumsum(sizes.ravel()).reshape(sizes.shape)
    starts = ends - sizes
    layout = _layout(mask, lo.shape[1])

    def one(k: int) -> None:
        _decode(blob[starts[k, 0]:ends[k, 0]], blob[starts[k, 1]:ends[k, 1]], lo[k], layout, out[k])

    if threads > 1 and len(sizes) > 1:
        with ThreadPoolExecutor(max_workers=min(threads, len(sizes))) as ex:
            list(ex.map(one, range(len(sizes))))
    else:
        for k in range(len(sizes)):
            one(k)
    return out
