"""Meshes generated in code, so tests and benchmarks need no downloads.

Every function returns float32 triangles ``(n, 3, 3)``; sizes are chosen by the caller.
"""
import numpy as np


def grid_sheet(nx, ny, size=2.0, wave=0.15, seed=None):
    """A cloth-like tessellated sheet in the xz plane (2*nx*ny triangles), gently waved."""
    xs = np.linspace(-size / 2, size / 2, nx + 1)
    zs = np.linspace(-size / 2, size / 2, ny + 1)
    X, Z = np.meshgrid(xs, zs, indexing="ij")
    Y = wave * np.sin(3.0 * X) * np.cos(2.0 * Z)
    V = np.stack([X, Y, Z], axis=-1).reshape(-1, 3)
    i = np.arange(nx)[:, None] * (ny + 1) + np.arange(ny)[None, :]
    i = i.ravel()
    a, b, c, d = i, i + (ny + 1), i + (ny + 1) + 1, i + 1
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return V[F].astype(np.float32)


def uv_sphere(n_lat, n_lon, radius=1.0, center=(0.0, 0.0, 0.0)):
    """A closed UV sphere as an indexed mesh: (vertices (v,3) float64, faces (f,3) int64).
    Poles are single vertices, so the surface is watertight (2*n_lon*(n_lat-1) triangles)."""
    th = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    ph = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    ring = np.stack([np.sin(T) * np.cos(P), np.cos(T), np.sin(T) * np.sin(P)], -1).reshape(-1, 3)
    V = np.concatenate([[[0, 1, 0]], ring, [[0, -1, 0]]]) * radius + np.asarray(center)
    top, bot = 0, len(V) - 1
    j = np.arange(n_lon)
    jn = (j + 1) % n_lon
    cap_top = np.stack([np.full(n_lon, top), 1 + jn, 1 + j], 1)
    r0 = 1 + np.arange(n_lat - 2)[:, None] * n_lon            # ring starts, (n_lat-2, 1)
    r1 = r0 + n_lon
    a = np.stack([r0 + j, r0 + jn, r1 + jn], -1).reshape(-1, 3)
    b = np.stack([r0 + j, r1 + jn, r1 + j], -1).reshape(-1, 3)
    band = np.stack([a, b], 1).reshape(-1, 3)                 # a, b interleaved per quad
    last = 1 + (n_lat - 2) * n_lon
    cap_bot = np.stack([last + j, last + jn, np.full(n_lon, bot)], 1)
    return V, np.concatenate([cap_top, band, cap_bot]).astype(np.int64)


def sphere(n_lat=32, n_lon=64, radius=1.0, center=(0.0, 0.0, 0.0)):
    V, F = uv_sphere(n_lat, n_lon, radius, center)
    return V[F].astype(np.float32)


def random_soup(n, seed=0, extent=1.0, size=0.05):
    """n random small triangles in a cube: the classic builder stress input."""
    rng = np.random.default_rng(seed)
    c = rng.uniform(-extent, extent, (n, 1, 3))
    return (c + rng.normal(0, size, (n, 3, 3))).astype(np.float32)


def bumpy_sphere(n_target, seed=0):
    """A large closed, noisy sphere of about n_target triangles (scale tests)."""
    n_lon = max(8, int(np.sqrt(n_target)))
    n_lat = max(4, n_target // (2 * n_lon) + 1)
    V, F = uv_sphere(n_lat, n_lon)
    rng = np.random.default_rng(seed)
    V = V * (1.0 + 0.02 * rng.standard_normal((len(V), 1)))
    return V[F].astype(np.float32)


GENERATED = {
    "sheet-20k": lambda: grid_sheet(100, 100),
    "sphere-32k": lambda: sphere(128, 128),
    "soup-50k": lambda: random_soup(50_000),
}
