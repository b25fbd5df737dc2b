"""The stages of one Whitted wavefront, as Numba kernels (after pbrt-v4's wavefront integrator).

A wavefront is a queue of rays in structure-of-arrays form: origins ``O`` and directions ``D``
(n, 3) as ``shade`` spawns them, path weights ``wgt`` (n, 3) float64 and film pixels ``pix``
(n,), and the same rays in the tracer's order (``Ot``, ``Dt``; a secondary wavefront's ray j
for the tracer is row ``order[j]`` of the others, see ``group_by_octant``; the camera's rays
go straight to ``Ot``, ``Dt``). Origins and directions are held in the tracer's precision
(float32 for the hardware units), so the tracer reads them without a conversion, and shading
starts from the rays as the tracer traced them: a hit point is the traced origin plus t times
the traced direction, in float64. The renderer runs one band of image rows at a time on a
thread (``raytracer.render``); per bounce of a band:

1. ``generate_camera_rays``: the camera's rays for one sample pass, in 4x4 pixel tiles;
2. the tracer's ``intersect`` on the queue (our traversal or Embree: the only stage outside
   this module);
3. ``shade``: per ray, the background for a miss; for a hit, the first-hit layers, ambient
   light (a camera ray's is ``accumulate``'s to add), one shadow ray per light with the light
   it brings if visible (from a material with a diffuse or specular term:
   ``render.takes_direct_light``), and the secondary rays (mirror reflection, dielectric reflection and
   refraction) with their weights. Each output goes densely, in ray order, to its queue: the
   shadow rays of each light straight into the tracer's shadow queue, in the order of the
   rays that cast them (tile order for the camera's: coherent packets), and the secondary
   rays straight into the next wavefront, reflections from its first row, refractions from
   the row of this queue's length. Before it returns it joins the shadow queues
   (``join_light_queues``: the other lights' shadow rays behind the first's) and hands the
   tracer the next wavefront grouped by direction octant (``group_by_octant``, see there),
   which ``shade`` then reads in that order through ``order``;
4. the tracer's ``occluded`` on the shadow queue;
5. ``accumulate``: the light of the unblocked shadow rays and the other contributions into the
   film, in queue order, a fixed order per pixel.

Each stage is one call from Python per bounce (each call releases the interpreter lock and
takes it back, which another band's thread may hold): so the joins run inside ``shade``, and
both kinds of contribution go to the film in one ``accumulate``.

A band's pixels are its own and its queues come in ray order, so the image does not depend on
the thread count.

All shading is float64 on float32 hits, formula by formula as tests/naive_whitted.py, so
images agree with that reference to float rounding.
"""
import numpy as np
from numba import njit

from traversal.camera import TILE
from traversal.offset import offset_from_unit, onto_plane, unit_normal_and_plane
from traversal.packet import octant
from .config import BLOCK

POINT, DIRECTIONAL = 0, 1               # light kinds in the kernels' light table


def n_blocks(n):
    return (n + BLOCK - 1) // BLOCK


# A triangle's shading record: TRI_WORDS float64 words (the array aligned so that a record is
# two cache lines), so that the shading's gather of a hit's data reads one array at a constant
# stride, converts only the material index, and looks nothing up by material. The gather runs
# 6% faster (of the shading, on the default scene and on marbles) than from separate arrays of
# normals (float64), vertex normals (float32), magnitudes, materials and per-material flags,
# for 128 bytes a triangle instead of 72. Its plane puts each hit point on the triangle (see
# shade's pass 2).
TRI_G = 0            # unit geometric normal e1 x e2 (3 words)
TRI_MAG = 3          # largest coordinate magnitude: the scale of its rounding, for ray offsets
TRI_N = 4            # vertex normals, 3 x 3 words (float32 values, exact in float64)
TRI_MATERIAL = 13    # material index
TRI_KIND = 14        # what its material does: TAKES_LIGHT (render.takes_direct_light) + CASTS_RAYS
TRI_PLANE = 15       # the unit normal's dot product with vertex 0: the plane is G . x = this
TRI_WORDS = 16
TAKES_LIGHT, CASTS_RAYS = 1.0, 2.0      # TRI_KIND's terms (a sum of the two is exact)


@njit(cache=True, nogil=True, error_model="numpy")
def triangle_terms(lo, hi, tris, normals, material, direct, spawns, rec):
    """The shading records (TRI_* words) of triangles lo..hi of (n, 3, 3) float32 ``tris``
    with vertex ``normals`` (n, 3, 3) and ``material`` per triangle, whose materials take
    direct light and cast secondary rays as ``direct`` and ``spawns`` say; ``rec`` is
    (n * TRI_WORDS,) float64."""
    for j in range(lo, hi):
        r = TRI_WORDS * j
        gx, gy, gz, plane = unit_normal_and_plane(tris, j)
        rec[r + TRI_G] = gx
        rec[r + TRI_G + 1] = gy
        rec[r + TRI_G + 2] = gz
        rec[r + TRI_PLANE] = plane
        m = 0.0
        for v in range(3):
            for c in range(3):
                a = abs(np.float64(tris[j, v, c]))
                m = a if a > m else m
                rec[r + TRI_N + 3 * v + c] = np.float64(normals[j, v, c])
        rec[r + TRI_MAG] = m
        k = material[j]
        rec[r + TRI_MATERIAL] = k
        rec[r + TRI_KIND] = (TAKES_LIGHT if direct[k] else 0.0) + (CASTS_RAYS if spawns[k] else 0.0)


