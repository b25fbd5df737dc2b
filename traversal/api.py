"""Batched ray queries on an hwbvh tree: the public wrapper validates, the kernels trust.

>>> tracer = Tracer(bvh)                        # hwbvh.Bvh (nodes, index list, triangles)
>>> hits = tracer.intersect(origins, dirs)      # Hits: t, prim (-1 miss), u, v, ng
>>> blocked = tracer.occluded(origins, dirs, tmax=dist)
"""
import threading
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from hwbvh.config import LEAF_FLAG, MAX_LEAF_SIZE
from hwbvh.errors import InputError, ParameterError, checked_flag
from hwbvh.format import (BOX_MAX, WORD_A, WORD_B, WORD_BOX, WORD_FLAGS, check_nodes, node_views,
                          pack_indices, validate)
from hwbvh.primitives import checked_coordinates
from .aabb_unit import GAMMA3_F32, GAMMA3_F64
from hwbvh.parallel import run_ranges
from .config import CHUNK_RAYS, KEPT_BOUND_RAYS, MIN_RANGE_CHUNKS
from .traverse import trace_chunks
from .triangle_unit import Float32Range, Float64Range, band_eps2, preprocess
from .config import EDGE_EPS_F32, EDGE_EPS_F64, MAX_EDGE_EPS   # the valid check's slack


PRECISIONS = ("float32", "float64")     # the units' working precision: the hardware's, or wider
ACCELS = ("bvh", "grid", "kdtree")      # the structures traced on the triangle unit


@dataclass
class Hits:
    """Closest hits of a batch. t: (n,) with inf for a miss; prim: (n,) int32, -1 for a miss;
    u, v: (n,) barycentrics; ng: (n, 3) unnormalised geometric normal e1 x e2 (0 for a miss);
    counters: (n, 2) nodes visited / triangles tested, when asked for."""
    t: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    ng: np.ndarray
    counters: np.ndarray = None


def _ready(a, dtype):
    """``a`` itself when it is already a kernel input (an ndarray of ``dtype``, C-contiguous and
    writable), else None. A query's Python set-up is paid once per batch; the renderer asks a
    few batches per band and bounce, so this check costs far less than ``np.require``."""
    if type(a) is np.ndarray and a.dtype == dtype:
        f = a.flags
        if f.c_contiguous and f.writeable:
            return a
    return None


_fills = {}              # (dtype, bit pattern) -> the longest array of that value kept so far


def _filled(value, n):
    """n copies of the 0-d array ``value``: a slice of one kept array per value, since the
    renderer passes the same scalar bounds (0, inf, ...) with every query. Writable, not a
    broadcast view: Numba compiles a separate copy of every kernel for read-only arrays. The
    kernels only read a ray's bounds, so queries, threads included, can share it.
    ``release_kept_bounds`` frees the kept arrays."""
    if n > KEPT_BOUND_RAYS:
        return np.full(n, value, value.dtype)
    key = (value.dtype.str, value.tobytes())
    kept = _fills.get(key)
    if kept is None or len(kept) < n:
        kept = np.full(min(KEPT_BOUND_RAYS, max(n, 2 * len(kept) if kept is not None else n)),
                       value, value.dtype)
        if len(_fills) < 64:                   # a caller sweeping many values keeps a few
            _fills[key] = kept
    return kept[:n]


# (dtype, float.hex(x), nonnegative) -> the kept array of a Python float bound that passed
# ``_interval``'s checks: the renderer's scalar bounds skip NumPy's conversion and checks
_checked_fills = {}


def release_kept_bounds():
    """Free the bound arrays ``_filled`` keeps."""
    _fills.clear()
    _checked_fills.clear()


def negative_tmin_error(name):
    """The error for a negative t_min bound ``name`` (the interval starts at the origin or
    after it, as every tracer here and Embree assume)."""
    return ParameterError(name, "must not be negative: a ray's interval starts at its origin "
                                "or after it (as Embree's)")


