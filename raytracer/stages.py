"""The stages of one Whitted wavefront, as Numba kernels (after pbrt-v4's wavefront integrator).

A wavefront is a queue of rays in structure-of-arrays form: origins ``O`` (n, 3), directions
``D`` (n, 3), path weights ``wgt`` (n, 3) and film pixels ``pix`` (n,), all float64 but ``pix``.
Per bounce the renderer runs:

1. ``generate_camera_rays``: the camera's rays for one sample pass, in 4x4 pixel tiles;
2. the tracer's ``intersect`` on the queue (our traversal or Embree, the only stage outside
   this module);
3. ``shade``: per ray, the background for a miss; for a hit, the first-hit layers, ambient
   light, one candidate shadow ray per light with the light it would bring, and the
   secondary rays (mirror reflection, dielectric reflection and refraction) with their weights.
   Candidates go to fixed slots (light l of ray i at ``l * n + i``; the reflection of ray i at
   ``i``, its refraction at ``n + i``), so every ray writes alone and no order depends on the
   thread count;
4. ``compact``: the used slots, in slot order, gathered into dense queues (so a light's shadow
   rays and each kind of secondary ray stay in tile order: coherent packets);
5. the tracer's ``occluded`` on the shadow queue;
6. ``accumulate``: every contribution into the film, in queue order on one thread (film
   pixels repeat across a wavefront; a fixed order keeps the image independent of the thread
   count, and at ~1 ns per add it is not worth a parallel reduction).

All shading is float64 on float32 hits, as the NumPy formulation it replaces, so images agree
to float32 rounding.
"""
import numpy as np
from numba import njit, prange

from traversal.offset import offset_origin

POINT, DIRECTIONAL = 0, 1               # light kinds in the kernels' light table
COMPACT_BLOCKS = 64                     # prefix-sum blocks: a few per thread, whatever the pool