def camera_terms(width, height, half, cell_x, cell_y, grid_x, grid_y):
    """The per-pass constants of ``generate_camera_rays``: (off_x, off_y, inv_gx, inv_gy,
    kx, bx, ky, by), so that a sample at pixel (x, y) with uniform offsets (jx, jy) lands at
    screen point sx = (x + (off_x + jx) * inv_gx) * kx - bx, sy = by - (y + ...) * ky (without
    jitter, at the pixel centre): stratum (cell_x, cell_y) of a grid_x x grid_y grid, pinhole
    camera with tan(fov/2) = ``half``. Reciprocals, so the kernel does no division but one."""
    aspect = width / height
    return (float(cell_x), float(cell_y), 1.0 / grid_x, 1.0 / grid_y, 2.0 * half * aspect / width,
            half * aspect, 2.0 * half / height, half)


@njit(cache=True, error_model="numpy", inline="always")
def _screen_point(x, y, q, jitter, jit_x, jit_y, terms):
    """The screen point of the camera ray at pixel (x, y), the band's pixel q (see
    ``camera_terms``)."""
    off_x, off_y, inv_gx, inv_gy, kx, bx, ky, by = terms
    if jitter:
        px = x + (off_x + jit_x[q]) * inv_gx
        py = y + (off_y + jit_y[q]) * inv_gy
    else:
        px = x + 0.5
        py = y + 0.5
    return px * kx - bx, by - py * ky


@njit(cache=True, nogil=True, error_model="numpy")
def generate_camera_rays(y0, y1, width, jit_x, jit_y, jitter, terms, eye, cu, cv, cw,
                         pix, Ot, Dt, SX, SY):
    """Camera rays of one sample pass for image rows y0..y1 (y0 a multiple of TILE), in
    TILE x TILE pixel tiles (``traversal.camera.tile_order``, whose slots y0 * width
    onward these are): slot k from 0. A pixel is placed by ``terms`` (``camera_terms``) with
    its uniform offsets jit_x/jit_y (pixel p at p - y0 * width) when ``jitter``. Camera
    basis (cu, cv, cw). Writes pix and the rays in the tracer's precision, Ot (the eye) and
    Dt (the float64 unit direction, rounded), which ``shade`` reads too; the weight (1) of
    camera rays it takes as given. ``SX``, ``SY``: float64 scratch, one of each per ray.

    Two loops: the tile loops place each ray's screen point (in SX, SY), then one flat loop
    over the rays turns the points into unit directions, in SIMD lanes (with the arrays seen
    flat, so that a row is 3 words on from the last: a 2D index's run-time row length keeps
    LLVM from vectorising); 30% faster than one loop doing both, and 14% faster again than
    with the points parked in Dt's rows (strided loads). The tile loops are written out here,
    not read from the tile order: placing pixels from a list of indices made this stage
    20-30% slower. A whole tile is placed by loops of the constant TILE, which LLVM unrolls,
    with unsigned indices (see config.PIXEL): 19 us a band of 16k pixels, against 50 us with
    run-time tile bounds and signed indices (the stage 35 us against 66 us). A test keeps the
    two orders in step."""
    ex = eye[0]                     # rounded to the tracer's precision as Ot stores it
    ey = eye[1]
    ez = eye[2]
    Of = Ot.reshape(-1)
    Dtf = Dt.reshape(-1)
    n = (y1 - y0) * width
    # (1) in tile order, each ray's screen point; q: the pixel's index within the band
    slot = np.uint64(0)
    w = np.uint64(width)
    first = np.uint64(y0) * w
    for ty in range(y0, y1, TILE):
        th = min(TILE, y1 - ty)
        tile_row = np.uint64(ty - y0) * w
        for tx in range(0, width, TILE):
            tw = min(TILE, width - tx)
            if th == TILE and tw == TILE:
                for row_in_tile in range(TILE):
                    yf = np.float64(ty + row_in_tile)
                    row = tile_row + np.uint64(row_in_tile) * w + np.uint64(tx)
                    for col in range(TILE):
                        q = row + np.uint64(col)
                        s = slot + np.uint64(row_in_tile * TILE + col)
                        SX[s], SY[s] = _screen_point(np.float64(tx + col), yf, q, jitter, jit_x,
                                                     jit_y, terms)
                        pix[s] = first + q
                slot += np.uint64(TILE * TILE)
            else:                                   # a tile cut by the frame's edge
                for y in range(ty, ty + th):
                    for x in range(tx, tx + tw):
                        q = np.uint64(y - y0) * w + np.uint64(x)
                        SX[slot], SY[slot] = _screen_point(np.float64(x), np.float64(y), q,
                                                           jitter, jit_x, jit_y, terms)
                        pix[slot] = first + q
                        slot += np.uint64(1)
    # (2) the unit directions, ray by ray (SIMD: the square root and the divider in lanes)
    ux = cu[0]; uy = cu[1]; uz = cu[2]
    vx = cv[0]; vy = cv[1]; vz = cv[2]
    wx = cw[0]; wy = cw[1]; wz = cw[2]
    for k in range(n):
        sx = SX[k]
        sy = SY[k]
        dx = sx * ux + sy * vx + wx
        dy = sx * uy + sy * vy + wy
        dz = sx * uz + sy * vz + wz
        inv = 1.0 / np.sqrt(dx * dx + dy * dy + dz * dz)
        dx *= inv
        dy *= inv
        dz *= inv
        Of[3 * k] = ex
        Of[3 * k + 1] = ey
        Of[3 * k + 2] = ez
        Dtf[3 * k] = dx
        Dtf[3 * k + 1] = dy
        Dtf[3 * k + 2] = dz


@njit(cache=True, nogil=True, error_model="numpy")
def finish_band(q0, q1, film, spp, image):
    """The image of pixels q0..q1: the mean of their ``spp`` samples, in float32. Returns how
    many of them are too bright for float32 (+inf in the image; the film is float64). Over
    the arrays seen flat with unsigned indices (see config.PIXEL), which LLVM runs in SIMD
    lanes: 16 us a band of 16k pixels, against 60 us by 2D index."""
    over = 0
    flat_film = film.reshape(-1)
    flat_image = image.reshape(-1)
    for q in range(np.uint64(q0), np.uint64(q1)):
        k = np.uint64(3) * q
        r = np.float32(flat_film[k] / spp)
        g = np.float32(flat_film[k + np.uint64(1)] / spp)
        b = np.float32(flat_film[k + np.uint64(2)] / spp)
        flat_image[k] = r
        flat_image[k + np.uint64(1)] = g
        flat_image[k + np.uint64(2)] = b
        over += np.isinf(r) | np.isinf(g) | np.isinf(b)
    return over


