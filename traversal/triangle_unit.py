"""Moller-Trumbore triangle intersection unit (thesis appendix A, Figs. A.3/A.4, [MT97]; SPEC 7).

One ray against one triangle per call, with the unit's valid check: ``det`` outside the parallel
band, ``u >= 0``, ``v >= 0``, ``u + v <= 1``, ``t`` in ``[t_min, t_max]``.

The parallel band is *relative*: ``det^2 <= (k*eps)^2 |e1|^2 |e2|^2 |d|^2``. ``det = -d . (e1 x
e2)`` = ``|d| |e1| |e2| sin(a) sin(theta)`` (``a`` the ray's angle to the plane, ``theta`` the
angle at ``v0``), so this rejects rays with ``sin(a) sin(theta) <= k*eps``: within ``k*eps``
radians of a well-shaped triangle's plane whatever its size, more on slivers, where ``det`` is
below its own rounding noise (``~eps |d| |e1| |e2|``). An absolute epsilon would drop every hit
on a 1e-4-sized triangle (det ~ 1e-8).

Evaluated as written, its squares leave the float range long before the datapath does. In
float32 with ``|d|`` near 1: ``|e1|^2 |e2|^2`` and ``det^2`` overflow for edges above ~4e9, so
every ray on a 1e12-sized mesh read as parallel; the band turns subnormal below edges of ~5e-7,
zero below ~1e-8 (grazing rays no longer rejected) and ``det^2`` zero below ~5e-12, so every ray
on a 1e-12-sized mesh read as parallel; and ``|d|^2`` leaves the range for directions above
~2e19 or below ~1e-19 whatever the mesh. So both sides are scaled by powers of two before
squaring: ``det`` by ``c_T`` (per triangle, ``|e1| |e2| c_T`` in [0.5, 2)) and by ``c_R`` (per
ray, ``max |d_i| c_R`` in [1, 2)), ``|e1|^2 |e2|^2`` by ``c_T^2`` and ``|d|^2`` by ``c_R^2``.
Then every term of the test is near 1 (the smallest, ``(k*eps)^2``, is 2^-42 in float32; only
``det^2`` deep inside the band, which reads as inside either way, goes lower), for any triangle
and ray whose ``det`` is itself in range. A product with a power of two is exact and commutes with
rounding, so wherever every unscaled term was a normal number (all ordinary scenes: in float32,
edges from ~5e-7 to ~4e9 seen along directions near 1) the verdict is the same, bit for bit.

Triangles are preprocessed once into ``(n, TRI_WORDS)`` rows ``v0, e1, e2, |e1|^2 |e2|^2 c_T^2,
c_T`` (the vertex/edge form the unit's subtractors produce), in the working precision.
"""
import numpy as np
from numba import njit, types
from numba.extending import overload

from hwbvh.errors import ParameterError
from .config import BAND_K, F32_UNIT_MAX_PRODUCT, F32_UNIT_MIN_EDGES, F64_UNIT_MAX_PRODUCT

# A preprocessed triangle row: offsets of its words (x, y, z each) in the working float type.
TRI_V0 = 0            # vertex 0
TRI_E1 = 3            # e1 = v1 - v0
TRI_E2 = 6            # e2 = v2 - v0
TRI_NORMS = 9         # |e1|^2 |e2|^2 c_T^2, the scale of the parallel band (in [0.25, 4))
TRI_SCALE = 10        # c_T, the power of two that brings det to that scale
TRI_WORDS = 11

# ``store_normals``' row map for rows kept in primitive order (an empty map: row j is primitive j)
PRIMITIVE_ORDER = np.zeros(0, np.int32)