@njit(cache=True, parallel=True, error_model="numpy")
def generate_camera_rays(order, width, height, jit_x, jit_y, cell_x, cell_y, grid_x, grid_y,
                         jitter, eye, cu, cv, cw, half, aspect, O, D, wgt, pix):
    """Camera rays of one sample pass for queue slots 0..len(order): slot q is pixel order[q]
    (row-major index). The sample falls at the pixel centre, or with ``jitter`` at cell
    (cell_x, cell_y) of a grid_x x grid_y stratification plus the pixel's uniform offsets
    jit_x/jit_y (indexed by pixel). Pinhole camera with basis (cu, cv, cw), tan(fov/2) = half."""
    for q in prange(order.shape[0]):
        p = order[q]
        px = np.float64(p % width) + 0.5
        py = np.float64(p // width) + 0.5
        if jitter:
            px = px + ((cell_x + jit_x[p]) / grid_x - 0.5)
            py = py + ((cell_y + jit_y[p]) / grid_y - 0.5)
        sx = (2 * px / width - 1) * half * aspect
        sy = (1 - 2 * py / height) * half
        dx = sx * cu[0] + sy * cv[0] + cw[0]
        dy = sx * cu[1] + sy * cv[1] + cw[1]
        dz = sx * cu[2] + sy * cv[2] + cw[2]
        ln = np.sqrt(dx * dx + dy * dy + dz * dz)
        O[q, 0] = eye[0]
        O[q, 1] = eye[1]
        O[q, 2] = eye[2]
        D[q, 0] = dx / ln
        D[q, 1] = dy / ln
        D[q, 2] = dz / ln
        wgt[q, 0] = 1.0
        wgt[q, 1] = 1.0
        wgt[q, 2] = 1.0
        pix[q] = p


@njit(cache=True, error_model="numpy", inline="always")
def fresnel_dielectric(cos_i, eta_i, eta_t):
    """Unpolarised Fresnel reflectance for cos_i >= 0: (F, cos_t, total internal reflection)."""
    r = eta_i / eta_t
    sin_t2 = r * r * max(0.0, 1.0 - cos_i * cos_i)
    if sin_t2 >= 1.0:
        return 1.0, 0.0, True
    cos_t = np.sqrt(max(0.0, 1.0 - sin_t2))
    rs = (eta_i * cos_i - eta_t * cos_t) / (eta_i * cos_i + eta_t * cos_t)
    rp = (eta_t * cos_i - eta_i * cos_t) / (eta_t * cos_i + eta_i * cos_t)
    return 0.5 * (rs * rs + rp * rp), cos_t, False


@njit(cache=True, error_model="numpy", inline="always")
def _unit(x, y, z):
    ln = np.sqrt(x * x + y * y + z * z)
    ln = ln if ln > 1e-300 else 1e-300
    return x / ln, y / ln, z / ln


@njit(cache=True, parallel=True, error_model="numpy")
def shade(O, D, wgt, n, hit_prim, hit_t, hit_u, hit_v,
          face_n, shading_n, material, tri_mag, kd, ks, shininess, kr, ior,
          light_kind, light_pos, light_dir, light_val, ambient, background, cutoff,
          offset, do_shadow, do_spawn, first, pix, aov_depth, aov_normal, aov_prim,
          contrib, sh_O, sh_D, sh_tmax, sh_C, sh_used, sp_O, sp_D, sp_W, sp_used):
    """Shade rays 0..n of the queue from their closest hits (see the module text). Writes
    ``contrib`` (the ray's own contribution: background or ambient), the shadow slots
    (sh_*, light l of ray i at l*n + i: origin, direction, t_max and the light brought if
    visible) and the spawn slots (sp_*, reflection at i, refraction at n + i). ``first``: write
    the first-hit layers at the rays' pixels. ``offset``: traversal.offset strategy index."""
    n_lights = light_kind.shape[0]
    for i in prange(n):
        w0 = wgt[i, 0]
        w1 = wgt[i, 1]
        w2 = wgt[i, 2]
        p = hit_prim[i]
        if p < 0:
            # -- a miss sees the background --
            contrib[i, 0] = w0 * background[0]
            contrib[i, 1] = w1 * background[1]
            contrib[i, 2] = w2 * background[2]
            for l in range(n_lights):
                sh_used[l * n + i] = 0
            sp_used[i] = 0
            sp_used[n + i] = 0
            continue
        dx = D[i, 0]
        dy = D[i, 1]
        dz = D[i, 2]
        t = np.float64(hit_t[i])
        u = np.float64(hit_u[i])
        v = np.float64(hit_v[i])
        Px = O[i, 0] + dx * t
        Py = O[i, 1] + dy * t
        Pz = O[i, 2] + dz * t
        # -- normals: geometric (unit, per face) and interpolated shading normal --
        ngx = face_n[p, 0]
        ngy = face_n[p, 1]
        ngz = face_n[p, 2]
        a = 1 - u - v
        nsx = a * np.float64(shading_n[p, 0, 0]) + u * np.float64(shading_n[p, 1, 0]) + v * np.float64(shading_n[p, 2, 0])
        nsy = a * np.float64(shading_n[p, 0, 1]) + u * np.float64(shading_n[p, 1, 1]) + v * np.float64(shading_n[p, 2, 1])
        nsz = a * np.float64(shading_n[p, 0, 2]) + u * np.float64(shading_n[p, 1, 2]) + v * np.float64(shading_n[p, 2, 2])
        nsx, nsy, nsz = _unit(nsx, nsy, nsz)
        if first:
            q = pix[i]
            aov_depth[q] = hit_t[i]
            aov_normal[q, 0] = nsx
            aov_normal[q, 1] = nsy
            aov_normal[q, 2] = nsz
            aov_prim[q] = p
        m = material[p]
        eta = ior[m]
        dielectric = eta > 0
        # -- two-sided surfaces: both normals turned toward the incoming ray --
        facing = -1.0 if ngx * dx + ngy * dy + ngz * dz > 0 else 1.0
        gx = ngx * facing
        gy = ngy * facing
        gz = ngz * facing
        sd = nsx * gx + nsy * gy + nsz * gz
        sg = 1.0 if sd > 0 else (-1.0 if sd < 0 else 0.0)
        fx = nsx * sg
        fy = nsy * sg
        fz = nsz * sg
        if not (np.isfinite(fx) and np.isfinite(fy) and np.isfinite(fz)) or \
                abs(fx) + abs(fy) + abs(fz) == 0:
            fx, fy, fz = gx, gy, gz                     # shading normal unusable: geometric
        # -- ambient --
        kd0 = kd[m, 0]
        kd1 = kd[m, 1]
        kd2 = kd[m, 2]
        contrib[i, 0] = w0 * (kd0 * ambient[0])
        contrib[i, 1] = w1 * (kd1 * ambient[1])
        contrib[i, 2] = w2 * (kd2 * ambient[2])
        # -- direct light: one shadow ray per light (Lambert + normalised Blinn-Phong) --
        if do_shadow:
            kspec = ks[m]
            shin = shininess[m]
            norm_spec = (shin + 8) / (8 * np.pi)
            for l in range(n_lights):
                slot = l * n + i
                if light_kind[l] == POINT:
                    tx = light_pos[l, 0] - Px
                    ty = light_pos[l, 1] - Py
                    tz = light_pos[l, 2] - Pz
                    dist = np.sqrt(tx * tx + ty * ty + tz * tz)
                    dd = dist if dist > 1e-300 else 1e-300
                    lx = tx / dd
                    ly = ty / dd
                    lz = tz / dd
                    r2 = dist * dist
                    r2 = r2 if r2 > 1e-300 else 1e-300
                    e0 = light_val[l, 0] / r2
                    e1 = light_val[l, 1] / r2
                    e2 = light_val[l, 2] / r2
                else:
                    lx = light_dir[l, 0]
                    ly = light_dir[l, 1]
                    lz = light_dir[l, 2]
                    e0 = light_val[l, 0]
                    e1 = light_val[l, 1]
                    e2 = light_val[l, 2]
                c = fx * lx + fy * ly + fz * lz
                if not (c > 0 and gx * lx + gy * ly + gz * lz > 0 and not dielectric):
                    sh_used[slot] = 0
                    continue
                ox, oy, oz = offset_origin(Px, Py, Pz, gx, gy, gz, lx, ly, lz, tri_mag[p], offset)
                if light_kind[l] == POINT:
                    qx = light_pos[l, 0] - ox
                    qy = light_pos[l, 1] - oy
                    qz = light_pos[l, 2] - oz
                    tmax = np.sqrt(qx * qx + qy * qy + qz * qz)
                else:
                    tmax = np.inf
                hx, hy, hz = _unit(lx - dx, ly - dy, lz - dz)
                ch = fx * hx + fy * hy + fz * hz
                spec = kspec * norm_spec * max(ch, 0.0) ** shin
                sh_O[slot, 0] = ox
                sh_O[slot, 1] = oy
                sh_O[slot, 2] = oz
                sh_D[slot, 0] = lx
                sh_D[slot, 1] = ly
                sh_D[slot, 2] = lz
                sh_tmax[slot] = tmax
                sh_C[slot, 0] = w0 * (e0 * c * (kd0 / np.pi + spec))
                sh_C[slot, 1] = w1 * (e1 * c * (kd1 / np.pi + spec))
                sh_C[slot, 2] = w2 * (e2 * c * (kd2 / np.pi + spec))
                sh_used[slot] = 1
        if not do_spawn:
            continue
        # -- secondary rays: mirror reflection; dielectric reflection and refraction --
        sp_used[i] = 0
        sp_used[n + i] = 0
        kr0 = kr[m, 0]
        kr1 = kr[m, 1]
        kr2 = kr[m, 2]
        if max(kr0, kr1, kr2) > 0 and not dielectric:
            k = 2 * (dx * fx + dy * fy + dz * fz)
            rx = dx - k * fx
            ry = dy - k * fy
            rz = dz - k * fz
            a0 = w0 * kr0
            a1 = w1 * kr1
            a2 = w2 * kr2
            if max(a0, a1, a2) >= cutoff:               # contribution cut-off
                sp_O[i, 0], sp_O[i, 1], sp_O[i, 2] = offset_origin(Px, Py, Pz, gx, gy, gz, rx, ry, rz,
                                                                    tri_mag[p], offset)
                sp_D[i, 0] = rx
                sp_D[i, 1] = ry
                sp_D[i, 2] = rz
                sp_W[i, 0] = a0
                sp_W[i, 1] = a1
                sp_W[i, 2] = a2
                sp_used[i] = 1
        elif dielectric:
            # ns points out of the object
            entering = dx * nsx + dy * nsy + dz * nsz < 0
            sgn = 1.0 if entering else -1.0
            nix = nsx * sgn
            niy = nsy * sgn
            niz = nsz * sgn
            eta_i = 1.0 if entering else eta
            eta_t = eta if entering else 1.0
            cos_i = min(max(-(dx * nix + dy * niy + dz * niz), 0.0), 1.0)
            F, cos_t, tir = fresnel_dielectric(cos_i, eta_i, eta_t)
            k = 2 * (dx * nix + dy * niy + dz * niz)
            rx = dx - k * nix
            ry = dy - k * niy
            rz = dz - k * niz
            a0 = w0 * F
            a1 = w1 * F
            a2 = w2 * F
            if max(a0, a1, a2) >= cutoff:
                sp_O[i, 0], sp_O[i, 1], sp_O[i, 2] = offset_origin(Px, Py, Pz, gx, gy, gz, rx, ry, rz,
                                                                    tri_mag[p], offset)
                sp_D[i, 0] = rx
                sp_D[i, 1] = ry
                sp_D[i, 2] = rz
                sp_W[i, 0] = a0
                sp_W[i, 1] = a1
                sp_W[i, 2] = a2
                sp_used[i] = 1
            if not tir:
                r = eta_i / eta_t                       # Snell's law
                kt = r * cos_i - cos_t
                tx, ty, tz = _unit(r * dx + kt * nix, r * dy + kt * niy, r * dz + kt * niz)
                b0 = w0 * (1 - F)
                b1 = w1 * (1 - F)
                b2 = w2 * (1 - F)
                j = n + i
                if max(b0, b1, b2) >= cutoff:
                    sp_O[j, 0], sp_O[j, 1], sp_O[j, 2] = offset_origin(Px, Py, Pz, gx, gy, gz, tx, ty, tz,
                                                                        tri_mag[p], offset)
                    sp_D[j, 0] = tx
                    sp_D[j, 1] = ty
                    sp_D[j, 2] = tz
                    sp_W[j, 0] = b0
                    sp_W[j, 1] = b1
                    sp_W[j, 2] = b2
                    sp_used[j] = 1


@njit(cache=True, parallel=True, error_model="numpy")
def compact(used, n_slots, idx):
    """Indices of the used slots among 0..n_slots, in slot order, into idx; returns their
    count. Parallel over blocks: count, prefix-sum (serial, COMPACT_BLOCKS long), write."""
    nb = COMPACT_BLOCKS
    size = (n_slots + nb - 1) // nb
    start = np.zeros(nb + 1, np.int64)
    for b in prange(nb):
        c = 0
        for s in range(b * size, min(n_slots, (b + 1) * size)):
            c += used[s]
        start[b + 1] = c
    for b in range(nb):
        start[b + 1] += start[b]
    for b in prange(nb):
        k = start[b]
        for s in range(b * size, min(n_slots, (b + 1) * size)):
            if used[s]:
                idx[k] = s
                k += 1
    return start[nb]


@njit(cache=True, parallel=True, error_model="numpy")
def gather_shadow(idx, m, n, pix, sh_O, sh_D, sh_tmax, sh_C, qO, qD, qtmax, qC, qpix):
    """Shadow slots idx[:m] into the dense shadow queue (slot l*n + i belongs to ray i)."""
    for k in prange(m):
        s = idx[k]
        for c in range(3):
            qO[k, c] = sh_O[s, c]
            qD[k, c] = sh_D[s, c]
            qC[k, c] = sh_C[s, c]
        qtmax[k] = sh_tmax[s]
        qpix[k] = pix[s % n]


@njit(cache=True, parallel=True, error_model="numpy")
def gather_spawn(idx, m, n, pix, sp_O, sp_D, sp_W, O, D, wgt, qpix):
    """Spawn slots idx[:m] into the next wavefront (slot i or n + i belongs to ray i)."""
    for k in prange(m):
        s = idx[k]
        for c in range(3):
            O[k, c] = sp_O[s, c]
            D[k, c] = sp_D[s, c]
            wgt[k, c] = sp_W[s, c]
        qpix[k] = pix[s % n]


@njit(cache=True, error_model="numpy")
def accumulate(film, pix, contrib, n):
    """film[pix[k]] += contrib[k] for k < n, in order."""
    for k in range(n):
        q = pix[k]
        film[q, 0] += contrib[k, 0]
        film[q, 1] += contrib[k, 1]
        film[q, 2] += contrib[k, 2]


@njit(cache=True, error_model="numpy")
def accumulate_unblocked(film, pix, contrib, blocked, m):
    """film[pix[k]] += contrib[k] for the shadow rays k < m that reached their light."""
    for k in range(m):
        if not blocked[k]:
            q = pix[k]
            film[q, 0] += contrib[k, 0]
            film[q, 1] += contrib[k, 1]
            film[q, 2] += contrib[k, 2]
