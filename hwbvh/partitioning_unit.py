"""Partitioning unit (thesis 3.3.2, Fig. 3.3/3.5; SPEC 2).

Reads a node's primitive records from one buffer of its pair and writes them, split by the
chosen bin boundary (bin ``< boundary`` goes left), into the opposite buffer. The functional
model keeps both sides in their input order (a stable partition), so the buffer order - which
the no-split fallback depends on - is one canonical order for every instantiation. A record's
bin on the split axis is Eq. 3.1 on the node's box, which the binning units have just
evaluated for the same record: the model reads it back from their pass (``slots``) rather
than dividing again.
"""
import numpy as np
from numba import njit, prange


@njit(cache=True)
def _move_records(src_b, src_i, dst_b, dst_i, lo, hi, li, ri, sides, stride, offset, limit):
    """Records [lo, hi) from src to dst: record lo + q goes left (to li onward) when
    ``sides[stride * q + offset] < limit``, else right (to ri onward), each side in order.
    Returns the next free left position. The destination is chosen without a branch: below
    the upper levels a record's side is as good as random, and a mispredicted branch per record
    cost more than the rest of the move."""
    for q in range(hi - lo):
        i = lo + q
        left = 1 if sides[stride * q + offset] < limit else 0
        j = li if left else ri
        li += left
        ri += 1 - left
        for k in range(6):
            dst_b[j, k] = src_b[i, k]
        dst_i[j] = src_i[i]
    return li


@njit(cache=True)
def partition_binned(src_b, src_i, dst_b, dst_i, start, end, axis, boundary, nbins, nl, slots):
    """Stable partition of records [start, end) from src into dst; ``nl`` records go left
    (the SAH calculator's count). Returns the number that did. The records are those that
    ``binning_unit.bin_records`` has just binned, in order, into ``slots`` (record q's slot on
    axis a at 3q + a, numbered a * S + bin): a record's side is its bin's, read back instead
    of a second Eq. 3.1 (the same bin: the same node box, the same records)."""
    return _move_records(src_b, src_i, dst_b, dst_i, start, end, start, start + nl, slots, 3,
                         axis, axis * nbins + boundary) - start


@njit(cache=True)
def chunk_offsets(starts, counts, axes, boundaries, chunk_counts):
    """Where each chunk of each node of a level writes: (left_off, right_off) (K, nchunks),
    from the chunks' bin counts (``binning_unit.bin_level``); a node's left-going records
    first, each side in chunk order. Apart from ``partition_level``, whose parallel
    compilation would turn every array expression here into a parallel region of its own:
    two thread meetings per node, most of a level's partition time."""
    nodes, nchunks = chunk_counts.shape[0], chunk_counts.shape[1]
    left_off = np.empty((nodes, nchunks), dtype=np.int64)
    right_off = np.empty((nodes, nchunks), dtype=np.int64)
    chunk_left = np.empty(nchunks, dtype=np.int64)
    for k in range(nodes):
        if axes[k] < 0:
            continue
        n = counts[k]
        total_left = 0
        for c in range(nchunks):
            chunk_left[c] = 0
            for b in range(boundaries[k]):
                chunk_left[c] += chunk_counts[k, c, axes[k], b]
            total_left += chunk_left[c]
        acc_l = 0
        acc_r = 0
        for c in range(nchunks):
            left_off[k, c] = starts[k] + acc_l
            right_off[k, c] = starts[k] + total_left + acc_r
            size = (n * (c + 1)) // nchunks - (n * c) // nchunks
            acc_l += chunk_left[c]
            acc_r += size - chunk_left[c]
    return left_off, right_off


@njit(cache=True, parallel=True)
def partition_level(bb, bi, starts, counts, bufs, axes, boundaries, nbins, chunk_counts, slots):
    """Data-parallel stable partition of every node of one upper level at once (as
    ``binning_unit.bin_level`` bins them): node k's records, in the same ``nchunks`` chunks,
    from buffer ``bufs[k]`` of the pair (``bb`` boxes, ``bi`` indices) into the other, split
    at ``boundaries[k]`` on ``axes[k]`` (a node with axis < 0 is skipped), each record's side
    read from the slot ``bin_level`` left in ``slots``. ``chunk_counts`` (K, nchunks, 3, S):
    each chunk's bin counts, from which every chunk knows where its left-going and
    right-going records start without a counting pass. Nodes of one level hold disjoint
    ranges, so their chunks write apart. One parallel region: nothing but the ``prange`` loop
    may be an array expression here (see ``chunk_offsets``)."""
    nchunks = chunk_counts.shape[1]
    left_off, right_off = chunk_offsets(starts, counts, axes, boundaries, chunk_counts)
    for w in prange(starts.shape[0] * nchunks):
        k = w // nchunks
        c = w - k * nchunks
        if axes[k] < 0:
            continue
        n = counts[k]
        src = bufs[k]
        lo = starts[k] + (n * c) // nchunks
        hi = starts[k] + (n * (c + 1)) // nchunks
        _move_records(bb[src], bi[src], bb[1 - src], bi[1 - src], lo, hi, left_off[k, c],
                      right_off[k, c], slots[3 * lo:3 * hi], 3, axes[k],
                      axes[k] * nbins + boundaries[k])


@njit(cache=True)
def range_bounds(boxes, start, end, out):
    """Union AABB of records [start, end) into out (6,) (used by the no-split fallback)."""
    for k in range(3):
        out[k] = np.inf
        out[3 + k] = -np.inf
    for i in range(start, end):
        for k in range(3):
            if boxes[i, k] < out[k]:
                out[k] = boxes[i, k]
            if boxes[i, 3 + k] > out[3 + k]:
                out[3 + k] = boxes[i, 3 + k]


@njit(cache=True, parallel=True)
def range_bounds_parallel(boxes, start, end, nchunks):
    n = end - start
    part = np.empty((nchunks, 6), dtype=np.float32)
    for c in prange(nchunks):
        range_bounds(boxes, start + (n * c) // nchunks, start + (n * (c + 1)) // nchunks, part[c])
    # merged in chunk order with loops: as an array expression, each min and max would be a
    # parallel region of its own, with its own order of equal bounds (+0 and -0)
    out = np.empty(6, dtype=np.float32)
    range_bounds(part, 0, nchunks, out)
    return out
