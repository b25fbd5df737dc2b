"""A uniform grid over triangles, traversed by 3D-DDA (Amanatides & Woo 1987) with the same
Moller-Trumbore unit as the BVH traversal.

>>> grid = GridTracer(triangles)                # (n, 3, 3); resolution from the density heuristic
>>> hits = grid.intersect(origins, dirs)        # traversal.api.Hits
>>> blocked = grid.occluded(origins, dirs, tmax=dist)

Build (two passes, compiled): the resolution puts ``GRID_DENSITY * N`` cells over the mesh's
bounds, as cubic as the bounds allow (an axis with no extent gets one cell and the others share
the count). Each triangle is inserted into every cell its padded bounding box overlaps: a first
pass counts the references per cell, a second fills a CSR list (cell offsets, triangle ids in
ascending order). The references are capped at ``GRID_MAX_REFS_PER_TRI * N`` and the cells at
``GRID_MAX_CELLS``: a resolution whose boxes would need more references is coarsened until they
fit, so no input (one huge triangle over every cell, all triangles in one cell, a flat mesh, an
axis of zero extent) makes the grid's memory grow beyond those bounds.

Traversal: the ray is clipped to the grid's box and walks its cells front to back; each cell's
triangles go through ``triangle_unit.mt_valid_at`` with ``t`` in ``[t_min, closest hit]``. A
per-ray mailbox keeps a triangle that spans several cells from being tested again. The walk
stops once a cell ends beyond the closest hit (with ``GRID_STOP_SLACK``), so a hit at the same
``t`` in the next cell is still seen: exact-t ties go to the lower primitive index, as in the
BVH traversal, and the answer does not depend on the walk. ``occluded`` returns at the first hit.

Packets (coherent grid traversal, Wald, Ize, Kensler, Knoll & Parker 2006): 16 consecutive rays
(``PACKET_RAYS``) whose directions share a strict sign on some axis walk the grid together, one
slice of cells across that axis after another; per slice, the rectangle of cells that bounds
every ray's segment in it has its triangles tested once for the packet, against all 16 rays in
the BVH packet kernel's SIMD lane loop. Each ray tests a superset of the triangles its own walk
would, with the same unit and tie rule, so its answer is the same bit for bit. Camera rays in
pixel tiles, shadow rays toward a light and a mirror's reflections go this way; other groups go
ray by ray. ``packets=False`` traces every ray alone.
"""
import time

import numpy as np
from numba import njit

from hwbvh.errors import ParameterError, checked_flag
from hwbvh.parallel import run_ranges
from .api import PacketCount
from .structure import TriangleStructure, checked_triangles, padded_box
from .config import (CHUNK_RAYS, MIN_RANGE_CHUNKS, GRID_DENSITY, GRID_MAILBOX, GRID_MAX_CELLS,
                     GRID_MAX_REFS_PER_TRI, GRID_PACKET_MAILBOX, GRID_PACKET_WIDEN,
                     GRID_PAD_COORD, GRID_PAD_TRI, GRID_STOP_SLACK)
from .packet import (ALIVE, BEST, BU, BV, DX, DY, DZ, MASK, NF, NI, NM, OX, OY, OZ, P, PRIM,
                     TMIN, _triangle, load_lane, row_bits)
from .rawtree import _ray_ok
from .triangle_unit import (PRIMITIVE_ORDER, TRI_WORDS, mt_valid_at, store_answer,
                            store_normals, takes_hit)


def density_resolution(extent, n_tris, density=GRID_DENSITY, max_cells=GRID_MAX_CELLS):
    """Cells per axis for ``density * n_tris`` cells over a box of ``extent`` (3,): cells as
    cubic as possible; axes with no extent (relative to the largest) get one cell."""
    extent = np.asarray(extent, np.float64)
    target = min(max(density * max(n_tris, 1), 1.0), float(max_cells))
    big = extent.max()
    live = extent > big * 2.0**-20 if big > 0 else np.zeros(3, bool)
    res = np.ones(3, np.int64)
    if live.any():
        side = (target / np.prod(extent[live])) ** (1.0 / live.sum())   # cells per unit length
        res[live] = np.clip(np.round(extent[live] * side), 1, max_cells).astype(np.int64)
    while np.prod(res) > max_cells:
        res = np.maximum(1, (res * 0.8).astype(np.int64))
    return res