def real_array(x, name, dtype=None):
    """``x`` as an ndarray of real numbers (converted to ``dtype`` when given); ParameterError
    naming ``name`` for None, complex, boolean, string or object data: NumPy would drop an
    imaginary part, read True as 1 and None as NaN, each a silently wrong ray or bound; and
    for rows of different lengths, which NumPy's own message would not name."""
    try:
        a = np.asarray(x) if x is not None else None
    except ValueError:                  # a ragged list: "setting an array element with a sequence"
        raise ParameterError(name, "must be rows of equal length (an (n, 3) array or list of "
                                   "rows), got rows of different lengths") from None
    if a is None or a.dtype.kind not in "fiu":
        got = "None" if a is None else str(a.dtype)
        raise ParameterError(name, f"must be real numbers, got {got}")
    if dtype is None:
        return a
    with np.errstate(over="ignore"):     # callers that cannot take infinity check for it
        return np.asarray(a, dtype=dtype)


def _nan_bound_error(name, a):
    where = "" if a.ndim == 0 else f" (ray {int(np.argmax(np.isnan(a)))})"
    return ParameterError(name, f"must be a number or one per ray, got NaN{where}")


def _interval(x, n, dtype, name, nonnegative=False):
    """A per-ray bound ``name`` as a writable contiguous (n,) array (a scalar is broadcast);
    ParameterError naming it on None, a NaN, a complex or boolean value or another shape, or
    with ``nonnegative`` on a value below 0 (as converted: a tiny negative that rounds to -0 is
    none). One reduction over an array of bounds: the minimum is NaN when any bound is."""
    if type(x) is float:
        key = (dtype, x.hex(), nonnegative)
        kept = _checked_fills.get(key)
        if kept is not None and len(kept) >= n:
            return kept[:n]
    a = _ready(x, dtype)
    if a is None or a.shape != (n,):
        if x is None:
            raise ParameterError(name, "must be a number or one per ray, got None")
        a = real_array(x, name, dtype)
        if a.ndim == 0:
            if np.isnan(a):
                raise _nan_bound_error(name, a)
            if nonnegative and n and a < 0:
                raise negative_tmin_error(name)
            kept = _filled(a, n)
            if type(x) is float and n and kept.base is not None and len(_checked_fills) < 64:
                _checked_fills[(dtype, x.hex(), nonnegative)] = kept.base
            return kept
        if a.shape == (n,):
            a = np.require(a, requirements=("C", "W"))
        else:
            try:
                a = np.array(np.broadcast_to(a, (n,)))
            except ValueError:
                raise ParameterError(name, f"must be a scalar or one value per ray ({n},), "
                                           f"got shape {a.shape}") from None
    if n:
        low = a.min()
        if not low >= 0:                    # negative or NaN
            if np.isnan(low):
                raise _nan_bound_error(name, a)
            if nonnegative:
                raise negative_tmin_error(name)
    return a


def ray_arrays(origins, dirs, dtype, names=("origins", "dirs")):
    """(origins, dirs) as C-contiguous, writable (n, 3) arrays of ``dtype``; ParameterError
    naming the argument (``names``: as the caller spells its parameters) on data that are not
    real numbers or on a bad shape. Writable even when the caller's arrays are read-only views,
    since Numba compiles (and caches) a separate copy of every kernel for read-only arguments
    (twice the first render's compile time)."""
    o_name, d_name = names
    o = _ready(origins, dtype)
    if o is None:
        o = _converted(origins, o_name, dtype)
    d = _ready(dirs, dtype)
    if d is None:
        d = _converted(dirs, d_name, dtype)
    if o.ndim != 2 or o.shape[1] != 3:
        raise ParameterError(o_name, f"must be (n, 3), got shape {o.shape}")
    if d.shape != o.shape:
        raise ParameterError(d_name, f"must be (n, 3) with one row per origin {o.shape}, "
                                     f"got shape {d.shape}")
    return o, d


def _converted(x, name, dtype):
    """``x`` (``real_array``) as a C-contiguous, writable array of ``dtype``; ParameterError
    naming ``name`` when a finite number is beyond ``dtype``'s range (as infinity, its ray
    would miss without a word)."""
    a = real_array(x, name)
    with np.errstate(over="ignore"):
        out = np.require(np.asarray(a, dtype=dtype), requirements=("C", "W"))
    if a.dtype.kind == "f" and a.dtype.itemsize > out.dtype.itemsize:
        lost = np.isinf(out) & np.isfinite(a)
        if lost.any():
            big = float(np.abs(a[lost]).max())
            raise ParameterError(name, f"holds {big:.3g}, beyond {out.dtype}'s range "
                                       f"({float(np.finfo(out.dtype).max):.3g}): as infinity its "
                                       f"ray would miss ({Float32Range.REMEDY})")
    return out


