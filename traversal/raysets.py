"""The ray sets of the verification and the benchmarks: primary, incoherent, shadow, bounces.

Each returns exactly the ``n`` rays asked for. Shadow rays and bounces start at surface hits, so
they are drawn from more first rays than ``n`` until ``n`` of them hit; only a mesh that almost
no first ray hits can give fewer (``len`` of the result says how many).
"""
import numpy as np

from hwbvh.errors import InputError, ParameterError, is_integer
from hwbvh.primitives import checked_coordinates
from .camera import directions_through, frame_bounds, look_at_basis, tile_pixels
from .config import HIT_GROWTH, HIT_ROUNDS, MAKE_CHUNK, MAX_RAYS
from .offset import offset_origins, points_on_planes


def checked_set_arguments(tris, n, seed=0, dtype=np.float64):
    """A ray set's arguments, refused with a ParameterError naming the argument (an
    InputError naming ``tris`` for a coordinate NaN, infinite or beyond the builder's bound):
    ``tris`` (m, 3, 3) real coordinates (m >= 1), ``n`` an integer of rays in
    1..``MAX_RAYS``, ``seed`` a non-negative integer, ``dtype`` float32 or float64. Returns
    the triangles as an array."""
    t = np.asarray(tris)
    if t.dtype.kind not in "fiu":
        raise ParameterError("tris", f"must be real numbers, got {t.dtype}")
    if t.ndim != 3 or t.shape[1:] != (3, 3) or len(t) == 0:
        raise ParameterError("tris", f"must be (m, 3, 3) with m >= 1, got shape {t.shape}")
    t = checked_coordinates(t, "tris")
    if not is_integer(n) or not 1 <= n <= MAX_RAYS:
        raise ParameterError("n", f"must be an integer from 1 to {MAX_RAYS} (rays), got {n!r}")
    if not is_integer(seed) or seed < 0:
        raise ParameterError("seed", f"must be a non-negative integer, got {seed!r}")
    try:
        known = np.dtype(dtype) in (np.float32, np.float64)
    except TypeError:
        known = False
    if not known:
        raise ParameterError("dtype", f"must be float32 or float64, got {dtype!r}")
    return t


def check_extent(points, source):
    """InputError naming ``source`` when the points (triangles' vertices, any shape of 3-vectors)
    all coincide: a view framing their box (``primary``'s, a mesh scene's camera) needs a box
    with extent."""
    lo, hi = bounds_of(points)
    if not (hi > lo).any():
        raise InputError(source, "its triangles' vertices all coincide; nothing to frame")


def bounds_of(tris):
    p = np.asarray(tris, np.float64).reshape(-1, 3)
    return p.min(0), p.max(0)


