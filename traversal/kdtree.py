"""An SAH kd-tree over triangles (Wald & Havran 2006, "On building fast kd-trees for ray
tracing, and on doing that in O(N log N)"), traversed front to back with the same
Moller-Trumbore unit as the BVH traversal.

>>> kd = KdTreeTracer(triangles)                # (n, 3, 3)
>>> hits = kd.intersect(origins, dirs)          # traversal.api.Hits
>>> blocked = kd.occluded(origins, dirs, tmax=dist)

Build (compiled, ``nogil``): each node looks for the plane of least SAH cost by one sweep over
its references' events (a start and an end event at the bounds of each reference on each axis,
or one planar event where the bounds are flat), in WH06's order (axis, then
position, then ends before planars before starts), with the costs of ``traversal.config``
(``KD_COST_TRAVERSAL``, ``KD_COST_INTERSECT``, ``KD_EMPTY_FACTOR``). A node whose best split
costs no less than testing its triangles becomes a leaf. WH06's split classification puts
each triangle left, right or on both sides from its events on the split axis. References are
*perfect*: a triangle on both sides is clipped to each child's box (Sutherland-Hodgman in
float64) and the clipped polygon's bounds give its events below; a triangle that misses the
child's box is dropped from it. Bounds are padded (``KD_PAD_TRI``, ``KD_PAD_COORD``) so that
every point where the unit can report a hit lies in a leaf that lists the triangle.

The events are sorted once, at the root; a split keeps the one-sided triangles' events in their
order and sorts only the straddling triangles' new events, then merges the two lists, so
that the build is O(N log N) where straddlers are few (WH06's O(sqrt N) per node).

Caps, stated in ``traversal.config``: depth ``KD_DEPTH_BASE + KD_DEPTH_LOG2 * log2(N)``
(PBRT's rule) and ``KD_MAX_REFS_PER_TRI * N`` references in all; a split that would exceed
either makes a leaf.

Traversal: the ray is clipped to the tree's box; at an inner node the near child is visited
first with the t interval up to the plane and the far child is pushed with the rest. A leaf's
triangles go through ``triangle_unit.mt_valid_at``; a hit counts only up to the leaf's exit
(plus ``KD_T_SLACK``), so a triangle that several leaves list is found where it is hit, and
exact-t ties go to the lower primitive index as in the BVH traversal. The walk stops once the
closest hit lies before the current leaf's exit by more than the slack. ``occluded`` returns at
the first hit.
"""
import math
import time

import numpy as np
from numba import njit
from numba.typed import List

from hwbvh.parallel import run_ranges
from .structure import TriangleStructure, checked_triangles, padded_box
from .config import (CHUNK_RAYS, KD_COST_INTERSECT, KD_COST_TRAVERSAL,
                     KD_DEPTH_BASE, KD_DEPTH_LOG2, KD_EMPTY_FACTOR, KD_MAX_REFS_PER_TRI,
                     KD_PAD_COORD, KD_PAD_TRI, KD_T_SLACK)
from .grid import _slab
from .rawtree import _ray_ok
from .triangle_unit import (TRI_WORDS, mt_valid_at, store_answer, store_normals)

LEAF = 3               # the axis word of a leaf node
EVENT_END = 0          # event types, in their order at equal positions (WH06)
EVENT_PLANAR = 1
EVENT_START = 2


def max_depth(n_tris):
    """The depth cap for ``n_tris`` triangles (PBRT's rule)."""
    return int(round(KD_DEPTH_BASE + KD_DEPTH_LOG2 * math.log2(max(n_tris, 1))))


