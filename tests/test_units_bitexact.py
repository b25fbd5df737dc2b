"""The two hardware units, as every kernel runs them, against one reference, bit for bit.

The Moller-Trumbore datapath (``triangle_unit.mt_datapath``) as the single-ray traversal calls
it (``mt_valid_at``) and as a packet lane does (``packet._mt``, and ``packet._triangle``'s
closest-hit and any-hit lane loops, which LLVM vectorises), plus the verifier's own float64 copy
(``verify._mt64``); the slab test (``aabb_unit.slab_test``) through ``aabb_hit_at`` and through
a packet lane (``packet._slab`` with the planes ``packet._planes`` picks from the signs of d,
and ``packet._box``'s lane loop). The reference is written here once, in NumPy, from the units'
definition (thesis appendix A, Figs. A.2-A.4): one IEEE operation at a time in the working
precision, in the datapath's order. NumPy rounds every operation on its own, so it is
independent of how Numba and LLVM compile (inline, vectorise, contract) the kernels.

"Bit for bit": the same verdict, and the same bits of every output the caller defines (NaN
matches NaN whatever its payload). Inputs: seeded random rays and triangles/boxes plus the hard
cases: axis-parallel rays (1/d = +-inf, signed zeros), origins on slab planes, rays through
shared edges and vertices, rays in and grazing a triangle's plane or a box face, zero-area
triangles and flat boxes, coordinates near 1e30, 1e12, 1e-12 and 1e-30, directions near 1e25 and
1e-25, and t exactly at t_min / t_max. Beside the reference: the parallel band's verdicts do not
change when the scene or the directions are scaled by a power of two (the band's squares must
not leave the float range), and the preprocessed band words are what the unit assumes.
The test wrappers are compiled without Numba's cache, so they always inline the current units.
"""
import math

import numpy as np
import pytest
from numba import njit

from traversal.aabb_unit import aabb_hit_at, near_far_planes
from traversal.config import EDGE_EPS_F32, EDGE_EPS_F64, GAMMA3_F32, GAMMA3_F64
from traversal.packet import (ALIVE, BEST, BU, BV, MASK, NF, NI, NM, PRIM, P, _box,
                              _lane_setup, _mt, _planes, _slab, _triangle)
from traversal.triangle_unit import (TRI_E1, TRI_E2, TRI_NORMS, TRI_SCALE, TRI_V0, TRI_WORDS,
                                     band_eps2, mt_valid_at, preprocess)
from traversal.verify import _mt64

DTYPES = (np.float32, np.float64)
EDGE = {np.float32: EDGE_EPS_F32, np.float64: EDGE_EPS_F64}
GAMMA3 = {np.float32: GAMMA3_F32, np.float64: GAMMA3_F64}


# ---------------------------------------------------------------------------------------------
# The reference
# ---------------------------------------------------------------------------------------------

def ref_ray_band(D):
    """The ray's side of the parallel band: c_R = 2^-e with 2^e <= max |d_i| < 2^(e+1) (e
    clamped so that c_R is a normal number), and |d c_R|^2 summed x, y, z."""
    T = D.dtype.type
    info = np.finfo(T)
    m = np.abs(D).max(1)
    e = np.clip(np.frexp(m)[1] - 1, info.minexp, info.maxexp - 2)
    cr = np.ldexp(np.ones(len(D)), -e).astype(T)          # a power of two: exact in T
    S = D * cr[:, None]
    with np.errstate(all="ignore"):
        dd = S[:, 0] * S[:, 0] + S[:, 1] * S[:, 1] + S[:, 2] * S[:, 2]
    return cr, dd


def ref_mt(rows, O, D, tmin, tmax, eps2, edge):
    """Moller-Trumbore with the unit's valid check, every ray against its own preprocessed row.
    Returns (valid, t, u, v, det); t, u, v are the datapath outputs whatever the verdict."""
    T = rows.dtype.type
    one = T(1)
    v0x, v0y, v0z = (rows[:, TRI_V0 + k] for k in range(3))
    e1x, e1y, e1z = (rows[:, TRI_E1 + k] for k in range(3))
    e2x, e2y, e2z = (rows[:, TRI_E2 + k] for k in range(3))
    ox, oy, oz = O.T
    dx, dy, dz = D.T
    with np.errstate(all="ignore"):
        px = dy * e2z - dz * e2y                   # p = d x e2
        py = dz * e2x - dx * e2z
        pz = dx * e2y - dy * e2x
        det = e1x * px + e1y * py + e1z * pz       # det = e1 . p
        inv = one / det                            # the divider
        sx = ox - v0x                              # s = o - v0
        sy = oy - v0y
        sz = oz - v0z
        u = (sx * px + sy * py + sz * pz) * inv
        qx = sy * e1z - sz * e1y                   # q = s x e1
        qy = sz * e1x - sx * e1z
        qz = sx * e1y - sy * e1x
        v = (dx * qx + dy * qy + dz * qz) * inv
        t = (e2x * qx + e2y * qy + e2z * qz) * inv
        # the relative parallel band, det scaled by the row's c_T and the ray's c_R
        cr, dd = ref_ray_band(D)
        ds = det * rows[:, TRI_SCALE] * cr
        parallel = ds * ds <= eps2 * rows[:, TRI_NORMS] * dd
        valid = ~parallel & (u >= -edge) & (u <= one + edge) & (v >= -edge) \
            & (u + v <= one + edge) & (t >= tmin) & (t <= tmax)
    return valid, t, u, v, det


