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


@njit(cache=True, error_model="numpy")
def bin_index(c, bb_lo, bb_hi, s_f32, nbins):
    """Eq. 3.1 in float32 for one axis; clamped to [0, nbins-1]. Without a branch, so that in
    a loop over records the divisions of successive records overlap; an axis of zero extent
    (division by zero) gives a bin that no caller uses."""
    t = (c - bb_lo) / (bb_hi - bb_lo) * s_f32
    # t < 1, negative from rounding, or NaN: bin 0; else floor(t) (truncation, t >= 1 > 0),
    # taken of min(t, S) so that the conversion stays in range (floor(S) clamps as floor(t))
    b = np.int64(min(t, s_f32)) if t >= F32_ONE else np.int64(0)
    return b if b < nbins else nbins - 1


# Software layout of the collectors (``bin_scratch``): per (axis, bin) slot a = axis * S + bin,
# eight float32 words ``min x, y, z, -max x, y, z`` and two unused (32 bytes: a slot never
# straddles a cache line), every update a min (max x = -min(-x), exactly, and of equal
# bounds, +0 or -0, the one already held stays in both forms); the counts apart. An empty
# bin's words are +inf. The SAH calculator reads the bins in this form; ``collector_bins`` /
# ``collector_words`` convert from and to the unit's (3, S, 6) form.
SLOT_WORDS = 8


@njit(cache=True)
def collector_scratch(nbins):
    """The collectors' words (float32) and counts (int64) of ``bin_records``."""
    return (np.empty(3 * nbins * SLOT_WORDS, dtype=np.float32),
            np.empty(3 * nbins, dtype=np.int64))


@njit(cache=True)
def bin_scratch(nbins, records):
    """Working arrays of ``bin_records`` for nodes of up to ``records`` primitives: each
    record's three slots (int32), the collectors' words (float32) and counts (int64)."""
    F, C = collector_scratch(nbins)
    return np.empty(3 * max(records, 1), dtype=np.int32), F, C


@njit(cache=True)
def _collect(F, C, slot, r0, r1, r2, r3, r4, r5):
    """SAH uni-collector update (Fig. 3.9): the slot's bin grows by a record given as
    min x, y, z, -max x, y, z."""
    C[slot] += 1
    o = SLOT_WORDS * slot
    F[o] = min(F[o], r0)
    F[o + 1] = min(F[o + 1], r1)
    F[o + 2] = min(F[o + 2], r2)
    F[o + 3] = min(F[o + 3], r3)
    F[o + 4] = min(F[o + 4], r4)
    F[o + 5] = min(F[o + 5], r5)


@njit(cache=True, error_model="numpy")
def bin_records(boxes, start, end, nodebox, nbins, slots, F, C):
    """Bin primitives ``boxes[start:end]`` (f32 (n, 6)) into the collectors ``F``, ``C`` (every
    bin written, in the layout above); each record's three slots go to ``slots`` (record q's
    at 3q onward). Axes with zero node extent are left empty. The three binning units of a
    group see each record at the same time, so one pass serves all axes. ``slots``, ``F``,
    ``C``: ``bin_scratch`` arrays.

    Two loops: Eq. 3.1 for every record and axis first, without a branch, so that the
    divisions of successive records overlap; then the collectors, record by record in order,
    whose updates of one bin wait on each other. 40% less time per record than one loop
    doing both (the records' strided layout keeps LLVM from vectorising either loop)."""
    for q in range(3 * nbins * SLOT_WORDS):
        F[q] = np.inf
    for q in range(3 * nbins):
        C[q] = 0
    s_f32 = np.float32(nbins)
    lx = nodebox[0]; ly = nodebox[1]; lz = nodebox[2]
    hx = nodebox[3]; hy = nodebox[4]; hz = nodebox[5]
    bf = boxes.reshape(-1)
    m = end - start
    for q in range(m):
        j = 6 * (start + q)
        slots[3 * q] = bin_index(centre(bf[j], bf[j + 3]), lx, hx, s_f32, nbins)
        slots[3 * q + 1] = nbins + bin_index(centre(bf[j + 1], bf[j + 4]), ly, hy, s_f32, nbins)
        slots[3 * q + 2] = 2 * nbins + bin_index(centre(bf[j + 2], bf[j + 5]), lz, hz, s_f32,
                                                 nbins)
    ux = hx > lx
    uy = hy > ly
    uz = hz > lz
    for q in range(m):
        j = 6 * (start + q)
        a0 = bf[j]; a1 = bf[j + 1]; a2 = bf[j + 2]
        b0 = -bf[j + 3]; b1 = -bf[j + 4]; b2 = -bf[j + 5]
        if ux:
            _collect(F, C, slots[3 * q], a0, a1, a2, b0, b1, b2)
        if uy:
            _collect(F, C, slots[3 * q + 1], a0, a1, a2, b0, b1, b2)
        if uz:
            _collect(F, C, slots[3 * q + 2], a0, a1, a2, b0, b1, b2)