@njit(cache=True, error_model="numpy")
def _cell_ranges(tris, gmin, inv, res, out):
    """Per triangle the inclusive cell range (x0, y0, z0, x1, y1, z1) of its padded box;
    returns the total number of references."""
    total = np.int64(0)
    for j in range(tris.shape[0]):
        cells = np.int64(1)
        for a in range(3):
            lo = min(tris[j, 0, a], min(tris[j, 1, a], tris[j, 2, a]))
            hi = max(tris[j, 0, a], max(tris[j, 1, a], tris[j, 2, a]))
            mag = max(abs(lo), abs(hi))
            ext = 0.0
            for b in range(3):
                e = max(tris[j, 0, b], max(tris[j, 1, b], tris[j, 2, b])) - \
                    min(tris[j, 0, b], min(tris[j, 1, b], tris[j, 2, b]))
                ext = max(ext, e)
            pad = GRID_PAD_TRI * ext + GRID_PAD_COORD * mag
            c0 = np.int64(np.floor((lo - pad - gmin[a]) * inv[a]))
            c1 = np.int64(np.floor((hi + pad - gmin[a]) * inv[a]))
            c0 = min(max(c0, 0), res[a] - 1)
            c1 = min(max(c1, 0), res[a] - 1)
            out[j, a] = c0
            out[j, 3 + a] = c1
            cells *= c1 - c0 + 1
        total += cells
    return total


@njit(cache=True, error_model="numpy")
def _fill(ranges, res, offsets, refs):
    """The two passes over the cell ranges: count references per cell, prefix-sum them into
    ``offsets`` (cells + 1), then write the triangle ids (ascending within each cell)."""
    nx, ny = res[0], res[1]
    for j in range(ranges.shape[0]):
        for z in range(ranges[j, 2], ranges[j, 5] + 1):
            for y in range(ranges[j, 1], ranges[j, 4] + 1):
                for x in range(ranges[j, 0], ranges[j, 3] + 1):
                    offsets[1 + x + nx * (y + ny * z)] += 1
    for c in range(1, offsets.shape[0]):
        offsets[c] += offsets[c - 1]
    cursor = offsets[:-1].copy()
    for j in range(ranges.shape[0]):
        for z in range(ranges[j, 2], ranges[j, 5] + 1):
            for y in range(ranges[j, 1], ranges[j, 4] + 1):
                for x in range(ranges[j, 0], ranges[j, 3] + 1):
                    c = x + nx * (y + ny * z)
                    refs[cursor[c]] = j
                    cursor[c] += 1


@njit(cache=True, error_model="numpy", inline="always")
def _axis_setup(o, d, gmin, gmax, cs, inv, n, t0):
    """Entry cell of one axis at ray parameter t0 and the t of its next cell boundary.

    Where the ray enters the grid through this axis' face (its slab's near t is t0), the cell
    is the first along d, whatever o + t0 d rounds to: for a distant origin that sum loses
    more than a cell to cancellation (|o| 1e15 against a unit-sized grid: 0.1 in float64), and
    the clamp would send the walk to the far end of the axis. That settles axis-parallel rays
    from any distance; on the other axes of an oblique ray the cancellation stays (a ray from
    that far is ill-conditioned anyway: the float32 unit's o - v0 has lost as much)."""
    near = ((gmin if d > 0 else gmax) - o) / d          # as _slab computes it
    c = np.int64(np.floor((o + t0 * d - gmin) * inv))
    c = min(max(c, 0), n - 1)
    if d != 0 and near == t0:
        c = 0 if d > 0 else n - 1
    if d > 0:
        return c, 1, (gmin + (c + 1) * cs - o) / d
    if d < 0:
        return c, -1, (gmin + c * cs - o) / d
    return c, 0, np.inf


@njit(cache=True, error_model="numpy", inline="always")
def _slab(o, d, lo, hi, t0, t1):
    if d == 0:
        if o < lo or o > hi:
            return 1.0, 0.0
        return t0, t1
    a = (lo - o) / d
    b = (hi - o) / d
    if a > b:
        a, b = b, a
    return max(t0, a), min(t1, b)


