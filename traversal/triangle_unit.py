"""Moller-Trumbore triangle intersection unit (thesis appendix A, Figs. A.3/A.4, [MT97]; SPEC 7).

One ray against one triangle per call, with the unit's valid check: ``det`` outside the parallel
band, ``u >= 0``, ``v >= 0``, ``u + v <= 1``, ``t`` in ``[t_min, t_max]``.

The parallel band is *relative*: ``det^2 <= band2`` with ``band2 = (k*eps)^2 |e1|^2 |e2|^2
|d|^2`` (precomputed per triangle without the ``|d|^2`` factor). ``det = -d . (e1 x e2)``, so this
rejects rays within about ``k*eps`` radians of the triangle's plane whatever the triangle's size;
an absolute epsilon would drop every hit on a 1e-4-sized triangle (det ~ 1e-8).

Triangles are preprocessed once into ``(n, TRI_WORDS)`` rows ``v0, e1, e2, |e1|^2 |e2|^2`` (the
vertex/edge form the unit's subtractors produce), in the working precision.
"""
import numpy as np
from numba import njit, prange

from .config import BAND_K

# A preprocessed triangle row: offsets of its words (x, y, z each) in the working float type.
TRI_V0 = 0            # vertex 0
TRI_E1 = 3            # e1 = v1 - v0
TRI_E2 = 6            # e2 = v2 - v0
TRI_NORMS = 9         # |e1|^2 |e2|^2, the scale of the parallel band
TRI_WORDS = 10


def preprocess(tris, dtype=np.float32):
    """(n, 3, 3) triangles -> (n, TRI_WORDS) rows v0, e1, e2, |e1|^2*|e2|^2 in ``dtype``."""
    t = np.asarray(tris, dtype=dtype)
    out = np.empty((len(t), TRI_WORDS), dtype=dtype)
    out[:, TRI_V0:TRI_V0 + 3] = t[:, 0]
    out[:, TRI_E1:TRI_E1 + 3] = t[:, 1] - t[:, 0]
    out[:, TRI_E2:TRI_E2 + 3] = t[:, 2] - t[:, 0]
    e1 = out[:, TRI_E1:TRI_E1 + 3].astype(np.float64)
    e2 = out[:, TRI_E2:TRI_E2 + 3].astype(np.float64)
    out[:, TRI_NORMS] = ((e1 * e1).sum(1) * (e2 * e2).sum(1)).astype(dtype)
    return out


def band_eps2(dtype):
    eps = np.finfo(dtype).eps
    return dtype((BAND_K * eps) ** 2)


@njit(cache=True, error_model="numpy", inline="always")
def mt_hit_at(tris, b, ox, oy, oz, dx, dy, dz, dd, tmin, tmax, eps2, one, edge):
    """Triangle row ``tris[b:b + TRI_WORDS]`` of the flattened preprocessed array
    (``b = TRI_WORDS * j``). Returns (valid, t, u, v). ``dd`` = |d|^2, ``eps2`` = (k*eps)^2 and
    ``one`` = 1 in the working float type (so that the divider stays in that precision);
    ``edge`` >= 0 widens the barycentric checks (``traversal.config.EDGE_EPS_F32``)."""
    e1x = tris[b + TRI_E1]; e1y = tris[b + TRI_E1 + 1]; e1z = tris[b + TRI_E1 + 2]
    e2x = tris[b + TRI_E2]; e2y = tris[b + TRI_E2 + 1]; e2z = tris[b + TRI_E2 + 2]
    # p = d x e2 ; det = e1 . p
    px = dy * e2z - dz * e2y
    py = dz * e2x - dx * e2z
    pz = dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    if det * det <= eps2 * tris[b + TRI_NORMS] * dd:  # parallel band (relative), also det == 0
        return False, tmax, tmax, tmax
    inv = one / det                              # the divider (Fig. A.4)
    sx = ox - tris[b + TRI_V0]; sy = oy - tris[b + TRI_V0 + 1]; sz = oz - tris[b + TRI_V0 + 2]
    u = (sx * px + sy * py + sz * pz) * inv
    if not (u >= -edge and u <= one + edge):
        return False, tmax, tmax, tmax
    qx = sy * e1z - sz * e1y
    qy = sz * e1x - sx * e1z
    qz = sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    if not (v >= -edge and u + v <= one + edge):
        return False, tmax, tmax, tmax
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    if not (t >= tmin and t <= tmax):
        return False, tmax, tmax, tmax
    return True, t, u, v


