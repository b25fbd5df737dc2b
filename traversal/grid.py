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
"""
import time

import numpy as np
from numba import njit

from hwbvh.parallel import run_ranges
from .structure import TriangleStructure, checked_triangles, padded_box
from .config import (CHUNK_RAYS, GRID_DENSITY, GRID_MAILBOX, GRID_MAX_CELLS,
                     GRID_MAX_REFS_PER_TRI, GRID_PAD_COORD, GRID_PAD_TRI, GRID_STOP_SLACK)
from .rawtree import _ray_ok
from .triangle_unit import (TRI_WORDS, mt_valid_at, store_answer, store_normals)


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
def _axis_setup(o, d, gmin, cs, inv, n, t0):
    """Entry cell of one axis at ray parameter t0 and the t of its next cell boundary."""
    c = np.int64(np.floor((o + t0 * d - gmin) * inv))
    c = min(max(c, 0), n - 1)
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
    cx, sx, nx = _axis_setup(fx, gx, gmin[0], cs[0], inv[0], res[0], t0)
    cy, sy, ny = _axis_setup(fy, gy, gmin[1], cs[1], inv[1], res[1], t0)
    cz, sz, nz = _axis_setup(fz, gz, gmin[2], cs[2], inv[2], res[2], t0)
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
            acc = ok & ((t < best_t) | (prim < 0) | (j < prim))
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


@njit(cache=True, nogil=True, error_model="numpy")
def grid_chunks(c0, c1, tris, offsets, refs, gmin, gmax, cs, inv, res, O, D, tmin, tmax, eps2,
                one, edge, anyhit, out_prim, out_t, out_u, out_v, out_ng):
    """Chunks c0..c1 of CHUNK_RAYS rays (``hwbvh.parallel.run_ranges`` hands them out).
    ``out_t``/``out_u``/``out_v`` are (n,) or (0,) when only ``out_prim`` is wanted; ``out_ng``
    is (n, 3) for geometric normals or (0, 3)."""
    n = O.shape[0]
    mailbox = np.empty(GRID_MAILBOX, np.int64)
    for i in range(c0 * CHUNK_RAYS, min(n, c1 * CHUNK_RAYS)):
        prim, t, bu, bv = trace_grid_ray(tris, offsets, refs, gmin, gmax, cs, inv, res,
                                         O[i, 0], O[i, 1], O[i, 2], D[i, 0], D[i, 1], D[i, 2],
                                         tmin[i], tmax[i], eps2, one, edge, mailbox, anyhit)
        store_answer(i, prim, t, bu, bv, out_prim, out_t, out_u, out_v)
    store_normals(c0 * CHUNK_RAYS, min(n, c1 * CHUNK_RAYS), tris, out_prim, out_ng, one)


class GridTracer(TriangleStructure):
    """Ray queries on a uniform grid over ``triangles`` ((n, 3, 3)), with the BVH traversal's
    float32 triangle unit. ``resolution``: cells per axis (an int for all three or three ints);
    default from the density heuristic. Implements the tracer interface of
    ``traversal.tracers``. After the build: ``resolution`` (3 ints), ``build_seconds``,
    ``memory_bytes`` (cell offsets, references and preprocessed triangles),
    ``references`` and ``references_per_triangle``."""

    name = "grid"

    def __init__(self, triangles, resolution=None):
        start = time.perf_counter()
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
                raise ValueError(f"resolution must be a positive int or three, got {resolution!r}")
            res = np.broadcast_to(res, (3,)).astype(np.int64)
            if np.prod(res.astype(np.float64)) > GRID_MAX_CELLS:
                raise ValueError(f"resolution {tuple(res.tolist())} has more than "
                                 f"{GRID_MAX_CELLS} cells")
        ranges = np.empty((n, 6), np.int64)
        while True:
            inv = res / extent
            total = _cell_ranges(tris, self.gmin, inv, res, ranges)
            if total <= cap:
                break
            if resolution is not None:
                raise ValueError(f"resolution {tuple(res.tolist())} needs {total} references, "
                                 f"over the cap of {GRID_MAX_REFS_PER_TRI} per triangle")
            res = np.maximum(1, (res * 0.8).astype(np.int64))
        self.resolution = tuple(int(r) for r in res)
        self._res = res.astype(np.int64)
        self._inv = (res / extent).astype(np.float64)
        self._cs = (extent / res).astype(np.float64)
        self.offsets = np.zeros(int(np.prod(res)) + 1, np.int64)
        self.refs = np.empty(total, np.int32)
        _fill(ranges, self._res, self.offsets, self.refs)
        self._set_unit(tris)
        self.references = int(total)
        self.references_per_triangle = total / max(n, 1)
        self.memory_bytes = int(self.offsets.nbytes + self.refs.nbytes + self.tris.nbytes)
        self.build_seconds = time.perf_counter() - start

    def _trace(self, o, d, tmin, tmax, anyhit, prim, t, u, v, ng):
        run_ranges(grid_chunks, (len(o) + CHUNK_RAYS - 1) // CHUNK_RAYS, self._tris1, self.offsets,
                   self.refs, self.gmin, self.gmax, self._cs, self._inv, self._res, o, d, tmin,
                   tmax, self.eps2, self.one, self.edge, anyhit, prim, t, u, v, ng)

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
    o = np.array([[0.25, 0.25, 1.0]], np.float32)
    d = np.array([[0.0, 0.0, -1.0]], np.float32)
    grid.intersect(o, d)
    grid.intersect(o, d, normals=False)
    grid.occluded(o, d)
    return time.perf_counter() - start
