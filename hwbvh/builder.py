"""The functional HWBVH builder: the tree the hardware builds, bit for bit (thesis ch. 3, SPEC 2-3).

Every node is split by the binned SAH of the binning units and the SAH calculator, its records
partitioned by bin index, and recursion follows state S4 of Fig. 3.3: both children leaves ->
pop; one leaf -> continue with the other; neither -> push right, continue left. Leaves are
nodes with ``count <= leaf_size``. A node none of whose axes has a valid candidate is split at
the midpoint of its list (``fallback_splits``).

The hardware splits the work between one upper builder (nodes above the subtree capacity, in
DRAM) and subtree builders (everything below, on chip). The algorithm is the same in both, so
the *tree* does not depend on the capacity; only node placement does, and that is decided by
the tree output logic in :mod:`hwbvh.layout`. This module therefore builds one canonical tree,
in software-friendly parallel phases that mirror the hardware:

1. large nodes (the upper levels) are binned and partitioned data-parallel over chunks, every
   node of a level in the same parallel pass;
2. the remaining subtrees are independent tasks, built in parallel, one per thread at a time,
   exactly like subtree builders working side by side.

The canonical tree lives in arrays of ``2N + n_top`` slots: a task over records
``[s, s + n)`` writes its nodes depth-first (left child right after its parent) into slots
``[2s, 2s + 2n - 1)``; upper nodes live at ``2N + k``.
"""
from dataclasses import dataclass, field

import numpy as np
from numba import njit, prange, get_num_threads

from . import config
from .binning_unit import bin_level, bin_records, bin_scratch
from .errors import InputError, ParameterError, is_integer
from .parallel import check_threading, fetch_add
from .partitioning_unit import (partition_binned, partition_level, range_bounds,
                                range_bounds_parallel)
from .sah_calculator import best_split, sah_scratch

AXIS_LEAF = -1
AXIS_FALLBACK = 3


@dataclass
class CanonicalTree:
    """A built tree before layout. Node arrays have ``2N + n_top`` slots (unused ones are
    ``count == 0``); ``root`` is the root slot; ``ids`` is the index list in depth-first leaf
    order (leaf ``start`` indexes it)."""
    box: np.ndarray      # (M, 6) float32
    left: np.ndarray     # (M,) int32, -1 for leaves
    right: np.ndarray    # (M,) int32
    start: np.ndarray    # (M,) int32
    count: np.ndarray    # (M,) int32
    axis: np.ndarray     # (M,) int8: split axis, -1 leaf, 3 fallback
    root: int
    ids: np.ndarray      # (N,) int32
    n_prims: int
    leaf_size: int
    bins: int
    builder: str = "hwbvh"
    stats: dict = field(default_factory=dict)


def union_box(boxes):
    """The union of (n, 6) float32 boxes, bit for bit as NumPy's reduction over axis 0 gives
    it. Column by column: some 15 times faster, but its order of comparisons differs, which
    can change which of +0 and -0 stays, so a bound that comes out zero is taken again the
    slow way."""
    out = np.empty(6, dtype=np.float32)
    slow = [None, None]                     # NumPy's own mins and maxes, taken once if needed
    for c in range(6):
        out[c] = boxes[:, c].min() if c < 3 else boxes[:, c].max()
        if out[c] == 0:
            half = c // 3
            if slow[half] is None:
                slow[half] = boxes[:, :3].min(axis=0) if half == 0 else boxes[:, 3:].max(axis=0)
            out[c] = slow[half][c % 3]
    return out


def alloc_canonical(m):
    """Empty canonical node arrays of m slots: (box, left, right, start, count, axis)."""
    return (np.zeros((m, 6), dtype=np.float32), np.full(m, -1, dtype=np.int32),
            np.full(m, -1, dtype=np.int32), np.zeros(m, dtype=np.int32),
            np.zeros(m, dtype=np.int32), np.full(m, AXIS_LEAF, dtype=np.int8))


# --------------------------------------------------------------------------------------
# Subtree builder: one task, sequential, depth-first (Fig. 3.3)
# --------------------------------------------------------------------------------------
@njit(cache=True)
def _copy_box(dst, src):
    """The six bounds of box ``src`` into ``dst``, element by element: a slice assignment
    compiles a shape check whose error message alone takes seconds of a first run."""
    for c in range(6):
        dst[c] = src[c]