@njit(cache=True, error_model="numpy", inline="always")
def trace_grid_ray(tris, offsets, refs, gmin, gmax, cs, inv, res, ox, oy, oz, dx, dy, dz,
                   tmin, tmax, eps2, one, edge, mailbox, anyhit):
    """One ray through the grid: (prim, t, u, v), prim -1 for a miss."""
    best_t = tmax
    prim = -1
    bu = one - one
    bv = bu
    if not _ray_ok(ox, oy, oz, dx, dy, dz, tmin, tmax):
        return prim, best_t, bu, bv
    # the walk in float64 on the float32 ray (exact conversions)
    fx, fy, fz = np.float64(ox), np.float64(oy), np.float64(oz)
    gx, gy, gz = np.float64(dx), np.float64(dy), np.float64(dz)
    t0, t1 = _slab(fx, gx, gmin[0], gmax[0], np.float64(tmin), np.float64(tmax))
    t0, t1 = _slab(fy, gy, gmin[1], gmax[1], t0, t1)
    t0, t1 = _slab(fz, gz, gmin[2], gmax[2], t0, t1)
    if not t0 <= t1:
        return prim, best_t, bu, bv
    scale = max(abs(fx), max(abs(fy), abs(fz))) / max(abs(gx), max(abs(gy), abs(gz)))
    cx, sx, nx = _axis_setup(fx, gx, gmin[0], gmax[0], cs[0], inv[0], res[0], t0)
    cy, sy, ny = _axis_setup(fy, gy, gmin[1], gmax[1], cs[1], inv[1], res[1], t0)
    cz, sz, nz = _axis_setup(fz, gz, gmin[2], gmax[2], cs[2], inv[2], res[2], t0)
    wx = cs[0] / abs(gx)                  # t-width of a cell along each axis (inf if d_a = 0)
    wy = cs[1] / abs(gy)
    wz = cs[2] / abs(gz)
    mailbox[:] = -1
    dd = dx * dx + dy * dy + dz * dz
    rx, ry = res[0], res[1]
    while True:
        cell = cx + rx * (cy + ry * cz)
        for p in range(offsets[cell], offsets[cell + 1]):
            j = np.int64(refs[p])
            slot = j & (GRID_MAILBOX - 1)
            if mailbox[slot] == j:
                continue
            mailbox[slot] = j
            ok, t, tu, tv = mt_valid_at(tris, TRI_WORDS * j, ox, oy, oz, dx, dy, dz, dd, tmin,
                                        best_t, eps2, one, edge)
            acc = takes_hit(ok, t, j, best_t, prim)
            if anyhit and acc:
                return j, t, tu, tv
            best_t = t if acc else best_t
            prim = j if acc else prim
            bu = tu if acc else bu
            bv = tv if acc else bv
        t_exit = min(nx, min(ny, nz))
        if t_exit > t1:
            break
        if prim >= 0 and np.float64(best_t) + GRID_STOP_SLACK * (abs(np.float64(best_t)) + scale) < t_exit:
            break
        # step along the axis whose boundary comes first (Amanatides-Woo: the next boundary
        # is one cell's t-width further; the drift of the sums, a few float64 ulps, is far
        # inside the triangles' padding)
        if nx <= ny and nx <= nz:
            cx += sx
            if cx < 0 or cx >= rx:
                break
            nx += wx
        elif ny <= nz:
            cy += sy
            if cy < 0 or cy >= ry:
                break
            ny += wy
        else:
            cz += sz
            if cz < 0 or cz >= res[2]:
                break
            nz += wz
    return prim, best_t, bu, bv


# A packet's float64 walk state: one row of P lanes per quantity at a constant offset (as the
# packet kernel's scratch), so the lane loops index plain rows and run in SIMD.
W_O = 0              # origin x, y, z: rows 0, 1, 2
W_D = 3 * P          # direction x, y, z: rows 3, 4, 5
W_T0 = 6 * P         # t where the lane enters the grid's box (at least t_min)
W_T1 = 7 * P         # t where it leaves it (at most t_max)
W_SC = 8 * P         # |o|/|d|, the scale of the stop slack (as in the single-ray walk)
W_EPS = 9 * P        # how far the lane's bounds in a slice are widened (GRID_PACKET_WIDEN)
W_IK = 10 * P        # 1/d along the packet's major axis K
W_OK = 11 * P        # origin on K; origin and direction on the two other axes U and V
W_OU, W_DU, W_OV, W_DV = 12 * P, 13 * P, 14 * P, 15 * P
W_ULO, W_UHI, W_VLO, W_VHI = 16 * P, 17 * P, 18 * P, 19 * P    # the lanes' bounds in a slice
NWF = 20 * P
S_IN, S_OUT = 0, P   # the lane's first and last slice, in steps from the packet's first
NWS = 2 * P


