"""Stack traversal of the raw hwbvh output: 48-byte nodes and the packed 24-bit index list,
read as written (no conversion to another layout).

Two queries, as in every serious tracer: ``intersect`` (closest hit) and ``occluded`` (any hit
in ``[t_min, t_max]``, early exit, for shadow rays). Batches run in parallel over rays.

Traversal order: at an internal node both children go through the AABB unit; the nearer hit
child is visited next and the farther pushed with its entry distance, which is re-checked
against the closest hit when popped. The stack is sized from the tree's depth, so it cannot
overflow on a valid tree; if it would (a corrupted tree), the batch raises instead of
answering wrongly. Exact-t ties between triangles go to the lower primitive index, so the
answer does not depend on the visiting order.

Triangles are read in index-list order (row p for list position p), so a leaf's triangles lie
side by side. An incoherent ray waits on memory at every step (the nodes and triangles of a
large mesh are far beyond the caches), so at an internal node the traversal asks for the
children's children and the first triangle rows of leaf children to be fetched while it tests
the two boxes: 1.1-1.3x the incoherent throughput on the 202k-triangle dragon.
"""
import numpy as np
from numba import njit

from hwbvh.config import LEAF_FLAG
from hwbvh.format import WORD_A, WORD_B, WORD_BOX, WORD_FLAGS, WORDS_PER_NODE
from .aabb_unit import aabb_hit_at, near_far_planes
from .config import CHUNK_RAYS
from .packet import NF, NI, NM, P, coherent_packet, trace_packets
from .prefetch import prefetch
from .rawtree import read_index, _ray_ok
from .triangle_unit import (TRI_WORDS, mt_valid_at, store_answer, store_normals, takes_hit,
                            wt_hit_ray)


@njit(cache=True, error_model="numpy", inline="always")
def _prefetch_below(u, tris, rec):
    """Ask for what a visit of the node at word ``rec`` reads next: the records of its
    children if it is internal, its first triangle rows if it is a leaf. All three requests
    go out whatever the node is (a prefetch never faults): choosing by the leaf flag
    measured no faster."""
    a = np.int64(u[rec + WORD_A])
    prefetch(u, WORDS_PER_NODE * a)
    prefetch(u, WORDS_PER_NODE * np.int64(u[rec + WORD_B]))
    prefetch(tris, TRI_WORDS * a)


@njit(cache=True, error_model="numpy", inline="always")
def trace_ray(u, f, ib, tris, raw, ox, oy, oz, dx, dy, dz, tmin, tmax, eps2, one,
              widen, edge, stack, stack_t, anyhit):
    """One ray. ``u``/``f`` are the node buffer seen as flat uint32/float32 words (the raw bytes,
    WORDS_PER_NODE words per node), ``tris`` the flattened preprocessed triangles, one row per
    index-list position (``Tracer.tris``). Returns (prim, t, bu, bv, nodes_visited,
    tris_tested, overflow). ``raw`` = None selects the Moller-Trumbore unit; an (n, 9) vertex
    array selects the Woop et al. watertight test on it
    (accuracy study). The choice is made at compile time (Numba prunes the ``raw is None``
    branch), so the hardware path carries no code of the other test."""
    best_t = tmax
    prim = -1
    bu = one - one                  # a zero of the working float type
    bv = bu
    nodes = 0
    tested = 0
    if not _ray_ok(ox, oy, oz, dx, dy, dz, tmin, tmax):
        return prim, best_t, bu, bv, nodes, tested, False
    ix = one / dx
    iy = one / dy
    iz = one / dz
    kx, ky, kz = near_far_planes(ix, iy, iz)
    dd = dx * dx + dy * dy + dz * dz
    hit, tn = aabb_hit_at(f, WORD_BOX, ox, oy, oz, ix, iy, iz, kx, ky, kz, tmin, best_t, widen)
    if not hit:
        return prim, best_t, bu, bv, nodes, tested, False
    node = 0
    sp = 0
    while True:
        nodes += 1
        base = WORDS_PER_NODE * node
        if u[base + WORD_FLAGS] & LEAF_FLAG:
            # -- leaf: primitives through the triangle unit --
            first = np.int64(u[base + WORD_A])
            for p in range(first, first + np.int64(u[base + WORD_B])):
                j = read_index(ib, p)
                tested += 1
                if raw is not None:
                    ok, t, tu, tv = wt_hit_ray(raw, j, ox, oy, oz, dx, dy, dz, one, tmin, best_t)
                else:
                    ok, t, tu, tv = mt_valid_at(tris, TRI_WORDS * p, ox, oy, oz, dx, dy, dz, dd, tmin,
                                                best_t, eps2, one, edge)
                acc = takes_hit(ok, t, j, best_t, prim)
                if anyhit and acc:
                    return j, t, tu, tv, nodes, tested, False
                best_t = t if acc else best_t
                prim = j if acc else prim
                bu = tu if acc else bu
                bv = tv if acc else bv
            node = -1
        else:
            # -- internal: both children through the AABB unit --
            l = np.int64(u[base + WORD_A])
            r = np.int64(u[base + WORD_B])
            _prefetch_below(u, tris, WORDS_PER_NODE * l)
            _prefetch_below(u, tris, WORDS_PER_NODE * r)
            hl, tl = aabb_hit_at(f, WORDS_PER_NODE * l + WORD_BOX, ox, oy, oz, ix, iy, iz, kx, ky, kz,
                                 tmin, best_t, widen)
            hr, tr = aabb_hit_at(f, WORDS_PER_NODE * r + WORD_BOX, ox, oy, oz, ix, iy, iz, kx, ky, kz,
                                 tmin, best_t, widen)
            if hl and hr:
                if tr < tl:
                    l, r = r, l
                    tl, tr = tr, tl
                if sp >= stack.shape[0]:
                    return -1, tmax, bu, bv, nodes, tested, True
                stack[sp] = r
                stack_t[sp] = tr
                sp += 1
                node = l
            elif hl:
                node = l
            elif hr:
                node = r
            else:
                node = -1
        while node < 0:
            if sp == 0:
                return prim, best_t, bu, bv, nodes, tested, False
            sp -= 1
            # cull subtrees behind the closest hit, with the box test's slack: a triangle on
            # the box's entry face can round an ulp nearer than the box (as the packet kernel,
            # which re-tests boxes on pop)
            if stack_t[sp] <= best_t * widen:
                node = stack[sp]


