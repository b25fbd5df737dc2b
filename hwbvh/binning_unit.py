"""Binning unit (thesis 3.3.3, Fig. 3.6/3.7; SPEC 2).

Each primitive's centre ``C = 0.5 * (min + max)`` is binned on every axis against the node
AABB ``BB`` (not the centroid bounds):

    Bin_n = floor((C_n - BB.min_n) / (BB.max_n - BB.min_n) * S)      (Eq. 3.1)

in float32, clamped to ``[0, S-1]``. The SAH bin collectors (3.3.4) accumulate, per axis and
bin, the union AABB and a primitive count. An axis whose node extent is 0 offers no candidates
and is not binned.
"""
import numpy as np
from numba import njit, prange

F32_HALF = np.float32(0.5)
F32_ONE = np.float32(1.0)


@njit(cache=True)
def centre(lo, hi):
    """AABB centre on one axis, float32: 0.5 * (min + max)."""
    return (lo + hi) * F32_HALF


@njit(cache=True)
def bin_index(c, bb_lo, bb_hi, s_f32, nbins):
    """Eq. 3.1 in float32 for one axis; clamped to [0, nbins-1]."""
    t = (c - bb_lo) / (bb_hi - bb_lo) * s_f32
    if not (t >= F32_ONE):          # t < 1, negative from rounding, or NaN: bin 0
        return 0
    b = int(t)                      # t >= 1 > 0, so truncation is floor
    return b if b < nbins else nbins - 1


@njit(cache=True)
def clear_bins(binbox, bincnt):
    """Empty every bin: box (+inf, -inf), count 0. binbox (3, S, 6) f32, bincnt (3, S) i64."""
    for a in range(3):
        for b in range(binbox.shape[1]):
            for k in range(3):
                binbox[a, b, k] = np.inf
                binbox[a, b, 3 + k] = -np.inf
            bincnt[a, b] = 0


@njit(cache=True)
def _accumulate(binbox, bincnt, a, b, boxes, i):
    """SAH uni-collector update (Fig. 3.9): bin b of axis a grows by record i."""
    bincnt[a, b] += 1
    for k in range(3):
        binbox[a, b, k] = min(binbox[a, b, k], boxes[i, k])
        binbox[a, b, 3 + k] = max(binbox[a, b, 3 + k], boxes[i, 3 + k])


@njit(cache=True)
def bin_range(boxes, start, end, nodebox, nbins, binbox, bincnt):
    """Bin primitives ``boxes[start:end]`` (f32 (n, 6)) into ``binbox``/``bincnt`` (cleared
    here). Axes with zero node extent are left empty. The three binning units of a group see
    each record at the same time, so one pass serves all axes."""
    clear_bins(binbox, bincnt)
    s_f32 = np.float32(nbins)
    lx = nodebox[0]; ly = nodebox[1]; lz = nodebox[2]
    hx = nodebox[3]; hy = nodebox[4]; hz = nodebox[5]
    ux = hx > lx
    uy = hy > ly
    uz = hz > lz
    for i in range(start, end):
        if ux:
            _accumulate(binbox, bincnt, 0, bin_index(centre(boxes[i, 0], boxes[i, 3]), lx, hx, s_f32, nbins), boxes, i)
        if uy:
            _accumulate(binbox, bincnt, 1, bin_index(centre(boxes[i, 1], boxes[i, 4]), ly, hy, s_f32, nbins), boxes, i)
        if uz:
            _accumulate(binbox, bincnt, 2, bin_index(centre(boxes[i, 2], boxes[i, 5]), lz, hz, s_f32, nbins), boxes, i)


@njit(cache=True, parallel=True)
def bin_range_parallel(boxes, start, end, nodebox, nbins, nchunks):
    """Data-parallel binning for the upper levels: each chunk bins into private collectors
    (one SAH bin collector per binning unit group, 3.3.4), then the collectors are merged
    (the SAH bin merge units). Returns (binbox, bincnt, chunk_counts (nchunks, 3, S))."""
    n = end - start
    part_box = np.empty((nchunks, 3, nbins, 6), dtype=np.float32)
    part_cnt = np.empty((nchunks, 3, nbins), dtype=np.int64)
    for c in prange(nchunks):
        lo = start + (n * c) // nchunks
        hi = start + (n * (c + 1)) // nchunks
        bin_range(boxes, lo, hi, nodebox, nbins, part_box[c], part_cnt[c])
    binbox = np.empty((3, nbins, 6), dtype=np.float32)
    bincnt = np.zeros((3, nbins), dtype=np.int64)
    clear_bins(binbox, bincnt)
    for c in range(nchunks):
        for a in range(3):
            for b in range(nbins):
                bincnt[a, b] += part_cnt[c, a, b]
                for k in range(3):
                    binbox[a, b, k] = min(binbox[a, b, k], part_box[c, a, b, k])
                    binbox[a, b, 3 + k] = max(binbox[a, b, 3 + k], part_box[c, a, b, 3 + k])
    return binbox, bincnt, part_cnt