@njit(cache=True, error_model="numpy", inline="always")
def slicing_axes(D, lo):
    """Bit a set when every ray of [lo, lo + P) has a direction component on axis a of one
    strict sign (all > 0 or all < 0): the axes along which the rays can walk the grid's slices
    together (the other two components may have any signs)."""
    axes = 0
    for a in range(3):
        pos = True
        neg = True
        for k in range(P):
            x = D[lo + k, a]
            pos &= x > 0
            neg &= x < 0
        axes |= (1 << a) if pos | neg else 0
    return axes


@njit(cache=True, error_model="numpy", inline="always")
def _clip(f, g, ig, lo, hi, t0, t1):
    """[t0, t1] clipped to the slab [lo, hi] of one axis, branch-free (``ig`` = 1/g; g = 0:
    the whole line or nothing)."""
    a = (lo - f) * ig
    b = (hi - f) * ig
    inside = (f >= lo) & (f <= hi)
    near = min(a, b) if g != 0 else (-np.inf if inside else np.inf)
    far = max(a, b) if g != 0 else (np.inf if inside else -np.inf)
    return max(t0, near), min(t1, far)


@njit(cache=True, error_model="numpy", inline="always")
def _packet_lanes(lo, Of, Df, tmin, tmax, gmin, gmax, F, I, M, W, zero, one):
    """Lane state of rays [lo, lo + P) (``Of``/``Df``: the origins and directions seen flat):
    the packet kernel's (``packet.load_lane``) and the walk's, the ray clipped to the grid's
    box in float64 (exact conversions of the float32 ray). A lane that the unit rejects or
    that misses the box is not live. Returns the live lanes.

    Branch-free, so that it runs in SIMD. The clip multiplies by 1/d where the single-ray walk
    divides: its ends may differ by a rounding, far inside every padding (a ray that meets the
    box only within a rounding of its faces reaches no triangle's padded box)."""
    gm = max(max(abs(gmin[0]), abs(gmax[0])), max(max(abs(gmin[1]), abs(gmax[1])),
                                                  max(abs(gmin[2]), abs(gmax[2]))))
    # views indexed from 0, as in packet._packet, so that LLVM can bound the addresses
    Os = Of[3 * lo:3 * lo + 3 * P]
    Ds = Df[3 * lo:3 * lo + 3 * P]
    As = tmin[lo:lo + P]
    Bs = tmax[lo:lo + P]
    nlive = 0
    for k in range(P):
        ok = load_lane(F, I, M, k, Os, Ds, As, Bs, zero, one)
        M[MASK + k] = 1                 # every live lane takes part in every triangle test
        fx, fy, fz = np.float64(F[OX + k]), np.float64(F[OY + k]), np.float64(F[OZ + k])
        gx, gy, gz = np.float64(F[DX + k]), np.float64(F[DY + k]), np.float64(F[DZ + k])
        t0, t1 = _clip(fx, gx, 1.0 / gx, gmin[0], gmax[0], np.float64(F[TMIN + k]),
                       np.float64(F[BEST + k]))
        t0, t1 = _clip(fy, gy, 1.0 / gy, gmin[1], gmax[1], t0, t1)
        t0, t1 = _clip(fz, gz, 1.0 / gz, gmin[2], gmax[2], t0, t1)
        live = ok & (t0 <= t1)
        M[ALIVE + k] = np.uint8(live)
        nlive += np.int64(live)
        W[W_O + k] = fx; W[W_O + P + k] = fy; W[W_O + 2 * P + k] = fz
        W[W_D + k] = gx; W[W_D + P + k] = gy; W[W_D + 2 * P + k] = gz
        t0 = t0 if live else 0.0
        t1 = t1 if live else 0.0
        W[W_T0 + k] = t0
        W[W_T1 + k] = t1
        dmax = max(abs(gx), max(abs(gy), abs(gz)))
        omax = max(abs(fx), max(abs(fy), abs(fz)))
        W[W_SC + k] = omax / dmax
        # |o| + |t d| + the grid's magnitude bounds every coordinate the lane's walk computes
        W[W_EPS + k] = GRID_PACKET_WIDEN * (omax + max(abs(t0), abs(t1)) * dmax + gm)
    return nlive


@njit(cache=True, error_model="numpy", inline="always")
def _major_axis(axes, inv, M, W):
    """Of the axes in ``axes``, the one whose slices the packet's slowest live lane crosses
    fastest (-1 if none moves along any: the rays then go one by one)."""
    K = -1
    best = 0.0
    for a in range(3):
        rate = np.inf
        for k in range(P):
            rate = min(rate, abs(W[W_D + a * P + k]) * inv[a]) if M[ALIVE + k] != 0 else rate
        if (axes >> a) & 1 and rate > best:
            best = rate
            K = a
    return K


