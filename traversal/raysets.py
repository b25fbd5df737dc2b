"""The ray sets of the verification and the benchmarks: primary, incoherent, shadow, bounces.

Each returns exactly the ``n`` rays asked for. Shadow rays and bounces start at surface hits, so
they are drawn from more first rays than ``n`` until ``n`` of them hit; only a mesh that almost
no first ray hits can give fewer (``len`` of the result says how many).
"""
import numpy as np

from .camera import frame_bounds, primary_rays, tile_order
from .offset import offset_origins


def bounds_of(tris):
    p = np.asarray(tris, np.float64).reshape(-1, 3)
    return p.min(0), p.max(0)


# Hit-based sets draw n first rays, then (from the hit rate seen) more, growing at most
# HIT_GROWTH-fold per round for HIT_ROUNDS rounds: enough for any mesh that one first ray in 16
# hits, while memory stays bounded (n = 10^6 shadow rays never needs more than 1.6e7 first rays).
HIT_GROWTH = 4
HIT_ROUNDS = 2


def primary(tris, n):
    """n camera rays of a 4:3 view framing the mesh, in 4x4 pixel tiles (the image is the
    smallest 4:3 one with at least n pixels; the last tiles are left out)."""
    n = int(n)
    lo, hi = bounds_of(tris)
    eye, target, up = frame_bounds(lo, hi)
    w = max(1, int(np.ceil(np.sqrt(n * 4 / 3))))
    h = max(1, -(-n // w))
    o, d = primary_rays(eye, target, up, 40.0, w, h)
    order = tile_order(w, h)[:n]            # in 4x4 pixel tiles, as a renderer issues them
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


def _n_hits(tracer, tris, n, first_rays, spread):
    """(o, d, points, normals, magnitudes) of n first hits of ``first_rays(m)`` (m rays), m
    grown until n hit. ``spread``: pick the n evenly from all hits (coherent sets keep covering
    the whole view) rather than the first n (random sets)."""
    n = int(n)
    m = max(n, 1)
    for _ in range(HIT_ROUNDS + 1):
        o, d = first_rays(m)
        mask, p, ng, mag = hit_points(tracer, tris, o, d)
        k = len(p)
        if k >= n:
            break
        m = max(m + 16, int(m * min(HIT_GROWTH, max(1.1, 1.05 * n / max(k, 1)))))
    got = min(n, k)
    pick = (np.arange(got) * k) // max(got, 1) if spread else np.arange(got)
    return o[mask][pick], d[mask][pick], p[pick], ng[pick], mag[pick]


def shadow(tracer, tris, n):
    """n rays from first hits of primary rays toward a point light (tmax = the light)."""
    _, _, p, ng, mag = _n_hits(tracer, tris, n, lambda m: primary(tris, m), spread=True)
    L = light_position(tris)
    to = L - p
    dist = np.linalg.norm(to, axis=1)
    dl = to / dist[:, None]
    org = offset_origins(p, ng, dl, mag)
    return org, dl, np.linalg.norm(L - org, axis=1)


def bounces(tracer, tris, n, seed=1):
    """n secondary rays: mirror reflections of incoherent first hits plus random directions,
    from offset origins (self-intersection is part of what is verified)."""
    _, di, p, ng, mag = _n_hits(tracer, tris, n, lambda m: incoherent(tris, m, seed), spread=False)
    nn = ng / np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)
    refl = di - 2 * np.einsum("ij,ij->i", di, nn)[:, None] * nn
    rng = np.random.default_rng(seed + 1)
    rnd = rng.normal(size=refl.shape)
    rnd /= np.linalg.norm(rnd, axis=1, keepdims=True)
    half = len(refl) // 2
    dirs = np.concatenate([refl[:half], rnd[half:]])
    org = offset_origins(p, ng, dirs, mag)
    return org, dirs