def edge_norms2(rows):
    """|e1|^2 and |e2|^2 (float64 (n,) each) of preprocessed ``rows``, from their stored
    edges. Column by column over 1-D strided views (NumPy on (n, 3) views and its sum over
    axis 1 take several times as long), summed x, y, z in order, as that sum does."""
    n1 = np.zeros(len(rows))
    n2 = np.zeros(len(rows))
    for c in range(3):
        e1 = rows[:, TRI_E1 + c].astype(np.float64)
        e2 = rows[:, TRI_E2 + c].astype(np.float64)
        n1 += e1 * e1
        n2 += e2 * e2
    return n1, n2


def _half_exponent(x):
    """h with x * 4^-h in [0.5, 2) (x > 0 finite; 0 for 0 and non-finite x), from float64 x."""
    return np.frexp(x)[1] // 2


def preprocess(tris, dtype=np.float32):
    """(n, 3, 3) triangles -> (n, TRI_WORDS) rows v0, e1, e2, |e1|^2 |e2|^2 c_T^2, c_T in
    ``dtype``. The squared norms are taken in float64 from the stored edges, each scaled by its
    own power of two before the product, so nothing overflows or underflows on the way.
    ``c_T`` stays a normal number of ``dtype``: where that clamps it (|e1| |e2| below 2^-127,
    edges under ~1e-19 in float32) the word drops below 0.25 instead, still a normal number
    for edges down to ~1e-28, far below where ``det`` itself underflows."""
    t = np.asarray(tris, dtype=dtype)
    out = np.empty((len(t), TRI_WORDS), dtype=dtype)
    for c in range(3):
        v0 = t[:, 0, c]
        out[:, TRI_V0 + c] = v0
        np.subtract(t[:, 1, c], v0, out=out[:, TRI_E1 + c])
        np.subtract(t[:, 2, c], v0, out=out[:, TRI_E2 + c])
    n1, n2 = edge_norms2(out)
    h1 = _half_exponent(n1)
    h2 = _half_exponent(n2)
    info = np.finfo(dtype)
    h = np.clip(h1 + h2, -info.maxexp + 1, -info.minexp)     # c_T = 2^-h, normal in dtype
    # n1 n2 4^-h, as (n1 4^-h1) (n2 4^-h2) 4^(h1 + h2 - h): the same rounding as n1 n2 in
    # float64 then scaled, without its overflow
    norms = np.ldexp(np.ldexp(n1, -2 * h1) * np.ldexp(n2, -2 * h2), 2 * (h1 + h2 - h))
    out[:, TRI_NORMS] = norms.astype(dtype)
    out[:, TRI_SCALE] = np.ldexp(1.0, -h).astype(dtype)
    return out


def f32_reach_bound(tri_mag, point_mag):
    """A bound on ``f32_unit_reach`` from magnitudes alone: triangles whose coordinates are at
    most ``tri_mag`` in magnitude, origins at most max(tri_mag, ``point_mag``) (NumPy arrays
    work element by element). An edge spans at most 2 sqrt(3) tri_mag, an origin lies at most
    2 sqrt(3) of the larger magnitude from a vertex."""
    k = 2 * np.sqrt(3)
    return (k * tri_mag) ** 2 * (k * np.maximum(tri_mag, point_mag))


def f32_unit_reach(triangles, points, box=None):
    """The largest |e1| |e2| |o - v0| the float32 unit can meet on ``triangles`` (n, 3, 3) with
    ray origins anywhere in the box of the triangles and ``points`` (k, 3) (a camera, lights):
    compare with ``config.F32_UNIT_MAX_PRODUCT``. A bound from the coordinates' magnitude comes
    first (one pass; ``box``: the triangles' ``coordinate_box``, if the caller has it); the
    edges are measured only where that bound is not small enough."""
    t = np.asarray(triangles)
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    lo, hi, m = coordinate_box(t) if box is None else box
    # from the largest magnitudes
    bound = f32_reach_bound(m, float(np.abs(pts).max(initial=0)))
    if bound <= F32_UNIT_MAX_PRODUCT:
        return bound
    lo = np.minimum(lo, pts.min(axis=0, initial=np.inf))
    hi = np.maximum(hi, pts.max(axis=0, initial=-np.inf))
    reach = float(np.linalg.norm(hi - lo))   # any origin to any vertex
    e1 = (t[:, 1] - t[:, 0]).astype(np.float64)
    e2 = (t[:, 2] - t[:, 0]).astype(np.float64)
    edges = float(np.sqrt(((e1 * e1).sum(1) * (e2 * e2).sum(1)).max()))
    return edges * reach


