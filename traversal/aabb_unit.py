"""AABB intersection unit (thesis appendix A, Fig. A.2, after Williams et al. 2005; SPEC 7).

Per axis a divider forms ``1/d`` (once per ray: ``d = +0`` gives ``+inf``, ``d = -0`` gives
``-inf``), two subtractors form ``min - o`` and ``max - o``, a comparator on the sign of ``1/d``
selects near and far, and two multipliers give the axis interval. ``tmin = max(near)``,
``tmax = min(far)``; the box is hit when ``tmin <= tmax`` and the interval overlaps the ray's [tmin, tmax].

Two robustness rules, both conservative (they can only add a box visit, never lose a hit):

* an origin exactly on a slab plane with ``d = 0`` gives ``0 * inf = NaN``; the max/min are
  written so that a NaN operand is ignored, i.e. the ray counts as inside that (closed) slab;
* the far distance is widened by ``1 + 2*gamma(3)`` (pbrt-v4's slab test; ``traversal.config``),
  so float rounding cannot turn a grazing hit on a flat box into a miss.

Kernels use IEEE division (error_model="numpy": 1/0 = inf, never an exception).
Functions are written without fixed float types: float32 inputs give the hardware's float32
unit, float64 inputs the float64 variant of the accuracy study.
"""
import numpy as np
from numba import njit, prange

from hwbvh.format import BOX_MAX
from .config import GAMMA3_F32, GAMMA3_F64  # noqa: F401  (re-exported for the tracer's widening)


@njit(cache=True, error_model="numpy")
def near_far_planes(ix, iy, iz):
    """The comparator on the sign of 1/d, done once per ray: for each axis, the offset (0 for
    min, BOX_MAX for max) of the near plane; the far plane is the other one."""
    return (BOX_MAX if ix < 0 else 0), (BOX_MAX if iy < 0 else 0), (BOX_MAX if iz < 0 else 0)


@njit(cache=True, error_model="numpy", inline="always")
def aabb_hit_at(f, b, ox, oy, oz, ix, iy, iz, kx, ky, kz, tmin, tmax, widen):
    """Box ``f[b:b + 6]`` (min xyz, max xyz in a flat array) against a ray with reciprocal direction ``(ix, iy, iz)``, near-plane
    offsets ``(kx, ky, kz)`` and interval [tmin, tmax]. Returns (hit, tnear).

    Subtract, then multiply, per plane (the unit's subtractors and multipliers). A NaN plane
    distance (origin on a slab plane with d = 0: 0 * inf) compares false in the selects below
    and is ignored, so the ray counts as inside that closed slab."""
    nx = (f[b + kx] - ox) * ix
    fx = (f[b + BOX_MAX - kx] - ox) * ix
    ny = (f[b + 1 + ky] - oy) * iy
    fy = (f[b + 1 + BOX_MAX - ky] - oy) * iy
    nz = (f[b + 2 + kz] - oz) * iz
    fz = (f[b + 2 + BOX_MAX - kz] - oz) * iz
    tnear = nx if nx > tmin else tmin
    tnear = ny if ny > tnear else tnear
    tnear = nz if nz > tnear else tnear
    tfar = fx if fx < tmax else tmax
    tfar = fy if fy < tfar else tfar
    tfar = fz if fz < tfar else tfar
    return tnear <= tfar * widen, tnear


@njit(cache=True, parallel=True, error_model="numpy")
def aabb_batch(boxes, origins, dirs, tmin, tmax, widen, one):
    """Batch form: ray i against box i (``one`` is 1 in the working float type, so the divider
    stays in that precision). Returns (hit bool (n,), tnear (n,))."""
    n = origins.shape[0]
    hit = np.empty(n, dtype=np.bool_)
    tn = np.empty(n, dtype=origins.dtype)
    flat = boxes.ravel()
    for i in prange(n):
        ix = one / dirs[i, 0]
        iy = one / dirs[i, 1]
        iz = one / dirs[i, 2]
        kx, ky, kz = near_far_planes(ix, iy, iz)
        h, t = aabb_hit_at(flat, 6 * i, origins[i, 0], origins[i, 1], origins[i, 2],
                           ix, iy, iz, kx, ky, kz, tmin[i], tmax[i], widen)
        hit[i] = h
        tn[i] = t
    return hit, tn