@njit(cache=True)
def build_subtree(bb, bi, out_ids, cbox, cleft, cright, cstart, ccount, caxis,
                  slot0, start, count, buf, rootbox, depth0, leaf_size, nbins, stats):
    """Build the subtree of records [start, start+count) held in buffer ``buf`` of the pair
    ``bb`` (2, N, 6) / ``bi`` (2, N). Nodes go to slots ``slot0, slot0+1, ...`` in pre-order.
    ``stats`` (int64 (4,)) accumulates nodes, leaves, fallback splits, max depth."""
    slots, bin_words, bin_counts = bin_scratch(nbins, count)
    left_sa, left_n, occupied = sah_scratch(nbins)
    lbox = np.empty(6, dtype=np.float32)
    rbox = np.empty(6, dtype=np.float32)
    cap = count + 2
    st_parent = np.empty(cap, dtype=np.int64)
    st_start = np.empty(cap, dtype=np.int64)
    st_count = np.empty(cap, dtype=np.int64)
    st_buf = np.empty(cap, dtype=np.int64)
    st_depth = np.empty(cap, dtype=np.int64)
    st_box = np.empty((cap, 6), dtype=np.float32)
    sp = 0

    slot = slot0
    nxt = slot0 + 1
    s = start
    n = count
    cur_buf = buf
    depth = depth0
    curbox = np.empty(6, dtype=np.float32)
    _copy_box(curbox, rootbox)
    while True:
        # -- write the node record (its AABB now; child pointers fill the gap later) --
        _copy_box(cbox[slot], curbox)
        cstart[slot] = s
        ccount[slot] = n
        stats[0] += 1
        if depth > stats[3]:
            stats[3] = depth
        if n <= leaf_size:
            # -- leaf: indices go to the index output in leaf order --
            cleft[slot] = -1
            cright[slot] = -1
            caxis[slot] = AXIS_LEAF
            for i in range(s, s + n):
                out_ids[i] = bi[cur_buf, i]
            stats[1] += 1
            if sp == 0:
                break
            sp -= 1
            slot = nxt
            nxt += 1
            cright[st_parent[sp]] = slot
            s = st_start[sp]
            n = st_count[sp]
            cur_buf = st_buf[sp]
            depth = st_depth[sp]
            _copy_box(curbox, st_box[sp])
            continue
        # -- binning units + SAH calculator --
        src_b = bb[cur_buf]
        bin_records(src_b, s, s + n, curbox, nbins, slots, bin_words, bin_counts)
        axis, boundary, nl, nr, cost = best_split(bin_words, bin_counts, nbins, lbox, rbox,
                                                  left_sa, left_n, occupied)
        if axis < 0:
            # -- no valid candidate on any axis: midpoint of the list, in buffer order --
            nl = n // 2
            nr = n - nl
            range_bounds(src_b, s, s + nl, lbox)
            range_bounds(src_b, s + nl, s + n, rbox)
            caxis[slot] = AXIS_FALLBACK
            stats[2] += 1
            child_buf = cur_buf
        else:
            # -- partitioning unit: into the opposite buffer of the pair --
            partition_binned(src_b, bi[cur_buf], bb[1 - cur_buf], bi[1 - cur_buf],
                             s, s + n, axis, boundary, nbins, nl, slots)
            caxis[slot] = axis
            child_buf = 1 - cur_buf
        # -- state S4: push right, continue left (pre-order output) --
        st_parent[sp] = slot
        st_start[sp] = s + nl
        st_count[sp] = nr
        st_buf[sp] = child_buf
        st_depth[sp] = depth + 1
        _copy_box(st_box[sp], rbox)
        sp += 1
        left_slot = nxt
        nxt += 1
        cleft[slot] = left_slot
        slot = left_slot
        n = nl
        cur_buf = child_buf
        depth += 1
        _copy_box(curbox, lbox)
    return nxt - slot0


@njit(cache=True, parallel=True)
def build_tasks(bb, bi, out_ids, cbox, cleft, cright, cstart, ccount, caxis,
                t_start, t_count, t_buf, t_box, t_depth, leaf_size, nbins, nthreads):
    """Build every task subtree. The caller sorts the tasks largest first; each thread takes
    the next task from a shared counter as soon as it is free, as subtrees go to the first
    idle subtree builder (a greedy balance; a thread slowed by another process on its core
    simply takes fewer). Each task writes its own slots, so the tree does not depend on who
    built what."""
    ntasks = t_start.shape[0]
    stats = np.empty((nthreads, 4), dtype=np.int64)
    taken = np.empty(1, dtype=np.int64)
    taken[0] = 0
    for k in prange(nthreads):
        for j in range(4):          # a loop, not np.zeros: that would be a parallel region too
            stats[k, j] = 0
        while True:
            t = fetch_add(taken, 0, 1)
            if t >= ntasks:
                break
            build_subtree(bb, bi, out_ids, cbox, cleft, cright, cstart, ccount, caxis,
                          2 * t_start[t], t_start[t], t_count[t], t_buf[t], t_box[t],
                          t_depth[t], leaf_size, nbins, stats[k])
    return stats