@njit(cache=True, nogil=True, error_model="numpy")
def _clip_bounds(tris, j, box, pad, out, a, b):
    """Triangle ``j`` clipped to ``box`` (lo xyz, hi xyz) widened by ``pad``: writes the clipped
    polygon's bounds, widened by ``pad`` and limited to ``box``, to ``out`` (6,). Returns False
    when the triangle misses the widened box. ``a``, ``b``: (10, 3) scratch polygons (three
    vertices and one more per clipping plane at most)."""
    for k in range(3):
        for c in range(3):
            a[k, c] = tris[j, k, c]
    n = 3
    for plane in range(6):
        ax = plane % 3
        upper = plane >= 3
        bound = box[plane] + pad if upper else box[plane] - pad
        m = 0
        for k in range(n):
            p = a[k]
            q = a[(k + 1) % n]
            pin = p[ax] <= bound if upper else p[ax] >= bound
            qin = q[ax] <= bound if upper else q[ax] >= bound
            if pin:
                b[m] = p
                m += 1
            if pin != qin:
                s = (bound - p[ax]) / (q[ax] - p[ax])
                for c in range(3):
                    b[m, c] = p[c] + s * (q[c] - p[c])
                b[m, ax] = bound
                m += 1
        n = m
        if n == 0:
            return False
        a, b = b, a
    for c in range(3):
        lo = a[0, c]
        hi = a[0, c]
        for k in range(1, n):
            lo = min(lo, a[k, c])
            hi = max(hi, a[k, c])
        out[c] = min(max(lo - pad, box[c]), box[3 + c])
        out[3 + c] = min(max(hi + pad, box[c]), box[3 + c])
    return True


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _area(ex, ey, ez):
    return 2.0 * (ex * ey + ey * ez + ez * ex)


@njit(cache=True, nogil=True, error_model="numpy")
def _add_events(bounds, tri, pos, code, ids, e):
    """The events of one reference with ``bounds`` (6,) on every axis, from slot ``e`` on:
    a planar event where the bounds are flat, else a start and an end. Returns the next slot."""
    for ax in range(3):
        lo = bounds[ax]
        hi = bounds[3 + ax]
        if lo == hi:
            pos[e] = lo
            code[e] = 3 * ax + EVENT_PLANAR
            ids[e] = tri
            e += 1
        else:
            pos[e] = lo
            code[e] = 3 * ax + EVENT_START
            ids[e] = tri
            pos[e + 1] = hi
            code[e + 1] = 3 * ax + EVENT_END
            ids[e + 1] = tri
            e += 2
    return e


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _before(pa, ca, pb, cb):
    """Event a sorts before event b (axis, position, type)."""
    if ca // 3 != cb // 3:
        return ca // 3 < cb // 3
    if pa != pb:
        return pa < pb
    return ca < cb


@njit(cache=True, nogil=True, error_model="numpy")
def _sort_events(pos, code, ids):
    """Events in the order of the sweep: by axis, then position, then type (ends before planars
    before starts). Sorts by code (axis and type) first, then stably by position within each
    axis. A few events (most nodes deep in the tree) are sorted in place by insertion instead,
    without the sorts' temporary arrays, which cost more than the sorting itself there."""
    if pos.shape[0] <= 32:
        for i in range(1, pos.shape[0]):
            p, c, t = pos[i], code[i], ids[i]
            k = i
            while k > 0 and _before(p, c, pos[k - 1], code[k - 1]):
                pos[k] = pos[k - 1]
                code[k] = code[k - 1]
                ids[k] = ids[k - 1]
                k -= 1
            pos[k] = p
            code[k] = c
            ids[k] = t
        return pos, code, ids
    order = np.argsort(code, kind="mergesort")
    p = pos[order]
    c = code[order]
    t = ids[order]
    k = 0
    for ax in range(3):
        start = k
        while k < c.shape[0] and c[k] // 3 == ax:
            k += 1
        if k - start > 1:
            sub = np.argsort(p[start:k], kind="mergesort") + start
            p[start:k] = p[sub]
            c[start:k] = c[sub]
            t[start:k] = t[sub]
    return p, c, t


@njit(cache=True, nogil=True, error_model="numpy")
def _merge(pa, ca, ta, pb, cb, tb):
    """Two sorted event lists merged into one."""
    na = pa.shape[0]
    nb = pb.shape[0]
    p = np.empty(na + nb)
    c = np.empty(na + nb, np.int64)
    t = np.empty(na + nb, np.int64)
    i = 0
    j = 0
    for k in range(na + nb):
        if j >= nb or (i < na and not _before(pb[j], cb[j], pa[i], ca[i])):
            p[k] = pa[i]
            c[k] = ca[i]
            t[k] = ta[i]
            i += 1
        else:
            p[k] = pb[j]
            c[k] = cb[j]
            t[k] = tb[j]
            j += 1
    return p, c, t


