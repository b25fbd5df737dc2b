"""The ray sets of the verification and the benchmarks: primary, incoherent, shadow, bounces."""
import numpy as np

from .camera import frame_bounds, primary_rays, tile_order
from .offset import offset_origins


def bounds_of(tris):
    p = np.asarray(tris, np.float64).reshape(-1, 3)
    return p.min(0), p.max(0)


def primary(tris, n):
    """Camera rays of a view framing the mesh, about n of them, in 4x4 pixel tiles."""
    lo, hi = bounds_of(tris)
    eye, target, up = frame_bounds(lo, hi)
    w = max(1, int(round(np.sqrt(n * 4 / 3))))
    h = max(1, n // w)
    o, d = primary_rays(eye, target, up, 40.0, w, h)
    order = tile_order(w, h)                # in 4x4 pixel tiles, as a renderer issues them
    return o[order], d[order]


def incoherent(tris, n, seed=0):
    lo, hi = bounds_of(tris)
    rng = np.random.default_rng(seed)
    o = rng.uniform(lo, hi, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o, d


def light_position(tris):
    lo, hi = bounds_of(tris)
    return (lo + hi) / 2 + np.array([0.3, 1.0, 0.6]) * np.linalg.norm(hi - lo)


def hit_points(tracer, tris, o, d):
    """First hits of (o, d) with our tracer: (mask, points, normals, triangle magnitudes)."""
    h = tracer.intersect(o, d)
    m = h.prim >= 0
    p = o[m] + d[m] * h.t[m, None].astype(np.float64)
    ng = h.ng[m].astype(np.float64)
    mag = np.abs(np.asarray(tris)[h.prim[m]]).reshape(-1, 9).max(axis=1)
    return m, p, ng, mag


def shadow(tracer, tris, n):
    """Rays from the first hits of primary rays toward a point light (tmax = the light)."""
    o, d = primary(tris, n)
    m, p, ng, mag = hit_points(tracer, tris, o, d)
    L = light_position(tris)
    to = L - p
    dist = np.linalg.norm(to, axis=1)
    dl = to / dist[:, None]
    org = offset_origins(p, ng, dl, mag)
    return org, dl, np.linalg.norm(L - org, axis=1)


def bounces(tracer, tris, n, seed=1):
    """Secondary rays: mirror reflections of incoherent first hits plus random hemisphere
    directions, from offset origins (self-intersection is part of what is verified)."""
    o, d = incoherent(tris, n, seed)
    m, p, ng, mag = hit_points(tracer, tris, o, d)
    nn = ng / np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)
    di = d[m]
    refl = di - 2 * np.einsum("ij,ij->i", di, nn)[:, None] * nn
    rng = np.random.default_rng(seed + 1)
    rnd = rng.normal(size=refl.shape)
    rnd /= np.linalg.norm(rnd, axis=1, keepdims=True)
    half = len(refl) // 2
    dirs = np.concatenate([refl[:half], rnd[half:]])
    org = offset_origins(p, ng, dirs, mag)
    return org, dirs