@njit(cache=True, error_model="numpy", inline="always")
def _lane_slices(K, step, gmin, gmax, inv, nk, M, W, S):
    """Each live lane's first and last slice along K (where it enters and leaves the box),
    stored as steps from the packet's first slice, which is returned; the lanes' rows on K, U,
    V are copied to fixed offsets for the slice loop."""
    U = (K + 1) % 3
    V = (K + 2) % 3
    first = nk if step > 0 else -1
    for k in range(P):
        oK = W[W_O + K * P + k]
        dK = W[W_D + K * P + k]
        W[W_OK + k] = oK
        W[W_IK + k] = 1.0 / dK
        W[W_OU + k] = W[W_O + U * P + k]
        W[W_DU + k] = W[W_D + U * P + k]
        W[W_OV + k] = W[W_O + V * P + k]
        W[W_DV + k] = W[W_D + V * P + k]
        live = M[ALIVE + k] != 0
        c_in = min(max(np.int64(np.floor((oK + W[W_T0 + k] * dK - gmin[K]) * inv[K])), 0), nk - 1)
        c_out = min(max(np.int64(np.floor((oK + W[W_T1 + k] * dK - gmin[K]) * inv[K])), 0), nk - 1)
        # a lane that enters (leaves) through a face across K starts (ends) in the first (last)
        # slice, whatever o + t d rounds to (as the single-ray walk's _axis_setup)
        lo_t = (gmin[K] - oK) * W[W_IK + k]             # the faces' t as _clip computes them
        hi_t = (gmax[K] - oK) * W[W_IK + k]
        c_in = (0 if step > 0 else nk - 1) if min(lo_t, hi_t) == W[W_T0 + k] else c_in
        c_out = (nk - 1 if step > 0 else 0) if max(lo_t, hi_t) == W[W_T1 + k] else c_out
        S[S_IN + k] = c_in if live else 0
        S[S_OUT + k] = c_out if live else 0
        if live:
            first = min(first, c_in) if step > 0 else max(first, c_in)
    for k in range(P):
        s_in = (S[S_IN + k] - first) * step
        S[S_IN + k] = s_in
        S[S_OUT + k] = max(s_in, (S[S_OUT + k] - first) * step)   # never before its start
    return first


@njit(cache=True, error_model="numpy", inline="always")
def _slice_bounds(s, xn, xf, F, I, M, W, S, MORE, MORE64):
    """Slice s (its near and far planes at xn, xf on K): the bounds on U and V of the live
    lanes' segments in it, widened by each lane's W_EPS, as (ulo, uhi, vlo, vhi) (ulo > uhi:
    no lane in this slice), and whether some lane goes on past it. A lane's segment runs from
    where it enters the slice (or the grid, in its first slice) to where it leaves it or its
    stop limit: its closest hit plus GRID_STOP_SLACK, as in the single-ray walk. Its first slice
    always counts, so that its entry cell is tested as in the single-ray walk."""
    # per lane first (no reductions in this loop, so it runs in SIMD), then reduced pairwise
    for k in range(P):
        alive = M[ALIVE + k] != 0
        b64 = np.float64(F[BEST + k])
        t1 = W[W_T1 + k]
        tl = t1 if I[PRIM + k] < 0 else \
            min(t1, b64 + GRID_STOP_SLACK * (abs(b64) + W[W_SC + k]))
        tn = (xn - W[W_OK + k]) * W[W_IK + k]
        tf = (xf - W[W_OK + k]) * W[W_IK + k]
        s_in = S[S_IN + k]
        s_out = S[S_OUT + k]
        ta = W[W_T0 + k] if s == s_in else tn
        tb = tl if s == s_out else min(tf, tl)
        act = alive & (s >= s_in) & (s <= s_out) & ((ta <= tb) | (s == s_in))
        tb = max(ta, tb)
        e = W[W_EPS + k]
        ua = W[W_OU + k] + ta * W[W_DU + k]
        ub = W[W_OU + k] + tb * W[W_DU + k]
        va = W[W_OV + k] + ta * W[W_DV + k]
        vb = W[W_OV + k] + tb * W[W_DV + k]
        W[W_ULO + k] = min(ua, ub) - e if act else np.inf
        W[W_UHI + k] = max(ua, ub) + e if act else -np.inf
        W[W_VLO + k] = min(va, vb) - e if act else np.inf
        W[W_VHI + k] = max(va, vb) + e if act else -np.inf
        MORE[k] = np.uint8(alive & ((s < s_in) | ((s < s_out) & (tf <= tl))))
    h = P // 2
    while h > 0:
        for k in range(h):
            W[W_ULO + k] = min(W[W_ULO + k], W[W_ULO + h + k])
            W[W_UHI + k] = max(W[W_UHI + k], W[W_UHI + h + k])
            W[W_VLO + k] = min(W[W_VLO + k], W[W_VLO + h + k])
            W[W_VHI + k] = max(W[W_VHI + k], W[W_VHI + h + k])
        h //= 2
    return W[W_ULO], W[W_UHI], W[W_VLO], W[W_VHI], row_bits(MORE64, 0) != 0