@njit(cache=True, nogil=True, error_model="numpy")
def _best_split(pos, code, m, box):
    """The SAH sweep over one node's sorted events (``m`` references) on every axis at once:
    (cost, axis, position, planar_left); axis -1 when no plane lies strictly inside the box."""
    ext = np.empty(3)
    for c in range(3):
        ext[c] = box[3 + c] - box[c]
    area = _area(ext[0], ext[1], ext[2])
    best_cost = np.inf
    best_axis = -1
    best_pos = 0.0
    best_left = True
    if not area > 0:
        return best_cost, best_axis, best_pos, best_left
    inv_area = 1.0 / area
    e = pos.shape[0]
    n_left = np.zeros(3, np.int64)
    n_right = np.full(3, m, np.int64)
    k = 0
    while k < e:
        ax = code[k] // 3
        p = pos[k]
        n_end = 0
        n_planar = 0
        n_start = 0
        while k < e and pos[k] == p and code[k] == 3 * ax + EVENT_END:
            n_end += 1
            k += 1
        while k < e and pos[k] == p and code[k] == 3 * ax + EVENT_PLANAR:
            n_planar += 1
            k += 1
        while k < e and pos[k] == p and code[k] == 3 * ax + EVENT_START:
            n_start += 1
            k += 1
        n_right[ax] -= n_planar + n_end
        if box[ax] < p < box[3 + ax]:
            u = (ax + 1) % 3
            w = (ax + 2) % 3
            pl = _area(p - box[ax], ext[u], ext[w]) * inv_area
            pr = _area(box[3 + ax] - p, ext[u], ext[w]) * inv_area
            for left in (True, False):
                nl = n_left[ax] + (n_planar if left else 0)
                nr = n_right[ax] + (0 if left else n_planar)
                factor = KD_EMPTY_FACTOR if nl == 0 or nr == 0 else 1.0
                cost = KD_COST_TRAVERSAL + KD_COST_INTERSECT * factor * (pl * nl + pr * nr)
                if cost < best_cost:
                    best_cost = cost
                    best_axis = ax
                    best_pos = p
                    best_left = left
        n_left[ax] += n_start + n_planar
    return best_cost, best_axis, best_pos, best_left


