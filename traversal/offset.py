"""Robust origins for secondary rays.

A secondary ray starts from its hit point put onto the triangle's plane (``onto_plane``):
the point at the float32 unit's t can lie off a sliver's plane by about
eps (|o - v0| + t |d|) / sin(the angle at v0), beyond the offset below, and rays would then
start behind the surface. A point on the plane is off the float32 surface the traversal
tests by a few ulps of its coordinates, so a secondary ray started exactly there can re-hit
its own triangle (shadow acne, speckled reflections). A fixed epsilon breaks at other scene
scales. We offset along the geometric normal, to the side the new ray leaves on, by
``OFFSET_REL`` times the largest coordinate magnitude of the hit point and its triangle: a
bound on the float32 error of the point and of the triangle's plane (pbrt-v4 offsets by a
propagated error bound in the same way, ``OffsetRayOrigin``). It scales with the scene, so scaling a scene by 1e-3 or 1e3
scales the offset with it, and translating by 1e5 grows it to the float32 resolution there.
"""
import numpy as np
from numba import njit

from hwbvh.errors import ParameterError

from .config import FIXED_EPS, OFFSET_REL   # the offsets, with their reasons


STRATEGIES = ("relative", "fixed", "none")


STRATEGY_CODES = {name: k for k, name in enumerate(STRATEGIES)}


@njit(cache=True, error_model="numpy")
def offset_from_unit(px, py, pz, nx, ny, nz, dx, dy, dz, tri_mag, strategy):
    """One origin: the hit point (px, py, pz) moved along the unit geometric normal
    (nx, ny, nz) to the side of the outgoing direction (dx, dy, dz). ``strategy`` is an index
    into STRATEGIES. Returns (ox, oy, oz)."""
    if strategy == 2:                                   # "none"
        return px, py, pz
    s = nx * dx + ny * dy + nz * dz
    side = 1.0 if s >= 0 else -1.0                      # on the plane: leave to the front
    if strategy == 1:                                   # "fixed"
        k = side * FIXED_EPS
    else:                                               # "relative"
        mag = max(abs(px), abs(py), abs(pz))
        mag = mag if mag > tri_mag else tri_mag
        k = side * OFFSET_REL * (mag if mag > 1e-30 else 1e-30)
    return px + nx * k, py + ny * k, pz + nz * k


@njit(cache=True, inline="always")
def onto_plane(px, py, pz, gx, gy, gz, plane):
    """The point (px, py, pz) moved along the unit normal (gx, gy, gz) onto the plane
    g . x = ``plane``."""
    off = px * gx + py * gy + pz * gz - plane
    return px - off * gx, py - off * gy, pz - off * gz


@njit(cache=True, inline="always")
def unit_normal_and_plane(tris, j):
    """Triangle j of (n, 3, 3) ``tris``: its unit geometric normal e1 x e2 and its plane
    (the normal's dot product with vertex 0), in float64: (gx, gy, gz, plane)."""
    ax = np.float64(tris[j, 1, 0]) - np.float64(tris[j, 0, 0])
    ay = np.float64(tris[j, 1, 1]) - np.float64(tris[j, 0, 1])
    az = np.float64(tris[j, 1, 2]) - np.float64(tris[j, 0, 2])
    bx = np.float64(tris[j, 2, 0]) - np.float64(tris[j, 0, 0])
    by = np.float64(tris[j, 2, 1]) - np.float64(tris[j, 0, 1])
    bz = np.float64(tris[j, 2, 2]) - np.float64(tris[j, 0, 2])
    nx = ay * bz - az * by
    ny = az * bx - ax * bz
    nz = ax * by - ay * bx
    ln = np.sqrt(nx * nx + ny * ny + nz * nz)
    ln = ln if ln > 1e-300 else 1e-300
    gx = nx / ln
    gy = ny / ln
    gz = nz / ln
    return gx, gy, gz, (gx * np.float64(tris[j, 0, 0]) + gy * np.float64(tris[j, 0, 1]) +
                        gz * np.float64(tris[j, 0, 2]))


@njit(cache=True, error_model="numpy")
def _onto_planes_batch(p, tris, prim, out):
    for i in range(p.shape[0]):
        gx, gy, gz, plane = unit_normal_and_plane(tris, prim[i])
        out[i, 0], out[i, 1], out[i, 2] = onto_plane(p[i, 0], p[i, 1], p[i, 2], gx, gy, gz,
                                                     plane)