def _rays(origins, dirs, tmin, tmax, dtype):
    """Kernel inputs (``ray_arrays``) and their (n,) bounds; ParameterError naming the argument
    on a bad shape, data that are not real numbers, a NaN bound or a negative ``tmin``."""
    o, d = ray_arrays(origins, dirs, dtype)
    n = len(o)
    return o, d, _interval(tmin, n, dtype, "tmin", nonnegative=True), \
        _interval(tmax, n, dtype, "tmax")


def _answers(n, anyhit, normals, dtype):
    """Output arrays of a batch of ``n`` rays: prim (n,) int32; t, u, v ((n,), or empty for an
    any-hit query, which needs the primitive only) and ng ((n, 3), or (0, 3) without
    ``normals``) in ``dtype``."""
    m = 0 if anyhit else n
    return (np.empty(n, np.int32), np.empty(m, dtype), np.empty(m, dtype), np.empty(m, dtype),
            np.empty((n if normals else 0, 3), dtype))


def _checked_triangles(tris, source):
    """(n, 3, 3) triangles in their own float precision (integers as float64), refused
    (InputError naming ``source``) as the builder refuses its input: data that are not real
    numbers, another shape, or a coordinate NaN, infinite or beyond the builder's bound."""
    t = np.asarray(tris)
    if t.dtype.kind not in "fiu":
        raise InputError(source, f"must be real numbers, got {t.dtype}")
    if t.ndim != 3 or t.shape[1:] != (3, 3):
        raise InputError(source, f"must have shape (n, 3, 3), got {t.shape}")
    return checked_coordinates(t, source)


@njit(cache=True)
def _leaf_check_and_depth(u, f, rows):
    """(leaf, depth): the first leaf reached from the root whose box does not contain, in
    float32 (as the builder boxed them), the vertices of the triangles it lists, or -1; and
    the tree's depth (its longest root-to-leaf path, in edges), which sizes the traversal
    stack, taken in the same walk. ``rows``: the triangles in index-list order (a leaf's rows
    side by side, read in one sweep). The topology must be checked (``check_nodes`` with the
    index list's length): each node is then pushed once and every leaf range lies inside
    ``rows``."""
    stack = np.empty(u.shape[0], np.int64)
    dstack = np.empty(u.shape[0], np.int64)
    stack[0] = 0
    dstack[0] = 0
    sp = 1
    depth = 0
    while sp > 0:
        sp -= 1
        i = stack[sp]
        d = dstack[sp]
        depth = max(depth, d)
        if u[i, WORD_FLAGS] & LEAF_FLAG:
            # the box of the leaf's vertices first (no branch per coordinate), then one test
            a = np.int64(u[i, WORD_A])
            lx = ly = lz = np.float32(np.inf)
            hx = hy = hz = np.float32(-np.inf)
            for p in range(a, a + np.int64(u[i, WORD_B])):
                for v in range(3):
                    x = np.float32(rows[p, v, 0])
                    y = np.float32(rows[p, v, 1])
                    z = np.float32(rows[p, v, 2])
                    lx = min(lx, x)
                    ly = min(ly, y)
                    lz = min(lz, z)
                    hx = max(hx, x)
                    hy = max(hy, y)
                    hz = max(hz, z)
            b = WORD_BOX
            c = WORD_BOX + BOX_MAX
            if lx < f[i, b] or ly < f[i, b + 1] or lz < f[i, b + 2] or \
                    hx > f[i, c] or hy > f[i, c + 1] or hz > f[i, c + 2]:
                return i, depth
        else:
            stack[sp] = u[i, WORD_A]
            stack[sp + 1] = u[i, WORD_B]
            dstack[sp] = d + 1
            dstack[sp + 1] = d + 1
            sp += 2
    return -1, depth