@njit(cache=True, error_model="numpy", inline="always")
def fresnel_dielectric(cos_i, eta_i, eta_t):
    """Unpolarised Fresnel reflectance for cos_i >= 0: (F, cos_t, total internal reflection).
    Without a branch, so that it runs in SIMD lanes: under total internal reflection
    1 - sin_t^2 <= 0, so cos_t is 0 as it is, and F is chosen to be 1."""
    r = eta_i / eta_t
    sin_t2 = r * r * max(0.0, 1.0 - cos_i * cos_i)
    tir = sin_t2 >= 1.0
    cos_t = np.sqrt(max(0.0, 1.0 - sin_t2))
    rs = (eta_i * cos_i - eta_t * cos_t) / (eta_i * cos_i + eta_t * cos_t)
    rp = (eta_t * cos_i - eta_i * cos_t) / (eta_t * cos_i + eta_i * cos_t)
    return 1.0 if tir else 0.5 * (rs * rs + rp * rp), cos_t, tir


@njit(cache=True, error_model="numpy")
def _unit(x, y, z):
    ln = np.sqrt(x * x + y * y + z * z)
    inv = 1.0 / (ln if ln > 1e-300 else 1e-300)
    return x * inv, y * inv, z * inv


@njit(cache=True, error_model="numpy")
def _put_ray(O, D, W, pix, k, ox, oy, oz, dx, dy, dz, w0, w1, w2, p):
    """Ray k of a queue: origin, direction, weight and pixel."""
    O[k, 0] = ox
    O[k, 1] = oy
    O[k, 2] = oz
    D[k, 0] = dx
    D[k, 1] = dy
    D[k, 2] = dz
    W[k, 0] = w0
    W[k, 1] = w1
    W[k, 2] = w2
    pix[k] = p


# Rows of the shading kernel's per-block scratch (structure of arrays, one column per ray of
# the block). One 2D array rather than one per field: LLVM then proves the rows apart and
# runs the passes over them in SIMD lanes. Rows lie one cache line more than BLOCK apart: at
# BLOCK doubles (2 KB) apart, a ray's entries in every other row fall in one set of the L1
# cache, and the passes that read 15-23 rows (the shadow records, the secondary rays)
# evicted their own lines; padded, they shade 4-7% faster.
_ROWS = 73
_ROW = BLOCK + 8
(_DX, _DY, _DZ, _PX, _PY, _PZ, _GX, _GY, _GZ, _FX, _FY, _FZ, _NX, _NY, _NZ, _W0, _W1, _W2, _MAG,
 _OX, _OY, _OZ, _LX, _LY, _LZ, _TMAX, _COS, _E0, _E1, _E2,
 _RX, _RY, _RZ, _RW0, _RW1, _RW2, _ROX, _ROY, _ROZ,
 _TX, _TY, _TZ, _TW0, _TW1, _TW2, _TOX, _TOY, _TOZ, _REFRACTS,
 _SDX, _SDY, _SDZ, _SPX, _SPY, _SPZ, _SGX, _SGY, _SGZ, _SFX, _SFY, _SFZ, _SNX, _SNY, _SNZ,
 _SW0, _SW1, _SW2, _SMAG, _SETA, _SKR0, _SKR1, _SKR2, _PLANE) = range(0, _ROWS * _ROW, _ROW)


# Pass 4b reads a spawning ray's values from the rows _SDX.._SKR2 (copied there side by side)
# or, in a block where nearly every ray spawns, from its own rows, _SPAWN words (49 rows)
# before them: _DX.._MAG in the same order, and the index of refraction and kr in _OX.._LX,
# which pass 3 is done with by then.
_SPAWN = _SDX - _DX
if not (_SMAG - _SDX == _MAG - _DX and (_SETA, _SKR2) == (_OX + _SPAWN, _LX + _SPAWN)):
    raise ImportError("stages: the spawning rows must mirror the rays' own rows")


@njit(cache=True, inline="always")
def _row(camera, order, i):
    """The wavefront row of a queue's ray i: i for the camera's queue, else ``order[i]`` (the
    tracer's order, ``group_by_octant``)."""
    return i if camera else order[i]


@njit(cache=True, inline="always")
def _put_hit_row(S, j, Df, i, t, ox, oy, oz, w0, w1, w2):
    """Column j of the scratch from ray i (direction in ``Df``, seen flat, in the tracer's
    precision): its direction, its hit point at t from origin (ox, oy, oz), and its weight,
    in float64."""
    dx = np.float64(Df[3 * i])
    dy = np.float64(Df[3 * i + 1])
    dz = np.float64(Df[3 * i + 2])
    S[_DX + j] = dx
    S[_DY + j] = dy
    S[_DZ + j] = dz
    S[_PX + j] = ox + dx * t
    S[_PY + j] = oy + dy * t
    S[_PZ + j] = oz + dz * t
    S[_W0 + j] = w0
    S[_W1 + j] = w1
    S[_W2 + j] = w2