def _primary_view(tris, n):
    """The view of ``primary``: (eye, basis (u, v, w), width, height)."""
    check_extent(tris, "tris")
    lo, hi = bounds_of(tris)
    eye, target, up = frame_bounds(lo, hi)
    w = max(1, int(np.ceil(np.sqrt(n * 4 / 3))))
    h = max(1, -(-n // w))
    return eye, look_at_basis(eye, target, up), w, h


def points_beyond(tris):
    """Where the rays of every set start or head for outside the mesh's box: the eye of
    ``primary``'s view and the light of ``shadow``'s (the others start within the box or on
    the mesh). (2, 3) float64."""
    return np.array([_primary_view(tris, 1)[0], light_position(tris)], np.float64)


def primary_chunks(tris, n, dtype=np.float64):
    """``primary``'s rays, a slice of up to ``MAKE_CHUNK`` at a time: (origins, dirs)."""
    return _primary_chunks(checked_set_arguments(tris, n, dtype=dtype), n, dtype)


def _primary_chunks(tris, n, dtype):
    """``primary_chunks`` of checked arguments."""
    n = int(n)
    eye, basis, w, h = _primary_view(tris, n)
    for a in range(0, n, MAKE_CHUNK):
        # as camera.primary_rays, pixel by pixel of the slice
        y, x = np.divmod(tile_pixels(np.arange(a, min(n, a + MAKE_CHUNK)), w, h), w)
        d = directions_through(x + 0.5, y + 0.5, w, h, basis, 40.0)
        yield np.broadcast_to(eye.astype(dtype), d.shape).copy(), d.astype(dtype, copy=False)


def primary(tris, n, dtype=np.float64):
    """n camera rays of a 4:3 view framing the mesh, in 4x4 pixel tiles (the image is the
    smallest 4:3 one with at least n pixels; the last tiles are left out). The rays are
    computed in float64 and stored in ``dtype`` (float32: as the float32 tracers take them)."""
    return _joined(_primary_chunks(checked_set_arguments(tris, n, dtype=dtype), n, dtype), n, dtype)


def incoherent_chunks(tris, n, seed=0, dtype=np.float64):
    """``incoherent``'s rays, a slice of up to ``MAKE_CHUNK`` at a time: (origins, dirs). The
    stream holds the n origins, then the n directions: the directions come from a second
    generator advanced past the origins' 3n draws (one 64-bit draw per uniform)."""
    return _incoherent_chunks(checked_set_arguments(tris, n, seed, dtype), n, seed, dtype)


def _incoherent_chunks(tris, n, seed, dtype):
    """``incoherent_chunks`` of checked arguments."""
    n = int(n)
    lo, hi = bounds_of(tris)
    rng_o = np.random.default_rng(seed)
    rng_d = np.random.default_rng(seed)
    rng_d.bit_generator.advance(3 * n)
    for a in range(0, n, MAKE_CHUNK):
        m = min(MAKE_CHUNK, n - a)
        o = rng_o.uniform(lo, hi, (m, 3))
        d = rng_d.normal(size=(m, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        yield o.astype(dtype, copy=False), d.astype(dtype, copy=False)


def incoherent(tris, n, seed=0, dtype=np.float64):
    """n rays from uniform points of the mesh's box in uniform directions: the stream of
    ``default_rng(seed)``, n origins then n directions, computed in float64 and stored in
    ``dtype``."""
    return _joined(_incoherent_chunks(checked_set_arguments(tris, n, seed, dtype), n, seed, dtype), n,
                   dtype)


def _joined(chunks, n, dtype):
    o = np.empty((n, 3), dtype)
    d = np.empty((n, 3), dtype)
    a = 0
    for oc, dc in chunks:
        o[a:a + len(oc)] = oc
        d[a:a + len(dc)] = dc
        a += len(oc)
    return o, d


def light_position(tris):
    lo, hi = bounds_of(tris)
    return (lo + hi) / 2 + np.array([0.3, 1.0, 0.6]) * np.linalg.norm(hi - lo)


def hit_points(tracer, tris, tri_mag, chunks, keep_dirs=False, enough=None):
    """First hits of the rays of ``chunks`` (slices of (origins, dirs)) with our tracer on
    triangles ``tris``: (rays drawn, points (float64, at t along the rays as given, then onto
    their triangles' planes as the renderer puts them), normals (float32), the hit
    triangles' ``tri_mag``, and with ``keep_dirs`` their rays' directions, as given). A slice
    at a time, so that only the hits' arrays grow with the set; with ``enough``, no slice is
    traced once that many hits are in."""
    fields = ([], [], [], [])
    m = got = 0
    for o, d in chunks:
        if enough is not None and got >= enough:
            break
        h = tracer.intersect(o, d)
        hit = h.prim >= 0
        dc = d[hit]
        points = points_on_planes(
            o[hit].astype(np.float64) + dc.astype(np.float64) * h.t[hit, None].astype(np.float64),
            tris, h.prim[hit])
        for field, x in zip(fields, (points, h.ng[hit], tri_mag[h.prim[hit]],
                                     dc if keep_dirs else dc[:0])):
            field.append(x)
        m += len(o)
        got += int(hit.sum())
    if not fields[0]:
        return (m, np.empty((0, 3)), np.empty((0, 3), np.float32), tri_mag[:0], np.empty((0, 3)))
    # joined field by field, each slice let go once copied: the hits are held once, not twice
    joined = []
    for field in fields:
        joined.append(np.concatenate(field))
        field.clear()
    return (m, *joined)


def _n_hits(tracer, tris, n, first_rays, spread, keep_dirs=False):
    """(points, normals, magnitudes, directions or none) of n first hits of the rays of
    ``first_rays(m)`` (slices of m rays, float32 as the tracer takes them), m grown until n
    hit. ``spread``: pick the n evenly from all hits (coherent sets keep covering the whole
    view) rather than the first n (random sets)."""
    n = int(n)
    m = max(n, 1)
    # held in float32: the scale of a triangle's rounding, for offsets (exact for the float32
    # triangles the tracers take), in half the memory a set of 2^26 hits holds
    tri_mag = np.abs(np.asarray(tris, np.float64)).reshape(-1, 9).max(axis=1).astype(np.float32)
    tris = np.asarray(tris, np.float32)             # as the tracers take them
    for _ in range(HIT_ROUNDS + 1):
        # the first n hits are all a set that is not spread takes
        _, p, ng, mag, di = hit_points(tracer, tris, tri_mag, first_rays(m), keep_dirs,
                                       None if spread else n)
        k = len(p)
        if k >= n:
            break
        m = max(m + 16, int(m * min(HIT_GROWTH, max(1.1, 1.05 * n / max(k, 1)))))
    got = min(n, k)
    # the first n: views, not copies
    pick = (np.arange(got) * k) // max(got, 1) if spread else slice(0, got)
    return p[pick], ng[pick], mag[pick], di[pick] if keep_dirs else di


def shadow(tracer, tris, n, dtype=np.float64):
    """n rays from first hits of primary rays toward a point light (tmax = the light), stored
    in ``dtype`` (computed in float64, a slice at a time)."""
    tris = checked_set_arguments(tris, n, dtype=dtype)
    p, ng, mag, _ = _n_hits(tracer, tris, n, lambda m: _primary_chunks(tris, m, np.float32),
                            spread=True)
    L = light_position(tris)
    k = len(p)
    org, dirs, tmax = np.empty((k, 3), dtype), np.empty((k, 3), dtype), np.empty(k, dtype)
    for a in range(0, k, MAKE_CHUNK):
        b = min(k, a + MAKE_CHUNK)
        to = L - p[a:b]
        dl = to / np.linalg.norm(to, axis=1)[:, None]
        o = offset_origins(p[a:b], ng[a:b], dl, mag[a:b])
        org[a:b], dirs[a:b], tmax[a:b] = o, dl, np.linalg.norm(L - o, axis=1)
    return org, dirs, tmax


def bounces(tracer, tris, n, seed=1, dtype=np.float64):
    """n secondary rays: mirror reflections of incoherent first hits plus random directions,
    from offset origins (self-intersection is part of what is verified); stored in ``dtype``
    (computed in float64, a slice at a time)."""
    tris = checked_set_arguments(tris, n, seed, dtype)
    p, ng, mag, di = _n_hits(tracer, tris, n,
                             lambda m: _incoherent_chunks(tris, m, seed, np.float32),
                             spread=False, keep_dirs=True)
    k = len(p)
    half = k // 2
    # the random directions: rows half.. of k normals of default_rng(seed + 1) (the first half
    # drawn and passed over: a normal takes a varying number of the stream's draws)
    rng = np.random.default_rng(seed + 1)
    for a in range(0, half, MAKE_CHUNK):
        rng.normal(size=(min(MAKE_CHUNK, half - a), 3))
    org, dirs = np.empty((k, 3), dtype), np.empty((k, 3), dtype)
    for a in range(0, k, MAKE_CHUNK):
        b = min(k, a + MAKE_CHUNK)
        g = ng[a:b].astype(np.float64)
        nn = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-300)
        da = di[a:b].astype(np.float64)
        out = da - 2 * np.einsum("ij,ij->i", da, nn)[:, None] * nn
        rest = max(b, half) - max(a, half)
        if rest:
            rnd = rng.normal(size=(rest, 3))
            rnd /= np.linalg.norm(rnd, axis=1, keepdims=True)
            out[max(a, half) - a:] = rnd
        o = offset_origins(p[a:b], ng[a:b], out, mag[a:b])
        org[a:b], dirs[a:b] = o, out
    return org, dirs