def _boxes_widened_by_an_ulp(nodes):
    """A copy of ``nodes`` whose every box reaches one float32 ulp further out on each side.
    Widening every node alike keeps each child's box inside its parent's."""
    wide = nodes.copy()
    _, f = node_views(wide)
    box_min = f[:, WORD_BOX:WORD_BOX + BOX_MAX]
    box_max = f[:, WORD_BOX + BOX_MAX:WORD_BOX + 2 * BOX_MAX]
    box_min[:] = np.nextafter(box_min, np.float32(-np.inf))
    box_max[:] = np.nextafter(box_max, np.float32(np.inf))
    return wide


class PacketCount:
    """``last_packets``: the packets the calling thread's last query traced (the rest went ray
    by ray). Per thread, since a ``concurrent`` tracer takes queries from several at once."""

    def _start_packet_count(self):
        self._packets_by_thread = threading.local()

    def _count_packets(self, per_range):
        """Keep the calling thread's last query's packets per range of work (an array, summed
        only when asked for: most queries never are)."""
        self._packets_by_thread.per_range = per_range

    @property
    def last_packets(self):
        per_range = getattr(self._packets_by_thread, "per_range", None)
        return 0 if per_range is None else int(per_range.sum())


class Tracer(PacketCount):
    """Ray queries on one BVH (``hwbvh.build``'s, or the sweep builder's). ``triangles``: the
    (n, 3, 3) triangles the tree was built over, needed for a tree from ``hwbvh.load``
    (a built tree carries its own). precision: "float32" (the hardware units) or "float64";
    ``edge_eps``: the triangle unit's barycentric slack, which closes cracks along shared
    edges (default ``traversal.config.EDGE_EPS_F32`` or ``EDGE_EPS_F64``; 0: the strict
    unit); watertight=True swaps the Moller-Trumbore unit for the Woop et al. 2013 test.

    packets=True (default) traces each group of 16 consecutive rays that share a direction
    octant as a packet (``traversal.packet``): the same answers, bit for bit, with the box and
    triangle tests in SIMD. Give coherent rays in a coherent order (e.g. a camera's rays in
    pixel order) to profit. Per-ray counters and the watertight test use the single-ray path.

    Implements the tracer interface of ``traversal.tracers`` (plus per-ray work counters)."""

    name = "numba"
    has_counters = True
    concurrent = True                 # queries may come from several threads at once

    def __init__(self, bvh, triangles=None, precision="float32", edge_eps=None, watertight=False,
                 packets=True):
        if precision not in PRECISIONS:
            raise ParameterError("precision", f"must be 'float32' or 'float64', got {precision!r}")
        for name, flag in (("watertight", watertight), ("packets", packets)):
            checked_flag(flag, name)
        self.dtype = np.float32 if precision == "float32" else np.float64
        f32 = self.dtype == np.float32
        if edge_eps is None:
            edge_eps = EDGE_EPS_F32 if f32 else EDGE_EPS_F64
        elif isinstance(edge_eps, (bool, np.bool_)) \
                or not isinstance(edge_eps, (int, float, np.integer, np.floating)) \
                or not (np.isfinite(edge_eps) and 0 <= edge_eps <= MAX_EDGE_EPS):
            # a negative or NaN slack fails every valid check: every ray would miss; a wide
            # one takes the neighbours' hits
            raise ParameterError("edge_eps", f"must be a finite number in [0, {MAX_EDGE_EPS:g}], "
                                             f"got {edge_eps!r}")
        if not (hasattr(bvh, "nodes") and hasattr(bvh, "indices")):
            raise ParameterError("bvh", "expected an hwbvh.Bvh (nodes, indices, triangles), "
                                        f"got {type(bvh).__name__}")
        source = "bvh.triangles" if triangles is None else "triangles"
        tris = getattr(bvh, "triangles", None) if triangles is None else triangles
        if tris is None:
            meta = getattr(bvh, "meta", None)
            meta = meta if isinstance(meta, dict) else {}
            mesh = meta.get("source")
            # a refitted tree bounds the triangles it was refitted to, not its mesh file's
            hint = " (a refitted tree: the triangles it was refitted to)" \
                if meta.get("refitted") else \
                f" (built from {mesh}: triangles=hwbvh.load_triangles(that file))" \
                if isinstance(mesh, str) and mesh else ""
            raise InputError("bvh.triangles", f"the BVH has no triangles attached (a tree read "
                                              f"by hwbvh.load); pass triangles={hint}")
        tris = _checked_triangles(tris, source)
        # the triangle rows in index-list order, so that a leaf's rows lie side by side;
        # row_of[j]: primitive j's row (for the normals of hits)
        order = np.asarray(bvh.indices) if bvh.indices is not None else None
        if order is None or order.dtype.kind not in "iu":
            raise InputError("bvh.indices", f"must be an array of integers, got "
                                            f"{'None' if order is None else order.dtype}")
        order = order.astype(np.int64)
        n = len(tris)
        if order.ndim != 1 or len(order) != n:
            raise InputError(source, f"{n} triangles, but the tree has {len(order)} primitives "
                                     "(bvh.indices): not the triangles it was built over")
        self.n_triangles = n
        self.triangles = tris
        self.row_of = np.full(n, -1, np.int32)
        in_range = n == 0 or (order.min() >= 0 and order.max() < n)
        if in_range:
            self.row_of[order] = np.arange(n)
        if not in_range or (self.row_of < 0).any():           # a triangle missed or repeated
            raise InputError("bvh.indices", f"must list each of the {n} triangles once")
        # the kernels follow child pointers and leaf ranges unchecked: refuse a tree they
        # cannot walk before any of them reads it
        self.nodes = check_nodes(bvh.nodes, n_positions=n, source="bvh.nodes")
        if not getattr(bvh, "_invariants_hold", False):
            # not as hwbvh built or loaded it: a child box outside its parent's would make
            # every ray below it miss (6.9 ms on 262k triangles, so not paid for built trees)
            validate(self.nodes, order, n, MAX_LEAF_SIZE, source="bvh.nodes")
        self.u, self.f = node_views(self.nodes)
        # a leaf whose box does not hold its triangles (as the builder boxed them, in float32)
        # means other triangles than the tree's: every ray would miss them
        # (n, 9) rows taken by index: NumPy gathers those some 4 times faster than (3, 3) ones
        rows = np.take(tris.reshape(n, 9), order, axis=0).reshape(n, 3, 3)
        bad, self.depth = _leaf_check_and_depth(self.u, self.f, rows)
        if bad >= 0:
            raise InputError(source, f"a triangle lies outside its leaf's box (node {bad}): "
                                     "not the triangles the tree was built over")
        if not f32 and not np.array_equal(rows, rows.astype(np.float32)):
            # the builder boxed these triangles' float32 roundings, which can lie up to half a
            # float32 ulp inside the triangles themselves: the wider units trace them in boxes
            # widened outward by one ulp, or a ray near a box face would miss a triangle the
            # box was built to hold
            self.u, self.f = node_views(_boxes_widened_by_an_ulp(self.nodes))
        # flat word views of the same bytes for the kernels (no copy, no other layout)
        self._u1 = self.u.reshape(-1)
        self._f1 = self.f.reshape(-1)
        self.index_bytes = np.frombuffer(pack_indices(order), dtype=np.uint8)
        self.tris = preprocess(rows, self.dtype)
        self._tris1 = self.tris.reshape(-1)
        # rays that could take the unit's products out of its float range are refused, not
        # traced to lost hits (float64: only rays from beyond about 1e270)
        self.unit_range = (Float32Range if f32 else Float64Range)(self.tris, rows)
        # the watertight test (accuracy study) needs the original vertices, not v0 + e1
        self.watertight = bool(watertight)
        self.raw = np.ascontiguousarray(np.asarray(tris, self.dtype).reshape(len(tris), 9)) \
            if watertight else None
        self.eps2 = band_eps2(self.dtype)
        self.one = self.dtype(1)
        self.widen = self.dtype(1.0 + 2.0 * (GAMMA3_F32 if f32 else GAMMA3_F64))
        self.edge = self.dtype(edge_eps)
        self.packets = bool(packets)
        self._start_packet_count()

    def _run(self, origins, dirs, tmin, tmax, anyhit, counters, normals=False, as_run=False):
        counters = checked_flag(counters, "counters")
        normals = checked_flag(normals, "normals")
        as_run = checked_flag(as_run, "as_run")
        o, d, lo, hi = _rays(origins, dirs, tmin, tmax, self.dtype)
        if self.unit_range is not None:
            self.unit_range.check(o, d)
        n = len(o)
        prim, t, u, v, ng = _answers(n, anyhit, normals, self.dtype)
        cnt = np.zeros((n if counters else 0, 2), np.int64)
        nchunks = (n + CHUNK_RAYS - 1) // CHUNK_RAYS
        over = np.zeros(nchunks, np.int64)
        traced = np.zeros(nchunks, np.int64)
        packets = self.packets and (as_run or not counters) and self.raw is None
        run_ranges(trace_chunks, nchunks, self._u1, self._f1, self.index_bytes, self._tris1,
                   self.row_of, self.raw, o, d, o.reshape(-1), d.reshape(-1), lo, hi, self.eps2,
                   self.one, self.widen, self.edge, self.depth, anyhit, packets, prim, t, u, v, ng,
                   cnt, over, traced, min_items=MIN_RANGE_CHUNKS)
        self._count_packets(traced)
        if over.any():
            raise RuntimeError(f"traversal stack overflow on {over.sum()} rays: the tree is deeper "
                               f"than its recorded depth {self.depth} (corrupted tree?)")
        return prim, t, u, v, (ng if normals else None), (cnt if counters else None)

    def intersect(self, origins, dirs, tmin=0.0, tmax=np.inf, counters=False, normals=True,
                  as_run=False):
        """Closest hit per ray in [tmin, tmax] (scalars or (n,) arrays). ``normals=False``
        skips the geometric normals (ng is then None) for callers that look them up. A ray
        with a NaN or infinite coordinate, a zero direction or tmin > tmax misses (prim -1),
        as in Embree: a batch may hold such rays without failing as a whole. A batch whose rays
        would take the units' products out of their range (origins far from the triangles
        against their size, directions far longer or shorter than unit length) is refused
        whole, with a ParameterError naming ``origins`` or ``dirs``, rather than traced to lost
        hits.
        ``counters``: nodes visited and triangles tested per ray, by the single-ray unit; with
        ``as_run`` as the query actually runs them (a packet's rays each count every node and
        triangle the packet tests)."""
        prim, t, u, v, ng, cnt = self._run(origins, dirs, tmin, tmax, False, counters, normals, as_run)
        return Hits(t=t, prim=prim, u=u, v=v, ng=ng, counters=cnt)

    def occluded(self, origins, dirs, tmin=0.0, tmax=np.inf, counters=False, as_run=False):
        """True where any triangle is hit in [tmin, tmax]; returns (blocked, counters or None)
        when counters=True (``as_run`` as for :meth:`intersect`)."""
        prim, _, _, _, _, cnt = self._run(origins, dirs, tmin, tmax, True, counters, False, as_run)
        return (prim >= 0, cnt) if counters else prim >= 0


def compile_kernels(precision="float32"):
    """Compile the traversal kernel that ``Tracer`` queries run (or load it from Numba's
    on-disk cache) without building a tree: a tracer on a one-leaf tree answers an empty batch,
    which compiles the kernel for exactly the argument types of a real query. Lets another
    process compile the traversal while a first render compiles the builder and the shading
    (``raytracer.render.warm_up``). Returns seconds."""
    from hwbvh.format import NODE_DTYPE
    from types import SimpleNamespace

    t = time.perf_counter()
    leaf = np.zeros(1, NODE_DTYPE)
    leaf["bounds"][0] = (0, 0, 0, 1, 1, 0)
    leaf["b"][0] = 1                                   # one primitive, at index position 0
    leaf["flags"][0] = LEAF_FLAG
    triangle = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float32)
    # one leaf holding its triangle: valid as made (validating would load another kernel)
    tracer = Tracer(SimpleNamespace(nodes=leaf, indices=np.zeros(1, np.int64), triangles=triangle,
                                    _invariants_hold=True), precision=precision)
    none = np.zeros((0, 3), tracer.dtype)
    tracer.intersect(none, none, normals=False)
    return time.perf_counter() - t
