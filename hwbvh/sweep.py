"""Reference full-SAH sweep builder (thesis 4.3.3 "gold standard", [WBS07]; SPEC 5).

Centres are sorted once along each axis (ties by primitive index) and the three orders are kept
sorted by stable partitioning, so each level costs O(N). Every primitive boundary on every axis
is a candidate; costs are float64 on the float32 AABBs. Leaf termination is SAH-driven in the
metric's own costs (T1 = 1 per child, T2 = 1 per primitive): a node becomes a leaf when

    N * A(node) <= 2 * A(node) + N_L * A(L) + N_R * A(R)

for its best split; a single primitive is always a leaf. Above ``max_leaf`` primitives a split
is forced, so a pile of identical triangles cannot make an unbounded leaf.
"""
import numpy as np
from numba import njit

from . import config
from .builder import AXIS_LEAF, CanonicalTree, alloc_canonical
from .sah_calculator import surface_half_area as _half_area


@njit(cache=True)
def _sweep_build(boxes, orders, max_leaf, cbox, cleft, cright, cstart, ccount, caxis):
    n_all = boxes.shape[0]
    larea = np.empty(n_all, dtype=np.float64)
    tmp = np.empty(n_all, dtype=np.int32)
    flag = np.zeros(n_all, dtype=np.uint8)
    st_parent = np.empty(n_all + 1, dtype=np.int64)
    st_start = np.empty(n_all + 1, dtype=np.int64)
    st_count = np.empty(n_all + 1, dtype=np.int64)
    st_depth = np.empty(n_all + 1, dtype=np.int64)
    sp = 0
    slot = 0
    nxt = 1
    s = 0
    n = n_all
    depth = 0
    max_depth = 0
    leaves = 0
    while True:
        # node AABB
        lx = np.inf; ly = np.inf; lz = np.inf; hx = -np.inf; hy = -np.inf; hz = -np.inf
        for i in range(s, s + n):
            p = orders[0, i]
            lx = min(lx, boxes[p, 0]); ly = min(ly, boxes[p, 1]); lz = min(lz, boxes[p, 2])
            hx = max(hx, boxes[p, 3]); hy = max(hy, boxes[p, 4]); hz = max(hz, boxes[p, 5])
        cbox[slot, 0] = lx; cbox[slot, 1] = ly; cbox[slot, 2] = lz
        cbox[slot, 3] = hx; cbox[slot, 4] = hy; cbox[slot, 5] = hz
        cstart[slot] = s
        ccount[slot] = n
        if depth > max_depth:
            max_depth = depth
        node_area = _half_area(np.float64(lx), np.float64(ly), np.float64(lz),
                               np.float64(hx), np.float64(hy), np.float64(hz))
        # full sweep on every axis: every primitive boundary is a candidate
        best = np.inf
        best_axis = -1
        best_k = 0
        if n > 1:
            for a in range(3):
                lx = np.inf; ly = np.inf; lz = np.inf; hx = -np.inf; hy = -np.inf; hz = -np.inf
                for j in range(n - 1):
                    p = orders[a, s + j]
                    lx = min(lx, boxes[p, 0]); ly = min(ly, boxes[p, 1]); lz = min(lz, boxes[p, 2])
                    hx = max(hx, boxes[p, 3]); hy = max(hy, boxes[p, 4]); hz = max(hz, boxes[p, 5])
                    larea[j] = _half_area(np.float64(lx), np.float64(ly), np.float64(lz),
                                          np.float64(hx), np.float64(hy), np.float64(hz))
                lx = np.inf; ly = np.inf; lz = np.inf; hx = -np.inf; hy = -np.inf; hz = -np.inf
                for j in range(n - 1, 0, -1):
                    p = orders[a, s + j]
                    lx = min(lx, boxes[p, 0]); ly = min(ly, boxes[p, 1]); lz = min(lz, boxes[p, 2])
                    hx = max(hx, boxes[p, 3]); hy = max(hy, boxes[p, 4]); hz = max(hz, boxes[p, 5])
                    ra = _half_area(np.float64(lx), np.float64(ly), np.float64(lz),
                                    np.float64(hx), np.float64(hy), np.float64(hz))
                    # left = first j primitives
                    cost = larea[j - 1] * j + ra * (n - j)
                    if cost < best or (cost == best and a == best_axis):
                        best = cost
                        best_axis = a
                        best_k = j
        make_leaf = n == 1 or (n <= max_leaf and n * node_area <= 2.0 * node_area + best)
        if make_leaf:
            cleft[slot] = -1
            cright[slot] = -1
            caxis[slot] = AXIS_LEAF
            leaves += 1
            if sp == 0:
                break
            sp -= 1
            slot = nxt
            nxt += 1
            cright[st_parent[sp]] = slot
            s = st_start[sp]
            n = st_count[sp]
            depth = st_depth[sp]
            continue
        # partition the other two axis orders by membership of the left set (stable)
        for j in range(best_k):
            flag[orders[best_axis, s + j]] = 1
        for a in range(3):
            if a == best_axis:
                continue
            li = 0
            ri = best_k
            for j in range(n):
                p = orders[a, s + j]
                if flag[p]:
                    tmp[li] = p
                    li += 1
                else:
                    tmp[ri] = p
                    ri += 1
            for j in range(n):
                orders[a, s + j] = tmp[j]
        for j in range(best_k):
            flag[orders[best_axis, s + j]] = 0
        caxis[slot] = best_axis
        st_parent[sp] = slot
        st_start[sp] = s + best_k
        st_count[sp] = n - best_k
        st_depth[sp] = depth + 1
        sp += 1
        cleft[slot] = nxt
        slot = nxt
        nxt += 1
        n = best_k
        depth += 1
    return nxt, leaves, max_depth


def build_sweep(boxes, max_leaf=config.SWEEP_MAX_LEAF):
    """Full SAH sweep build over primitive AABBs (n, 6) float32 -> CanonicalTree."""
    boxes = np.ascontiguousarray(boxes, dtype=np.float32)
    n = len(boxes)
    cen = (boxes[:, :3] + boxes[:, 3:]) * np.float32(0.5)
    orders = np.empty((3, n), dtype=np.int32)
    for a in range(3):
        orders[a] = np.argsort(cen[:, a], kind="stable")
    cbox, cleft, cright, cstart, ccount, caxis = alloc_canonical(2 * n)
    used, leaves, depth = _sweep_build(boxes, orders, int(max_leaf), cbox, cleft, cright, cstart,
                                       ccount, caxis)
    return CanonicalTree(box=cbox, left=cleft, right=cright, start=cstart, count=ccount,
                         axis=caxis, root=0, ids=orders[0].copy(), n_prims=n,
                         leaf_size=int(max_leaf), bins=0, builder="sweep",
                         stats={"nodes": int(used), "leaves": int(leaves),
                                "fallback_splits": 0, "max_depth": int(depth)})