def ref_slab(boxes, O, D, tmin, tmax, widen):
    """The slab test, every ray against its own box (min xyz, max xyz). Returns (hit, tnear)."""
    T = boxes.dtype.type
    n = len(boxes)
    rows = np.arange(n)
    with np.errstate(all="ignore"):
        inv = T(1) / D                             # the divider, once per ray
        tnear = tmin.copy()
        tfar = tmax.copy()
        for a in range(3):
            near = np.where(inv[:, a] < 0, 3, 0) + a          # comparator on the sign of 1/d
            far = np.where(inv[:, a] < 0, 0, 3) + a
            tn = (boxes[rows, near] - O[:, a]) * inv[:, a]
            tf = (boxes[rows, far] - O[:, a]) * inv[:, a]
            tnear = np.where(tn > tnear, tn, tnear)            # a NaN plane distance is ignored
            tfar = np.where(tf < tfar, tf, tfar)
        hit = tnear <= tfar * widen
    return hit, tnear


# ---------------------------------------------------------------------------------------------
# Wrappers that run the inline kernels, one ray against its own triangle / box
# ---------------------------------------------------------------------------------------------

@njit(error_model="numpy")
def run_single_mt(rows, O, D, tmin, tmax, eps2, one, edge):
    """mt_valid_at, as the single-ray traversal calls it."""
    n = O.shape[0]
    flat = rows.ravel()
    ok = np.zeros(n, np.bool_)
    out = np.empty((n, 3), O.dtype)
    for i in range(n):
        dx = D[i, 0]
        dy = D[i, 1]
        dz = D[i, 2]
        dd = dx * dx + dy * dy + dz * dz
        r = mt_valid_at(flat, TRI_WORDS * i, O[i, 0], O[i, 1], O[i, 2], dx, dy, dz, dd,
                        tmin[i], tmax[i], eps2, one, edge)
        ok[i] = r[0]
        out[i, 0] = r[1]
        out[i, 1] = r[2]
        out[i, 2] = r[3]
    return ok, out


@njit(error_model="numpy")
def _lanes(O, D, tmin, tmax, c, F, I, M, one):
    """Rays c*P.. into the packet's lanes, as the packet kernel sets them up (all lanes live)."""
    zero = one - one
    for k in range(P):
        i = min(c * P + k, O.shape[0] - 1)
        _lane_setup(F, I, M, k, True, O[i, 0], O[i, 1], O[i, 2], D[i, 0], D[i, 1], D[i, 2],
                    tmin[i], tmax[i], zero, one)


@njit(error_model="numpy")
def _lane_mt(flat, b, F, k, eps2, one, edge):
    """``packet._mt`` for lane k against the triangle row at word ``b`` of ``flat``, up to the
    lane's closest hit so far: (ok, t, u, v)."""
    return _mt(F, k, flat[b + TRI_V0], flat[b + TRI_V0 + 1], flat[b + TRI_V0 + 2],
               flat[b + TRI_E1], flat[b + TRI_E1 + 1], flat[b + TRI_E1 + 2],
               flat[b + TRI_E2], flat[b + TRI_E2 + 1], flat[b + TRI_E2 + 2],
               eps2 * flat[b + TRI_NORMS], flat[b + TRI_SCALE], -edge, one + edge,
               F[BEST + k], one)


