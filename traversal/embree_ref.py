"""Intel Embree through embreex: the reference for every hit, and the peer in benchmarks.

embreex conventions (checked against embreex 4.4): ``tnear`` is fixed at 0; ``dists`` sets the
initial ``tfar``; a miss has primID -1 and tfar 1e37 (or the given dists); u, v and Ng of a
missed ray are stale and must not be read; ``query='OCCLUDED'`` returns 0 for occluded rays and
-1 otherwise. A robust scene (``robust=True``, RTC_SCENE_FLAG_ROBUST) avoids the fast path's
missed edge hits, which is what a reference should do.
"""
import time

import numpy as np

from hwbvh.errors import ParameterError, checked_flag
from hwbvh.parallel import run_ranges
from hwbvh.primitives import within_bound
from .api import _interval, ray_arrays, real_array
from .config import EMBREE_CHUNK_RAYS


def indexed_mesh(vertices, faces):
    """(vertices float32 (k, 3), faces int64 (m, 3)) of an indexed mesh, refused with a
    ParameterError naming the argument unless the vertices are real (k, 3) coordinates, finite
    in float32, and the faces (m, 3) integers in [0, k): embreex reads faces as int32 vertex
    ids and would read past the vertex buffer, truncate fractional ids, or regroup a flat
    array into other triangles."""
    V = real_array(vertices, "vertices")
    if V.ndim != 2 or V.shape[1] != 3:
        raise ParameterError("vertices", f"must be (k, 3), got shape {V.shape}")
    with np.errstate(over="ignore"):            # beyond float32's range is refused just below
        V = np.ascontiguousarray(V, dtype=np.float32)
    if not within_bound(V, np.finfo(np.float32).max):      # NaN and inf both fail
        bad = int(np.argmin(np.isfinite(V).all(axis=1)))
        raise ParameterError("vertices", f"vertex {bad} has a NaN or infinite coordinate "
                                         "(in float32)")
    F = np.asarray(faces)
    if F.dtype.kind not in "iu":
        raise ParameterError("faces", f"must be integers (vertex ids), got {F.dtype}")
    if F.ndim != 2 or F.shape[1] != 3:
        raise ParameterError("faces", f"must be (m, 3), got shape {F.shape}")
    F = F.astype(np.int64)
    if F.size and (F.min() < 0 or F.max() >= len(V)):
        bad = int(np.argmax(((F < 0) | (F >= len(V))).any(axis=1)))
        raise ParameterError("faces", f"face {bad} has a vertex id outside [0, {len(V)}): "
                                      f"{F[bad].tolist()}")
    return V, F


def mesh_of(triangles, vertices, faces):
    """``indexed_mesh`` of ``vertices``/``faces``, refused (ParameterError naming ``faces``)
    unless ``vertices[faces]`` are ``triangles`` (float32 (n, 3, 3)) as float32: Embree would
    trace other geometry than the tracer it checks."""
    V, F = indexed_mesh(vertices, faces)
    if len(F) != len(triangles) or not np.array_equal(V[F], triangles):
        raise ParameterError("faces", "vertices[faces] are not the triangles checked: Embree "
                                      "would trace other geometry than the tracer")
    return V, F


def _commit(V, F, robust):
    """An Embree scene of a checked mesh (``indexed_mesh``), built and committed."""
    from embreex import rtcore_scene as rs
    from embreex.mesh_construction import TriangleMesh

    scene = rs.EmbreeScene(robust=robust)
    TriangleMesh(scene, V, np.ascontiguousarray(F, dtype=np.int32))
    # embreex commits lazily on the first query; one ray makes the build part of this call
    scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))
    return scene


def embree_scene(vertices, faces, robust=True):
    """Build and commit an Embree scene from an indexed mesh (checked by ``indexed_mesh``)."""
    return _commit(*indexed_mesh(vertices, faces), robust)


def shared_vertices(vertices, faces):
    """The same triangles as an indexed mesh whose vertices are unique (bitwise): what an Embree
    user hands over. A triangle soup (three vertices per face) makes Embree's build read and
    transform three times the vertices, so timing it would not be timing Embree fairly.
    Returns (float32 vertices, int32 faces); the input is checked by ``indexed_mesh``."""
    V, F = indexed_mesh(vertices, faces)
    if len(V) == 0:
        return V, np.ascontiguousarray(F, dtype=np.int32)
    rows = V.view(np.dtype((np.void, V.dtype.itemsize * 3))).ravel()
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    return V[first], inverse.reshape(-1)[F].astype(np.int32)


def embree_build_seconds(vertices, faces, robust=True):
    """Seconds Embree takes to build and commit the scene (the input is checked first, outside
    the time)."""
    V, F = indexed_mesh(vertices, faces)
    F = np.ascontiguousarray(F, dtype=np.int32)
    t = time.perf_counter()
    _commit(V, F, robust)
    return time.perf_counter() - t


