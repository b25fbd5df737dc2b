"""Slow, literal reference implementations used only by the tests.

``naive_hwbvh`` follows SPEC section 2 line by line with NumPy float32 scalars and Python lists;
``naive_best_split`` is the SAH choice of one node's bins over every boundary;
``naive_sweep_cost`` evaluates every split of a small set by brute force; ``ray_triangle_f64``
is a float64 Moller-Trumbore for checking hits.
"""
import numpy as np

F = np.float32


def _bounds(boxes, idx):
    b = boxes[idx]
    return np.concatenate([b[:, :3].min(0), b[:, 3:].max(0)]).astype(np.float32)


def _sa(b):
    dx, dy, dz = b[3] - b[0], b[4] - b[1], b[5] - b[2]
    return dx * dy + dy * dz + dz * dx


def naive_hwbvh(boxes, leaf_size=4, S=16):
    """Pre-order list of (box tuple, is_leaf, sorted primitive tuple or None); fallback count."""
    boxes = np.asarray(boxes, dtype=np.float32)
    out = []
    fallback = [0]

    def rec(idx):
        box = _bounds(boxes, idx)
        if len(idx) <= leaf_size:
            out.append((tuple(box.tolist()), True, tuple(sorted(idx))))
            return
        best = None
        binof = {}
        for a in range(3):
            lo, hi = box[a], box[3 + a]
            if not hi > lo:
                continue
            bins = []
            for i in idx:
                c = (boxes[i, a] + boxes[i, 3 + a]) * F(0.5)
                t = (c - lo) / (hi - lo) * F(S)
                b = int(np.floor(t))
                bins.append(min(max(b, 0), S - 1))
            binof[a] = bins
            for k in range(1, S):
                L = [i for i, b in zip(idx, bins) if b < k]
                R = [i for i, b in zip(idx, bins) if b >= k]
                if not L or not R:
                    continue
                cost = _sa(_bounds(boxes, L)) * F(len(L)) + _sa(_bounds(boxes, R)) * F(len(R))
                if best is None or cost < best[0]:
                    best = (cost, a, k)
        if best is None:
            fallback[0] += 1
            L, R = idx[: len(idx) // 2], idx[len(idx) // 2:]
        else:
            _, a, k = best
            L = [i for i, b in zip(idx, binof[a]) if b < k]
            R = [i for i, b in zip(idx, binof[a]) if b >= k]
        out.append((tuple(box.tolist()), False, None))
        rec(L)
        rec(R)

    rec(list(range(len(boxes))))
    return out, fallback[0]


def naive_best_split(binbox, bincnt):
    """SPEC 2's SAH choice from one node's bins (binbox (3, S, 6), bincnt (3, S)), every
    boundary of every axis in turn, the lowest cost kept (ties: lower axis, then lower
    boundary). The boundaries of an axis come downwards, as the hardware's LIFOs give them:
    with finite costs the order does not matter, but a cost that overflowed to NaN compares
    false with everything, so the first candidate met stays. Sides are unions of their
    occupied bins in bin order (Python's min and max keep the first of equal bounds, +0 or -0,
    as the hardware's comparators do). Returns (axis, boundary, n_left, n_right, cost, left
    box, right box); axis -1 without a candidate."""
    S = binbox.shape[1]

    def union(a, bins):
        box = [F(np.inf)] * 3 + [F(-np.inf)] * 3
        for b in bins:
            if bincnt[a, b]:
                box = [min(box[k], binbox[a, b, k]) for k in range(3)] + \
                      [max(box[3 + k], binbox[a, b, 3 + k]) for k in range(3)]
        return np.array(box, np.float32)

    best = (-1, 0, 0, 0, F(np.inf), None, None)
    for a in range(3):
        for k in range(S - 1, 0, -1):
            nl, nr = int(bincnt[a, :k].sum()), int(bincnt[a, k:].sum())
            if nl == 0 or nr == 0:
                continue
            lb, rb = union(a, range(k)), union(a, range(k, S))
            cost = _sa(lb) * F(nl) + _sa(rb) * F(nr)
            if best[0] < 0 or cost < best[4] or (a == best[0] and cost == best[4]):
                best = (a, k, nl, nr, cost, lb, rb)
    return best


def preorder(nodes, indices):
    """The same pre-order description, read from a NODE_DTYPE array and its index list."""
    out = []
    stack = [0]
    while stack:
        i = stack.pop()
        n = nodes[i]
        box = tuple(np.asarray(n["bounds"], dtype=np.float32).tolist())
        if n["flags"] & 1:
            a, c = int(n["a"]), int(n["b"])
            out.append((box, True, tuple(sorted(int(x) for x in indices[a:a + c]))))
        else:
            out.append((box, False, None))
            stack.append(int(n["b"]))
            stack.append(int(n["a"]))
    return out


def ray_triangle_f64(o, d, tri):
    """Float64 Moller-Trumbore without epsilon: (hit, t, u, v) for one ray and triangle."""
    o = np.asarray(o, np.float64); d = np.asarray(d, np.float64); tri = np.asarray(tri, np.float64)
    e1 = tri[1] - tri[0]
    e2 = tri[2] - tri[0]
    p = np.cross(d, e2)
    det = e1 @ p
    if det == 0:
        return False, np.inf, 0.0, 0.0
    s = o - tri[0]
    u = (s @ p) / det
    q = np.cross(s, e1)
    v = (d @ q) / det
    t = (e2 @ q) / det
    ok = u >= 0 and v >= 0 and u + v <= 1
    return ok, t, u, v