@njit(cache=True, nogil=True, error_model="numpy")
def _grow(a, n):
    if n <= a.shape[0]:
        return a
    out = np.empty((max(n, 2 * a.shape[0]),) + a.shape[1:], a.dtype)
    out[:a.shape[0]] = a
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def build_kdtree(tris, pads, root_box, depth_cap, ref_cap):
    """The tree over ``tris`` ((n, 3, 3) float64), ``pads`` (n,) each triangle's padding.
    Returns (node_words (k, 3) int32: axis or LEAF, first child (children are adjacent) or first
    reference, reference count; node_split (k,) float64; refs (r,) int32; depth)."""
    n = tris.shape[0]
    words = np.zeros((64, 3), np.int32)
    split = np.zeros(64)
    refs = np.empty(max(n, 16), np.int32)
    side = np.zeros(n, np.int64)          # per triangle of the current node: 1 left, 2 right, 3 both
    n_nodes = 1
    n_refs = 0
    deepest = 0
    bounds = np.empty(6)
    poly_a = np.empty((10, 3))
    poly_b = np.empty((10, 3))
    pos = np.empty(6 * n)
    code = np.empty(6 * n, np.int64)
    ids = np.empty(6 * n, np.int64)
    e = 0
    total = 0                             # references held by leaves and pending nodes
    for j in range(n):
        if _clip_bounds(tris, j, root_box, pads[j], bounds, poly_a, poly_b):
            e = _add_events(bounds, j, pos, code, ids, e)
            total += 1
    pos, code, ids = _sort_events(pos[:e], code[:e], ids[:e])
    s_node = List()
    s_depth = List()
    s_pos = List()
    s_code = List()
    s_ids = List()
    s_box = List()
    s_node.append(0)
    s_depth.append(0)
    s_pos.append(pos)
    s_code.append(code)
    s_ids.append(ids)
    s_box.append(root_box.copy())
    while len(s_node) > 0:
        node = s_node.pop()
        depth = s_depth.pop()
        pos = s_pos.pop()
        code = s_code.pop()
        ids = s_ids.pop()
        box = s_box.pop()
        e = pos.shape[0]
        # the node's triangles: one start or planar event each on axis 0
        tri = np.empty(e, np.int64)
        m = 0
        for k in range(e):
            if code[k] == EVENT_START or code[k] == EVENT_PLANAR:
                tri[m] = ids[k]
                m += 1
        deepest = max(deepest, depth)
        ax = -1
        p = 0.0
        planar_left = True
        nl = 0
        nr = 0
        if m > 0 and depth < depth_cap:
            cost, ax, p, planar_left = _best_split(pos, code, m, box)
            if not cost < KD_COST_INTERSECT * m:
                ax = -1
        if ax >= 0:
            # split classification: both sides unless an event on the split axis
            # shows the triangle on one side only
            for i in range(m):
                side[tri[i]] = 3
            for k in range(e):
                if code[k] // 3 != ax:
                    continue
                typ = code[k] % 3
                if typ == EVENT_END and pos[k] <= p:
                    side[ids[k]] = 1
                elif typ == EVENT_START and pos[k] >= p:
                    side[ids[k]] = 2
                elif typ == EVENT_PLANAR:
                    if pos[k] < p or (pos[k] == p and planar_left):
                        side[ids[k]] = 1
                    else:
                        side[ids[k]] = 2
            for i in range(m):
                nl += side[tri[i]] & 1
                nr += side[tri[i]] >> 1
            if total + nl + nr - m > ref_cap:
                ax = -1
        if ax < 0:
            refs = _grow(refs, n_refs + m)
            srt = np.sort(tri[:m])
            for i in range(m):
                refs[n_refs + i] = srt[i]
            words[node, 0] = LEAF
            words[node, 1] = n_refs
            words[node, 2] = m
            n_refs += m
            continue
        first = n_nodes
        n_nodes += 2
        words = _grow(words, n_nodes)
        split = _grow(split, n_nodes)
        words[node, 0] = ax
        words[node, 1] = first
        split[node] = p
        total += nl + nr - m
        n_both = 0
        for i in range(m):
            if side[tri[i]] == 3:
                tri[n_both] = tri[i]          # the straddling triangles, in place
                n_both += 1
        for child in range(2):
            cbox = box.copy()
            if child == 0:
                cbox[3 + ax] = p
            else:
                cbox[ax] = p
            bit = child + 1
            # the events of the triangles on this side only, still sorted
            c = 0
            for k in range(e):
                if side[ids[k]] == bit:
                    c += 1
            op = np.empty(c)
            oc = np.empty(c, np.int64)
            oi = np.empty(c, np.int64)
            c = 0
            for k in range(e):
                if side[ids[k]] == bit:
                    op[c] = pos[k]
                    oc[c] = code[k]
                    oi[c] = ids[k]
                    c += 1
            # the straddling triangles clipped to this side's box: new events, sorted, merged
            npos = np.empty(6 * n_both)
            ncode = np.empty(6 * n_both, np.int64)
            nids = np.empty(6 * n_both, np.int64)
            ne = 0
            kept = 0
            for i in range(n_both):
                j = tri[i]
                if _clip_bounds(tris, j, cbox, pads[j], bounds, poly_a, poly_b):
                    ne = _add_events(bounds, j, npos, ncode, nids, ne)
                    kept += 1
            total -= n_both - kept
            if ne == 0:
                cp, cc, ci = op, oc, oi
            else:
                npos, ncode, nids = _sort_events(npos[:ne], ncode[:ne], nids[:ne])
                cp, cc, ci = _merge(op, oc, oi, npos, ncode, nids)
            s_node.append(first + child)
            s_depth.append(depth + 1)
            s_pos.append(cp)
            s_code.append(cc)
            s_ids.append(ci)
            s_box.append(cbox)
    return words[:n_nodes].copy(), split[:n_nodes].copy(), refs[:n_refs].copy(), deepest


