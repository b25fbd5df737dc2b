"""Partitioning unit (thesis 3.3.2, Fig. 3.3/3.5; SPEC 2).

Reads a node's primitive records from one buffer of its pair and writes them, split by the
chosen bin boundary (bin ``< boundary`` goes left), into the opposite buffer. The functional
model keeps both sides in their input order (a stable partition), so the buffer order - which
the no-split fallback depends on - is one canonical order for every instantiation.
"""
import numpy as np
from numba import njit, prange

from .binning_unit import bin_index, centre


@njit(cache=True)
def _partition_chunk(src_b, src_i, dst_b, dst_i, lo, hi, li, ri, axis, boundary, nodebox, nbins):
    """Records [lo, hi): left-going ones to dst from li up, the rest from ri up (in order).
    Returns the next free left position."""
    lo_ax = nodebox[axis]
    hi_ax = nodebox[3 + axis]
    s_f32 = np.float32(nbins)
    for i in range(lo, hi):
        if bin_index(centre(src_b[i, axis], src_b[i, 3 + axis]), lo_ax, hi_ax, s_f32, nbins) < boundary:
            j = li
            li += 1
        else:
            j = ri
            ri += 1
        for k in range(6):
            dst_b[j, k] = src_b[i, k]
        dst_i[j] = src_i[i]
    return li


@njit(cache=True)
def partition_range(src_b, src_i, dst_b, dst_i, start, end, axis, boundary, nodebox, nbins, nl):
    """Stable partition of records [start, end) from src into dst; ``nl`` records go left
    (the SAH calculator's count). Returns the number that did."""
    return _partition_chunk(src_b, src_i, dst_b, dst_i, start, end, start, start + nl, axis,
                            boundary, nodebox, nbins) - start


@njit(cache=True, parallel=True)
def partition_range_parallel(src_b, src_i, dst_b, dst_i, start, end, axis, boundary, nodebox,
                             nbins, chunk_left):
    """Data-parallel stable partition for the upper levels. ``chunk_left[c]`` is the number of
    left-going records in chunk c (known from that chunk's bin counts), so every chunk knows
    where to write without a second counting pass."""
    n = end - start
    nchunks = chunk_left.shape[0]
    left_off = np.empty(nchunks, dtype=np.int64)
    right_off = np.empty(nchunks, dtype=np.int64)
    total_left = 0
    for c in range(nchunks):
        total_left += chunk_left[c]
    acc_l = 0
    acc_r = 0
    for c in range(nchunks):
        left_off[c] = start + acc_l
        right_off[c] = start + total_left + acc_r
        size = (n * (c + 1)) // nchunks - (n * c) // nchunks
        acc_l += chunk_left[c]
        acc_r += size - chunk_left[c]
    for c in prange(nchunks):
        _partition_chunk(src_b, src_i, dst_b, dst_i, start + (n * c) // nchunks,
                         start + (n * (c + 1)) // nchunks, left_off[c], right_off[c], axis,
                         boundary, nodebox, nbins)
    return total_left


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
    out = np.empty(6, dtype=np.float32)
    for k in range(3):
        out[k] = part[:, k].min()
        out[3 + k] = part[:, 3 + k].max()
    return out