# --------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------
def check_params(leaf_size, bins):
    if not (is_integer(leaf_size) and 1 <= leaf_size <= config.MAX_LEAF_SIZE):
        raise ParameterError("leaf_size", f"must be an integer in 1..{config.MAX_LEAF_SIZE}, "
                                          f"got {leaf_size!r}")
    if not (is_integer(bins) and config.MIN_BINS <= bins <= config.MAX_SOFTWARE_BINS):
        raise ParameterError("bins", f"must be an integer in {config.MIN_BINS}.."
                                     f"{config.MAX_SOFTWARE_BINS} (the hardware has at most "
                                     f"{config.MAX_HARDWARE_BINS}), got {bins!r}")


def builds_in_parallel(n_prims):
    """Whether a build of ``n_prims`` primitives (task_prims at its default) runs the
    data-parallel kernels: above ``config.SEQUENTIAL_MAX_PRIMS``, so a caller timing such a
    build loads them first (``hwbvh.warm_up(parallel=True)``)."""
    return n_prims > config.SEQUENTIAL_MAX_PRIMS


def check_task_prims(task_prims):
    """``task_prims`` (None for the default) must be an integer >= 1."""
    if task_prims is not None and not (is_integer(task_prims) and task_prims >= 1):
        raise ParameterError("task_prims", f"must be a positive integer, got {task_prims!r}")