@njit(cache=True, error_model="numpy", inline="always")
def trace_kd_ray(tris, words, split, refs, box, ox, oy, oz, dx, dy, dz, tmin, tmax, eps2, one,
                 edge, st_node, st_near, st_far, anyhit):
    """One ray through the kd-tree: (prim, t, u, v), prim -1 for a miss."""
    best_t = tmax
    prim = -1
    bu = one - one
    bv = bu
    if not _ray_ok(ox, oy, oz, dx, dy, dz, tmin, tmax):
        return prim, best_t, bu, bv
    # the walk in float64 on the float32 ray (exact conversions)
    o = (np.float64(ox), np.float64(oy), np.float64(oz))
    d = (np.float64(dx), np.float64(dy), np.float64(dz))
    t0, t1 = _slab(o[0], d[0], box[0], box[3], np.float64(tmin), np.float64(tmax))
    t0, t1 = _slab(o[1], d[1], box[1], box[4], t0, t1)
    t0, t1 = _slab(o[2], d[2], box[2], box[5], t0, t1)
    if not t0 <= t1:
        return prim, best_t, bu, bv
    scale = max(abs(o[0]), max(abs(o[1]), abs(o[2]))) / max(abs(d[0]), max(abs(d[1]), abs(d[2])))
    dd = dx * dx + dy * dy + dz * dz
    top = 0
    node = 0
    near_t = t0
    far_t = t1
    while True:
        ax = words[node, 0]
        if ax != LEAF:
            s = split[node]
            oa = o[0] if ax == 0 else (o[1] if ax == 1 else o[2])
            da = d[0] if ax == 0 else (d[1] if ax == 1 else d[2])
            below_first = oa < s or (oa == s and da <= 0)
            first = words[node, 1]
            near = first if below_first else first + 1
            far = first + 1 if below_first else first
            if da == 0:
                node = near
                continue
            tp = (s - oa) / da
            if tp > far_t or tp <= 0:
                node = near
            elif tp < near_t:
                node = far
            else:
                st_node[top] = far
                st_near[top] = tp
                st_far[top] = far_t
                top += 1
                node = near
                far_t = tp
            continue
        # a leaf: hits count up to its exit plus the slack
        limit = far_t + KD_T_SLACK * (abs(far_t) + scale)
        hi = best_t if anyhit else min(best_t, np.float32(limit))
        for p in range(words[node, 1], words[node, 1] + words[node, 2]):
            j = np.int64(refs[p])
            ok, t, tu, tv = mt_valid_at(tris, TRI_WORDS * j, ox, oy, oz, dx, dy, dz, dd, tmin,
                                        hi, eps2, one, edge)
            acc = ok & ((t < best_t) | (prim < 0) | (j < prim))
            if anyhit and acc:
                return j, t, tu, tv
            best_t = t if acc else best_t
            prim = j if acc else prim
            bu = tu if acc else bu
            bv = tv if acc else bv
            hi = best_t if anyhit else min(best_t, np.float32(limit))
        if prim >= 0 and np.float64(best_t) + KD_T_SLACK * (abs(np.float64(best_t)) + scale) < far_t:
            break
        if top == 0:
            break
        top -= 1
        node = st_node[top]
        near_t = st_near[top]
        far_t = st_far[top]
        if prim >= 0 and np.float64(best_t) + KD_T_SLACK * (abs(np.float64(best_t)) + scale) < near_t:
            break
    return prim, best_t, bu, bv


