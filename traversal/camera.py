"""Pinhole camera (look-at, vertical field of view, resolution) producing ray arrays."""
import numpy as np

from hwbvh.errors import ParameterError, is_integer
from .config import FOV_RANGE, PACKET_RAYS

TILE = int(round(np.sqrt(PACKET_RAYS)))   # camera tiles of TILE x TILE pixels: one packet


def _power_of_two_scaled(x):
    """``x`` times the power of two that brings its largest magnitude into [1, 2) (zero stays
    zero). A power of two scales exactly, so a norm taken afterwards neither underflows (an
    eye 1e-200 from its target: the squares are 1e-400) nor overflows, and ``x / norm(x)`` has
    the same bits as without the scaling wherever that did not underflow."""
    m = np.max(np.abs(x))
    return x if m == 0 else np.ldexp(x, 1 - np.frexp(m)[1])


def look_at_basis(eye, target, up):
    """Orthonormal camera basis (right u, up v, forward w) of an eye looking at a target that
    differs from it by any amount. An ``up`` parallel to the view direction (or zero) gives
    no roll, so another up is chosen."""
    eye = np.asarray(eye, np.float64)
    w = _power_of_two_scaled(np.asarray(target, np.float64) - eye)
    w /= np.linalg.norm(w)
    up = _power_of_two_scaled(np.asarray(up, np.float64))
    u = np.cross(w, up)
    # looking along up (sine of the angle between them at most 1e-12, whatever up's length):
    # pick another up
    if np.linalg.norm(u) <= 1e-12 * np.linalg.norm(up):
        u = np.cross(w, [1.0, 0.0, 0.0] if abs(w[0]) < 0.9 else [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(u, w)
    return u, v, w


def primary_rays(eye, target, up, fov_deg, width, height, jitter=None):
    """Rays through pixel centres (or centre + jitter in [-0.5, 0.5)^2, shape (h*w, 2)), row-major
    from the top-left. Returns (origins (n,3) float64, dirs (n,3) float64 normalised)."""
    check_camera(eye, target, up, fov_deg)
    for name, v in (("width", width), ("height", height)):
        if not is_integer(v) or v < 1:
            raise ParameterError(name, f"expected a positive integer, got {v!r}")
    if jitter is not None and np.shape(jitter) != (width * height, 2):
        raise ParameterError("jitter", f"expected shape ({width * height}, 2), one offset per "
                                       f"pixel, got {np.shape(jitter)}")
    ys, xs = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    px = xs.ravel() + 0.5
    py = ys.ravel() + 0.5
    if jitter is not None:
        px = px + jitter[:, 0]
        py = py + jitter[:, 1]
    d = directions_through(px, py, width, height, look_at_basis(eye, target, up), fov_deg)
    o = np.broadcast_to(np.asarray(eye, np.float64), d.shape).copy()
    return o, d


# What ``check_camera`` calls a camera's settings: ``primary_rays``' arguments ("apart": the
# name for eye and target together, when they coincide)
CAMERA_ARGUMENTS = {"eye": "eye", "target": "target", "up": "up", "fov": "fov_deg",
                    "apart": "target"}


def check_camera(eye, target, up, fov_deg, names=CAMERA_ARGUMENTS):
    """ParameterError naming (``names``) the first setting of a pinhole camera that cannot
    make rays: eye, target and up must be 3 finite numbers, the eye apart from its target, up
    not zero, and the vertical field of view in ``FOV_RANGE`` degrees."""
    vectors = []
    for key, v in (("eye", eye), ("target", target), ("up", up)):
        try:
            a = np.asarray(v, np.float64)
        except (TypeError, ValueError):
            a = None
        if a is None or a.shape != (3,) or not np.isfinite(a).all():
            raise ParameterError(names[key], f"must be 3 finite numbers, got {v!r}")
        vectors.append(a)
    if np.array_equal(vectors[0], vectors[1]) or not np.any(vectors[2]):
        raise ParameterError(names["apart"], "needs an eye apart from its target and an up that "
                                             "is not zero")
    lo, hi = FOV_RANGE
    if isinstance(fov_deg, (bool, np.bool_)) or not isinstance(fov_deg, (int, float, np.number)) \
            or not lo <= fov_deg <= hi:
        raise ParameterError(names["fov"], f"must be in [{lo}, {hi}] degrees, got {fov_deg!r}")


def directions_through(px, py, width, height, basis, fov_deg):
    """Unit directions (float64 (n, 3)) through image points (px, py) (pixel units from the
    top-left) of a ``width`` x ``height`` pinhole camera with ``basis`` (``look_at_basis``)."""
    u, v, w = basis
    half = np.tan(np.radians(fov_deg) / 2)
    sx = (2 * px / width - 1) * half * (width / height)
    sy = (1 - 2 * py / height) * half
    d = sx[:, None] * u + sy[:, None] * v + w
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d


def tile_order(width, height, tile=TILE):
    """Pixel indices (row-major numbering) listed tile by tile: ``tile`` x ``tile`` squares, row
    by row inside a tile, tiles row by row; partial tiles at the right and bottom edges. A
    renderer issues its camera rays in this order so that 16 consecutive rays are a 4x4 block
    of neighbours, which the packet traversal needs (``traversal.packet``)."""
    return tile_pixels(np.arange(width * height), width, height, tile)


def tile_pixels(k, width, height, tile=TILE):
    """Row-major pixel indices of positions ``k`` (an int64 array) of ``tile_order``: a row
    of tiles holds ``tile`` image rows (fewer in the last), its tiles ``tile`` columns each
    (fewer in the last), so a position's row of tiles, tile and place in it follow by
    division, without the order of every pixel."""
    band = k // (tile * width)                          # the row of tiles
    rows = np.minimum(tile, height - band * tile)       # image rows in it
    j = k - band * tile * width
    tx = (j // (tile * rows)) * tile                    # the tile's first column
    cols = np.minimum(tile, width - tx)
    q = j - (tx // tile) * tile * rows
    return (band * tile + q // cols) * width + tx + q % cols


def frame_bounds(lo, hi, fov_deg=40.0, direction=(0.35, 0.45, 1.0)):
    """A camera (eye, target, up) that frames the box [lo, hi] from ``direction``."""
    lo = np.asarray(lo, np.float64)
    hi = np.asarray(hi, np.float64)
    c = (lo + hi) / 2
    r = max(np.linalg.norm(hi - lo) / 2, 1e-30)
    d = np.asarray(direction, np.float64)
    d /= np.linalg.norm(d)
    dist = r / np.sin(np.radians(fov_deg) / 2) * 1.05
    return c + d * dist, c, np.array([0.0, 1.0, 0.0])