@njit(cache=True, error_model="numpy", _nrt=False)
def _trace_range(u, f, ib, tris, row_of, raw, O, D, Of, Df, tmin, tmax, eps2, one, widen,
                 edge, lo, hi, anyhit, packets, stack, stack_t, F, I, M, M64, out_prim, out_t,
                 out_u, out_v, out_ng, counters):
    """Rays [lo, hi) in a plain (non-parfor) function, so LLVM optimises the loop fully.
    With ``packets``, each full group of P consecutive rays that share a direction octant goes
    through the packet kernel (same answers, SIMD box and triangle tests), a run of such groups
    in one call (``packet.trace_packets``); other groups go ray by ray. Returns (rays whose
    stack would have overflowed, packets traced)."""
    count = counters.shape[0] > 0
    over = 0
    npk = 0
    a = lo
    while a < hi:
        b = a                           # the run of coherent full groups from a
        while packets and b + P <= hi and coherent_packet(Df, b):
            b += P
        if b > a:
            over += trace_packets(u, f, ib, tris, Of, Df, tmin, tmax, eps2, one, widen, edge, a,
                                  b, anyhit, stack, F, I, M, M64, out_prim, out_t, out_u, out_v,
                                  counters)
            npk += (b - a) // P
            a = b
            if a >= hi:
                break
        b = min(hi, a + P)              # then one group ray by ray
        for i in range(a, b):
            prim, t, bu, bv, nv, nt, of = trace_ray(
                u, f, ib, tris, raw, O[i, 0], O[i, 1], O[i, 2], D[i, 0], D[i, 1], D[i, 2],
                tmin[i], tmax[i], eps2, one, widen, edge, stack, stack_t, anyhit)
            store_answer(i, prim, t, bu, bv, out_prim, out_t, out_u, out_v)
            if of:
                over += 1
            if count:
                counters[i, 0] = nv
                counters[i, 1] = nt
        a = b
    store_normals(lo, hi, tris, row_of, out_prim, out_ng, one)
    return over, npk


@njit(cache=True, nogil=True, error_model="numpy")
def trace_chunks(c0, c1, u, f, ib, tris, row_of, raw, O, D, Of, Df, tmin, tmax, eps2, one,
                 widen, edge, depth, anyhit, packets, out_prim, out_t, out_u, out_v, out_ng,
                 counters, overflow, packets_traced):
    """Chunks c0..c1 of CHUNK_RAYS rays each (the last may be short), traced as one range with
    one stack and one packet scratch; ``Of``/``Df`` are ``O``/``D`` seen flat (3n,), as the
    packet kernel reads them (a reshape in compiled code would compile its error path: seconds
    of a first run); ``hwbvh.parallel.run_ranges`` hands the chunk ranges out to its threads.
    ``tris``: the triangle rows in index-list order, ``row_of``: each primitive's row (for
    ``out_ng``). ``out_t``, ``out_u``, ``out_v`` are (n,) or, when only ``out_prim`` is wanted,
    (0,);
    ``out_ng`` is (n, 3) for geometric normals or (0, 3); ``counters`` is (n, 2) int (nodes
    visited, triangles tested) or (0, 2). ``overflow[c0]`` gets the range's rays whose stack
    would have overflowed (0 on a valid tree) and ``packets_traced[c0]`` its packets; the
    other entries of c0..c1 are left as they are (the caller sums zeroed arrays).

    One ``_trace_range`` call per range, not per chunk: each call of that large function costs
    about as much as tracing a packet of rays that miss the scene (rays that miss the root box,
    traced in 64-ray calls, took twice as long as in one call)."""
    n = O.shape[0]
    if c1 <= c0:                  # no chunk: an empty batch has no entry c0 to write
        return
    stack = np.empty(depth + 2, dtype=np.int64)
    stack_t = np.empty(depth + 2, dtype=O.dtype)
    F = np.empty(NF, dtype=O.dtype)
    I = np.empty(NI, dtype=np.int32)
    M = np.zeros(NM, dtype=np.uint8)
    M64 = M.view(np.uint64)
    o_, p_ = _trace_range(u, f, ib, tris, row_of, raw, O, D, Of, Df, tmin, tmax, eps2, one,
                          widen, edge, c0 * CHUNK_RAYS, min(n, c1 * CHUNK_RAYS), anyhit, packets,
                          stack, stack_t, F, I, M, M64, out_prim, out_t, out_u, out_v, out_ng,
                          counters)
    overflow[c0] = o_
    packets_traced[c0] = p_