@njit(cache=True, error_model="numpy", inline="always")
def mt_valid_at(tris, b, ox, oy, oz, dx, dy, dz, dd, tmin, tmax, eps2, one, edge):
    """``mt_hit_at`` as the hardware evaluates it: every datapath output is computed and the
    valid check is one AND of its conditions, with no early exit. Same operations in the same
    order, so (valid, t, u, v) agree with ``mt_hit_at`` whenever valid (t, u, v are not
    meaningful otherwise). Traversal uses this form: a random ray makes each early exit an
    unpredictable branch, and one branch costs more than the rest of the test (measured on
    incoherent rays: 3-12% of the whole trace)."""
    e1x = tris[b + TRI_E1]; e1y = tris[b + TRI_E1 + 1]; e1z = tris[b + TRI_E1 + 2]
    e2x = tris[b + TRI_E2]; e2y = tris[b + TRI_E2 + 1]; e2z = tris[b + TRI_E2 + 2]
    px = dy * e2z - dz * e2y
    py = dz * e2x - dx * e2z
    pz = dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    inv = one / det
    sx = ox - tris[b + TRI_V0]; sy = oy - tris[b + TRI_V0 + 1]; sz = oz - tris[b + TRI_V0 + 2]
    u = (sx * px + sy * py + sz * pz) * inv
    qx = sy * e1z - sz * e1y
    qy = sz * e1x - sx * e1z
    qz = sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    valid = (not (det * det <= eps2 * tris[b + TRI_NORMS] * dd)) & (u >= -edge) \
        & (u <= one + edge) & (v >= -edge) & (u + v <= one + edge) & (t >= tmin) & (t <= tmax)
    return valid, t, u, v


@njit(cache=True, parallel=True, error_model="numpy")
def mt_batch(tris, origins, dirs, tmin, tmax, eps2, one, edge):
    """Batch form: ray i against preprocessed triangle i -> (hit, t, u, v)."""
    n = origins.shape[0]
    hit = np.empty(n, dtype=np.bool_)
    t = np.empty(n, dtype=origins.dtype)
    u = np.empty(n, dtype=origins.dtype)
    v = np.empty(n, dtype=origins.dtype)
    flat = tris.ravel()
    for i in prange(n):
        dx = dirs[i, 0]; dy = dirs[i, 1]; dz = dirs[i, 2]
        h, ti, ui, vi = mt_hit_at(flat, TRI_WORDS * i, origins[i, 0], origins[i, 1], origins[i, 2], dx, dy, dz,
                               dx * dx + dy * dy + dz * dz, tmin[i], tmax[i], eps2, one, edge)
        hit[i] = h
        t[i] = ti
        u[i] = ui
        v[i] = vi
    return hit, t, u, v