def points_on_planes(points, triangles, prim):
    """Hit points (n, 3) moved onto the planes of their triangles, ``triangles[prim]`` of
    (m, 3, 3) ``triangles``, in float64, as the renderer shades them: where secondary rays
    start from (``offset_origins``). Returns float64 points."""
    p = np.ascontiguousarray(points, np.float64)
    tris = np.ascontiguousarray(triangles)
    prim = np.asarray(prim)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ParameterError("points", f"must be (n, 3), got shape {p.shape}")
    if tris.ndim != 3 or tris.shape[1:] != (3, 3) or tris.dtype.kind != "f":
        raise ParameterError("triangles", f"must be (m, 3, 3) floats, got {tris.dtype} of "
                                          f"shape {tris.shape}")
    if prim.shape != (len(p),) or prim.dtype.kind not in "iu":
        raise ParameterError("prim", f"must be one integer per point ({len(p)}), got "
                                     f"{prim.dtype} of shape {prim.shape}")
    bad = (prim < 0) | (prim >= len(tris))
    if bad.any():
        raise ParameterError("prim", f"holds {prim[bad][0]}, outside 0..{len(tris) - 1} (a miss?)")
    out = np.empty_like(p)
    _onto_planes_batch(p, tris, prim.astype(np.int64, copy=False), out)
    return out


@njit(cache=True, error_model="numpy")
def offset_origin(px, py, pz, nx, ny, nz, dx, dy, dz, tri_mag, strategy):
    """``offset_from_unit`` for a normal of any length."""
    ln = np.sqrt(nx * nx + ny * ny + nz * nz)
    ln = ln if ln > 1e-300 else 1e-300
    return offset_from_unit(px, py, pz, nx / ln, ny / ln, nz / ln, dx, dy, dz, tri_mag, strategy)


@njit(cache=True, error_model="numpy")
def _offset_batch(p, n, d, tri_mag, strategy, out):
    for i in range(p.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = offset_origin(
            p[i, 0], p[i, 1], p[i, 2], n[i, 0], n[i, 1], n[i, 2], d[i, 0], d[i, 1], d[i, 2],
            tri_mag[i], strategy)


def offset_origins(points, ng, dirs, tri_mag, strategy="relative"):
    """points (n,3) (on their triangles' planes: ``points_on_planes``), ng (n,3) geometric
    normals (any length), dirs (n,3) outgoing directions,
    tri_mag (n,) largest |coordinate| of each hit triangle. Returns float64 origins.
    ``strategy``: "relative" (the default, above), "fixed" (1e-4 along the normal, what breaks
    at other scales) or "none" (start on the surface), the last two for comparison."""
    if not isinstance(strategy, str) or strategy not in STRATEGY_CODES:
        raise ParameterError("strategy", f"unknown offset strategy {strategy!r} (choose from "
                                         f"{', '.join(STRATEGIES)})")
    p = _finite_rows("points", points)
    n = len(p)
    normals = _finite_rows("ng", ng, n)
    d = _finite_rows("dirs", dirs, n)
    mag = _finite_numbers("tri_mag", tri_mag)
    if mag.ndim > 1 or (mag.ndim == 1 and mag.shape != (n,)):
        raise ParameterError("tri_mag", f"must be one number, or one per point ({n}), got "
                                        f"shape {mag.shape}")
    if (mag < 0).any():
        raise ParameterError("tri_mag", f"must be >= 0, got {mag.min()}")
    out = np.empty_like(p)
    _offset_batch(p, normals, d, np.ascontiguousarray(np.broadcast_to(mag, (n,))),
                  STRATEGY_CODES[strategy], out)
    return out


def _finite_numbers(name, values):
    """``values`` as a float64 array, else ParameterError naming ``name``."""
    try:
        a = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise ParameterError(name, "must hold numbers") from None
    if not np.isfinite(a).all():
        raise ParameterError(name, "must be finite (it holds NaN or infinity)")
    return a


def _finite_rows(name, values, n=None):
    """``values`` as a contiguous float64 (n, 3) array of finite numbers (``n`` rows when
    given), else ParameterError naming ``name``."""
    a = np.ascontiguousarray(_finite_numbers(name, values))
    if a.ndim != 2 or a.shape[1] != 3 or (n is not None and len(a) != n):
        rows = "n" if n is None else str(n)
        raise ParameterError(name, f"must be ({rows}, 3), got shape {a.shape}")
    return a