@njit(cache=True, error_model="numpy", inline="always")
def _spawn_pair(S, k, b, offset):
    """Pass 4b of ``shade`` for scratch column k: both secondary rays of a spawning ray,
    mirror or dielectric alike, a choice of values and no branch: the reflection about the
    facing shading normal (a mirror) or about the shading normal turned toward the ray (a
    dielectric), with its weight, w * kr or w * Fresnel; the refraction by Snell's law, weight
    w * (1 - Fresnel), which only a dielectric short of total internal reflection casts; each
    ray's origin off the surface. Reads the ray's values ``b`` words past the spawning rows
    (0, or -_SPAWN for its own rows). Inlined into a loop per ``b``, each with ``b`` a constant,
    so that LLVM runs both in SIMD lanes: with ``b`` known at run time only, LLVM kept the
    loop scalar (the shading 14% slower)."""
    eta = S[b + _SETA + k]
    dielectric = eta > 0
    dx = S[b + _SDX + k]
    dy = S[b + _SDY + k]
    dz = S[b + _SDZ + k]
    Px = S[b + _SPX + k]
    Py = S[b + _SPY + k]
    Pz = S[b + _SPZ + k]
    gx = S[b + _SGX + k]
    gy = S[b + _SGY + k]
    gz = S[b + _SGZ + k]
    w0 = S[b + _SW0 + k]
    w1 = S[b + _SW1 + k]
    w2 = S[b + _SW2 + k]
    mag = S[b + _SMAG + k]
    # ns points out of the object
    nsx = S[b + _SNX + k]
    nsy = S[b + _SNY + k]
    nsz = S[b + _SNZ + k]
    entering = dx * nsx + dy * nsy + dz * nsz < 0
    sgn = 1.0 if entering else -1.0
    nix = nsx * sgn
    niy = nsy * sgn
    niz = nsz * sgn
    eta_i = 1.0 if entering else eta
    eta_t = eta if entering else 1.0
    cos_i = min(max(-(dx * nix + dy * niy + dz * niz), 0.0), 1.0)
    F, cos_t, tir = fresnel_dielectric(cos_i, eta_i, eta_t)
    nx = nix if dielectric else S[b + _SFX + k]
    ny = niy if dielectric else S[b + _SFY + k]
    nz = niz if dielectric else S[b + _SFZ + k]
    k2 = 2 * (dx * nx + dy * ny + dz * nz)
    rx = dx - k2 * nx
    ry = dy - k2 * ny
    rz = dz - k2 * nz
    S[_RX + k] = rx
    S[_RY + k] = ry
    S[_RZ + k] = rz
    S[_RW0 + k] = w0 * (F if dielectric else S[b + _SKR0 + k])
    S[_RW1 + k] = w1 * (F if dielectric else S[b + _SKR1 + k])
    S[_RW2 + k] = w2 * (F if dielectric else S[b + _SKR2 + k])
    ox, oy, oz = offset_from_unit(Px, Py, Pz, gx, gy, gz, rx, ry, rz, mag, offset)
    S[_ROX + k] = ox
    S[_ROY + k] = oy
    S[_ROZ + k] = oz
    r = eta_i / eta_t                           # Snell's law
    kt = r * cos_i - cos_t
    tx, ty, tz = _unit(r * dx + kt * nix, r * dy + kt * niy, r * dz + kt * niz)
    S[_TX + k] = tx
    S[_TY + k] = ty
    S[_TZ + k] = tz
    S[_TW0 + k] = w0 * (1 - F)
    S[_TW1 + k] = w1 * (1 - F)
    S[_TW2 + k] = w2 * (1 - F)
    ox, oy, oz = offset_from_unit(Px, Py, Pz, gx, gy, gz, tx, ty, tz, mag, offset)
    S[_TOX + k] = ox
    S[_TOY + k] = oy
    S[_TOZ + k] = oz
    S[_REFRACTS + k] = 1.0 if dielectric and not tir else 0.0


