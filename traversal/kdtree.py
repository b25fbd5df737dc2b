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
child's box is dropped from it. Bounds are padded (``KD_PAD_TRI``, ``KD_PAD_COORD``) and
rounded outwards to float32, so that every point where the unit can report a hit lies in a leaf
that lists the triangle, and split planes are float32 values.

An event is one uint64 key (axis, the float32 position's order-preserving bits, type,
triangle), so sorting keys sorts events. They are sorted once, at the root; a split hands the
one-sided triangles' events to their child in order and sorts only the straddling triangles'
new events, merged in on the way, so that the build is O(N log N) where straddlers are few
(WH06's O(sqrt N) per node). The events of the nodes on the way down live in one buffer used
as a stack: a node's children are written above its own events, the one processed first on top.

From ``KD_PARALLEL_MIN_TRIS`` triangles on, the nodes down to ``KD_PARALLEL_DEPTH`` are built
first; the subtrees below them are then built independently on ``hwbvh.parallel.run_ranges``'
threads and joined in a fixed order, so the tree is the same on any thread count.

Caps, stated in ``traversal.config``: depth ``KD_DEPTH_BASE + KD_DEPTH_LOG2 * log2(N)`` and
``KD_MAX_REFS_PER_TRI * N`` references in all; a split that would exceed either makes a leaf
(each subtree built apart gets a share of the references left under the cap, in proportion to
its own). At most ``MAX_TRIANGLES - 1`` triangles.

Traversal: the ray is clipped to the tree's box; at an inner node the near child is visited
first with the t interval up to the plane and the far child is pushed with the rest (8-byte
nodes, see ``KdTreeTracer``). Rays go in groups of ``PACKET_RAYS``: a group whose directions
share an octant (primary and shadow rays, mostly) takes a step that branches, whose branches
are predicted so that the next node loads early (a branch-free step ran those rays 20-30%
slower); any other group takes a branch-free step (10-20% faster on incoherent rays, where
every branch is a coin flip). A leaf's triangles go through the datapath of
``triangle_unit.mt_valid_at``; a hit counts only up to the leaf's exit (plus ``KD_T_SLACK``),
so a triangle that several leaves list is found where it is hit, and exact-t ties go to the
lower primitive index as in the BVH traversal. The walk stops once the closest hit lies before
the current leaf's exit by more than the slack. ``occluded`` returns at the first hit.
"""
import math
import time

import numpy as np
from numba import njit

from hwbvh.errors import ParameterError
from hwbvh.parallel import run_ranges
from .structure import TriangleStructure, checked_triangles, padded_box
from .config import (CHUNK_RAYS, MIN_RANGE_CHUNKS, PACKET_RAYS, KD_COST_INTERSECT,
                     KD_COST_TRAVERSAL, KD_DEPTH_BASE,
                     KD_DEPTH_LOG2, KD_EMPTY_FACTOR, KD_MAX_REFS_PER_TRI, KD_PAD_COORD,
                     KD_PAD_TRI, KD_PARALLEL_DEPTH, KD_PARALLEL_MIN_TRIS, KD_T_SLACK)
from .grid import _slab
from .packet import coherent
from .triangle_unit import (PRIMITIVE_ORDER, TRI_E1, TRI_E2, TRI_NORMS, TRI_SCALE, TRI_V0,
                            TRI_WORDS, mt_datapath, ray_band_terms, store_answer, store_normals,
                            takes_hit)

LEAF = 3               # the axis field of a leaf node
EVENT_END = 0          # event types, in their order at equal positions (WH06)
EVENT_PLANAR = 1
EVENT_START = 2
# An event is one uint64 key, so that sorting the keys sorts the events in the sweep's order:
# axis (2 bits) | position (32 bits: the float32 position's order-preserving code) |
# type (2 bits) | triangle (TRI_BITS bits).
TRI_BITS = 28
# Triangles a tree holds: the event key's triangle field, and int32 reference offsets for up to
# KD_MAX_REFS_PER_TRI references per triangle.
MAX_TRIANGLES = min(1 << TRI_BITS, 2**31 // KD_MAX_REFS_PER_TRI)
MAX_NODES = 1 << 29    # an inner node's word holds (first child << 2) | axis in an int32
_SH_AXIS = np.uint64(62)
_SH_POS = np.uint64(30)
_SH_TYPE = np.uint64(28)
_MASK_TRI = np.uint64((1 << TRI_BITS) - 1)
_MASK_32 = np.uint64(0xFFFFFFFF)
_MASK_2 = np.uint64(3)
_SIGN_32 = np.uint64(0x80000000)
_T_END = np.uint64(EVENT_END)
_T_PLANAR = np.uint64(EVENT_PLANAR)
_ZERO = np.uint64(0)
_NO_KEY_ABOVE = np.uint64(0xFFFFFFFFFFFFFFFF)   # above every key: the axis field is at most 2
_SMALL_SORT = 32       # sort in place by insertion up to this many items
_TINY32 = float(np.finfo(np.float32).tiny)


def max_depth(n_tris):
    """The depth cap for ``n_tris`` triangles (``KD_DEPTH_BASE + KD_DEPTH_LOG2 * log2(n)``)."""
    return int(round(KD_DEPTH_BASE + KD_DEPTH_LOG2 * math.log2(max(n_tris, 1))))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _down32(x):
    """The largest float32 value <= x (as float64)."""
    f = np.float32(x)
    if np.float64(f) > x:
        f = np.nextafter(f, np.float32(-np.inf))
    return np.float64(f)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _up32(x):
    """The smallest float32 value >= x (as float64)."""
    f = np.float32(x)
    if np.float64(f) < x:
        f = np.nextafter(f, np.float32(np.inf))
    return np.float64(f)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _pos_code(x, fbuf, ubuf):
    """The order-preserving 32-bit code of the float32 value ``x`` (-0 coded as +0).
    ``fbuf`` (1,) float32 and ``ubuf``, its uint32 view: the bit cast."""
    fbuf[0] = np.float32(x) + np.float32(0.0)
    u = np.uint64(ubuf[0])
    if u & _SIGN_32:
        return _MASK_32 ^ u
    return u | _SIGN_32


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _code_pos(c, fbuf, ubuf):
    """The float32 value (as float64) of position code ``c``."""
    u = c ^ _SIGN_32 if c & _SIGN_32 else _MASK_32 ^ c
    ubuf[0] = np.uint32(u)
    return np.float64(fbuf[0])


@njit(cache=True, nogil=True, error_model="numpy")
def _clip_bounds(tris, j, box, pad, out, poly):
    """Triangle ``j`` clipped to ``box`` (lo xyz, hi xyz) widened by ``pad`` (Sutherland-Hodgman
    in float64): writes the clipped polygon's bounds, widened by ``pad``, rounded outwards to
    float32 and limited to ``box`` (float32 values) to ``out`` (6,). Returns False when the
    triangle misses the widened box. ``poly``: (2, 10, 3) scratch, the polygon before and after
    a plane (three vertices and one more per clipping plane at most)."""
    for k in range(3):
        for c in range(3):
            poly[0, k, c] = tris[j, k, c]
    n = 3
    cur = 0
    for plane in range(6):
        ax = plane % 3
        upper = plane >= 3
        bound = box[plane] + pad if upper else box[plane] - pad
        inside = 0
        for k in range(n):
            x = poly[cur, k, ax]
            inside += (x <= bound) if upper else (x >= bound)
        if inside == n:
            continue                      # the plane cuts nothing off
        if inside == 0:
            return False
        nxt = 1 - cur
        m = 0
        for k in range(n):
            k2 = k + 1 if k + 1 < n else 0
            pa = poly[cur, k, ax]
            qa = poly[cur, k2, ax]
            pin = pa <= bound if upper else pa >= bound
            qin = qa <= bound if upper else qa >= bound
            if pin:
                for c in range(3):
                    poly[nxt, m, c] = poly[cur, k, c]
                m += 1
            if pin != qin:
                f = (bound - pa) / (qa - pa)
                for c in range(3):
                    poly[nxt, m, c] = poly[cur, k, c] + f * (poly[cur, k2, c] - poly[cur, k, c])
                poly[nxt, m, ax] = bound
                m += 1
        n = m
        cur = nxt
    _polygon_bounds(poly, cur, n, box, pad, out)
    return True


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _polygon_bounds(poly, cur, n, box, pad, out):
    for c in range(3):
        lo = poly[cur, 0, c]
        hi = poly[cur, 0, c]
        for k in range(1, n):
            lo = min(lo, poly[cur, k, c])
            hi = max(hi, poly[cur, k, c])
        out[c] = min(max(_down32(lo - pad), box[c]), box[3 + c])
        out[3 + c] = min(max(_up32(hi + pad), box[c]), box[3 + c])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _area(ex, ey, ez):
    return 2.0 * (ex * ey + ey * ez + ez * ex)


@njit(cache=True, nogil=True, error_model="numpy")
def _add_events(bounds, tri, ev, e, fbuf, ubuf):
    """The events of one reference with ``bounds`` (6,) on every axis, from slot ``e`` on:
    a planar event where the bounds are flat, else a start and an end. Returns the next slot."""
    t = np.uint64(tri)
    for ax in range(3):
        head = np.uint64(ax) << _SH_AXIS
        lo = _pos_code(bounds[ax], fbuf, ubuf) << _SH_POS
        if bounds[ax] == bounds[3 + ax]:
            ev[e] = head | lo | (np.uint64(EVENT_PLANAR) << _SH_TYPE) | t
            e += 1
        else:
            hi = _pos_code(bounds[3 + ax], fbuf, ubuf) << _SH_POS
            ev[e] = head | lo | (np.uint64(EVENT_START) << _SH_TYPE) | t
            ev[e + 1] = head | hi | (np.uint64(EVENT_END) << _SH_TYPE) | t
            e += 2
    return e


@njit(cache=True, nogil=True, error_model="numpy")
def _sort_small(a, n):
    """a[:n] sorted in place (insertion up to _SMALL_SORT items: no temporary arrays)."""
    if n > _SMALL_SORT:
        a[:n].sort()
        return
    for i in range(1, n):
        x = a[i]
        k = i
        while k > 0 and x < a[k - 1]:
            a[k] = a[k - 1]
            k -= 1
        a[k] = x


@njit(cache=True, nogil=True, error_model="numpy")
def _grow(a, n):
    if n <= a.shape[0]:
        return a
    out = np.empty((max(n, 2 * a.shape[0]),) + a.shape[1:], a.dtype)
    out[:a.shape[0]] = a
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def triangle_pads(tris):
    """Each triangle's padding: KD_PAD_TRI of its extent and KD_PAD_COORD of its largest
    coordinate magnitude, at least the smallest normal float32."""
    pads = np.empty(tris.shape[0])
    for j in range(tris.shape[0]):
        ext = 0.0
        mag = 0.0
        for c in range(3):
            lo = min(tris[j, 0, c], min(tris[j, 1, c], tris[j, 2, c]))
            hi = max(tris[j, 0, c], max(tris[j, 1, c], tris[j, 2, c]))
            ext = max(ext, hi - lo)
            mag = max(mag, max(abs(lo), abs(hi)))
        pads[j] = max(KD_PAD_TRI * ext + KD_PAD_COORD * mag, _TINY32)
    return pads


@njit(cache=True, nogil=True, error_model="numpy")
def root_events(tris, pads, box):
    """Every triangle's events in the tree's ``box`` (which holds every padded triangle),
    unsorted (NumPy's sort, vectorised, sorts them ~15x faster than a compiled one)."""
    n = tris.shape[0]
    ev = np.empty(6 * n, np.uint64)
    bounds = np.empty(6)
    poly = np.empty((1, 3, 3))
    fbuf = np.empty(1, np.float32)
    ubuf = fbuf.view(np.uint32)
    e = 0
    for j in range(n):
        for k in range(3):
            for c in range(3):
                poly[0, k, c] = tris[j, k, c]
        _polygon_bounds(poly, 0, 3, box, pads[j], bounds)
        e = _add_events(bounds, j, ev, e, fbuf, ubuf)
    return ev[:e]


@njit(cache=True, error_model="numpy", inline="always")
def _split_cost(c_trav, scale, empty_factor, al, ar, nl, nr):
    """SAH cost of a split with child areas ``al``, ``ar`` (``scale``: the intersection cost over
    the parent's area) and ``nl``, ``nr`` triangles, with the empty-side factor when a side is
    empty."""
    factor = empty_factor if nl == 0 or nr == 0 else 1.0
    return c_trav + scale * factor * (al * nl + ar * nr)


@njit(cache=True, nogil=True, error_model="numpy")
def _best_split(ev, s, e, m, box, c_trav, c_isect, empty_factor, fbuf, ubuf):
    """The SAH's best plane over the sorted events ev[s:e] of a node with ``m`` triangles:
    (cost, axis (-1: none), position code, planar triangles go left). One sweep per axis over
    that axis' events (WH06): at each position, the triangles ending there and the planar ones
    leave the right side, and the planar ones and those starting there join the left after it."""
    ext = (box[3] - box[0], box[4] - box[1], box[5] - box[2])
    area = _area(ext[0], ext[1], ext[2])
    best_cost = np.inf
    best_axis = -1
    best_code = np.uint64(0)
    best_left = True
    if not area > 0:
        return best_cost, best_axis, best_code, best_left
    scale = c_isect / area
    k = s
    for ax in range(3):
        lo = box[ax]
        hi = box[3 + ax]
        eu = ext[1] if ax == 0 else (ext[2] if ax == 1 else ext[0])
        ew = ext[2] if ax == 0 else (ext[0] if ax == 1 else ext[1])
        side_sum = eu + ew                # a child's area: 2 (x (eu + ew) + eu ew)
        side_prod = eu * ew
        head = np.uint64(ax)
        n_left = 0
        n_right = m
        while k < e and (ev[k] >> _SH_AXIS) == head:
            group = ev[k] >> _SH_POS          # axis and position
            n_end = 0
            n_planar = 0
            n_start = 0
            while k < e and (ev[k] >> _SH_POS) == group:
                typ = (ev[k] >> _SH_TYPE) & _MASK_2
                if typ == _T_END:
                    n_end += 1
                elif typ == _T_PLANAR:
                    n_planar += 1
                else:
                    n_start += 1
                k += 1
            n_right -= n_planar + n_end
            p = _code_pos(group & _MASK_32, fbuf, ubuf)
            if lo < p < hi:
                al = 2.0 * ((p - lo) * side_sum + side_prod)
                ar = 2.0 * ((hi - p) * side_sum + side_prod)
                # planar triangles on the left, then (if any) on the right
                cost = _split_cost(c_trav, scale, empty_factor, al, ar, n_left + n_planar, n_right)
                if cost < best_cost:
                    best_cost = cost
                    best_axis = ax
                    best_code = group & _MASK_32
                    best_left = True
                if n_planar > 0:
                    cost = _split_cost(c_trav, scale, empty_factor, al, ar, n_left,
                                       n_right + n_planar)
                    if cost < best_cost:
                        best_cost = cost
                        best_axis = ax
                        best_code = group & _MASK_32
                        best_left = False
            n_left += n_start + n_planar
    return best_cost, best_axis, best_code, best_left


@njit(cache=True, nogil=True, error_model="numpy")
def _split_events(ev, s, e, side, nev_l, ne_l, nev_r, ne_r, w_l, w_r):
    """One pass over the sorted events ev[s:e]: those whose triangle lies left only (side 1)
    go from ev[w_l] on, merged with the sorted new events nev_l[:ne_l]; right only (side 2)
    from ev[w_r] on with nev_r[:ne_r] (all keys differ). Returns both ends."""
    j_l = 0
    j_r = 0
    for k in range(s, e):
        key = ev[k]
        sd = side[np.int64(key & _MASK_TRI)]
        if sd == 1:
            w_l, j_l = _merge_up_to(ev, w_l, nev_l, j_l, ne_l, key)
            ev[w_l] = key
            w_l += 1
        elif sd == 2:
            w_r, j_r = _merge_up_to(ev, w_r, nev_r, j_r, ne_r, key)
            ev[w_r] = key
            w_r += 1
    w_l, j_l = _merge_up_to(ev, w_l, nev_l, j_l, ne_l, _NO_KEY_ABOVE)
    w_r, j_r = _merge_up_to(ev, w_r, nev_r, j_r, ne_r, _NO_KEY_ABOVE)
    return w_l, w_r


@njit(cache=True, error_model="numpy", inline="always")
def _merge_up_to(ev, w, nev, j, ne, key):
    """Copy the new events nev[j:ne] below ``key`` to ev[w:]; returns the advanced (w, j)."""
    while j < ne and nev[j] < key:
        ev[w] = nev[j]
        w += 1
        j += 1
    return w, j


@njit(cache=True, nogil=True, error_model="numpy")
def build_nodes(tris, pads, ev_in, root_box, depth0, depth_cap, ref_budget, cut_depth, c_trav,
                c_isect, empty_factor):
    """The (sub)tree over the sorted events ``ev_in`` in ``root_box`` at depth ``depth0``.

    A node at ``cut_depth`` that could still split is left pending (its events, box and
    depth returned) for a later ``build_nodes`` call; -1: none. Leaves plus pending nodes
    never hold more than ``ref_budget`` references. Returns (nodes (k, 2) int32 (see
    ``KdTreeTracer``), refs (r,) int32, deepest depth, references held, pending (p, 5) int64:
    node, depth, first event, end event, triangles; pending boxes (p, 6); pending events)."""
    n = tris.shape[0]
    e0 = ev_in.shape[0]
    ev = np.empty(max(4 * e0, 64), np.uint64)
    ev[:e0] = ev_in
    nodes = np.zeros((max(e0 // 4, 16), 2), np.int32)
    refs = np.empty(max(e0 // 3, 16), np.int32)
    side = np.zeros(n, np.uint8)          # per triangle of the current node: 1 left, 2 right, 3 both
    tri = np.empty(max(e0, 1), np.int64)
    nev = np.empty(64, np.uint64)
    nev_r = np.empty(64, np.uint64)
    bounds = np.empty(6)
    poly = np.empty((2, 10, 3))
    fbuf = np.empty(1, np.float32)
    ubuf = fbuf.view(np.uint32)
    slots = depth_cap - depth0 + 3
    f_node = np.empty(slots, np.int64)
    f_depth = np.empty(slots, np.int64)
    f_s = np.empty(slots, np.int64)
    f_e = np.empty(slots, np.int64)
    f_box = np.empty((slots, 6))
    pending = np.empty((16, 5), np.int64)
    p_box = np.empty((16, 6))
    p_ev = np.empty(16, np.uint64)
    n_pending = 0
    n_pev = 0
    box = np.empty(6)
    n_nodes = 1
    n_refs = 0
    deepest = depth0
    total = 0                             # references held by leaves and pending nodes
    for k in range(e0):
        if (ev[k] >> _SH_AXIS) != _ZERO:
            break
        if ((ev[k] >> _SH_TYPE) & _MASK_2) != _T_END:
            total += 1
    f_node[0] = 0
    f_depth[0] = depth0
    f_s[0] = 0
    f_e[0] = e0
    f_box[0] = root_box
    top = 1
    while top > 0:
        top -= 1
        node = f_node[top]
        depth = f_depth[top]
        s = f_s[top]
        e = f_e[top]
        for c in range(6):
            box[c] = f_box[top, c]
        # the node's triangles: one start or planar event each on axis 0 (the first events)
        m = 0
        for k in range(s, e):
            key = ev[k]
            if (key >> _SH_AXIS) != _ZERO:
                break
            if ((key >> _SH_TYPE) & _MASK_2) != _T_END:
                tri[m] = np.int64(key & _MASK_TRI)
                m += 1
        deepest = max(deepest, depth)
        if depth == cut_depth and m > 0 and depth < depth_cap:
            pending = _grow(pending, n_pending + 1)
            p_box = _grow(p_box, n_pending + 1)
            p_ev = _grow(p_ev, n_pev + e - s)
            p_ev[n_pev:n_pev + e - s] = ev[s:e]
            pending[n_pending, 0] = node
            pending[n_pending, 1] = depth
            pending[n_pending, 2] = n_pev
            pending[n_pending, 3] = n_pev + e - s
            pending[n_pending, 4] = m
            p_box[n_pending] = box
            n_pev += e - s
            n_pending += 1
            continue
        ax = -1
        code = np.uint64(0)
        planar_left = True
        nl = 0
        nr = 0
        if m > 0 and depth < depth_cap:
            cost, ax, code, planar_left = _best_split(ev, s, e, m, box, c_trav, c_isect,
                                                      empty_factor, fbuf, ubuf)
            if not cost < c_isect * m:
                ax = -1
        if ax >= 0:
            # split classification: both sides unless an event on the split axis
            # shows the triangle on one side only
            for i in range(m):
                side[tri[i]] = 3
            want = np.uint64(ax)
            k0 = s + np.searchsorted(ev[s:e], want << _SH_AXIS)
            for k in range(k0, e):
                key = ev[k]
                if key >> _SH_AXIS != want:
                    break
                c = (key >> _SH_POS) & _MASK_32
                typ = (key >> _SH_TYPE) & _MASK_2
                j = np.int64(key & _MASK_TRI)
                if typ == _T_END:
                    if c <= code:
                        side[j] = 1
                elif typ == np.uint64(EVENT_START):
                    if c >= code:
                        side[j] = 2
                elif c < code or (c == code and planar_left):
                    side[j] = 1
                else:
                    side[j] = 2
            for i in range(m):
                nl += side[tri[i]] & 1
                nr += side[tri[i]] >> 1
            if total + nl + nr - m > ref_budget:
                ax = -1
        if ax < 0:
            refs = _grow(refs, n_refs + m)
            _sort_small(tri, m)
            for i in range(m):
                refs[n_refs + i] = tri[i]
            nodes[node, 0] = n_refs
            nodes[node, 1] = (m << 2) | LEAF
            n_refs += m
            continue
        first = n_nodes
        n_nodes += 2
        if n_nodes > MAX_NODES:
            raise ValueError("triangles: the kd-tree would need more than 2^29 nodes")
        nodes = _grow(nodes, n_nodes)
        p = _code_pos(code, fbuf, ubuf)
        fbuf[0] = np.float32(p)
        nodes[node, 0] = np.int32(ubuf[0])
        nodes[node, 1] = (first << 2) | ax
        total += nl + nr - m
        n_both = 0
        for i in range(m):
            if side[tri[i]] == 3:
                tri[n_both] = tri[i]          # the straddling triangles, in place
                n_both += 1
        # the straddling triangles clipped to each child's box: their new events, sorted
        nev = _grow(nev, 6 * n_both)
        nev_r = _grow(nev_r, 6 * n_both)
        for c in range(6):
            f_box[top, c] = box[c]
            f_box[top + 1, c] = box[c]
        f_box[top, 3 + ax] = p                # the left child's box
        f_box[top + 1, ax] = p                # the right child's
        ne_l = 0
        ne_r = 0
        for i in range(n_both):
            j = tri[i]
            if _clip_bounds(tris, j, f_box[top], pads[j], bounds, poly):
                ne_l = _add_events(bounds, j, nev, ne_l, fbuf, ubuf)
            else:
                total -= 1
            if _clip_bounds(tris, j, f_box[top + 1], pads[j], bounds, poly):
                ne_r = _add_events(bounds, j, nev_r, ne_r, fbuf, ubuf)
            else:
                total -= 1
        _sort_small(nev, ne_l)
        _sort_small(nev_r, ne_r)
        # one pass hands the one-sided events to their child, merged with the new ones: the
        # left child's from ev[e] on, the right child's above the most the left can hold, so
        # that the right child (popped first) is on top
        lo_r = e + (e - s) + ne_l
        ev = _grow(ev, lo_r + (e - s) + ne_r)
        w_l, w_r = _split_events(ev, s, e, side, nev, ne_l, nev_r, ne_r, e, lo_r)
        f_node[top] = first
        f_depth[top] = depth + 1
        f_s[top] = e
        f_e[top] = w_l
        f_node[top + 1] = first + 1
        f_depth[top + 1] = depth + 1
        f_s[top + 1] = lo_r
        f_e[top + 1] = w_r
        top += 2
    return (nodes[:n_nodes].copy(), refs[:n_refs].copy(), deepest, total,
            pending[:n_pending].copy(), p_box[:n_pending].copy(), p_ev[:n_pev].copy())


def build_kdtree(tris, pads, box, depth_cap, ref_cap, costs=None, parallel_depth=None):
    """The tree over ``tris`` ((n, 3, 3) float64), ``pads`` (n,) each triangle's padding, in
    ``box`` (6,) (float32 values holding every padded triangle). ``costs``: (traversal,
    intersection, empty factor), default the configured ones. Returns (nodes (k, 2) int32,
    refs (r,) int32, depth).

    The nodes down to ``parallel_depth`` (-1: none; default ``KD_PARALLEL_DEPTH`` from
    ``KD_PARALLEL_MIN_TRIS`` triangles on, else -1) are built first; the subtrees below them
    are then built independently on the threads of ``hwbvh.parallel.run_ranges``, each with a
    share of the references left under the cap in proportion to its own, and joined in a fixed
    order: the tree does not depend on the thread count."""
    c_trav, c_isect, empty = (float(c) for c in costs or (KD_COST_TRAVERSAL, KD_COST_INTERSECT,
                                                            KD_EMPTY_FACTOR))
    if parallel_depth is None:
        parallel_depth = KD_PARALLEL_DEPTH if len(tris) >= KD_PARALLEL_MIN_TRIS else -1
    ev = root_events(tris, pads, box)
    ev.sort()
    nodes, refs, deepest, total, pending, p_box, p_ev = build_nodes(
        tris, pads, ev, box, 0, depth_cap, ref_cap, parallel_depth, c_trav, c_isect, empty)
    if len(pending) == 0:
        return nodes, refs, int(deepest)
    held = [int(x) for x in pending[:, 4]]
    spare = ref_cap - int(total)
    budgets = [m + spare * m // sum(held) for m in held]
    subtrees = [None] * len(pending)
    largest_first = sorted(range(len(pending)), key=lambda i: (pending[i, 2] - pending[i, 3], i))

    def build_range(lo, hi):
        for r in range(lo, hi):
            i = largest_first[r]
            subtrees[i] = build_nodes(tris, pads, p_ev[pending[i, 2]:pending[i, 3]], p_box[i],
                                      int(pending[i, 1]), depth_cap, budgets[i], -1, c_trav,
                                      c_isect, empty)

    run_ranges(build_range, len(pending))
    k = len(nodes) + sum(len(st[0]) - 1 for st in subtrees)
    if k > MAX_NODES:
        raise ValueError(f"triangles: the kd-tree would need {k} nodes (at most 2^29)")
    out = np.empty((k, 2), np.int32)
    out[:len(nodes)] = nodes
    parts = [refs]
    base = len(nodes)
    ref_base = len(refs)
    for i, st in enumerate(subtrees):
        sub, sub_refs = st[0], st[1]
        deepest = max(deepest, st[2])
        _relocate(sub, base - 1, ref_base)
        out[pending[i, 0]] = sub[0]
        out[base:base + len(sub) - 1] = sub[1:]
        base += len(sub) - 1
        ref_base += len(sub_refs)
        parts.append(sub_refs)
    return out, np.concatenate(parts), int(deepest)


@njit(cache=True, nogil=True, error_model="numpy")
def _relocate(nodes, node_shift, ref_shift):
    """A subtree's nodes moved into the whole tree: child indices by ``node_shift``, reference
    offsets by ``ref_shift``."""
    for i in range(nodes.shape[0]):
        w = nodes[i, 1]
        if w & 3 == LEAF:
            nodes[i, 0] += ref_shift
        else:
            nodes[i, 1] = (((w >> 2) + node_shift) << 2) | (w & 3)


@njit(cache=True, error_model="numpy", inline="always")
def _ray_ok(ox, oy, oz, dx, dy, dz, tmin, tmax):
    """The ray is finite, has a direction and a non-empty interval (as the BVH traversal's
    check, without branches: x - x == 0 exactly where x is finite)."""
    return ((ox - ox == 0) & (oy - oy == 0) & (oz - oz == 0) & (dx - dx == 0) & (dy - dy == 0)
            & (dz - dz == 0) & ((dx != 0) | (dy != 0) | (dz != 0)) & (tmin <= tmax))


@njit(cache=True, error_model="numpy", inline="always")
def trace_kd_ray(tris, nodes, nodes_f, refs, box, ox, oy, oz, dx, dy, dz, tmin, tmax, eps2, one,
                 edge, st_node, st_near, st_far, anyhit, predictable):
    """One ray through the kd-tree: (prim, t, u, v), prim -1 for a miss."""
    best_t = tmax
    prim = -1
    bu = one - one
    bv = bu
    ok = _ray_ok(ox, oy, oz, dx, dy, dz, tmin, tmax)
    # the walk in float64 on the float32 ray (exact conversions)
    o = (np.float64(ox), np.float64(oy), np.float64(oz))
    d = (np.float64(dx), np.float64(dy), np.float64(dz))
    t0, t1 = _slab(o[0], d[0], box[0], box[3], np.float64(tmin), np.float64(tmax))
    t0, t1 = _slab(o[1], d[1], box[1], box[4], t0, t1)
    t0, t1 = _slab(o[2], d[2], box[2], box[5], t0, t1)
    # one exit for a rejected ray and a miss of the tree's box (a separate early return for
    # the check made the whole walk slower: ~1.5x on primary rays)
    if not (ok and t0 <= t1):
        return prim, best_t, bu, bv
    scale = max(abs(o[0]), max(abs(o[1]), abs(o[2]))) / max(abs(d[0]), max(abs(d[1]), abs(d[2])))
    inv = (1.0 / d[0], 1.0 / d[1], 1.0 / d[2])
    # the unit's ray terms, once per ray (mt_valid_at's datapath on the rows below)
    rscale, dds = ray_band_terms(dx, dy, dz)
    lo_b = -edge
    hi_b = one + edge
    top = 0
    node = 0
    near_t = t0
    far_t = t1
    while True:
        w = nodes[node, 1]
        ax = w & 3
        if ax != LEAF:
            s = np.float64(nodes_f[node, 0])
            oa = o[0] if ax == 0 else (o[1] if ax == 1 else o[2])
            da = d[0] if ax == 0 else (d[1] if ax == 1 else d[2])
            ia = inv[0] if ax == 0 else (inv[1] if ax == 1 else inv[2])
            first = w >> 2
            tp = (s - oa) * ia
            if predictable:
                # rays of one direction octant: the branches are predicted, and the next node
                # loads before the test that chooses it is done
                below_first = oa < s or (oa == s and da <= 0)
                near = first if below_first else first + 1
                far = first + 1 if below_first else first
                if da == 0:
                    node = near
                    continue
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
            # incoherent rays: each decision is a coin flip, and selects cost less than the
            # mispredicted branches
            below_first = (oa < s) | ((oa == s) & (da <= 0))
            near = first + 1 - np.int64(below_first)
            far = first + np.int64(below_first)
            crosses = (tp <= far_t) & (tp > 0) & (da != 0)     # else the near child only
            far_only = crosses & (tp < near_t)
            both = crosses & (tp >= near_t)
            st_node[top] = far                 # written always, kept only when both
            st_near[top] = tp
            st_far[top] = far_t
            top += np.int64(both)
            node = far if far_only else near
            far_t = tp if both else far_t
            continue
        # a leaf: hits count up to its exit plus the slack
        limit = far_t + KD_T_SLACK * (abs(far_t) + scale)
        hi = best_t if anyhit else min(best_t, np.float32(limit))
        start = nodes[node, 0]
        for p in range(start, start + (w >> 2)):
            j = np.int64(refs[p])
            b = TRI_WORDS * j
            ok, t, tu, tv = mt_datapath(tris[b + TRI_V0], tris[b + TRI_V0 + 1], tris[b + TRI_V0 + 2],
                                        tris[b + TRI_E1], tris[b + TRI_E1 + 1], tris[b + TRI_E1 + 2],
                                        tris[b + TRI_E2], tris[b + TRI_E2 + 1], tris[b + TRI_E2 + 2],
                                        eps2 * tris[b + TRI_NORMS], tris[b + TRI_SCALE], ox, oy, oz,
                                        dx, dy, dz, dds, rscale, lo_b, hi_b, tmin, hi, one)
            acc = takes_hit(ok, t, j, best_t, prim)
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


@njit(cache=True, error_model="numpy", _nrt=False)
def _kd_range(lo, hi, tris, nodes, nodes_f, refs, box, O, D, tmin, tmax, eps2, one, edge, anyhit,
              st_node, st_near, st_far, out_prim, out_t, out_u, out_v):
    """Rays [lo, hi) in a plain function without reference counting, so LLVM optimises the
    loop fully (as the BVH traversal's ``_trace_range``; ~15% on primary rays). Each group of
    PACKET_RAYS consecutive rays whose directions share an octant (the BVH's packet test) takes
    the branching step, any other group the branch-free one."""
    a = lo
    while a < hi:
        b = min(hi, a + PACKET_RAYS)
        if coherent(D, a, b):
            for i in range(a, b):
                prim, t, bu, bv = trace_kd_ray(tris, nodes, nodes_f, refs, box, O[i, 0], O[i, 1],
                                               O[i, 2], D[i, 0], D[i, 1], D[i, 2], tmin[i],
                                               tmax[i], eps2, one, edge, st_node, st_near,
                                               st_far, anyhit, True)
                store_answer(i, prim, t, bu, bv, out_prim, out_t, out_u, out_v)
        else:
            for i in range(a, b):
                prim, t, bu, bv = trace_kd_ray(tris, nodes, nodes_f, refs, box, O[i, 0], O[i, 1],
                                               O[i, 2], D[i, 0], D[i, 1], D[i, 2], tmin[i],
                                               tmax[i], eps2, one, edge, st_node, st_near,
                                               st_far, anyhit, False)
                store_answer(i, prim, t, bu, bv, out_prim, out_t, out_u, out_v)
        a = b


@njit(cache=True, nogil=True, error_model="numpy")
def kd_chunks(c0, c1, tris, nodes, nodes_f, refs, box, stack_size, O, D, tmin, tmax, eps2, one,
              edge, anyhit, out_prim, out_t, out_u, out_v, out_ng):
    """Chunks c0..c1 of CHUNK_RAYS rays (``hwbvh.parallel.run_ranges`` hands them out).
    ``out_t``/``out_u``/``out_v`` are (n,) or (0,) when only ``out_prim`` is wanted; ``out_ng``
    is (n, 3) for geometric normals or (0, 3)."""
    n = O.shape[0]
    st_node = np.empty(stack_size, np.int64)
    st_near = np.empty(stack_size)
    st_far = np.empty(stack_size)
    lo = c0 * CHUNK_RAYS
    hi = min(n, c1 * CHUNK_RAYS)
    _kd_range(lo, hi, tris, nodes, nodes_f, refs, box, O, D, tmin, tmax, eps2, one, edge, anyhit,
              st_node, st_near, st_far, out_prim, out_t, out_u, out_v)
    store_normals(lo, hi, tris, PRIMITIVE_ORDER, out_prim, out_ng, one)


class KdTreeTracer(TriangleStructure):
    """Ray queries on an SAH kd-tree over ``triangles`` ((n, 3, 3)), with the BVH traversal's
    float32 triangle unit. Implements the tracer interface of ``traversal.tracers``.

    ``nodes`` (k, 2) int32, 8 bytes a node: an inner node holds its split position (float32
    bits) and (first child << 2) | axis, the children adjacent; a leaf holds its first
    reference and (count << 2) | LEAF. ``refs`` (r,) int32: the leaves' triangle ids.

    After the build: ``build_seconds``, ``memory_bytes`` (nodes, references and preprocessed
    triangles), ``nodes``, ``leaves``, ``references``, ``references_per_triangle``, ``depth``
    and the caps ``max_depth`` and ``max_references``."""

    name = "kdtree"

    def __init__(self, triangles):
        start = time.perf_counter()
        tris = checked_triangles(triangles)
        n = len(tris)
        if n >= MAX_TRIANGLES:
            raise ParameterError("triangles", f"{n} triangles, the kd-tree holds at most "
                                              f"{MAX_TRIANGLES - 1}")
        pads = triangle_pads(tris)
        # the tree's box: the mesh's, padded like a triangle's box, never flat, float32 bounds
        _, _, box_lo, box_hi = padded_box(tris, KD_PAD_TRI, KD_PAD_COORD)
        lo = box_lo.astype(np.float32)
        hi = box_hi.astype(np.float32)
        lo = np.where(lo > box_lo, np.nextafter(lo, np.float32(-np.inf)), lo)
        hi = np.where(hi < box_hi, np.nextafter(hi, np.float32(np.inf)), hi)
        self.box = np.r_[lo, hi].astype(np.float64)
        self.max_depth = max_depth(n)
        self.max_references = KD_MAX_REFS_PER_TRI * max(n, 1)
        self.node_words, self.refs, depth = build_kdtree(tris, pads, self.box, self.max_depth,
                                                         self.max_references)
        self.depth = int(depth)
        self.nodes = len(self.node_words)
        self.leaves = int(((self.node_words[:, 1] & 3) == LEAF).sum())
        self._set_unit(tris, triangles)
        self.references = int(len(self.refs))
        self.references_per_triangle = self.references / max(n, 1)
        self.memory_bytes = int(self.node_words.nbytes + self.refs.nbytes + self.tris.nbytes)
        self.build_seconds = time.perf_counter() - start

    def _trace(self, o, d, tmin, tmax, anyhit, prim, t, u, v, ng):
        run_ranges(kd_chunks, (len(o) + CHUNK_RAYS - 1) // CHUNK_RAYS, self._tris1,
                   self.node_words, self.node_words.view(np.float32), self.refs, self.box,
                   self.depth + 1, o, d, tmin, tmax, self.eps2, self.one, self.edge, anyhit, prim,
                   t, u, v, ng, min_items=MIN_RANGE_CHUNKS)

    def split_planes(self):
        """(axes, positions) of the inner nodes' split planes."""
        w = self.node_words
        inner = (w[:, 1] & 3) != LEAF
        return w[inner, 1] & 3, w.view(np.float32)[inner, 0].astype(np.float64)

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
    _relocate(kd.node_words.copy(), 0, 0)
    return time.perf_counter() - start