@njit(cache=True, error_model="numpy")
def wt_hit_at(raw, j, ox, oy, oz, kx, ky, kz, sx, sy, sz, tmin, tmax):
    """Watertight ray/triangle test (Woop, Benthin & Wald 2013), for the accuracy study.

    ``raw`` holds the original vertices (n, 9); (kx, ky, kz) is the ray's axis permutation
    (kz = largest |d| component, kx/ky swapped when d[kz] < 0 to keep the winding) and
    (sx, sy, sz) its shear constants. The edge functions are evaluated in the ray's sheared
    space, and an exact zero is recomputed in float64, so a ray through a shared edge or vertex
    hits at least one of the triangles that share it. Returns (valid, t, u, v)."""
    # vertices relative to the origin, permuted and sheared
    ax = raw[j, kx] - ox if kx == 0 else (raw[j, kx] - oy if kx == 1 else raw[j, kx] - oz)
    ay = raw[j, ky] - ox if ky == 0 else (raw[j, ky] - oy if ky == 1 else raw[j, ky] - oz)
    az = raw[j, kz] - ox if kz == 0 else (raw[j, kz] - oy if kz == 1 else raw[j, kz] - oz)
    bx = raw[j, 3 + kx] - ox if kx == 0 else (raw[j, 3 + kx] - oy if kx == 1 else raw[j, 3 + kx] - oz)
    by = raw[j, 3 + ky] - ox if ky == 0 else (raw[j, 3 + ky] - oy if ky == 1 else raw[j, 3 + ky] - oz)
    bz = raw[j, 3 + kz] - ox if kz == 0 else (raw[j, 3 + kz] - oy if kz == 1 else raw[j, 3 + kz] - oz)
    cx = raw[j, 6 + kx] - ox if kx == 0 else (raw[j, 6 + kx] - oy if kx == 1 else raw[j, 6 + kx] - oz)
    cy = raw[j, 6 + ky] - ox if ky == 0 else (raw[j, 6 + ky] - oy if ky == 1 else raw[j, 6 + ky] - oz)
    cz = raw[j, 6 + kz] - ox if kz == 0 else (raw[j, 6 + kz] - oy if kz == 1 else raw[j, 6 + kz] - oz)
    Ax = ax - sx * az
    Ay = ay - sy * az
    Bx = bx - sx * bz
    By = by - sy * bz
    Cx = cx - sx * cz
    Cy = cy - sy * cz
    U = Cx * By - Cy * Bx
    V = Ax * Cy - Ay * Cx
    W = Bx * Ay - By * Ax
    if U == 0 or V == 0 or W == 0:          # on an edge in float32: decide in float64
        U = np.float64(Cx) * np.float64(By) - np.float64(Cy) * np.float64(Bx)
        V = np.float64(Ax) * np.float64(Cy) - np.float64(Ay) * np.float64(Cx)
        W = np.float64(Bx) * np.float64(Ay) - np.float64(By) * np.float64(Ax)
    if (U < 0 or V < 0 or W < 0) and (U > 0 or V > 0 or W > 0):
        return False, tmax, tmax, tmax
    det = U + V + W
    if det == 0:
        return False, tmax, tmax, tmax
    Az = sz * az
    Bz = sz * bz
    Cz = sz * cz
    T = U * Az + V * Bz + W * Cz
    t = T / det
    if not (t >= tmin and t <= tmax):
        return False, tmax, tmax, tmax
    return True, t, V / det, W / det


@njit(cache=True, error_model="numpy")
def wt_setup(dx, dy, dz, one):
    """Per-ray constants of the watertight test: the axis permutation (kx, ky, kz), kz the
    largest |d| component and kx/ky swapped when d[kz] < 0 to keep the winding, and the shear
    (sx, sy, sz)."""
    kz = 0
    if abs(dy) > abs(dx):
        kz = 1
    if abs(dz) > max(abs(dx), abs(dy)):
        kz = 2
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    dkz = dz if kz == 2 else (dy if kz == 1 else dx)
    if dkz < 0:
        kx, ky = ky, kx
    dkx = dz if kx == 2 else (dy if kx == 1 else dx)
    dky = dz if ky == 2 else (dy if ky == 1 else dx)
    return kx, ky, kz, dkx / dkz, dky / dkz, one / dkz


@njit(cache=True, error_model="numpy")
def wt_hit_ray(raw, j, ox, oy, oz, dx, dy, dz, one, tmin, tmax):
    """``wt_hit_at`` with the per-ray set-up done here (kept out of the traversal loop, whose
    hot path is the Moller-Trumbore unit)."""
    kx, ky, kz, sx, sy, sz = wt_setup(dx, dy, dz, one)
    return wt_hit_at(raw, j, ox, oy, oz, kx, ky, kz, sx, sy, sz, tmin, tmax)