def _chunk_count(n):
    return max(1, n // EMBREE_CHUNK_RAYS)


def _embree_rays(origins, dirs, tmax):
    """float32 (n, 3) rays and a writable float32 copy of their t_max (embreex writes tfar
    into it), checked as ``traversal.Tracer`` checks its rays (ParameterError naming the
    argument); also whether each ray's interval [0, tmax] is empty (tmax < 0), judged before
    the float32 rounding, which could turn a tiny negative into -0."""
    o, d = ray_arrays(origins, dirs, np.float32)
    n = len(o)
    if tmax is None:
        return o, d, None, None
    hi = _interval(tmax, n, np.float64, "tmax")
    with np.errstate(over="ignore"):            # beyond float32's range is as good as inf
        return o, d, np.array(hi, dtype=np.float32), hi < 0


def embree_intersect(scene, origins, dirs, tmax=None):
    """Closest hits: (t float64 with inf for a miss, prim int64 -1 miss, u, v, Ng (n,3)).
    ``tmax``: None (no limit), a number or one per ray. The rays are traced in chunks on the
    same threads as our traversal (see ``EMBREE_CHUNK_RAYS``)."""
    o, d, dist, _ = _embree_rays(origins, dirs, tmax)
    n = len(o)
    t = np.empty(n)
    prim = np.empty(n, np.int64)
    u = np.empty(n, np.float32)
    v = np.empty(n, np.float32)
    ng = np.empty((n, 3), np.float32)

    def chunks(c0, c1):
        lo, hi = n * c0 // chunk_count, n * c1 // chunk_count
        kw = {} if dist is None else {"dists": dist[lo:hi]}
        r = scene.run(o[lo:hi], d[lo:hi], output=1, **kw)
        p = r["primID"]
        miss = p < 0
        prim[lo:hi] = p
        t[lo:hi] = np.where(miss, np.inf, r["tfar"])
        u[lo:hi] = np.where(miss, 0, r["u"])
        v[lo:hi] = np.where(miss, 0, r["v"])
        ng[lo:hi] = np.where(miss[:, None], 0, r["Ng"])

    chunk_count = _chunk_count(n)
    if n:
        run_ranges(chunks, chunk_count)
    return t, prim, u, v, ng


def embree_occluded(scene, origins, dirs, tmax):
    """Whether each ray is blocked in [0, tmax] (a number or one per ray); in chunks on our
    traversal's threads. A ray with an empty interval (tmax < 0) is not blocked, as in every
    tracer here: Embree itself reports such a ray as occluded."""
    o, d, dist, empty = _embree_rays(origins, dirs, tmax)
    # an infinite bound is passed as a large finite one, as every occluded query here has
    # always passed it to embreex
    if dist is not None:
        np.minimum(dist, np.float32(3e38), out=dist)
    n = len(o)
    blocked = np.empty(n, np.bool_)

    def chunks(c0, c1):
        lo, hi = n * c0 // chunk_count, n * c1 // chunk_count
        blocked[lo:hi] = scene.run(o[lo:hi], d[lo:hi], dists=dist[lo:hi], query="OCCLUDED") == 0

    chunk_count = _chunk_count(n)
    if n:
        run_ranges(chunks, chunk_count)
        blocked[empty] = False
    return blocked


class EmbreeTracer:
    """The tracer interface (``traversal.tracers``) on Embree: its own build, its own
    traversal. embreex fixes tnear at 0, so a t_min is applied by moving the origin along the
    ray."""

    name = "embree"
    has_counters = False
    concurrent = True                 # queries may come from several threads at once
    dtype = np.float32                # embreex takes float32 rays

    def __init__(self, vertices, faces, robust=True):
        self.scene = embree_scene(vertices, faces, robust)
        self.n_triangles = len(faces)           # embree_scene checked them: (m, 3) indices
        self._mesh = (vertices, faces)
        self._triangles = None

    @property
    def triangles(self):
        """The (n, 3, 3) float32 triangles traced, made when first asked for (outside the
        build, which a benchmark times against ours)."""
        if self._triangles is None:
            vertices, faces = self._mesh
            self._triangles = np.asarray(vertices, np.float32)[np.asarray(faces, np.int64)]
        return self._triangles

    def intersect(self, origins, dirs, tmin=0.0, tmax=np.inf, normals=True):
        from .api import Hits
        from .tracers import _shifted
        normals = checked_flag(normals, "normals")
        o, d, lo, hi = _shifted(origins, dirs, tmin, tmax)
        t, prim, u, v, ng = embree_intersect(self.scene, o, d, None if np.isinf(hi).all() else hi)
        return Hits(t=(t + lo).astype(np.float32), prim=prim.astype(np.int32), u=u, v=v,
                    ng=ng if normals else None)

    def occluded(self, origins, dirs, tmin=0.0, tmax=np.inf):
        from .tracers import _shifted
        o, d, lo, hi = _shifted(origins, dirs, tmin, tmax)
        return embree_occluded(self.scene, o, d, hi)