@njit(cache=True, error_model="numpy", inline="always")
def _cell_span(lo, hi, g0, inv_a, n):
    """Inclusive range of cells along one axis covering coordinates [lo, hi]."""
    c0 = np.int64(np.floor((lo - g0) * inv_a))
    c1 = np.int64(np.floor((hi - g0) * inv_a))
    return min(max(c0, 0), n - 1), min(max(c1, 0), n - 1)


@njit(cache=True, error_model="numpy", inline="always")
def _stride(res, a):
    """Distance between neighbouring cells along axis a in the cell index."""
    return 1 if a == 0 else (res[0] if a == 1 else res[0] * res[1])


@njit(cache=True, error_model="numpy", inline="always")
def _packet_answers(lo, F, I, out_prim, out_t, out_u, out_v, zero, one):
    """The packet's answers into the batch's outputs, as ``store_answer`` writes a ray's."""
    outp = out_prim[lo:lo + P]              # views indexed from 0, as in packet._packet
    for k in range(P):
        outp[k] = I[PRIM + k]
    if out_t.shape[0] > 0:
        inf = one / zero
        outt = out_t[lo:lo + P]
        outu = out_u[lo:lo + P]
        outv = out_v[lo:lo + P]
        for k in range(P):
            h = I[PRIM + k] >= 0
            outt[k] = F[BEST + k] if h else inf
            outu[k] = F[BU + k] if h else zero
            outv[k] = F[BV + k] if h else zero