def build_canonical(boxes, leaf_size=config.DEFAULT_LEAF_SIZE, bins=config.DEFAULT_BINS,
                    task_prims=None):
    """Build the HWBVH tree over primitive AABBs.

    boxes : (n, 6) float32 primitive AABBs (see :func:`hwbvh.primitives.primitive_boxes`).
    Returns a :class:`CanonicalTree`. The result does not depend on ``task_prims`` (the
    software scheduling grain), which tests use to check exactness.
    """
    check_params(leaf_size, bins)
    check_task_prims(task_prims)
    check_threading()
    boxes = np.ascontiguousarray(boxes, dtype=np.float32)
    n = len(boxes)
    if n == 0:
        raise InputError("<boxes>", "no primitives")
    nthreads = get_num_threads()
    if task_prims is None:
        task_prims = max(config.TASK_MIN_PRIMS, n // (config.TASKS_PER_THREAD * nthreads))
        if not builds_in_parallel(n):
            task_prims = n
    # A node of at most leaf_size primitives is a leaf. The upper phase below splits every node
    # above task_prims, so a smaller grain would split such nodes and change the tree; as a
    # task, the subtree builder makes it the leaf it must be.
    task_prims = max(int(task_prims), leaf_size)
    nchunks = max(1, 4 * nthreads)

    bb = np.empty((2, n, 6), dtype=np.float32)
    bb[0] = boxes
    bi = np.empty((2, n), dtype=np.int32)
    bi[0] = np.arange(n, dtype=np.int32)
    out_ids = np.empty(n, dtype=np.int32)

    rootbox = union_box(boxes)
    if n <= task_prims:
        # small input: one subtree builder does it all (no parallel kernels to compile or run)
        cbox, cleft, cright, cstart, ccount, caxis = alloc_canonical(2 * n)
        stats = np.zeros(4, dtype=np.int64)
        build_subtree(bb, bi, out_ids, cbox, cleft, cright, cstart, ccount, caxis, 0, 0, n, 0,
                      rootbox, 0, leaf_size, bins, stats)
        return CanonicalTree(
            box=cbox, left=cleft, right=cright, start=cstart, count=ccount, axis=caxis, root=0,
            ids=out_ids, n_prims=n, leaf_size=leaf_size, bins=bins,
            stats={"nodes": int(stats[0]), "leaves": int(stats[1]),
                   "fallback_splits": int(stats[2]), "max_depth": int(stats[3]),
                   "upper_phase_nodes": 0, "tasks": 1})

    # ---- upper levels: level by level, every node of a level binned, then partitioned, in
    #      one data-parallel region over (node, chunk) pairs ----
    top = []            # [box, axis, start, count, left_ref, right_ref]; refs resolved below
    tasks = []          # (start, count, buf, box, depth)
    fallback = 0
    # a level's nodes: (start, count, buf, box, depth, parent_top_index, side)
    level = [(0, n, 0, rootbox, 0, -1, 0)]
    level_slots = np.empty(3 * n, dtype=np.int32)     # each record's bins, for its partition
    while level:
        split = []      # (top index, start, count, buf, box, depth) of the nodes to split
        for s, cnt, buf, box, depth, parent, side in level:
            if cnt <= task_prims:
                tasks.append((s, cnt, buf, box, depth))
                ref = ("task", s)
            else:
                ref = ("top", len(top))
                split.append((len(top), s, cnt, buf, box, depth))
                top.append([box, 0, s, cnt, None, None])
            if parent >= 0:
                top[parent][4 + side] = ref
        if not split:
            break
        starts = np.array([x[1] for x in split], dtype=np.int64)
        counts = np.array([x[2] for x in split], dtype=np.int64)
        bufs = np.array([x[3] for x in split], dtype=np.int64)
        nodeboxes = np.array([x[4] for x in split], dtype=np.float32).reshape(-1, 6)
        words, word_cnt, chunk_cnt = bin_level(bb, starts, counts, bufs, nodeboxes, bins,
                                               nchunks, level_slots)
        axes = np.empty(len(split), dtype=np.int64)
        boundaries = np.zeros(len(split), dtype=np.int64)
        children = []
        scratch = sah_scratch(bins)
        for k, (t, s, cnt, buf, box, depth) in enumerate(split):
            lbox = np.empty(6, np.float32)
            rbox = np.empty(6, np.float32)
            axis, boundary, nl, nr, _ = best_split(words[k], word_cnt[k], bins, lbox, rbox,
                                                   *scratch)
            axes[k] = axis
            if axis < 0:
                # no valid candidate on any axis: midpoint of the list, in buffer order
                nl = cnt // 2
                nr = cnt - nl
                lbox = range_bounds_parallel(bb[buf], s, s + nl, nchunks)
                rbox = range_bounds_parallel(bb[buf], s + nl, s + cnt, nchunks)
                top[t][1] = AXIS_FALLBACK
                fallback += 1
                cbuf = buf
            else:
                boundaries[k] = boundary
                top[t][1] = axis
                cbuf = 1 - buf
            children.append((s, nl, cbuf, lbox, depth + 1, t, 0))
            children.append((s + nl, nr, cbuf, rbox, depth + 1, t, 1))
        partition_level(bb, bi, starts, counts, bufs, axes, boundaries, bins, chunk_cnt,
                        level_slots)
        level = children

    # ---- canonical arrays: task slots [0, 2N), upper nodes at 2N + k ----
    cbox, cleft, cright, cstart, ccount, caxis = alloc_canonical(2 * n + len(top))

    def slot_of(ref):
        return 2 * ref[1] if ref[0] == "task" else 2 * n + ref[1]

    for k, (box, axis, s, cnt, lref, rref) in enumerate(top):
        j = 2 * n + k
        cbox[j] = box
        caxis[j] = axis
        cstart[j] = s
        ccount[j] = cnt
        cleft[j] = slot_of(lref)
        cright[j] = slot_of(rref)

    stats = np.zeros(4, dtype=np.int64)
    if tasks:
        order = sorted(range(len(tasks)), key=lambda t: -tasks[t][1])
        t_start = np.array([tasks[t][0] for t in order], dtype=np.int64)
        t_count = np.array([tasks[t][1] for t in order], dtype=np.int64)
        t_buf = np.array([tasks[t][2] for t in order], dtype=np.int64)
        t_box = np.array([tasks[t][3] for t in order], dtype=np.float32).reshape(-1, 6)
        t_depth = np.array([tasks[t][4] for t in order], dtype=np.int64)
        per_thread = build_tasks(bb, bi, out_ids, cbox, cleft, cright, cstart, ccount, caxis,
                                 t_start, t_count, t_buf, t_box, t_depth, leaf_size, bins,
                                 min(nthreads, len(tasks)))
        stats = per_thread.sum(axis=0)
        stats[3] = per_thread[:, 3].max()
    root = 2 * n if top else 0
    return CanonicalTree(
        box=cbox, left=cleft, right=cright, start=cstart, count=ccount, axis=caxis,
        root=root, ids=out_ids, n_prims=n, leaf_size=leaf_size, bins=bins,
        stats={
            "nodes": int(stats[0]) + len(top),
            "leaves": int(stats[1]),
            "fallback_splits": int(stats[2]) + fallback,
            "max_depth": int(stats[3]),
            "upper_phase_nodes": len(top),
            "tasks": len(tasks),
        })
