"""SAH calculator (thesis 3.3.4, Fig. 3.8/3.11; SPEC 2).

From the merged bins of one node, evaluate the S-1 boundaries of every axis with

    C = SA(V_L) * N_L + SA(V_R) * N_R,   SA(b) = dx*dy + dy*dz + dz*dx      (Eq. 3.3)

in float32. A candidate with an empty side is invalid. Lowest cost wins; ties go to the lower
axis (x < y < z), then the lower boundary. The unit also outputs the child AABBs (bin unions)
and counts, which is what the partitioning units and the tree output consume.
"""
import numpy as np
from numba import njit


@njit(cache=True)
def surface_half_area(lox, loy, loz, hix, hiy, hiz):
    """dx*dy + dy*dz + dz*dx (half the surface area; the factor 2 cancels), in the type of
    its arguments: float32 in the SAH calculator, float64 in the sweep reference."""
    dx = hix - lox
    dy = hiy - loy
    dz = hiz - loz
    return dx * dy + dy * dz + dz * dx


@njit(cache=True)
def best_split(binbox, bincnt, nbins, out_lbox, out_rbox, left_sa, left_n):
    """Choose the split. Returns (axis, boundary, n_left, n_right, cost); axis -1 when no
    axis has a valid candidate. Fills out_lbox / out_rbox (f32 (6,)) with the child AABBs.
    Bins ``< boundary`` go left."""
    best_axis = -1
    best_b = 0
    best_cost = np.float32(0.0)
    # float32 accumulators: the bounds are float32, so their min and max are the same in
    # either width, and the SAH is taken in float32 without conversions
    inf = np.float32(np.inf)
    for a in range(3):
        # forward sweep: SA(V_L) * N_L for boundaries 1..S-1 (the FIFO of Fig. 3.11); an
        # entry with no primitive on the left is never read
        lx = inf; ly = inf; lz = inf
        hx = -inf; hy = -inf; hz = -inf
        n = 0
        for b in range(nbins - 1):
            c = bincnt[a, b]
            if c > 0:
                n += c
                lx = min(lx, binbox[a, b, 0]); ly = min(ly, binbox[a, b, 1]); lz = min(lz, binbox[a, b, 2])
                hx = max(hx, binbox[a, b, 3]); hy = max(hy, binbox[a, b, 4]); hz = max(hz, binbox[a, b, 5])
            left_n[b + 1] = n
            left_sa[b + 1] = surface_half_area(lx, ly, lz, hx, hy, hz)
        # backward sweep: SA(V_R) * N_R, and the total cost per boundary (the LIFOs)
        lx = inf; ly = inf; lz = inf
        hx = -inf; hy = -inf; hz = -inf
        n = 0
        for b in range(nbins - 1, 0, -1):
            c = bincnt[a, b]
            if c > 0:
                n += c
                lx = min(lx, binbox[a, b, 0]); ly = min(ly, binbox[a, b, 1]); lz = min(lz, binbox[a, b, 2])
                hx = max(hx, binbox[a, b, 3]); hy = max(hy, binbox[a, b, 4]); hz = max(hz, binbox[a, b, 5])
            if n == 0 or left_n[b] == 0:
                continue
            sa_r = surface_half_area(lx, ly, lz, hx, hy, hz)
            cost = left_sa[b] * np.float32(left_n[b]) + sa_r * np.float32(n)
            # ties: lower axis, then lower boundary (we sweep b downwards, so <= on the same axis)
            if best_axis < 0 or cost < best_cost or (a == best_axis and cost == best_cost):
                best_axis = a
                best_b = b
                best_cost = cost
    if best_axis < 0:
        return -1, 0, 0, 0, np.float32(np.inf)
    # child AABBs and counts: unions of the bins on each side
    for k in range(3):
        out_lbox[k] = np.inf
        out_lbox[3 + k] = -np.inf
        out_rbox[k] = np.inf
        out_rbox[3 + k] = -np.inf
    nl = 0
    nr = 0
    for b in range(nbins):
        if bincnt[best_axis, b] == 0:
            continue
        if b < best_b:
            nl += bincnt[best_axis, b]
            for k in range(3):
                out_lbox[k] = min(out_lbox[k], binbox[best_axis, b, k])
                out_lbox[3 + k] = max(out_lbox[3 + k], binbox[best_axis, b, 3 + k])
        else:
            nr += bincnt[best_axis, b]
            for k in range(3):
                out_rbox[k] = min(out_rbox[k], binbox[best_axis, b, k])
                out_rbox[3 + k] = max(out_rbox[3 + k], binbox[best_axis, b, 3 + k])
    return best_axis, best_b, nl, nr, best_cost
