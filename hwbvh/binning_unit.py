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
def bin_level(bb, starts, counts, bufs, nodeboxes, nbins, nchunks):
    """Data-parallel binning of every node of one upper level at once: node k's records
    [starts[k], starts[k] + counts[k]) of buffer ``bufs[k]`` of the pair ``bb`` (2, N, 6), in
    ``nchunks`` chunks, each into private collectors (one SAH bin collector per binning unit
    group, 3.3.4); then each node's collectors are merged in chunk order (the SAH bin merge
    units), so that of equal bounds (+0 and -0) the first record's stays, as in one pass.
    Every (node, chunk) pair is one work item of a single parallel region: a region per node
    cost more in thread wake-ups than the binning itself. Returns (binbox (K, 3, S, 6),
    bincnt (K, 3, S), chunk counts (K, nchunks, 3, S))."""
    nodes = starts.shape[0]
    part_box = np.empty((nodes, nchunks, 3, nbins, 6), dtype=np.float32)
    part_cnt = np.empty((nodes, nchunks, 3, nbins), dtype=np.int64)
    for w in prange(nodes * nchunks):
        k = w // nchunks
        c = w - k * nchunks
        n = counts[k]
        lo = starts[k] + (n * c) // nchunks
        hi = starts[k] + (n * (c + 1)) // nchunks
        bin_range(bb[bufs[k]], lo, hi, nodeboxes[k], nbins, part_box[k, c], part_cnt[k, c])
    binbox = np.empty((nodes, 3, nbins, 6), dtype=np.float32)
    bincnt = np.empty((nodes, 3, nbins), dtype=np.int64)
    for k in range(nodes):
        clear_bins(binbox[k], bincnt[k])
        for c in range(nchunks):
            for a in range(3):
                for b in range(nbins):
                    bincnt[k, a, b] += part_cnt[k, c, a, b]
                    for j in range(3):
                        binbox[k, a, b, j] = min(binbox[k, a, b, j], part_box[k, c, a, b, j])
                        binbox[k, a, b, 3 + j] = max(binbox[k, a, b, 3 + j],
                                                     part_box[k, c, a, b, 3 + j])
    return binbox, bincnt, part_cnt
