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
from numba import njit

from hwbvh.format import BOX_MAX
from .config import GAMMA3_F32, GAMMA3_F64  # noqa: F401  (re-exported for the tracer's widening)


@njit(cache=True, error_model="numpy")
def near_far_planes(ix, iy, iz):
    """The comparator on the sign of 1/d, done once per ray: for each axis, the offset (0 for
    min, BOX_MAX for max) of the near plane; the far plane is the other one."""
    return (BOX_MAX if ix < 0 else 0), (BOX_MAX if iy < 0 else 0), (BOX_MAX if iz < 0 else 0)


@njit(cache=True, error_model="numpy", inline="always")
def slab_test(nx_, ny_, nz_, fx_, fy_, fz_, ox, oy, oz, ix, iy, iz, tmin, tmax, widen):
    """The unit's datapath, for the single-ray traversal (``aabb_hit_at``) and the packet lanes
    alike: a box given by its near planes (nx_, ny_, nz_) and far planes (fx_, fy_, fz_) against
    a ray with origin ``o``, reciprocal direction ``(ix, iy, iz)`` and interval [tmin, tmax].
    Returns (hit, tnear).

    Subtract, then multiply, per plane (the unit's subtractors and multipliers). A NaN plane
    distance (origin on a slab plane with d = 0: 0 * inf) compares false in the selects below
    and is ignored, so the ray counts as inside that closed slab."""
    nx = (nx_ - ox) * ix
    fx = (fx_ - ox) * ix
    ny = (ny_ - oy) * iy
    fy = (fy_ - oy) * iy
    nz = (nz_ - oz) * iz
    fz = (fz_ - oz) * iz
    tnear = nx if nx > tmin else tmin
    tnear = ny if ny > tnear else tnear
    tnear = nz if nz > tnear else tnear
    tfar = fx if fx < tmax else tmax
    tfar = fy if fy < tfar else tfar
    tfar = fz if fz < tfar else tfar
    return tnear <= tfar * widen, tnear


@njit(cache=True, error_model="numpy", inline="always")
def aabb_hit_at(f, b, ox, oy, oz, ix, iy, iz, kx, ky, kz, tmin, tmax, widen):
    """Box ``f[b:b + 6]`` (min xyz, max xyz in a flat array) against a ray with reciprocal
    direction ``(ix, iy, iz)``, near-plane offsets ``(kx, ky, kz)`` (``near_far_planes``) and
    interval [tmin, tmax], through ``slab_test``. Returns (hit, tnear)."""
    return slab_test(f[b + kx], f[b + 1 + ky], f[b + 2 + kz],
                     f[b + BOX_MAX - kx], f[b + 1 + BOX_MAX - ky], f[b + 2 + BOX_MAX - kz],
                     ox, oy, oz, ix, iy, iz, tmin, tmax, widen)