@njit(error_model="numpy")
def run_packet_mt(rows, O, D, tmin, tmax, eps2, one, edge, anyhit):
    """Each ray in its packet lane: packet._mt called directly (ok, t, u, v: every output), and
    packet._triangle's lane loop with only that lane's mask bit set (verdict; t, u, v on a hit;
    the closest-hit or, with anyhit, the any-hit loop)."""
    n = O.shape[0]
    flat = rows.ravel()
    F = np.empty(NF, O.dtype)
    I = np.empty(NI, np.int32)
    M = np.zeros(NM, np.uint8)
    direct_ok = np.zeros(n, np.bool_)
    direct = np.empty((n, 3), O.dtype)
    loop_ok = np.zeros(n, np.bool_)
    loop = np.empty((n, 3), O.dtype)
    for c in range((n + P - 1) // P):
        _lanes(O, D, tmin, tmax, c, F, I, M, one)
        for k in range(P):
            i = c * P + k
            if i >= n:
                break
            b = TRI_WORDS * i
            r = _lane_mt(flat, b, F, k, eps2, one, edge)
            direct_ok[i] = r[0]
            direct[i, 0] = r[1]
            direct[i, 1] = r[2]
            direct[i, 2] = r[3]
            for q in range(P):
                M[MASK + q] = 1 if q == k else 0
            _triangle(flat, i, i, F, I, M, 0, eps2, one, edge, anyhit)
            loop_ok[i] = I[PRIM + k] == i
            loop[i, 0] = F[BEST + k]
            loop[i, 1] = F[BU + k]
            loop[i, 2] = F[BV + k]
    return direct_ok, direct, loop_ok, loop


@njit(error_model="numpy")
def run_mt64(tris, O, D):
    out = np.empty((O.shape[0], 3))
    for i in range(O.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = _mt64(tris[i], O[i], D[i])
    return out


@njit(error_model="numpy")
def run_aabb_hit_at(boxes, O, D, tmin, tmax, widen, one):
    n = O.shape[0]
    flat = boxes.ravel()
    hit = np.zeros(n, np.bool_)
    tn = np.empty(n, O.dtype)
    for i in range(n):
        ix = one / D[i, 0]
        iy = one / D[i, 1]
        iz = one / D[i, 2]
        kx, ky, kz = near_far_planes(ix, iy, iz)
        hit[i], tn[i] = aabb_hit_at(flat, 6 * i, O[i, 0], O[i, 1], O[i, 2], ix, iy, iz,
                                    kx, ky, kz, tmin[i], tmax[i], widen)
    return hit, tn


@njit(error_model="numpy")
def run_packet_slab(boxes, O, D, tmin, tmax, widen, one):
    """Each ray in its packet lane against its own box, the planes picked from the signs of d as
    the packet kernel picks them: packet._slab directly, and packet._box's lane loop."""
    n = O.shape[0]
    flat = boxes.ravel()
    F = np.empty(NF, O.dtype)
    I = np.empty(NI, np.int32)
    M = np.zeros(NM, np.uint8)
    M64 = M.view(np.uint64)
    direct = np.zeros(n, np.bool_)
    loop = np.zeros(n, np.bool_)
    for c in range((n + P - 1) // P):
        _lanes(O, D, tmin, tmax, c, F, I, M, one)
        for k in range(P):
            i = c * P + k
            if i >= n:
                break
            kx = 3 if math.copysign(1.0, D[i, 0]) < 0 else 0
            ky = 3 if math.copysign(1.0, D[i, 1]) < 0 else 0
            kz = 3 if math.copysign(1.0, D[i, 2]) < 0 else 0
            nx, ny, nz, fx, fy, fz = _planes(flat, 6 * i, kx, ky, kz)
            direct[i] = _slab(F, k, nx, ny, nz, fx, fy, fz, widen)
            _box(flat, 6 * i, kx, ky, kz, F, M, M64, widen)
            loop[i] = M[MASK + k] != 0
    return direct, loop


# ---------------------------------------------------------------------------------------------
# Inputs
# ---------------------------------------------------------------------------------------------

def _signed_zeros(rng, shape):
    return np.where(rng.random(shape) < 0.5, 0.0, -0.0)


def triangle_cases(seed):
    """(name -> (tris (n, 3, 3), O, D)) in float64, rounded to T by the caller."""
    rng = np.random.default_rng(seed)
    cases = {}
    n = 4000
    tris = rng.uniform(-1, 1, (n, 3, 3))
    O = rng.uniform(-2, 2, (n, 3))
    w = rng.dirichlet([1, 1, 1], n) * 1.4 - 0.2              # inside and just outside
    cases["random"] = (tris, O, np.einsum("nk,nkc->nc", w, tris) - O)

    # two triangles sharing the edge v1-v2 (a quad's diagonal), rays at its vertices and points
    quad = rng.uniform(-1, 1, (n // 2, 4, 3))
    a = quad[:, [0, 1, 2]]
    b = quad[:, [3, 2, 1]]                                   # same edge, the other winding
    pair = np.concatenate([a, b])
    s = rng.choice([0.0, 0.25, 0.5, 1.0, 1 / 3], (n // 2, 1))
    on_edge = quad[:, 1] + s * (quad[:, 2] - quad[:, 1])
    on_edge = np.concatenate([on_edge, on_edge])
    O = rng.uniform(-2, 2, (n, 3))
    cases["shared edges and vertices"] = (pair, O, on_edge - O)

    # axis-parallel rays (1/d = +-inf on two axes, signed zeros) at vertices, edges, interiors
    tris = rng.uniform(-1, 1, (n, 3, 3))
    w = rng.choice([0.0, 0.5, 1.0, 1 / 3], (n, 3))
    w /= np.maximum(w.sum(1, keepdims=True), 1e-9)
    target = np.einsum("nk,nkc->nc", w, tris)
    axis = rng.integers(0, 3, n)
    D = _signed_zeros(rng, (n, 3))
    D[np.arange(n), axis] = rng.choice([-1.0, 1.0], n)
    O = target - 3 * D
    cases["axis-parallel"] = (tris, O, D)

    # axis-aligned triangles hit along their normal axis, and rays lying in their plane
    tris = rng.uniform(-1, 1, (n, 3, 3))
    tris[np.arange(n), :, axis] = rng.choice([0.0, 0.5], (n, 1))
    D = _signed_zeros(rng, (n, 3))
    D[: n // 2][np.arange(n // 2), axis[: n // 2]] = 1.0                   # along the normal
    inplane = tris[n // 2:, 2] - tris[n // 2:, 1]
    D[n // 2:] = inplane
    O = np.einsum("nk,nkc->nc", rng.dirichlet([1, 1, 1], n), tris) - 2 * D
    O[n // 2:] = tris[n // 2:, 0] + 0.5 * (tris[n // 2:, 1] - tris[n // 2:, 0])  # origin on an edge
    cases["axis-aligned triangles, in-plane rays"] = (tris, O, D)

    # grazing: directions within a few ulps of the plane, across the parallel band
    tris = rng.uniform(-1, 1, (n, 3, 3))
    e1 = tris[:, 1] - tris[:, 0]
    e2 = tris[:, 2] - tris[:, 0]
    nrm = np.cross(e1, e2)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    along = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
    tilt = rng.choice([0.0, 1e-9, 1e-7, 2.4e-7, 5e-7, 1e-5, 1e-3], (n, 1)) * rng.choice([-1, 1], (n, 1))
    D = along + tilt * nrm
    c = tris.mean(1)
    O = c - 1.5 * D
    cases["grazing"] = (tris, O, D)

    # zero-area triangles: a repeated vertex, collinear vertices
    tris = rng.uniform(-1, 1, (n, 3, 3))
    tris[: n // 2, 2] = tris[: n // 2, 1]
    tris[n // 2:, 2] = 2 * tris[n // 2:, 1] - tris[n // 2:, 0]
    O = rng.uniform(-2, 2, (n, 3))
    cases["zero area"] = (tris, O, tris.mean(1) - O)

    # huge and tiny scales: overflow to inf / NaN and underflow to zero and subnormals in the
    # products, and mixes (a tiny triangle seen along a huge direction); at 1e12 and 1e-12
    # and for 1e25 and 1e-25 directions the datapath stays in range but the band's unscaled
    # squares would not
    base = rng.uniform(-1, 1, (n, 3, 3))
    O = rng.uniform(-2, 2, (n, 3))
    D = base.mean(1) - O
    for name, ts, ds, os_ in (("huge", 1e30, 1.0, 1e30), ("tiny", 1e-30, 1.0, 1e-30),
                              ("large", 1e12, 1.0, 1e12), ("small", 1e-12, 1.0, 1e-12),
                              ("long rays", 1.0, 1e25, 1.0), ("short rays", 1.0, 1e-25, 1.0),
                              ("huge rays, tiny triangles", 1e-30, 1e30, 1e-30),
                              ("tiny rays, huge triangles", 1e30, 1e-30, 1e30),
                              ("far from the origin", 1.0, 1.0, 1.0)):
        shift = 1e7 if name == "far from the origin" else 0.0
        cases[name] = (base * ts + shift, O * os_ + shift, D * ds)
    return cases


def box_cases(seed):
    """(name -> (boxes (n, 6), O, D)) in float64."""
    rng = np.random.default_rng(seed)
    cases = {}
    n = 4000

    def boxes_(m, flat_axes=None):
        lo = rng.uniform(-1, 1, (m, 3))
        hi = lo + rng.uniform(0, 1, (m, 3))
        if flat_axes is not None:
            hi[np.arange(m), flat_axes] = lo[np.arange(m), flat_axes]
        return np.concatenate([lo, hi], 1)

    B = boxes_(n)
    O = rng.uniform(-3, 3, (n, 3))
    cases["random"] = (B, O, rng.normal(size=(n, 3)))

    axis = rng.integers(0, 3, n)
    B = boxes_(n, axis)                                     # zero extent on one axis
    O = rng.uniform(-3, 3, (n, 3))
    target = B[:, :3] + rng.uniform(0, 1, (n, 3)) * (B[:, 3:] - B[:, :3])
    cases["flat boxes"] = (B, O, target - O)

    # axis-parallel rays (1/d = +-inf), origins exactly on the slab planes (0 * inf = NaN)
    B = boxes_(n)
    D = _signed_zeros(rng, (n, 3))
    D[np.arange(n), axis] = rng.choice([-1.0, 1.0], n)
    inside = B[:, :3] + rng.uniform(0, 1, (n, 3)) * (B[:, 3:] - B[:, :3])
    on_plane = np.where(rng.random((n, 3)) < 0.5, B[:, :3], B[:, 3:])
    O = np.where(rng.random((n, 3)) < 0.5, on_plane, inside)
    O[np.arange(n), axis] = rng.uniform(-3, 3, n)
    cases["axis-parallel, origins on slab planes"] = (B, O, D)

    # grazing a face: origin in a face's plane, direction within the plane or ulps off it
    B = boxes_(n)
    O = B[:, :3] + rng.uniform(-0.5, 1.5, (n, 3)) * (B[:, 3:] - B[:, :3])
    O[np.arange(n), axis] = np.where(rng.random(n) < 0.5, B[np.arange(n), axis], B[np.arange(n), 3 + axis])
    D = rng.normal(size=(n, 3))
    D[np.arange(n), axis] = rng.choice([0.0, -0.0, 1e-8, -1e-8, 1e-30], n)
    cases["grazing faces"] = (B, O, D)

    # through a box's edges and corners: entry and exit distances equal but for rounding,
    # which the widening of the far distance must absorb
    B = boxes_(n)
    corner = np.where(rng.random((n, 3)) < 0.5, B[:, :3], B[:, 3:])
    free = rng.integers(0, 4, n)                  # 0..2: that coordinate free (an edge); 3: corner
    pick = free < 3
    corner[pick, free[pick]] = B[pick, free[pick]] + rng.uniform(0, 1, pick.sum()) * \
        (B[pick, 3 + free[pick]] - B[pick, free[pick]])
    O = rng.uniform(-3, 3, (n, 3))
    cases["through edges and corners"] = (B, O, corner - O)

    # d components that are tiny (1/d huge or, below the float32 range, inf)
    B = boxes_(n)
    O = rng.uniform(-3, 3, (n, 3))
    D = rng.normal(size=(n, 3)) * rng.choice([1.0, 1e-20, 1e-40], (n, 3))
    cases["tiny direction components"] = (B, O, D)

    B = boxes_(n)
    O = rng.uniform(-3, 3, (n, 3))
    D = rng.normal(size=(n, 3))
    cases["huge"] = (B * 1e30, O * 1e30, D)
    cases["tiny"] = (B * 1e-30, O * 1e-30, D)
    cases["huge rays, tiny boxes"] = (B * 1e-30, O * 1e-30, D * 1e30)
    return cases


def _intervals(rng, n, T):
    tmin = np.where(rng.random(n) < 0.7, 0.0, rng.uniform(0, 3, n)).astype(T)
    tmax = np.where(rng.random(n) < 0.6, np.inf, rng.uniform(0, 4, n)).astype(T)
    return tmin, tmax


def _at_the_limits(rng, t, tmin, tmax):
    """Put t exactly on t_min for some rays and on t_max for others (where t is finite)."""
    fin = np.isfinite(t)
    lo = fin & (rng.random(len(t)) < 0.15)
    hi = fin & ~lo & (rng.random(len(t)) < 0.15)
    tmin, tmax = np.where(lo, t, np.where(hi, np.minimum(t, tmin), tmin)), \
        np.where(hi, t, np.where(lo, np.maximum(t, tmax), tmax))
    return tmin.astype(t.dtype), tmax.astype(t.dtype)


def same_bits(a, b):
    """Elementwise: identical bits, or both NaN."""
    a = np.ascontiguousarray(a)
    b = np.ascontiguousarray(b)
    u = np.uint32 if a.dtype == np.float32 else np.uint64
    return (a.view(u) == b.view(u)) | (np.isnan(a) & np.isnan(b))


def _first_diff(name, mask, *arrays):
    i = int(np.flatnonzero(~mask)[0])
    return f"{name}: {(~mask).sum()} rays differ, first {i}: " + "; ".join(repr(x[i]) for x in arrays)


# ---------------------------------------------------------------------------------------------
# Tests
# ---------------------------------------------------------------------------------------------

def triangle_inputs(T, seed=7):
    rng = np.random.default_rng(seed + (T == np.float64))
    out = []
    for name, (tris, O, D) in triangle_cases(seed).items():
        with np.errstate(all="ignore"):
            tris = tris.astype(T)
            rows = preprocess(tris, T)
        O = np.ascontiguousarray(O, T)
        D = np.ascontiguousarray(D, T)
        keep = (D != 0).any(1) & np.isfinite(D).all(1) & np.isfinite(O).all(1)  # the rays
        tris, rows, O, D = tris[keep], rows[keep], O[keep], D[keep]            # traversal takes
        tmin, tmax = _intervals(rng, len(O), T)
        _, t, _, _, det = ref_mt(rows, O, D, tmin, np.full(len(O), np.inf, T), band_eps2(T), T(0))
        tmin, tmax = _at_the_limits(rng, t, tmin, tmax)
        out.append((name, tris, rows, O, D, tmin, tmax))
        if name == "grazing":
            # the parallel band's edge: the row's |e1|^2 |e2|^2 c_T^2 word set so that the band
            # eps2 * word * |d c_R|^2 lands within a few ulps of (det c_T c_R)^2 (the unit takes
            # the word as given; here it is an input like any other)
            cr, dd = ref_ray_band(D)
            with np.errstate(all="ignore"):
                ds = det * rows[:, TRI_SCALE] * cr
                word = (ds * ds) / (band_eps2(T) * dd)
            ok = np.flatnonzero(np.isfinite(word) & (word > 0))
            up, down = word[ok], word[ok]
            words = [up]
            for _ in range(3):                      # the word and 3 ulps either side
                up = np.nextafter(up, T(np.inf))
                down = np.nextafter(down, T(0))
                words += [up, down]
            k = len(words)
            rows = np.repeat(rows[ok], k, axis=0)
            rows[:, TRI_NORMS] = np.stack(words, 1).ravel()
            rep = np.repeat(ok, k)
            out.append(("parallel band's edge", tris[rep], rows, O[rep], D[rep], tmin[rep], tmax[rep]))
    return out


@pytest.mark.parametrize("T", DTYPES, ids=lambda t: t.__name__)
def test_moller_trumbore_copies_are_the_reference_bit_for_bit(T):
    eps2 = band_eps2(T)
    one = T(1)
    valid_total = 0
    for edge in (T(0), T(EDGE[T])):
        for name, tris, rows, O, D, tmin, tmax in triangle_inputs(T):
            where = f"{T.__name__} edge={edge} {name}"
            valid, t, u, v, det = ref_mt(rows, O, D, tmin, tmax, eps2, edge)
            tuv = np.stack([t, u, v], 1)
            valid_total += valid.sum()
            ok, out = run_single_mt(rows, O, D, tmin, tmax, eps2, one, edge)
            assert np.array_equal(ok, valid), _first_diff(f"{where} mt_valid_at verdict", ok == valid, O, D)
            same = same_bits(out, tuv).all(1)
            assert same.all(), _first_diff(f"{where} mt_valid_at t/u/v", same, out, tuv)
            for anyhit in (False, True):
                d_ok, d_out, l_ok, l_out = run_packet_mt(rows, O, D, tmin, tmax, eps2, one, edge, anyhit)
                assert np.array_equal(d_ok, valid), _first_diff(f"{where} packet._mt verdict",
                                                                d_ok == valid, O, D, tuv, det)
                same = same_bits(d_out, tuv).all(1)
                assert same.all(), _first_diff(f"{where} packet._mt t/u/v", same, d_out, tuv)
                assert np.array_equal(l_ok, valid), _first_diff(
                    f"{where} packet._triangle (anyhit={anyhit}) verdict", l_ok == valid, O, D)
                if not anyhit:
                    same = same_bits(l_out[valid], tuv[valid]).all(1)
                    assert same.all(), _first_diff(f"{where} packet._triangle t/u/v", same,
                                                   l_out[valid], tuv[valid])
            if T == np.float64 and edge == 0:
                # the verifier's float64 re-test: the datapath without a valid check (det = 0:
                # no hit, reported as t = inf)
                out = run_mt64(tris, O, D)
                nz = det != 0
                same = same_bits(out[nz], tuv[nz]).all(1)
                assert same.all(), _first_diff(f"{where} verify._mt64", same, out[nz], tuv[nz])
                assert np.isinf(out[~nz, 0]).all()
    assert valid_total > 5000          # the cases hit as well as miss


@njit(error_model="numpy")
def run_triangle_on_lanes(flat, row, F, I, M, bit, eps2, one, edge, anyhit):
    """Each lane's ``packet._mt`` answer on the lane state (F, I, M) as given, then
    ``packet._triangle`` on that state (changed in place): (ok, t, u, v) per lane."""
    b = TRI_WORDS * row
    ok = np.zeros(P, np.bool_)
    tuv = np.empty((P, 3), F.dtype)
    for k in range(P):
        r = _lane_mt(flat, b, F, k, eps2, one, edge)
        ok[k] = r[0]
        tuv[k, 0] = r[1]
        tuv[k, 1] = r[2]
        tuv[k, 2] = r[3]
    _triangle(flat, row, row, F, I, M, bit, eps2, one, edge, anyhit)
    return ok, tuv


@pytest.mark.parametrize("T", DTYPES, ids=lambda t: t.__name__)
def test_triangle_lane_loops_change_only_the_lanes_that_take_the_hit(T):
    """``packet._triangle``'s lane loops on lane states as a packet meets them: box-test bits
    for either child (bit 0 or 1) or neither, dead lanes, earlier hits nearer, farther or tied
    (the lower primitive wins a tie), and closest distances of -0.0, +0.0, subnormals and
    +inf. A lane takes the hit when the unit accepts it, the lane is live and its bit is set
    (closest hit: and it is nearer, or first, or tied with a higher primitive); every other
    word of the scratch keeps its bits. Any-hit lanes that take it retire."""
    rng = np.random.default_rng(5)
    one = T(1)
    eps2 = band_eps2(T)
    edge = T(EDGE[T])
    tris = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], T)
    flat = preprocess(tris, T).ravel()
    j = 0
    specials = np.array([-0.0, 0.0, np.finfo(T).smallest_subnormal, np.inf, 0.5, 2.0, 1.0], T)
    taken = 0
    for case in range(400):
        anyhit = bool(case % 2)
        bit = int(rng.integers(2))
        F = np.empty(NF, T)
        I = np.empty(NI, np.int32)
        M = np.zeros(NM, np.uint8)
        O = np.column_stack([rng.uniform(-0.2, 1.2, P), rng.uniform(-0.2, 1.2, P),
                             rng.choice([1.0, -1.0], P)]).astype(T)
        D = np.column_stack([rng.normal(0, 0.05, P), rng.normal(0, 0.05, P), -O[:, 2]]).astype(T)
        for k in range(P):
            _lane_setup(F, I, M, k, True, O[k, 0], O[k, 1], O[k, 2], D[k, 0], D[k, 1], D[k, 2],
                        T(0), T(np.inf), T(0), one)
        F[BEST:BEST + P] = rng.choice(specials, P)
        F[BU:BU + P] = rng.normal(size=P).astype(T)
        F[BV:BV + P] = rng.normal(size=P).astype(T)
        M[MASK:MASK + P] = rng.integers(0, 4, P)
        M[ALIVE:ALIVE + P] = rng.integers(0, 2, P)
        I[PRIM:PRIM + P] = rng.choice([-1, 0, 1, 7], P)
        if anyhit:      # as a packet meets them: a live lane has found no blocker yet
            I[PRIM:PRIM + P] = np.where(M[ALIVE:ALIVE + P] != 0, -1, I[PRIM:PRIM + P])
        F0, I0, M0 = F.copy(), I.copy(), M.copy()
        ok, tuv = run_triangle_on_lanes(flat, 0, F, I, M, bit, eps2, one, edge, anyhit)
        lane = ok & (((M0[MASK:MASK + P] >> bit) & 1) != 0) & (M0[ALIVE:ALIVE + P] != 0)
        p = I0[PRIM:PRIM + P]
        take = lane if anyhit else lane & ((tuv[:, 0] < F0[BEST:BEST + P]) | (p < 0) | (j < p))
        taken += int(take.sum())
        F1, I1, M1 = F0.copy(), I0.copy(), M0.copy()
        I1[PRIM:PRIM + P][take] = j
        if anyhit:
            M1[ALIVE:ALIVE + P][take] = 0
        else:
            for row, c in ((BEST, 0), (BU, 1), (BV, 2)):
                F1[row:row + P][take] = tuv[take, c]
        where = f"{T.__name__} case {case} anyhit={anyhit} bit={bit}"
        assert same_bits(F, F1).all(), where
        assert np.array_equal(I, I1) and np.array_equal(M, M1), where
    assert taken > 100                  # lanes took the hit as well as kept their state


def box_inputs(T, seed=9):
    rng = np.random.default_rng(seed + (T == np.float64))
    out = []
    widen = T(1 + 2 * GAMMA3[T])
    for name, (B, O, D) in box_cases(seed).items():
        with np.errstate(all="ignore"):
            B = np.ascontiguousarray(B, T)
            O = np.ascontiguousarray(O, T)
            D = np.ascontiguousarray(D, T)
        keep = (D != 0).any(1) & np.isfinite(D).all(1) & np.isfinite(O).all(1)
        B, O, D = B[keep], O[keep], D[keep]
        tmin, tmax = _intervals(rng, len(O), T)
        _, tn = ref_slab(B, O, D, np.zeros(len(O), T), np.full(len(O), np.inf, T), widen)
        tmin, tmax = _at_the_limits(rng, tn, tmin, tmax)
        out.append((name, B, O, D, tmin, tmax))
    return out


@pytest.mark.parametrize("T", DTYPES, ids=lambda t: t.__name__)
def test_slab_test_copies_are_the_reference_bit_for_bit(T):
    widen = T(1 + 2 * GAMMA3[T])
    one = T(1)
    hits = 0
    nan_planes = 0
    for name, B, O, D, tmin, tmax in box_inputs(T):
        where = f"{T.__name__} {name}"
        hit, tn = ref_slab(B, O, D, tmin, tmax, widen)
        hits += hit.sum()
        with np.errstate(all="ignore"):
            inv = one / D
            nan_planes += (np.isnan((B[:, :3] - O) * inv) | np.isnan((B[:, 3:] - O) * inv)).any(1).sum()
        h, t = run_aabb_hit_at(B, O, D, tmin, tmax, widen, one)
        assert np.array_equal(h, hit), _first_diff(f"{where} aabb_hit_at hit", h == hit, B, O, D)
        same = same_bits(t, tn)
        assert same.all(), _first_diff(f"{where} aabb_hit_at tnear", same, t, tn)
        direct, loop = run_packet_slab(B, O, D, tmin, tmax, widen, one)
        assert np.array_equal(direct, hit), _first_diff(f"{where} packet._slab", direct == hit, B, O, D)
        assert np.array_equal(loop, hit), _first_diff(f"{where} packet._box", loop == hit, B, O, D)
    assert hits > 5000 and nan_planes > 500     # hits and misses; origins on slab planes occur


# tri_k, dir_k: the scene (triangles and origins) scaled by 2^tri_k, the directions by 2^dir_k.
# Each leaves the range of an unscaled band term (|e1|^2 |e2|^2 ~ 2^(4 tri_k), |d|^2 ~
# 2^(2 dir_k), or their product with (k eps)^2 ~ 2^-42 / 2^-100) while every datapath value
# stays a normal number, so the unit's answers must be those at scale 1.
POW2_SCALES = {np.float32: [(40, 0), (-36, 0), (0, 80), (0, -80), (30, -60), (-30, 60)],
               np.float64: [(300, 0), (-300, 0), (0, 600), (0, -600), (250, -500)]}


@pytest.mark.parametrize("T", DTYPES, ids=lambda t: t.__name__)
def test_band_verdicts_do_not_depend_on_a_power_of_two_scale(T):
    """A product with a power of two is exact, so scaling the scene by 2^a and the directions by
    2^b changes no verdict, no u or v, and t by exactly 2^(a - b), as long as the datapath stays
    in range. The band's squares (|e1|^2 |e2|^2 ~ size^4, |d|^2) leave the float range long
    before the datapath does (in float32 from sizes of ~4e9 and ~1e-10 on), which made every
    ray on a 1e12-sized mesh read as parallel; the grazing rays here straddle the band's edge."""
    eps2 = band_eps2(T)
    one = T(1)
    edge = T(EDGE[T])
    cases = triangle_cases(5)
    for name in ("grazing", "random"):
        tris, O, D = (np.asarray(x, T) for x in cases[name])
        rows = preprocess(tris, T)
        n = len(O)
        tmin = np.zeros(n, T)
        tmax = np.full(n, np.inf, T)
        ok0, out0 = run_single_mt(rows, O, D, tmin, tmax, eps2, one, edge)
        in_band = run_single_mt(rows, O, D, tmin, tmax, T(0), one, edge)[0] & ~ok0
        assert ok0.sum() > n // 5 and (name == "random" or in_band.sum() > n // 100)
        for a, b in POW2_SCALES[T]:
            where = f"{T.__name__} {name} scene 2^{a} directions 2^{b}"
            sa, sb = T(2.0 ** a), T(2.0 ** b)
            tris_s, O_s, D_s = tris * sa, O * sa, D * sb
            assert np.array_equal(tris_s / sa, tris) and np.array_equal(D_s / sb, D)  # exact
            rows_s = preprocess(tris_s, T)
            ok, out = run_single_mt(rows_s, O_s, D_s, tmin, tmax, eps2, one, edge)
            assert np.array_equal(ok, ok0), _first_diff(f"{where} mt_valid_at verdict", ok == ok0, O, D)
            want = out0.copy()
            want[:, 0] *= T(2.0 ** (a - b))
            same = same_bits(out[ok], want[ok0]).all(1)
            assert same.all(), _first_diff(f"{where} mt_valid_at t/u/v", same, out[ok], want[ok0])
            d_ok, d_out, l_ok, _ = run_packet_mt(rows_s, O_s, D_s, tmin, tmax, eps2, one, edge, False)
            assert np.array_equal(d_ok, ok0) and np.array_equal(l_ok, ok0), where
            assert same_bits(d_out[ok], want[ok0]).all(), where


@pytest.mark.parametrize("T", DTYPES, ids=lambda t: t.__name__)
def test_preprocessed_band_words(T):
    """Each row's c_T is a normal power of two and its band word is |e1|^2 |e2|^2 (float64, from
    the stored edges) times c_T^2, rounded once to T, near 1; so where the unscaled word is a
    normal number it is that word times c_T^2, exactly. Degenerate triangles get a zero word."""
    rng = np.random.default_rng(21)
    n = 6000
    lo, hi = (-18, 14) if T == np.float32 else (-70, 70)     # sizes; |e1|^2 |e2|^2 finite in f64
    size = 10.0 ** rng.uniform(lo, hi, (n, 1, 1))
    tris = rng.uniform(-1, 1, (n, 3, 3)) * size + rng.uniform(-1, 1, (n, 1, 3)) * size * 10
    tris[:200, 2] = tris[:200, 0]                               # a repeated vertex
    tris = tris.astype(T)
    rows = preprocess(tris, T)
    c = rows[:, TRI_SCALE].astype(np.float64)
    m, _ = np.frexp(c)
    assert (m == 0.5).all() and (c >= np.finfo(T).tiny).all() and np.isfinite(c).all()
    e1 = rows[:, TRI_E1:TRI_E1 + 3].astype(np.float64)
    e2 = rows[:, TRI_E2:TRI_E2 + 3].astype(np.float64)
    assert np.array_equal(e1, (tris[:, 1] - tris[:, 0]).astype(np.float64))
    norms = (e1 * e1).sum(1) * (e2 * e2).sum(1)
    assert np.isfinite(norms).all()
    assert np.array_equal(rows[:, TRI_NORMS], (norms * c * c).astype(T))
    assert (rows[:200, TRI_NORMS] == 0).all()
    word = rows[200:, TRI_NORMS].astype(np.float64)
    assert ((word >= 0.25) & (word < 4)).all()               # |e1| |e2| c_T in [0.5, 2)
    with np.errstate(all="ignore"):
        unscaled = norms.astype(T)
    normal = (unscaled >= np.finfo(T).tiny) & np.isfinite(unscaled)
    if T == np.float32:
        assert normal.mean() > 0.3 and (~normal).sum() > 100     # both kinds occur
    else:
        assert normal[200:].all()
    assert np.array_equal(rows[normal, TRI_NORMS], (unscaled[normal] * c[normal] ** 2).astype(T))