def shade_scratch():
    """The working arrays of one ``shade`` call (its last six arguments): the scratch ``S``
    (``_ROWS`` rows of ``_ROW``), and per ray of a block, its material, whether it takes direct
    light and whether the light is in front of it; the slots of the rays that spawn; the
    counts of the next wavefront's rays per octant, which ``group_by_octant`` turns into the
    octants' first slots. A kernel that allocated them itself would run at half the speed:
    Numba's reference counting then wraps its loops and LLVM no longer keeps the scratch in
    its SIMD passes. The material and slot arrays are unsigned (see config.PIXEL)."""
    return (np.empty(_ROWS * _ROW), np.empty(BLOCK, np.uint32), np.empty(BLOCK, np.bool_),
            np.empty(BLOCK, np.bool_), np.empty(BLOCK, np.uint32), np.empty(8, np.int64))


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def shade(n, Ot, Dt, wgt, pix, hit_prim, hit_t, hit_u, hit_v,
          tri_rec, ambient_light, kd_pi, ks,
          shininess, kr, ior, light_kind, light_pos, light_dir, light_val, background, cutoff,
          offset, do_shadow, do_spawn, camera, first, aov_depth, aov_normal, aov_prim,
          contrib, qO, qD, qT, sh_C, sh_pix, sh_cnt, stride, order, nO, nD, nW, npix, nOt,
          nDt, norder, spawned, S, mat, lit, leaves, spawning, octant_start):
    """Shade the ``n`` rays of a queue from their closest hits (see the module text), in
    blocks of BLOCK rays.

    The queue's rays are read from the tracer's copies ``Ot``, ``Dt``, in its order.
    ``camera``: the queue holds camera rays, whose origin is the eye (``Ot``'s first row) and
    weight 1 (``wgt`` is not read). A ray's own contribution (background or ambient) goes to
    ``contrib`` at its wavefront row ``order[i]`` for ``accumulate``, except a camera ray's,
    which ``accumulate`` computes from its hit (``contrib`` is not written for the camera's
    queue). The shadow rays toward light l go densely to l * ``stride`` onward: origin,
    direction and t_max in the tracer's queue (``qO``, ``qD``, ``qT``, in its precision), the
    light brought if visible and the pixel in ``sh_C``, ``sh_pix``; ``sh_cnt[l]`` of them. Reflections go
    densely to the next wavefront (``nO``, ``nD``, ``nW``, ``npix``) from row 0,
    ``spawned[0]`` of them; refractions densely from row ``n`` (no more rays spawn a
    reflection than the queue holds), ``spawned[1]`` of them; ``group_by_octant`` then writes
    the tracer's copies ``nOt``, ``nDt`` and ``norder`` from the octant counts kept in
    ``octant_start`` as the rays are put. A queue other than the camera's is shaded in the
    tracer's order: its i-th ray has its hit, origin and direction at i, and its weight,
    pixel and ``contrib`` entry at row ``order[i]`` (the camera's queue passes ``order``
    unread).
    Every output is in ray order, so the queues do not depend on anything but the rays.
    ``first`` (the first sample pass' camera rays) writes every pixel's first-hit layers
    (``aov_*``), so they need no clearing before (``accumulate`` stores the pixels' first
    radiance sums); ``offset``: traversal.offset strategy index; ``kd_pi``: kd / pi.

    A block is shaded in passes over a structure-of-arrays scratch ``S``, so that the
    arithmetic runs in SIMD lanes: (1) the hit points of every ray of the block, its triangle's
    data gathered (a miss computes values whose results go unused), which rays take direct
    light or spawn, and each ray's own light (background or ambient) but a camera ray's; (2)
    the unit normals, turned toward the ray, and the first-hit layers; (3) per light, the
    shadow ray of every ray of the block, then, in ray order, the records of the rays that take
    direct light and leave toward the light; (4) the spawning rays' values gathered side by
    side (unless nearly all of the block's rays spawn), both secondary rays of each, then, in
    ray order, those above the cut-off to their queues. A choice between a miss and a hit, or a
    mirror and a dielectric, is a choice of values, not of path, so that the passes run without
    branches. Every value is the float64 formula of a ray-by-ray loop, so the passes do not
    change a bit of the result. Then the shadow queues are joined and the next wavefront
    grouped by octant (module text). Returns the length of the joined shadow queue."""
    n_lights = light_kind.shape[0]
    for l in range(n_lights):
        sh_cnt[l] = 0
    n_refl = 0
    n_refr = 0
    for c in range(8):
        octant_start[c] = 0
    Df = Dt.reshape(-1)
    Of = Ot.reshape(-1)
    Wf = wgt.reshape(-1)
    Cf = contrib.reshape(-1)
    qOf = qO.reshape(-1)
    qDf = qD.reshape(-1)
    sh_Cf = sh_C.reshape(-1)
    # a camera ray's origin: the eye as the tracer took it (every row of the camera's Ot)
    ex = np.float64(Of[0]) if camera and n > 0 else 0.0
    ey = np.float64(Of[1]) if camera and n > 0 else 0.0
    ez = np.float64(Of[2]) if camera and n > 0 else 0.0
    for b in range((n + BLOCK - 1) // BLOCK):
        lo = b * BLOCK
        hi = min(n, lo + BLOCK)
        nr = hi - lo
        # -- pass 1a (branch-free): direction, hit point and weight; the camera's rays start at
        #    the eye with weight 1, the others' weights are read at their rows. A loop per
        #    case, over the (C-contiguous) arrays seen flat, 3 words a row, so that LLVM runs
        #    them in SIMD lanes: a per-ray choice of origin array, or 2D indexing with its
        #    run-time row length, keeps a loop scalar --
        if camera:
            for j in range(nr):
                i = lo + j
                _put_hit_row(S, j, Df, i, np.float64(hit_t[i]), ex, ey, ez, 1.0, 1.0, 1.0)
        else:
            for j in range(nr):
                i = lo + j
                r = order[i]
                _put_hit_row(S, j, Df, i, np.float64(hit_t[i]), np.float64(Of[3 * i]),
                             np.float64(Of[3 * i + 1]), np.float64(Of[3 * i + 2]),
                             Wf[3 * r], Wf[3 * r + 1], Wf[3 * r + 2])
        # -- pass 1b (scalar: gathers from the hit triangles' records, see TRI_WORDS): the unit
        #    geometric normal (per face) and plane, the interpolated shading normal, the
        #    coordinate magnitude and material; a miss reads triangle 0 (render() refuses a
        #    scene without triangles), unused. From the record's kind, which rays take direct
        #    light (hits on a material that ``render.takes_direct_light``) and which spawn: the spawning rays' slots go
        #    densely to ``spawning`` (each ray's slot is written, the count moves on for those
        #    that spawn) --
        n_spawning = 0
        for j in range(nr):
            i = lo + j
            hit = hit_prim[i] >= 0
            r = TRI_WORDS * max(np.int64(hit_prim[i]), 0)
            u = np.float64(hit_u[i])
            v = np.float64(hit_v[i])
            a = 1 - u - v
            S[_GX + j] = tri_rec[r + TRI_G]
            S[_GY + j] = tri_rec[r + TRI_G + 1]
            S[_GZ + j] = tri_rec[r + TRI_G + 2]
            vn = r + TRI_N                              # vertex 0's normal, then 1's, 2's
            S[_NX + j] = a * tri_rec[vn] + u * tri_rec[vn + 3] + v * tri_rec[vn + 6]
            S[_NY + j] = a * tri_rec[vn + 1] + u * tri_rec[vn + 4] + v * tri_rec[vn + 7]
            S[_NZ + j] = a * tri_rec[vn + 2] + u * tri_rec[vn + 5] + v * tri_rec[vn + 8]
            S[_MAG + j] = tri_rec[r + TRI_MAG]
            S[_PLANE + j] = tri_rec[r + TRI_PLANE]
            mat[j] = np.uint32(tri_rec[r + TRI_MATERIAL])
            kind = tri_rec[r + TRI_KIND]
            lit[j] = hit & ((kind == TAKES_LIGHT) | (kind == TAKES_LIGHT + CASTS_RAYS)) & do_shadow
            spawning[n_spawning] = j
            n_spawning += hit & (kind >= CASTS_RAYS) & do_spawn
        # -- pass 1c (branch-free: a miss and a hit differ by a choice of values, not of path),
        #    for a queue other than the camera's: each ray's own light, the background for a
        #    miss and the ambient light for a hit. A camera ray's own light, of weight 1, is
        #    ``accumulate``'s to add from its hit --
        if not camera:
            for j in range(nr):
                i = lo + j
                r = order[i]
                m = mat[j]
                hit = hit_prim[i] >= 0
                Cf[3 * r] = S[_W0 + j] * (ambient_light[m, 0] if hit else background[0])
                Cf[3 * r + 1] = S[_W1 + j] * (ambient_light[m, 1] if hit else background[1])
                Cf[3 * r + 2] = S[_W2 + j] * (ambient_light[m, 2] if hit else background[2])
        # -- pass 2 (SIMD: it reads and writes the scratch only): the hit point onto its
        #    triangle's plane; the unit shading normal; both normals turned toward the
        #    incoming ray --
        for j in range(nr):
            dx = S[_DX + j]
            dy = S[_DY + j]
            dz = S[_DZ + j]
            nsx, nsy, nsz = _unit(S[_NX + j], S[_NY + j], S[_NZ + j])
            S[_NX + j] = nsx
            S[_NY + j] = nsy
            S[_NZ + j] = nsz
            ngx = S[_GX + j]
            ngy = S[_GY + j]
            ngz = S[_GZ + j]
            # the hit point onto its triangle's plane (see traversal.offset)
            S[_PX + j], S[_PY + j], S[_PZ + j] = onto_plane(S[_PX + j], S[_PY + j], S[_PZ + j],
                                                            ngx, ngy, ngz, S[_PLANE + j])
            facing = -1.0 if ngx * dx + ngy * dy + ngz * dz > 0 else 1.0
            gx = ngx * facing
            gy = ngy * facing
            gz = ngz * facing
            S[_GX + j] = gx
            S[_GY + j] = gy
            S[_GZ + j] = gz
            sd = nsx * gx + nsy * gy + nsz * gz
            sg = 1.0 if sd > 0 else (-1.0 if sd < 0 else 0.0)
            fx = nsx * sg
            fy = nsy * sg
            fz = nsz * sg
            usable = np.isfinite(fx) & np.isfinite(fy) & np.isfinite(fz) & \
                (abs(fx) + abs(fy) + abs(fz) != 0)
            S[_FX + j] = fx if usable else gx       # shading normal unusable: geometric
            S[_FY + j] = fy if usable else gy
            S[_FZ + j] = fz if usable else gz
        if first:                                   # the first-hit layers
            for j in range(nr):
                i = lo + j
                q = pix[i]
                hit = hit_prim[i] >= 0
                aov_depth[q] = hit_t[i] if hit else np.inf
                aov_prim[q] = hit_prim[i] if hit else -1
                aov_normal[q, 0] = S[_NX + j] if hit else 0.0
                aov_normal[q, 1] = S[_NY + j] if hit else 0.0
                aov_normal[q, 2] = S[_NZ + j] if hit else 0.0
        # -- pass 3, per light: the shadow ray of every ray (SIMD), then in ray order the
        #    records of those that take the light (Lambert + normalised Blinn-Phong) --
        for l in range(n_lights):
            point = light_kind[l] == POINT
            Lx = light_pos[l, 0]
            Ly = light_pos[l, 1]
            Lz = light_pos[l, 2]
            v0 = light_val[l, 0]
            v1 = light_val[l, 1]
            v2 = light_val[l, 2]
            Ldx = light_dir[l, 0]
            Ldy = light_dir[l, 1]
            Ldz = light_dir[l, 2]
            for j in range(nr):
                if point:
                    tx = Lx - S[_PX + j]
                    ty = Ly - S[_PY + j]
                    tz = Lz - S[_PZ + j]
                    dist = np.sqrt(tx * tx + ty * ty + tz * tz)
                    inv = 1.0 / (dist if dist > 1e-300 else 1e-300)
                    lx = tx * inv
                    ly = ty * inv
                    lz = tz * inv
                    r2 = dist * dist
                    inv2 = 1.0 / (r2 if r2 > 1e-300 else 1e-300)
                    S[_E0 + j] = v0 * inv2
                    S[_E1 + j] = v1 * inv2
                    S[_E2 + j] = v2 * inv2
                else:
                    lx = Ldx
                    ly = Ldy
                    lz = Ldz
                    S[_E0 + j] = v0
                    S[_E1 + j] = v1
                    S[_E2 + j] = v2
                gx = S[_GX + j]
                gy = S[_GY + j]
                gz = S[_GZ + j]
                ox, oy, oz = offset_from_unit(S[_PX + j], S[_PY + j], S[_PZ + j], gx, gy, gz,
                                              lx, ly, lz, S[_MAG + j], offset)
                if point:
                    qx = Lx - ox
                    qy = Ly - oy
                    qz = Lz - oz
                    S[_TMAX + j] = np.sqrt(qx * qx + qy * qy + qz * qz)
                else:
                    S[_TMAX + j] = np.inf
                S[_OX + j] = ox
                S[_OY + j] = oy
                S[_OZ + j] = oz
                S[_LX + j] = lx
                S[_LY + j] = ly
                S[_LZ + j] = lz
                c = S[_FX + j] * lx + S[_FY + j] * ly + S[_FZ + j] * lz
                S[_COS + j] = c
                leaves[j] = (c > 0) & (gx * lx + gy * ly + gz * lz > 0)
            s = l * stride + sh_cnt[l]
            for j in range(nr):
                if not (lit[j] and leaves[j]):
                    continue
                m = mat[j]
                spec = 0.0
                kspec = ks[m]
                if kspec > 0:                           # pow is the dearest step: only if used
                    shin = shininess[m]
                    norm_spec = (shin + 8) / (8 * np.pi)
                    hx, hy, hz = _unit(S[_LX + j] - S[_DX + j], S[_LY + j] - S[_DY + j],
                                       S[_LZ + j] - S[_DZ + j])
                    ch = S[_FX + j] * hx + S[_FY + j] * hy + S[_FZ + j] * hz
                    spec = kspec * norm_spec * max(ch, 0.0) ** shin
                c = S[_COS + j]
                u = np.uint64(s)                        # unsigned: see config.PIXEL
                t = np.uint64(3) * u
                qOf[t] = S[_OX + j]
                qOf[t + np.uint64(1)] = S[_OY + j]
                qOf[t + np.uint64(2)] = S[_OZ + j]
                qDf[t] = S[_LX + j]
                qDf[t + np.uint64(1)] = S[_LY + j]
                qDf[t + np.uint64(2)] = S[_LZ + j]
                qT[u] = S[_TMAX + j]
                sh_Cf[t] = S[_W0 + j] * (S[_E0 + j] * c * (kd_pi[m, 0] + spec))
                sh_Cf[t + np.uint64(1)] = S[_W1 + j] * (S[_E1 + j] * c * (kd_pi[m, 1] + spec))
                sh_Cf[t + np.uint64(2)] = S[_W2 + j] * (S[_E2 + j] * c * (kd_pi[m, 2] + spec))
                sh_pix[u] = pix[np.uint64(_row(camera, order, lo + j))]
                s += 1
            sh_cnt[l] = s - l * stride
        # -- pass 4a (scalar): the spawning rays' values, side by side in slot order; or, in
        #    a block where at least 3/4 of the rays spawn (glass and mirrors fill most
        #    secondary wavefronts), none copied: pass 4b then runs on every ray of the block
        #    in its own rows (the others' results unread), with each ray's index of
        #    refraction and kr put beside them. Copying 23 values per spawning ray is 9% of
        #    the shading on the default scene; with dense blocks the shading is 5% faster
        #    there than with every block copied (1/2 as the threshold: 3%; 7/8: as 3/4) --
        dense = n_spawning * 4 >= nr * 3
        if dense:
            for j in range(nr):
                m = mat[j]
                S[_SETA - _SPAWN + j] = ior[m]
                S[_SKR0 - _SPAWN + j] = kr[m, 0]
                S[_SKR1 - _SPAWN + j] = kr[m, 1]
                S[_SKR2 - _SPAWN + j] = kr[m, 2]
        for k in range(0 if dense else n_spawning):
            j = spawning[k]
            m = mat[j]
            S[_SDX + k] = S[_DX + j]
            S[_SDY + k] = S[_DY + j]
            S[_SDZ + k] = S[_DZ + j]
            S[_SPX + k] = S[_PX + j]
            S[_SPY + k] = S[_PY + j]
            S[_SPZ + k] = S[_PZ + j]
            S[_SGX + k] = S[_GX + j]
            S[_SGY + k] = S[_GY + j]
            S[_SGZ + k] = S[_GZ + j]
            S[_SFX + k] = S[_FX + j]
            S[_SFY + k] = S[_FY + j]
            S[_SFZ + k] = S[_FZ + j]
            S[_SNX + k] = S[_NX + j]
            S[_SNY + k] = S[_NY + j]
            S[_SNZ + k] = S[_NZ + j]
            S[_SW0 + k] = S[_W0 + j]
            S[_SW1 + k] = S[_W1 + j]
            S[_SW2 + k] = S[_W2 + j]
            S[_SMAG + k] = S[_MAG + j]
            S[_SETA + k] = ior[m]
            S[_SKR0 + k] = kr[m, 0]
            S[_SKR1 + k] = kr[m, 1]
            S[_SKR2 + k] = kr[m, 2]
        # -- pass 4b (SIMD: it reads and writes the scratch only): both secondary rays of each
        #    spawning ray (``_spawn_pair``), in the column it was read from --
        if dense:
            for k in range(nr):
                _spawn_pair(S, k, -_SPAWN, offset)
        else:
            for k in range(n_spawning):
                _spawn_pair(S, k, 0, offset)
        # -- pass 4c, in ray order: the rays above the contribution cut-off to their queues --
        for k in range(n_spawning):
            j = spawning[k]
            p = pix[_row(camera, order, lo + j)]
            c = j if dense else k                   # the column pass 4b wrote
            a0 = S[_RW0 + c]
            a1 = S[_RW1 + c]
            a2 = S[_RW2 + c]
            if max(a0, a1, a2) >= cutoff:
                _put_ray(nO, nD, nW, npix, np.uint64(n_refl), S[_ROX + c], S[_ROY + c],
                         S[_ROZ + c], S[_RX + c], S[_RY + c], S[_RZ + c], a0, a1, a2, p)
                octant_start[octant(S[_RX + c], S[_RY + c], S[_RZ + c])] += 1
                n_refl += 1
            c0 = S[_TW0 + c]
            c1 = S[_TW1 + c]
            c2 = S[_TW2 + c]
            if S[_REFRACTS + c] != 0 and max(c0, c1, c2) >= cutoff:
                _put_ray(nO, nD, nW, npix, np.uint64(n + n_refr), S[_TOX + c], S[_TOY + c],
                         S[_TOZ + c], S[_TX + c], S[_TY + c], S[_TZ + c], c0, c1, c2, p)
                octant_start[octant(S[_TX + c], S[_TY + c], S[_TZ + c])] += 1
                n_refr += 1
    spawned[0] = n_refl
    spawned[1] = n_refr
    if do_spawn:
        group_by_octant(n_refl, n, n_refr, nO, nD, nOt, nDt, norder, octant_start)
    return join_light_queues(qO, qD, qT, sh_cnt, stride) if n_lights > 0 else 0


@njit(cache=True, nogil=True, error_model="numpy")
def join_light_queues(qO, qD, qT, sh_cnt, stride):
    """Move the shadow rays of lights 1.. (at l * stride onward, ``sh_cnt[l]`` of them) down
    behind those of light 0, so that the queue is one dense run, light by light. Returns its
    length. Each destination lies before its source, so copying forward is safe."""
    m = sh_cnt[0]
    for l in range(1, sh_cnt.shape[0]):
        src = l * stride
        for k in range(sh_cnt[l]):
            for c in range(3):
                qO[m + k, c] = qO[src + k, c]
                qD[m + k, c] = qD[src + k, c]
            qT[m + k] = qT[src + k]
        m += sh_cnt[l]
    return m


@njit(cache=True, nogil=True, error_model="numpy")
def group_by_octant(n_first, gap, n_second, O, D, Ot, Dt, order, start):
    """The tracer's copies ``Ot``, ``Dt`` of a wavefront's rays (``O``, ``D``: rows 0 to
    ``n_first``, then rows ``gap`` to ``gap + n_second``, in spawn order) grouped by direction
    octant: octant 0's rays first, then octant 1's, and so on, each group in spawn order;
    ``order[j]``: the wavefront row of the tracer's ray j, through which ``shade`` reads the
    rest of the ray. ``start``: (8,) int64, each octant's count of those rays on entry.

    The packet traversal takes 16 consecutive rays together only when they share an octant.
    Secondary rays from neighbouring pixels leave a curved mirror or glass in nearly the
    same direction, yet in spawn order a group of 16 of them straddles an axis plane often
    enough that most would go one by one (on marbles, 220k of its 370k secondary rays);
    grouped, nearly all go in packets. Only the tracer's copies move: the wavefront stays
    where ``shade`` wrote it, which counted the octants as it put the rays, so grouping costs
    one pass over the directions and an index per ray: over the arrays seen flat, with
    unsigned indices (see config.PIXEL), 2.5% off the shading on the default scene against
    2D indices."""
    at = 0
    for c in range(8):
        m = start[c]
        start[c] = at
        at += m
    Of = O.reshape(-1)
    Df = D.reshape(-1)
    Otf = Ot.reshape(-1)
    Dtf = Dt.reshape(-1)
    u64 = np.uint64
    for part in range(2):
        r0 = 0 if part == 0 else gap
        r1 = n_first if part == 0 else gap + n_second
        for k in range(u64(r0), u64(r1)):
            a = u64(3) * k
            o = octant(Df[a], Df[a + u64(1)], Df[a + u64(2)])
            j = start[o]
            start[o] = j + 1
            j = u64(j)
            order[j] = k
            b = u64(3) * j
            for c in range(3):
                Otf[b + u64(c)] = Of[a + u64(c)]
                Dtf[b + u64(c)] = Df[a + u64(c)]


@njit(cache=True, nogil=True, error_model="numpy")
def accumulate(film, sh_cnt, stride, sh_C, sh_pix, blocked, pix, contrib, n, gap, n_second,
               camera, first, hit_prim, material, ambient_light, background):
    """Into the film, in a fixed order per pixel: the queue's own contributions and the light
    brought by each shadow ray that reached its light, light by light in queue order
    (``blocked``: the joined queue's answers; the rays of light l at l * stride onward in
    ``sh_C``/``sh_pix``, ``sh_cnt[l]`` of them). The own contribution of wavefront row k goes
    to ``film[pix[k]]``, for rows 0 to ``n`` then ``gap`` to ``gap + n_second`` (a secondary
    wavefront's reflections and refractions, see ``shade``) in order: ``contrib[k]`` from
    ``shade``, or for the camera's queue (``camera``, rays of weight 1, rows 0 to ``n``) the
    background for a miss and the ambient light of the material hit, computed here from the
    hit's primitive (``hit_prim``). The camera's come first, as in a path a hit's own light
    comes before the light that reaches it; with ``first`` (the first sample pass) they are
    each pixel's first sum, 0 + c whatever the film held, so the film needs no clearing. For
    other queues the shadow rays' light comes first.

    The camera's own contributions reach the film here, not in ``shade``: a band's film is out
    of the cache after a trace, and going over it just before the shadow rays' light (the same
    pixels in the same order) brings it in once instead of twice; and computed here from the
    hit, they cost ``shade`` no writes, and this stage reads the hit's primitive and material
    instead of 24 bytes a ray."""
    u64 = np.uint64                 # unsigned indices: see config.PIXEL
    if camera:
        Ff = film.reshape(-1)
        for k in range(n):
            q = u64(3) * u64(pix[k])
            p = hit_prim[k]
            m = material[u64(max(p, 0))]
            hit = p >= 0
            c0 = ambient_light[m, 0] if hit else background[0]
            c1 = ambient_light[m, 1] if hit else background[1]
            c2 = ambient_light[m, 2] if hit else background[2]
            if first:
                Ff[q] = 0.0 + c0
                Ff[q + u64(1)] = 0.0 + c1
                Ff[q + u64(2)] = 0.0 + c2
            else:
                Ff[q] += c0
                Ff[q + u64(1)] += c1
                Ff[q + u64(2)] += c2
    start = u64(0)
    for l in range(sh_cnt.shape[0]):
        src = u64(l) * u64(stride)
        for k in range(u64(sh_cnt[l])):
            if not blocked[start + k]:
                q = u64(sh_pix[src + k])
                film[q, 0] += sh_C[src + k, 0]
                film[q, 1] += sh_C[src + k, 1]
                film[q, 2] += sh_C[src + k, 2]
        start += u64(sh_cnt[l])
    if not camera:
        for part in range(2):
            r0 = 0 if part == 0 else gap
            r1 = n if part == 0 else gap + n_second
            for k in range(u64(r0), u64(r1)):
                q = u64(pix[k])
                film[q, 0] += contrib[k, 0]
                film[q, 1] += contrib[k, 1]
                film[q, 2] += contrib[k, 2]