def collector_bins(F, C, nbins):
    """The collectors' bins in the unit's form: (binbox (3, S, 6) f32, bincnt (3, S) i64)."""
    w = np.asarray(F, np.float32).reshape(3, nbins, SLOT_WORDS)
    return (np.concatenate([w[..., :3], -w[..., 3:6]], axis=-1),
            np.asarray(C, np.int64).reshape(3, nbins).copy())


def collector_words(binbox, bincnt):
    """Bins given in the unit's form (binbox (3, S, 6), an empty bin (+inf, -inf); bincnt
    (3, S)) as the collectors hold them: (F, C)."""
    binbox = np.asarray(binbox, np.float32)
    w = np.full(binbox.shape[:2] + (SLOT_WORDS,), np.inf, np.float32)
    w[..., :3] = binbox[..., :3]
    w[..., 3:6] = -binbox[..., 3:]
    return w.reshape(-1), np.ascontiguousarray(bincnt, np.int64).reshape(-1)


@njit(cache=True, parallel=True)
def bin_level(bb, starts, counts, bufs, nodeboxes, nbins, nchunks, slots):
    """Data-parallel binning of every node of one upper level at once: node k's records
    [starts[k], starts[k] + counts[k]) of buffer ``bufs[k]`` of the pair ``bb`` (2, N, 6), in
    ``nchunks`` chunks, each into private collectors (one SAH bin collector per binning unit
    group, 3.3.4); then each node's collectors are merged in chunk order (the SAH bin merge
    units), so that of equal bounds (+0 and -0) the first record's stays, as in one pass.
    Every (node, chunk) pair is one work item of a single parallel region: a region per node
    cost more in thread wake-ups than the binning itself. Each record's slots go to
    ``slots`` (3N int32: the record at position i at 3i onward), where the partitioning
    reads its side. Returns node k's merged collectors (words (K, 3 S SLOT_WORDS), counts
    (K, 3 S)) and the chunks' counts (K, nchunks, 3, S)."""
    nodes = starts.shape[0]
    words = 3 * nbins * SLOT_WORDS
    part_words = np.empty((nodes, nchunks, words), dtype=np.float32)
    part_cnt = np.empty((nodes, nchunks, 3 * nbins), dtype=np.int64)
    for w in prange(nodes * nchunks):
        k = w // nchunks
        c = w - k * nchunks
        n = counts[k]
        lo = starts[k] + (n * c) // nchunks
        hi = starts[k] + (n * (c + 1)) // nchunks
        bin_records(bb[bufs[k]], lo, hi, nodeboxes[k], nbins, slots[3 * lo:3 * hi],
                    part_words[k, c], part_cnt[k, c])
    merged = np.empty((nodes, words), dtype=np.float32)
    merged_cnt = np.empty((nodes, 3 * nbins), dtype=np.int64)
    for k in range(nodes):
        for q in range(words):
            merged[k, q] = np.inf
        for q in range(3 * nbins):
            merged_cnt[k, q] = 0
        for c in range(nchunks):
            for q in range(words):
                merged[k, q] = min(merged[k, q], part_words[k, c, q])
            for q in range(3 * nbins):
                merged_cnt[k, q] += part_cnt[k, c, q]
    return merged, merged_cnt, part_cnt.reshape(nodes, nchunks, 3, nbins)