@njit(cache=True, nogil=True, error_model="numpy")
def kd_chunks(c0, c1, tris, words, split, refs, box, stack_size, O, D, tmin, tmax, eps2, one,
              edge, anyhit, out_prim, out_t, out_u, out_v, out_ng):
    """Chunks c0..c1 of CHUNK_RAYS rays (``hwbvh.parallel.run_ranges`` hands them out).
    ``out_t``/``out_u``/``out_v`` are (n,) or (0,) when only ``out_prim`` is wanted; ``out_ng``
    is (n, 3) for geometric normals or (0, 3)."""
    n = O.shape[0]
    st_node = np.empty(stack_size, np.int64)
    st_near = np.empty(stack_size)
    st_far = np.empty(stack_size)
    for i in range(c0 * CHUNK_RAYS, min(n, c1 * CHUNK_RAYS)):
        prim, t, bu, bv = trace_kd_ray(tris, words, split, refs, box, O[i, 0], O[i, 1], O[i, 2],
                                       D[i, 0], D[i, 1], D[i, 2], tmin[i], tmax[i], eps2, one,
                                       edge, st_node, st_near, st_far, anyhit)
        store_answer(i, prim, t, bu, bv, out_prim, out_t, out_u, out_v)
    store_normals(c0 * CHUNK_RAYS, min(n, c1 * CHUNK_RAYS), tris, out_prim, out_ng, one)


class KdTreeTracer(TriangleStructure):
    """Ray queries on an SAH kd-tree over ``triangles`` ((n, 3, 3)), with the BVH traversal's
    float32 triangle unit. Implements the tracer interface of ``traversal.tracers``. After the
    build: ``build_seconds``, ``memory_bytes`` (nodes, references and preprocessed triangles),
    ``nodes``, ``leaves``, ``references``, ``references_per_triangle``, ``depth`` and the caps
    ``max_depth`` and ``max_references``."""

    name = "kdtree"

    def __init__(self, triangles):
        start = time.perf_counter()
        tris = checked_triangles(triangles)
        n = len(tris)
        ext = (tris.max(axis=1) - tris.min(axis=1)).max(axis=1)
        mag = np.abs(tris).max(axis=(1, 2))
        pads = np.maximum(KD_PAD_TRI * ext + KD_PAD_COORD * mag, np.finfo(np.float32).tiny)
        # the tree's box: the mesh's, padded like a triangle's box, and never flat
        _, _, box_lo, box_hi = padded_box(tris, KD_PAD_TRI, KD_PAD_COORD)
        self.box = np.r_[box_lo, box_hi].astype(np.float64)
        self.max_depth = max_depth(n)
        self.max_references = KD_MAX_REFS_PER_TRI * max(n, 1)
        self.words, self.split, self.refs, depth = build_kdtree(
            tris, pads, self.box, self.max_depth, self.max_references)
        self.depth = int(depth)
        self.nodes = len(self.words)
        self.leaves = int((self.words[:, 0] == LEAF).sum())
        self._set_unit(tris)
        self.references = int(len(self.refs))
        self.references_per_triangle = self.references / max(n, 1)
        self.memory_bytes = int(self.words.nbytes + self.split.nbytes + self.refs.nbytes
                                + self.tris.nbytes)
        self.build_seconds = time.perf_counter() - start

    def _trace(self, o, d, tmin, tmax, anyhit, prim, t, u, v, ng):
        run_ranges(kd_chunks, (len(o) + CHUNK_RAYS - 1) // CHUNK_RAYS, self._tris1, self.words,
                   self.split, self.refs, self.box, self.depth + 1, o, d, tmin, tmax, self.eps2,
                   self.one, self.edge, anyhit, prim, t, u, v, ng)

    def stats(self):
        """The structure's figures for reports."""
        return {"build_seconds": self.build_seconds, "memory_bytes": self.memory_bytes,
                "nodes": self.nodes, "leaves": self.leaves, "depth": self.depth,
                "max_depth": self.max_depth, "references": self.references,
                "references_per_triangle": self.references_per_triangle}


def warm_up_kdtree():
    """Load (or, the first time ever, compile) the kd-tree's kernels on a tiny input, so that
    build and trace timings measure work, not JIT start-up. Returns seconds."""
    start = time.perf_counter()
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]],
                    [[0, 0, 2], [1, 0, 2], [0, 1, 2]]], np.float32)
    kd = KdTreeTracer(tri)
    o = np.array([[0.25, 0.25, 1.0]], np.float32)
    d = np.array([[0.0, 0.0, -1.0]], np.float32)
    kd.intersect(o, d)
    kd.intersect(o, d, normals=False)
    kd.occluded(o, d)
    return time.perf_counter() - start