def coordinate_box(triangles):
    """(lo, hi, m): the box of ``triangles`` (n, 3, 3) (float64 (3,) each; +inf / -inf for
    none) and their largest |coordinate| (NaN if any coordinate is NaN, 0 for none). Axis by
    axis over strided views: NumPy's min over axis 0 of an (m, 3) array is some 25 times
    slower, and a compiled pass would add its compile time to a first render."""
    t = np.asarray(triangles)
    if t.size == 0:
        return np.full(3, np.inf), np.full(3, -np.inf), 0.0
    p = t.reshape(-1, 3)
    lo = np.array([p[:, k].min() for k in range(3)], np.float64)
    hi = np.array([p[:, k].max() for k in range(3)], np.float64)
    return lo, hi, float(max(np.abs(lo).max(), np.abs(hi).max()))


def span_of(box):
    """The diagonal of a ``coordinate_box``; 0 for an empty one."""
    lo, hi, _ = box
    return float(np.linalg.norm(hi - lo)) if np.all(hi >= lo) else 0.0


@njit(cache=True, nogil=True, inline="always")
def _largest_finite_f32(x):
    """The largest finite |x_k| of float32 ``x`` (0 for none), on the bit patterns: |x| is the
    pattern without its sign bit, ordered as the numbers are, and NaN and infinity lie at and
    above 0x7F800000; an integer maximum runs in SIMD lanes (a float one with the NaN test
    took ten times as long)."""
    bits = x.view(np.uint32)
    m = np.uint32(0)
    for k in range(bits.shape[0]):
        b = bits[k] & np.uint32(0x7FFFFFFF)
        b = b if b < np.uint32(0x7F800000) else np.uint32(0)
        m = max(m, b)
    return np.float64(np.array([m], np.uint32).view(np.float32)[0])