@njit(cache=True, error_model="numpy", _nrt=False)
def trace_grid_range(c0, c1, tris, offsets, refs, gmin, gmax, cs, inv, res, O, D, tmin, tmax,
                     eps2, one, edge, anyhit, packets, mailbox, F, I, M, M64, W, S, MORE, MORE64,
                     box, out_prim, out_t, out_u, out_v, packets_traced):
    """Chunks c0..c1 of CHUNK_RAYS rays. With ``packets``, each full group of P consecutive
    rays whose directions share a strict sign on some axis (``slicing_axes``) is traced as one
    packet by coherent grid traversal (Wald, Ize, Kensler, Knoll & Parker 2006); the other
    groups go ray by ray (``trace_grid_ray``). ``packets_traced[c]`` gets chunk c's packets.

    A packet walks the slices of cells across its major axis K (``_major_axis``) front to
    back. In each slice, the bounds of its lanes' segments on the two other axes
    (``_slice_bounds``) give a rectangle of cells holding every cell a lane's ray crosses in
    the slice. Their triangles, once per packet (a mailbox), go through the packet kernel's
    branch-free lane loop (``packet._triangle``: the single-ray unit's datapath and tie rule)
    for every live lane. So each lane tests a superset of the triangles its single-ray walk
    would, and gets the same closest hit; an any-hit lane retires at its first hit. The walk
    ends when no lane goes on past the slice.

    The packet code is inline here, called once per batch range, so a packet costs no call
    (the arrays passed to a call are copied field by field). Scratch: ``mailbox``
    (GRID_MAILBOX,) int64 for single rays; ``F``/``I``/``M``/``M64`` as in
    ``packet._packet``, ``W`` (NWF,) float64, ``S`` (NWS,) int64, ``MORE`` (P,) uint8 and
    ``MORE64`` its uint64 view, ``box`` (GRID_PACKET_MAILBOX,) int64 for packets."""
    zero = one - one
    n = O.shape[0]
    Of = O.reshape(-1)
    Df = D.reshape(-1)
    for ch in range(c0, c1):
        npk = 0
        end = min(n, (ch + 1) * CHUNK_RAYS)
        for lo in range(ch * CHUNK_RAYS, end, P):
            axes = slicing_axes(D, lo) if packets and end - lo >= P else 0
            K = -1
            if axes != 0:
                nlive = _packet_lanes(lo, Of, Df, tmin, tmax, gmin, gmax, F, I, M, W, zero, one)
                K = _major_axis(axes, inv, M, W) if nlive > 0 else 3     # 3: every lane misses
            if K < 0:
                for i in range(lo, min(end, lo + P)):
                    prim, t, bu, bv = trace_grid_ray(
                        tris, offsets, refs, gmin, gmax, cs, inv, res, O[i, 0], O[i, 1], O[i, 2],
                        D[i, 0], D[i, 1], D[i, 2], tmin[i], tmax[i], eps2, one, edge, mailbox,
                        anyhit)
                    store_answer(i, prim, t, bu, bv, out_prim, out_t, out_u, out_v)
                continue
            if K < 3:
                U = (K + 1) % 3
                V = (K + 2) % 3
                nk = res[K]
                step = 1 if D[lo, K] > 0 else -1
                c = _lane_slices(K, step, gmin, gmax, inv, nk, M, W, S)
                near = 1 if step < 0 else 0        # plane offsets of a slice's near, far faces
                sK = _stride(res, K)
                sU = _stride(res, U)
                sV = _stride(res, V)
                for q in range(GRID_PACKET_MAILBOX):
                    box[q] = -1
                s = 0
                while 0 <= c < nk:
                    ulo, uhi, vlo, vhi, more = _slice_bounds(
                        s, gmin[K] + (c + near) * cs[K], gmin[K] + (c + 1 - near) * cs[K], F, I,
                        M, W, S, MORE, MORE64)
                    if ulo <= uhi:
                        cu0, cu1 = _cell_span(ulo, uhi, gmin[U], inv[U], res[U])
                        cv0, cv1 = _cell_span(vlo, vhi, gmin[V], inv[V], res[V])
                        for cv in range(cv0, cv1 + 1):
                            for cu in range(cu0, cu1 + 1):
                                cell = c * sK + cu * sU + cv * sV
                                for p in range(offsets[cell], offsets[cell + 1]):
                                    j = np.int64(refs[p])
                                    slot = j & (GRID_PACKET_MAILBOX - 1)
                                    if box[slot] != j:
                                        box[slot] = j
                                        _triangle(tris, j, j, F, I, M, 0, eps2, one, edge, anyhit)
                        if anyhit and row_bits(M64, ALIVE) == 0:
                            break                           # every lane has found a blocker
                    if not more:
                        break
                    s += 1
                    c += step
            _packet_answers(lo, F, I, out_prim, out_t, out_u, out_v, zero, one)
            npk += 1
        packets_traced[ch] = npk


@njit(cache=True, nogil=True, error_model="numpy")
def grid_chunks(c0, c1, tris, offsets, refs, gmin, gmax, cs, inv, res, O, D, tmin, tmax, eps2,
                one, edge, anyhit, packets, out_prim, out_t, out_u, out_v, out_ng, packets_traced):
    """Chunks c0..c1 of CHUNK_RAYS rays (``hwbvh.parallel.run_ranges`` hands them out), with
    one mailbox and one packet scratch for the call (``trace_grid_range``). ``out_t``/``out_u``/
    ``out_v`` are (n,) or (0,) when only ``out_prim`` is wanted; ``out_ng`` is (n, 3) for
    geometric normals or (0, 3); ``packets_traced`` (chunks,) gets the packets per chunk."""
    n = O.shape[0]
    mailbox = np.empty(GRID_MAILBOX, np.int64)
    F = np.empty(NF, O.dtype)
    I = np.empty(NI, np.int32)
    M = np.zeros(NM, np.uint8)
    M64 = M.view(np.uint64)
    W = np.empty(NWF, np.float64)
    S = np.empty(NWS, np.int64)
    MORE = np.zeros(P, np.uint8)
    MORE64 = MORE.view(np.uint64)
    box = np.empty(GRID_PACKET_MAILBOX, np.int64)
    trace_grid_range(c0, c1, tris, offsets, refs, gmin, gmax, cs, inv, res, O, D, tmin, tmax,
                     eps2, one, edge, anyhit, packets, mailbox, F, I, M, M64, W, S, MORE, MORE64,
                     box, out_prim, out_t, out_u, out_v, packets_traced)
    store_normals(c0 * CHUNK_RAYS, min(n, c1 * CHUNK_RAYS), tris, PRIMITIVE_ORDER, out_prim,
                  out_ng, one)


