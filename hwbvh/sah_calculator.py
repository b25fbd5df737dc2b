"""SAH calculator (thesis 3.3.4, Fig. 3.8/3.11; SPEC 2).

From the merged bins of one node, evaluate the S-1 boundaries of every axis with

    C = SA(V_L) * N_L + SA(V_R) * N_R,   SA(b) = dx*dy + dy*dz + dz*dx      (Eq. 3.3)

in float32. A candidate with an empty side is invalid. Lowest cost wins; ties go to the lower
axis (x < y < z), then the lower boundary. The unit also outputs the child AABBs (bin unions)
and counts, which is what the partitioning units and the tree output consume.
"""
import numpy as np
from numba import njit

from .binning_unit import SLOT_WORDS


@njit(cache=True)
def surface_half_area(lox, loy, loz, hix, hiy, hiz):
    """dx*dy + dy*dz + dz*dx (half the surface area; the factor 2 cancels), in the type of
    its arguments: float32 in the SAH calculator, float64 in the sweep reference."""
    dx = hix - lox
    dy = hiy - loy
    dz = hiz - loz
    return dx * dy + dy * dz + dz * dx


@njit(cache=True)
def sah_scratch(nbins):
    """Working arrays of ``best_split`` for ``nbins`` bins: the left sides' areas (float32)
    and counts (int64), and one axis' occupied bins (int64)."""
    return (np.empty(nbins, dtype=np.float32), np.empty(nbins, dtype=np.int64),
            np.empty(nbins, dtype=np.int64))


@njit(cache=True, inline="always")
def _bin_union(F, C, base, b0, b1, out_box):
    """The union of bins b0..b1 of the axis at ``base`` into ``out_box`` (min xyz, max xyz);
    returns their primitive count."""
    inf = np.float32(np.inf)
    l0 = inf; l1 = inf; l2 = inf; l3 = inf; l4 = inf; l5 = inf
    count = 0
    for b in range(b0, b1):
        o = SLOT_WORDS * (base + b)
        l0 = min(l0, F[o]); l1 = min(l1, F[o + 1]); l2 = min(l2, F[o + 2])
        l3 = min(l3, F[o + 3]); l4 = min(l4, F[o + 4]); l5 = min(l5, F[o + 5])
        count += C[base + b]
    out_box[0] = l0; out_box[1] = l1; out_box[2] = l2
    out_box[3] = -l3; out_box[4] = -l4; out_box[5] = -l5
    return count


@njit(cache=True, error_model="numpy")
def best_split(F, C, nbins, out_lbox, out_rbox, left_sa, left_n, occupied):
    """Choose the split from the bins as the collectors hold them (``binning_unit``: per
    (axis, bin) slot the words min x, y, z, -max x, y, z and a count in ``C``). Returns (axis,
    boundary, n_left, n_right, cost); axis -1 when no axis has a valid candidate. Fills
    out_lbox / out_rbox (f32 (6,)) with the child AABBs. Bins ``< boundary`` go left.
    ``left_sa``, ``left_n``, ``occupied``: ``sah_scratch`` arrays.

    Every boundary between two occupied bins of an axis splits the same two sets, so has the
    same cost; of those the rule keeps the lowest. Only the boundary just past each occupied
    bin is therefore evaluated: a node of a few primitives has a few candidates per axis, not
    S - 1. The sides' unions are the same min folds, in the same order, as over every bin
    (an empty bin's words are +inf, which a min leaves as it was), so cost and choice are
    those of the sweeps over all S - 1 boundaries, bit for bit."""
    best_axis = -1
    best_b = 0
    # float32 accumulators: the bounds are float32, so their min and max are the same in
    # either width, and the SAH is taken in float32 without conversions
    inf = np.float32(np.inf)
    best_cost = inf
    for a in range(3):
        base = a * nbins
        m = 0
        for b in range(nbins):                  # the occupied bins, in order, without a branch
            occupied[m] = b
            m += np.int64(C[base + b] != 0)
        # forward (the FIFO of Fig. 3.11): SA(V_L) and N_L past each occupied bin but the last
        l0 = inf; l1 = inf; l2 = inf; l3 = inf; l4 = inf; l5 = inf
        n = 0
        for i in range(m - 1):
            b = occupied[i]
            o = SLOT_WORDS * (base + b)
            l0 = min(l0, F[o]); l1 = min(l1, F[o + 1]); l2 = min(l2, F[o + 2])
            l3 = min(l3, F[o + 3]); l4 = min(l4, F[o + 4]); l5 = min(l5, F[o + 5])
            n += C[base + b]
            left_n[i] = n
            left_sa[i] = surface_half_area(l0, l1, l2, -l3, -l4, -l5)
        # backward (the LIFOs): SA(V_R) * N_R from each occupied bin but the first, and the
        # cost at the lowest boundary with these sides, one past the previous occupied bin
        l0 = inf; l1 = inf; l2 = inf; l3 = inf; l4 = inf; l5 = inf
        n = 0
        for i in range(m - 1, 0, -1):
            b = occupied[i]
            o = SLOT_WORDS * (base + b)
            l0 = min(l0, F[o]); l1 = min(l1, F[o + 1]); l2 = min(l2, F[o + 2])
            l3 = min(l3, F[o + 3]); l4 = min(l4, F[o + 4]); l5 = min(l5, F[o + 5])
            n += C[base + b]
            sa_r = surface_half_area(l0, l1, l2, -l3, -l4, -l5)
            cost = left_sa[i - 1] * np.float32(left_n[i - 1]) + sa_r * np.float32(n)
            # ties: lower axis, then lower boundary (boundaries come downwards, so <= on the
            # same axis). The first candidate taken stays if its cost is NaN (float32
            # overflow), at the highest boundary of its run, where the sweep meets it first
            if best_axis < 0:
                best_axis = a
                best_b = occupied[i - 1] + 1 if cost == cost else b
                best_cost = cost
            elif cost < best_cost or (a == best_axis and cost == best_cost):
                best_axis = a
                best_b = occupied[i - 1] + 1
                best_cost = cost
    if best_axis < 0:
        return -1, 0, 0, 0, inf
    # child AABBs and counts: unions of the bins on each side, in bin order
    base = best_axis * nbins
    nl = _bin_union(F, C, base, 0, best_b, out_lbox)
    nr = _bin_union(F, C, base, best_b, nbins, out_rbox)
    return best_axis, best_b, nl, nr, best_cost