@njit(cache=True, nogil=True, inline="always")
def _direction_extremes_f32(d):
    """(largest finite |coordinate|, shortest direction) of float32 directions ``d``, rows of
    3 seen flat; a direction's length is taken as its largest |coordinate| (within sqrt(3) of
    it). A direction with a NaN or infinite coordinate, or of length 0 (it hits nothing in
    any unit), is passed over; none left: infinity as the shortest. On the bit patterns, as
    ``_largest_finite_f32``."""
    bits = d.view(np.uint32)
    inf = np.uint32(0x7F800000)
    big = np.uint32(0)
    short = inf
    for k in range(bits.shape[0] // 3):
        a = bits[3 * k] & np.uint32(0x7FFFFFFF)
        b = bits[3 * k + 1] & np.uint32(0x7FFFFFFF)
        c = bits[3 * k + 2] & np.uint32(0x7FFFFFFF)
        m = max(a, max(b, c))
        m = m if m < inf else np.uint32(0)
        big = max(big, m)
        short = min(short, m if m != 0 else inf)
    return (np.float64(np.array([big], np.uint32).view(np.float32)[0]),
            np.float64(np.array([short], np.uint32).view(np.float32)[0]))


@njit(cache=True, nogil=True)
def ray_magnitudes(o, d):
    """(largest finite |coordinate| of the origins, of the directions, shortest direction),
    from float32 rows seen flat (``_direction_extremes_f32``): a ray with a NaN or infinite
    coordinate misses in the kernels whatever the range, so it is passed over."""
    big, short = _direction_extremes_f32(d)
    return _largest_finite_f32(o), big, short


class Float32Range:
    """Whether a batch of rays keeps the float32 unit within float32's range on a tracer's
    triangles, checked before its kernels run (they trust their rays).

    The unit's products are |d| |e1| |e2| (det), |o - v0| |d| |e| (u and v) and
    |o - v0| |e1| |e2| (t); each bounded by ``MAX_PRODUCT`` (``config.F32_UNIT_MAX_PRODUCT``),
    none can leave the range. From the triangles, once: the largest |e1| |e2|, the longest
    edge and the largest coordinate magnitude. Per batch, one pass over the rays (``ray_magnitudes``) bounds
    |o - v0| by sqrt(3) (max |o_i| + the mesh's magnitude) and |d| by sqrt(3) max |d_i|; where
    that bound fails, the boxes of the origins and the triangles (as ``f32_unit_reach`` takes
    them) and the rays' own lengths decide, so a scene the renderer accepts is traced."""

    MAX_PRODUCT = F32_UNIT_MAX_PRODUCT
    MIN_EDGES = F32_UNIT_MIN_EDGES
    UNIT = "float32"
    REMEDY = "trace with traversal.Tracer(precision='float64'), or scale the scene down"

    def __init__(self, rows, triangles):
        """``rows``: the ``preprocess`` rows of ``triangles`` (n, 3, 3). Triangles whose
        largest |e1| |e2| is below ``MIN_EDGES`` are refused (ParameterError naming
        ``triangles``): every ray's determinant would leave the normal numbers."""
        n1, n2 = edge_norms2(rows)
        self.edges = float(np.sqrt((n1 * n2).max(initial=0)))
        self.longest = float(np.sqrt(max(n1.max(initial=0), n2.max(initial=0))))
        self.box = coordinate_box(triangles)
        if 0 < self.edges < self.MIN_EDGES:     # no triangle with area: nothing to lose
            raise ParameterError("triangles", f"too small for the {self.UNIT} unit: the largest "
                                              f"|e1| |e2| of its triangles is {self.edges:.3g}, "
                                              f"below the {self.MIN_EDGES:.3g} that keeps a unit "
                                              f"direction's determinant a normal number (hits "
                                              f"would be lost)",
                                              remedy=self.REMEDY.replace('down', 'up'))
        # the usual batch in one comparison: directions no coordinate of which passes 1 (at
        # most sqrt(3) long), origins within this magnitude; -1 when no batch is that simple
        k = np.sqrt(3.0)
        worst = max(self.edges, k * self.longest)
        with np.errstate(over="ignore"):            # float64's bound over tiny edges: inf
            self.origin_limit = -1.0 if k * self.edges > self.MAX_PRODUCT or worst == 0 else \
                self.MAX_PRODUCT / worst / k - self.box[2]

    def _magnitudes(self, o, d):
        """(largest finite |coordinate| of the origins, of the directions, the shortest
        direction: ``ray_magnitudes``)."""
        return ray_magnitudes(o.reshape(-1), d.reshape(-1))

    def _largest(self, dist, dlen):
        """The largest of the unit's products for origins ``dist`` from a vertex and
        directions of length ``dlen`` (infinity past float64's range)."""
        with np.errstate(over="ignore"):
            return max(dist * self.edges, dist * self.longest * max(dlen, 1.0), dlen * self.edges)

    def check(self, o, d):
        """ParameterError naming ``origins`` or ``dirs`` when the rays ``o``, ``d`` (n, 3)
        could take a product past the bound, or the determinant of the shortest direction
        with the largest triangle below ``MIN_EDGES`` (the triangles' own floor for a unit
        direction)."""
        if self.edges == 0 or len(o) == 0:          # no triangle can be hit / no ray
            return
        om, dm, shortest = self._magnitudes(o, d)
        # the determinant is at most |d| |e1| |e2|: as the triangles' own floor (__init__),
        # for the shortest direction, whose length is at most sqrt(3) its largest coordinate
        if np.sqrt(3.0) * shortest * self.edges < self.MIN_EDGES:
            raise ParameterError("dirs", f"directions whose largest coordinate is as small as "
                                         f"{shortest:.3g} take the {self.UNIT} unit's determinant "
                                         f"below {self.MIN_EDGES:.3g} with these triangles (whose "
                                         f"largest |e1| |e2| is {self.edges:.3g}), too close to "
                                         f"float32's subnormal numbers (hits would be lost)",
                                 remedy="give directions of about unit length, or "
                                        + self.REMEDY.replace("down", "up"))
        if om <= self.origin_limit and dm <= 1.0:
            return
        k = np.sqrt(3.0)
        if self._largest(k * (om + self.box[2]), k * dm) <= self.MAX_PRODUCT:
            return
        # non-finite coordinates passed over here too (as NaN, which fmin/fmax skip)
        of = np.where(np.isfinite(o), o, np.nan).astype(np.float64)
        lo = np.fmin(np.fmin.reduce(of, axis=0), self.box[0])
        hi = np.fmax(np.fmax.reduce(of, axis=0), self.box[1])
        span = hi - lo
        m = float(np.abs(span).max())
        dist = m * float(np.linalg.norm(span / m)) if m > 0 else 0.0    # no float64 overflow
        # lengths of directions scaled by the largest coordinate, so that float64 squares
        # cannot overflow
        s = dm if dm > 0 else 1.0
        dd = np.zeros(len(d))
        for c in range(3):
            dc = d[:, c].astype(np.float64) / s
            dd += dc * dc
        dlen = s * float(np.sqrt(np.fmax.reduce(np.where(dd < np.inf, dd, np.nan), initial=0.0)))
        got = self._largest(dist, dlen)
        if got <= self.MAX_PRODUCT:
            return
        name = "dirs" if self._largest(dist, 1.0) <= self.MAX_PRODUCT else "origins"
        why = (f"directions up to {dlen:.3g} long" if name == "dirs" else
               f"origins up to {dist:.3g} from the triangles")
        to = f"to {got:.3g}" if got < np.inf else "to infinity"
        raise ParameterError(name, f"{why} take the {self.UNIT} unit's products {to}, beyond "
                                   f"the {self.MAX_PRODUCT:.3g} they stay within (hits would be "
                                   f"lost)", remedy=self.REMEDY)


class Float64Range(Float32Range):
    """``Float32Range`` for the float64 units: the builder's coordinates keep their products
    far inside float64's range, so only origins or directions beyond about 1e270 are refused."""

    MAX_PRODUCT = F64_UNIT_MAX_PRODUCT
    MIN_EDGES = 0.0                     # float32 triangles keep float64's products normal
    UNIT = "float64"
    REMEDY = "scale the scene down"

    def _magnitudes(self, o, d):
        """As ``Float32Range``'s, but the shortest direction: infinity, as float64's products
        of float32 triangles stay normal whatever it is (``MIN_EDGES`` 0)."""
        with np.errstate(invalid="ignore"):
            return tuple(float(np.fmax.reduce(np.where(np.isfinite(a), np.abs(a), np.nan),
                                              axis=None, initial=0.0)) for a in (o, d)) + (np.inf,)


def band_eps2(dtype):
    eps = np.finfo(dtype).eps
    return dtype((BAND_K * eps) ** 2)


def ray_scale(m):
    """The power of two c with m * c in [1, 2), m > 0 (clamped to the normal range: a subnormal
    m gives m * c < 1, an m at or above 2^(maxexp - 1) one in [2, 4)). Kernels get the bit-level
    version below, in m's own type."""
    m = np.asarray(m)
    info = np.finfo(m.dtype)
    e = np.clip(np.frexp(m)[1] - 1, info.minexp, info.maxexp - 2)
    return np.ldexp(m.dtype.type(1), -e)


@overload(ray_scale, inline="always")
def _ray_scale_kernel(m):
    """From m's exponent bits: an integer subtraction, branch-free, so that LLVM hoists it out of
    the traversal loop (m depends on the ray only) and vectorises it over packet lanes."""
    if m == types.float32:
        def impl(m):
            e = (np.int64(np.float32(m).view(np.uint32)) >> 23) & 0xFF      # biased exponent
            e = min(max(e, 1), 253)
            return np.uint32((254 - e) << 23).view(np.float32)
        return impl
    if m == types.float64:
        def impl(m):
            e = (np.int64(np.float64(m).view(np.uint64)) >> 52) & 0x7FF
            e = min(max(e, 1), 2045)
            return np.uint64((2046 - e) << 52).view(np.float64)
        return impl
    return None


@njit(cache=True, error_model="numpy", inline="always")
def ray_band_terms(dx, dy, dz):
    """The ray's side of the parallel band: (c_R, |d c_R|^2), c_R = ``ray_scale(max |d_i|)``."""
    c = ray_scale(max(abs(dx), max(abs(dy), abs(dz))))
    sx = dx * c
    sy = dy * c
    sz = dz * c
    return c, sx * sx + sy * sy + sz * sz


@njit(cache=True, error_model="numpy", inline="always")
def mt_datapath(v0x, v0y, v0z, e1x, e1y, e1z, e2x, e2y, e2z, band, tscale, ox, oy, oz, dx, dy, dz,
                dd, rscale, lo, hi, tmin, tmax, one):
    """The unit's datapath and valid check, for the single-ray traversal (``mt_valid_at``) and
    the packet lanes alike. Triangle ``v0, e1, e2`` with ``band`` = (k*eps)^2 |e1|^2 |e2|^2
    c_T^2 and ``tscale`` = c_T; ray ``o, d`` with ``dd`` = |d c_R|^2 and ``rscale`` = c_R
    (``ray_band_terms``); barycentric limits ``lo`` = -edge and ``hi`` = 1 + edge; ``one`` = 1
    in the working float type (so that the divider stays in that precision).
    Returns (valid, t, u, v); t, u, v are meaningful only when valid.

    As the hardware evaluates it: every datapath output is computed and the valid check is one
    AND of its conditions, with no early exit. A random ray would make each early exit an
    unpredictable branch, and one branch costs more than the rest of the test (measured on
    incoherent rays: 3-12% of the whole trace); packet lanes need it branch-free to run in
    SIMD."""
    # p = d x e2 ; det = e1 . p
    px = dy * e2z - dz * e2y
    py = dz * e2x - dx * e2z
    pz = dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    inv = one / det                              # the divider (Fig. A.4)
    # s = o - v0 ; q = s x e1
    sx = ox - v0x
    sy = oy - v0y
    sz = oz - v0z
    u = (sx * px + sy * py + sz * pz) * inv
    qx = sy * e1z - sz * e1y
    qy = sz * e1x - sx * e1z
    qz = sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    # outside the parallel band (relative, on det scaled by powers of two to near 1; also
    # det == 0), inside the widened triangle, t in [tmin, tmax]
    ds = det * tscale * rscale
    valid = (not (ds * ds <= band * dd)) & (u >= lo) & (u <= hi) & (v >= lo) & (u + v <= hi) \
        & (t >= tmin) & (t <= tmax)
    return valid, t, u, v


@njit(cache=True, error_model="numpy", inline="always")
def mt_valid_at(tris, b, ox, oy, oz, dx, dy, dz, dd, tmin, tmax, eps2, one, edge):
    """Triangle row ``tris[b:b + TRI_WORDS]`` of the flattened preprocessed array
    (``b = TRI_WORDS * row``) against one ray through ``mt_datapath``. Returns (valid, t, u, v).
    ``eps2`` = (k*eps)^2; ``edge`` >= 0 widens the barycentric checks
    (``traversal.config.EDGE_EPS_F32``). ``dd``, the caller's |d|^2, is not read: the band
    takes the scaled terms of ``ray_band_terms``, which depend on the ray only, so LLVM
    computes them once per ray, outside the traversal loop."""
    rscale, dds = ray_band_terms(dx, dy, dz)
    return mt_datapath(tris[b + TRI_V0], tris[b + TRI_V0 + 1], tris[b + TRI_V0 + 2],
                       tris[b + TRI_E1], tris[b + TRI_E1 + 1], tris[b + TRI_E1 + 2],
                       tris[b + TRI_E2], tris[b + TRI_E2 + 1], tris[b + TRI_E2 + 2],
                       eps2 * tris[b + TRI_NORMS], tris[b + TRI_SCALE], ox, oy, oz, dx, dy, dz,
                       dds, rscale, -edge, one + edge, tmin, tmax, one)


@njit(cache=True, error_model="numpy", inline="always")
def takes_hit(ok, t, j, best_t, prim):
    """Whether a valid test (``ok``) of triangle ``j`` at ``t`` replaces the closest hit so far
    (``prim`` at ``best_t``; prim < 0: none): a nearer hit, or an exact-t tie with a lower
    primitive index, so that the answer does not depend on the visiting order. The unit
    accepts only t <= best_t (the query's t_max shrinks to it), so ``t < best_t`` parts a
    nearer hit from a tie. Every structure and the packet lanes take hits by this rule, as a
    value, not a branch (the outcome is unpredictable for random rays)."""
    return ok & ((t < best_t) | (prim < 0) | (j < prim))


@njit(cache=True, error_model="numpy", inline="always")
def store_answer(i, prim, t, bu, bv, out_prim, out_t, out_u, out_v):
    """Ray i's answer into a batch's outputs, as every traversal writes them: the primitive
    (-1: a miss) and, unless ``out_t`` is empty (any-hit queries), t (inf for a miss), u, v."""
    out_prim[i] = prim
    if out_t.shape[0] > 0:
        out_t[i] = t if prim >= 0 else np.inf
        out_u[i] = bu
        out_v[i] = bv


@njit(cache=True, error_model="numpy")
def store_normals(lo, hi, tris, row_of, out_prim, out_ng, one):
    """Unnormalised geometric normals e1 x e2 of the hit triangles of rays lo..hi (0 for a
    miss), from the preprocessed rows: primitive j's at row ``row_of[j]``, or at row j when
    ``row_of`` is empty; nothing when ``out_ng`` is empty."""
    if out_ng.shape[0] == 0:
        return
    mapped = row_of.shape[0] > 0
    for i in range(lo, hi):
        gx = one - one
        gy = gx
        gz = gx
        prim = out_prim[i]
        if prim >= 0:
            b = TRI_WORDS * (np.int64(row_of[prim]) if mapped else np.int64(prim))
            e1 = b + TRI_E1
            e2 = b + TRI_E2
            gx = tris[e1 + 1] * tris[e2 + 2] - tris[e1 + 2] * tris[e2 + 1]
            gy = tris[e1 + 2] * tris[e2] - tris[e1] * tris[e2 + 2]
            gz = tris[e1] * tris[e2 + 1] - tris[e1 + 1] * tris[e2]
        out_ng[i, 0] = gx
        out_ng[i, 1] = gy
        out_ng[i, 2] = gz


@njit(cache=True, error_model="numpy")
def wt_hit_at(raw, j, ox, oy, oz, kx, ky, kz, sx, sy, sz, tmin, tmax):
    """Watertight ray/triangle test (Woop, Benthin & Wald 2013), for the accuracy study.

    ``raw`` holds the original vertices (n, 9); (kx, ky, kz) is the ray's axis permutation
    (kz = largest |d| component, kx/ky swapped when d[kz] < 0 to keep the winding) and
    (sx, sy, sz) its shear constants. The edge functions are evaluated in the ray's sheared
    space, and an exact zero is recomputed in float64, so a ray through a shared edge or vertex
    hits at least one of the triangles that share it. Returns (valid, t, u, v)."""
    # vertices relative to the origin, permuted and sheared
    ax = raw[j, kx] - ox if kx == 0 else (raw[j, kx] - oy if kx == 1 else raw[j, kx] - oz)
    ay = raw[j, ky] - ox if ky == 0 else (raw[j, ky] - oy if ky == 1 else raw[j, ky] - oz)
    az = raw[j, kz] - ox if kz == 0 else (raw[j, kz] - oy if kz == 1 else raw[j, kz] - oz)
    bx = raw[j, 3 + kx] - ox if kx == 0 else (raw[j, 3 + kx] - oy if kx == 1 else raw[j, 3 + kx] - oz)
    by = raw[j, 3 + ky] - ox if ky == 0 else (raw[j, 3 + ky] - oy if ky == 1 else raw[j, 3 + ky] - oz)
    bz = raw[j, 3 + kz] - ox if kz == 0 else (raw[j, 3 + kz] - oy if kz == 1 else raw[j, 3 + kz] - oz)
    cx = raw[j, 6 + kx] - ox if kx == 0 else (raw[j, 6 + kx] - oy if kx == 1 else raw[j, 6 + kx] - oz)
    cy = raw[j, 6 + ky] - ox if ky == 0 else (raw[j, 6 + ky] - oy if ky == 1 else raw[j, 6 + ky] - oz)
    cz = raw[j, 6 + kz] - ox if kz == 0 else (raw[j, 6 + kz] - oy if kz == 1 else raw[j, 6 + kz] - oz)
    Ax = ax - sx * az
    Ay = ay - sy * az
    Bx = bx - sx * bz
    By = by - sy * bz
    Cx = cx - sx * cz
    Cy = cy - sy * cz
    U = Cx * By - Cy * Bx
    V = Ax * Cy - Ay * Cx
    W = Bx * Ay - By * Ax
    if U == 0 or V == 0 or W == 0:          # on an edge in float32: decide in float64
        U = np.float64(Cx) * np.float64(By) - np.float64(Cy) * np.float64(Bx)
        V = np.float64(Ax) * np.float64(Cy) - np.float64(Ay) * np.float64(Cx)
        W = np.float64(Bx) * np.float64(Ay) - np.float64(By) * np.float64(Ax)
    if (U < 0 or V < 0 or W < 0) and (U > 0 or V > 0 or W > 0):
        return False, tmax, tmax, tmax
    det = U + V + W
    if det == 0:
        return False, tmax, tmax, tmax
    Az = sz * az
    Bz = sz * bz
    Cz = sz * cz
    T = U * Az + V * Bz + W * Cz
    t = T / det
    if not (t >= tmin and t <= tmax):
        return False, tmax, tmax, tmax
    return True, t, V / det, W / det


@njit(cache=True, error_model="numpy")
def wt_setup(dx, dy, dz, one):
    """Per-ray constants of the watertight test: the axis permutation (kx, ky, kz), kz the
    largest |d| component and kx/ky swapped when d[kz] < 0 to keep the winding, and the shear
    (sx, sy, sz)."""
    kz = 0
    if abs(dy) > abs(dx):
        kz = 1
    if abs(dz) > max(abs(dx), abs(dy)):
        kz = 2
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    dkz = dz if kz == 2 else (dy if kz == 1 else dx)
    if dkz < 0:
        kx, ky = ky, kx
    dkx = dz if kx == 2 else (dy if kx == 1 else dx)
    dky = dz if ky == 2 else (dy if ky == 1 else dx)
    return kx, ky, kz, dkx / dkz, dky / dkz, one / dkz


@njit(cache=True, error_model="numpy")
def wt_hit_ray(raw, j, ox, oy, oz, dx, dy, dz, one, tmin, tmax):
    """``wt_hit_at`` with the per-ray set-up done here (kept out of the traversal loop, whose
    hot path is the Moller-Trumbore unit)."""
    kx, ky, kz, sx, sy, sz = wt_setup(dx, dy, dz, one)
    return wt_hit_at(raw, j, ox, oy, oz, kx, ky, kz, sx, sy, sz, tmin, tmax)
