"""Intel Embree through embreex: the reference for every hit, and the peer in benchmarks.

embreex conventions (checked against embreex 4.4): ``tnear`` is fixed at 0; ``dists`` sets the
initial ``tfar``; a miss has primID -1 and tfar 1e37 (or the given dists); u, v and Ng of a
missed ray are stale and must not be read; ``query='OCCLUDED'`` returns 0 for occluded rays and
-1 otherwise. A robust scene (``robust=True``, RTC_SCENE_FLAG_ROBUST) avoids the fast path's
missed edge hits, which is what a reference should do.
"""
import time

import numpy as np

from hwbvh.parallel import run_ranges
from .config import EMBREE_CHUNK_RAYS

EMBREE_MISS_T = 1e37


def embree_scene(vertices, faces, robust=True):
    """Build and commit an Embree scene from an indexed mesh (float32 vertices, int32 faces)."""
    from embreex import rtcore_scene as rs
    from embreex.mesh_construction import TriangleMesh

    scene = rs.EmbreeScene(robust=robust)
    TriangleMesh(scene, np.ascontiguousarray(vertices, dtype=np.float32),
                 np.ascontiguousarray(faces, dtype=np.int32))
    # embreex commits lazily on the first query; one ray makes the build part of this call
    scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))
    return scene


def shared_vertices(vertices, faces):
    """The same triangles as an indexed mesh whose vertices are unique (bitwise): what an Embree
    user hands over. A triangle soup (three vertices per face) makes Embree's build read and
    transform three times the vertices, so timing it would not be timing Embree fairly.
    Returns (float32 vertices, int32 faces)."""
    V = np.ascontiguousarray(vertices, dtype=np.float32)
    F = np.asarray(faces, dtype=np.int64)
    if len(V) == 0:
        return V, np.ascontiguousarray(F, dtype=np.int32)
    rows = V.view(np.dtype((np.void, V.dtype.itemsize * 3))).ravel()
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    return V[first], inverse.reshape(-1)[F].astype(np.int32)


def embree_build_seconds(vertices, faces, robust=True):
    t = time.perf_counter()
    embree_scene(vertices, faces, robust)
    return time.perf_counter() - t


def _chunk_count(n):
    return max(1, n // EMBREE_CHUNK_RAYS)


def embree_intersect(scene, origins, dirs, tmax=None):
    """Closest hits: (t float64 with inf for a miss, prim int64 -1 miss, u, v, Ng (n,3)).
    The rays are traced in chunks on the same threads as our traversal (see
    ``EMBREE_CHUNK_RAYS``)."""
    o = np.ascontiguousarray(origins, dtype=np.float32)
    d = np.ascontiguousarray(dirs, dtype=np.float32)
    n = len(o)
    dist = None
    if tmax is not None:
        dist = np.array(np.broadcast_to(tmax, (n,)), dtype=np.float32)   # writable copy
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
    """Whether each ray is blocked before ``tmax``; in chunks on our traversal's threads."""
    o = np.ascontiguousarray(origins, dtype=np.float32)
    d = np.ascontiguousarray(dirs, dtype=np.float32)
    n = len(o)
    dist = np.array(np.broadcast_to(tmax, (n,)), dtype=np.float32)  # embreex writes tfar
    blocked = np.empty(n, np.bool_)

    def chunks(c0, c1):
        lo, hi = n * c0 // chunk_count, n * c1 // chunk_count
        blocked[lo:hi] = scene.run(o[lo:hi], d[lo:hi], dists=dist[lo:hi], query="OCCLUDED") == 0

    chunk_count = _chunk_count(n)
    if n:
        run_ranges(chunks, chunk_count)
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

    def intersect(self, origins, dirs, tmin=0.0, tmax=np.inf, normals=True):
        from .api import Hits
        from .tracers import _shifted
        o, d, lo, hi = _shifted(origins, dirs, tmin, tmax)
        t, prim, u, v, ng = embree_intersect(self.scene, o, d, None if np.isinf(hi).all() else hi)
        return Hits(t=(t + lo).astype(np.float32), prim=prim.astype(np.int32), u=u, v=v,
                    ng=ng if normals else None)

    def occluded(self, origins, dirs, tmin=0.0, tmax=np.inf):
        from .tracers import _shifted
        o, d, lo, hi = _shifted(origins, dirs, tmin, tmax)
        return embree_occluded(self.scene, o, d, np.minimum(hi, 3e38))