class GridTracer(TriangleStructure, PacketCount):
    """Ray queries on a uniform grid over ``triangles`` ((n, 3, 3)), with the BVH traversal's
    float32 triangle unit. ``resolution``: cells per axis (an int for all three or three ints);
    default from the density heuristic. ``packets``: trace coherent groups of rays as packets
    (the same answers; the attribute may be changed later). ``last_packets``: the packets the
    calling thread's last query traced. Implements the tracer interface of
    ``traversal.tracers``. After the build: ``resolution`` (3 ints), ``build_seconds``,
    ``memory_bytes`` (cell offsets, references and preprocessed triangles),
    ``references`` and ``references_per_triangle``."""

    name = "grid"

    def __init__(self, triangles, resolution=None, packets=True):
        start = time.perf_counter()
        self.packets = checked_flag(packets, "packets")
        self._start_packet_count()
        tris = checked_triangles(triangles)
        n = len(tris)
        # the grid's box: the mesh's, padded like a triangle's box, and never flat
        lo, hi, self.gmin, self.gmax = padded_box(tris, GRID_PAD_TRI, GRID_PAD_COORD)
        extent = self.gmax - self.gmin
        cap = GRID_MAX_REFS_PER_TRI * max(n, 1)
        if resolution is None:
            res = density_resolution(hi - lo, n)
        else:
            res = np.asarray(resolution)
            if res.shape not in ((), (3,)) or not np.issubdtype(res.dtype, np.integer) \
                    or (res < 1).any():
                raise ParameterError("resolution", "must be a positive int or three, "
                                                   f"got {resolution!r}")
            res = np.broadcast_to(res, (3,)).astype(np.int64)
            if np.prod(res.astype(np.float64)) > GRID_MAX_CELLS:
                raise ParameterError("resolution", f"{tuple(res.tolist())} has more than "
                                                   f"{GRID_MAX_CELLS} cells")
        ranges = np.empty((n, 6), np.int64)
        while True:
            inv = res / extent
            total = _cell_ranges(tris, self.gmin, inv, res, ranges)
            if total <= cap:
                break
            if resolution is not None:
                raise ParameterError("resolution", f"{tuple(res.tolist())} needs {total} "
                                                   f"references, over the cap of "
                                                   f"{GRID_MAX_REFS_PER_TRI} per triangle")
            res = np.maximum(1, (res * 0.8).astype(np.int64))
        self.resolution = tuple(int(r) for r in res)
        self._res = res.astype(np.int64)
        self._inv = (res / extent).astype(np.float64)
        self._cs = (extent / res).astype(np.float64)
        self.offsets = np.zeros(int(np.prod(res)) + 1, np.int64)
        self.refs = np.empty(total, np.int32)
        _fill(ranges, self._res, self.offsets, self.refs)
        self._set_unit(tris, triangles)
        self.references = int(total)
        self.references_per_triangle = total / max(n, 1)
        self.memory_bytes = int(self.offsets.nbytes + self.refs.nbytes + self.tris.nbytes)
        self.build_seconds = time.perf_counter() - start

    def _trace(self, o, d, tmin, tmax, anyhit, prim, t, u, v, ng):
        chunks = (len(o) + CHUNK_RAYS - 1) // CHUNK_RAYS
        traced = np.zeros(chunks, np.int64)
        run_ranges(grid_chunks, chunks, self._tris1, self.offsets, self.refs, self.gmin,
                   self.gmax, self._cs, self._inv, self._res, o, d, tmin, tmax, self.eps2,
                   self.one, self.edge, anyhit, self.packets, prim, t, u, v, ng, traced,
                   min_items=MIN_RANGE_CHUNKS)
        self._count_packets(traced)

    def stats(self):
        """The structure's figures for reports."""
        return {"resolution": list(self.resolution), "build_seconds": self.build_seconds,
                "memory_bytes": self.memory_bytes, "references": self.references,
                "references_per_triangle": self.references_per_triangle}


def warm_up_grid():
    """Load (or, the first time ever, compile) the grid's kernels on a tiny input, so that build
    and trace timings measure work, not JIT start-up. Returns seconds."""
    start = time.perf_counter()
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float32)
    grid = GridTracer(tri)
    o = np.array([[0.25, 0.25, 1.0], [0.25, 0.25, -1.0]], np.float32)
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]], np.float32)
    grid.intersect(o, d)
    grid.intersect(o, d, normals=False)
    grid.occluded(o, d)
    return time.perf_counter() - start
