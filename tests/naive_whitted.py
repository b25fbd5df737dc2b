"""The Whitted renderer as NumPy wavefronts: a slow, literal reference for the compiled stages
of ``raytracer`` (tests only). Shading, offsets and sampling follow raytracer/render.py's text
formula by formula, so the two agree to float rounding."""
import numpy as np

from raytracer.render import scene_passes
from traversal.camera import primary_rays, tile_order
from traversal.offset import offset_origins


def fresnel_dielectric(cos_i, eta_i, eta_t):
    """Unpolarised Fresnel reflectance; cos_i >= 0. Returns (F, cos_t, tir mask)."""
    sin_t2 = (eta_i / eta_t) ** 2 * np.maximum(0.0, 1.0 - cos_i * cos_i)
    tir = sin_t2 >= 1.0
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin_t2))
    rs = (eta_i * cos_i - eta_t * cos_t) / (eta_i * cos_i + eta_t * cos_t)
    rp = (eta_t * cos_i - eta_i * cos_t) / (eta_t * cos_i + eta_i * cos_t)
    F = np.where(tir, 1.0, 0.5 * (rs * rs + rp * rp))
    return F, cos_t, tir


def refract(d, n, eta, cos_i, cos_t):
    """Snell's law: d (k, 3) incident unit directions, n (k, 3) unit normals facing the incident
    side, eta = n1/n2, cos_i, cos_t: (k,)."""
    return eta[:, None] * d + (eta * cos_i - cos_t)[:, None] * n


def _accumulate(img, pix, values):
    """img[pix] += values, with repeated pixels (np.add.at is an order slower than bincount)."""
    n = img.shape[0]
    for c in range(3):
        img[:, c] += np.bincount(pix, weights=values[:, c], minlength=n)


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _unit(v):
    return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)


def naive_render(scene, tracer, seed=0, offset="relative"):
    """The Whitted renderer of raytracer.render written with NumPy wavefronts: the literal
    reference the compiled stages must reproduce (same seed, same rays, same image)."""
    W, H, spp = scene.width, scene.height, scene.spp
    npix = W * H
    passes = scene_passes(scene)
    img = np.zeros((npix, 3))
    depth_aov = np.full(npix, np.inf, np.float32)
    normal_aov = np.zeros((npix, 3), np.float32)
    prim_aov = np.full(npix, -1, np.int32)
    rays = {"primary": 0, "shadow": 0, "reflection": 0, "refraction": 0}
    tris64 = scene.triangles.astype(np.float64)
    ray_dtype = np.dtype(getattr(tracer, "dtype", np.float32))
    tri_mag = np.abs(scene.triangles).reshape(-1, 9).max(axis=1).astype(np.float64)
    e1 = tris64[:, 1] - tris64[:, 0]
    e2 = tris64[:, 2] - tris64[:, 0]
    face_n = _unit(np.cross(e1, e2))
    ambient = np.asarray(scene.ambient, np.float64)
    cam = scene.camera

    def trace(o, d, kind, tmax=None):
        if kind == "shadow":
            return tracer.occluded(o, d, 0.0, tmax)
        return tracer.intersect(o, d, normals=False)

    order = tile_order(W, H)
    gx = int(np.ceil(np.sqrt(spp)))
    gy = int(np.ceil(spp / gx))
    for s in range(spp):
        rng = np.random.default_rng([seed, s])
        cx, cy = s % gx, s // gx
        if scene.jitter:
            jit = np.stack([(cx + rng.random(npix)) / gx - 0.5, (cy + rng.random(npix)) / gy - 0.5], 1)
        else:
            jit = None
        O, D = primary_rays(cam["eye"], cam["target"], cam["up"], cam["fov"], W, H, jit)
        pix = order                                     # camera rays in 4x4 tiles
        O, D = O[pix], D[pix]
        wgt = np.ones((npix, 3))
        kind = "primary"
        for bounce in range(passes["depth"]):
            if len(O) == 0:
                break
            if kind == "primary":
                rays["primary"] += len(O)
            # shading starts from the rays as the tracer takes them (in its precision)
            O = O.astype(ray_dtype).astype(np.float64)
            D = D.astype(ray_dtype).astype(np.float64)
            h = trace(O, D, "closest")
            hit = h.prim >= 0
            # -- misses see the background --
            miss = ~hit
            if miss.any():
                _accumulate(img, pix[miss], wgt[miss] * scene.background)
            O, D, wgt, pix = O[hit], D[hit], wgt[hit], pix[hit]
            prim = h.prim[hit].astype(np.int64)
            t = h.t[hit].astype(np.float64)
            u = h.u[hit].astype(np.float64)[:, None]
            v = h.v[hit].astype(np.float64)[:, None]
            P = O + D * t[:, None]
            ng = face_n[prim]
            # onto the hit triangle's plane (ng . x = ng . v0), as the renderer does
            v0 = tris64[prim, 0]
            plane = ng[:, 0] * v0[:, 0] + ng[:, 1] * v0[:, 1] + ng[:, 2] * v0[:, 2]
            off = P[:, 0] * ng[:, 0] + P[:, 1] * ng[:, 1] + P[:, 2] * ng[:, 2] - plane
            P = P - off[:, None] * ng
            nsh = scene.normals[prim].astype(np.float64)
            ns = _unit((1 - u - v) * nsh[:, 0] + u * nsh[:, 1] + v * nsh[:, 2])
            if bounce == 0 and s == 0:
                depth_aov[pix] = t
                normal_aov[pix] = ns
                prim_aov[pix] = prim
            mat = scene.material[prim]
            ior = scene.ior[mat]
            diel = ior > 0
            # facing: normals toward the incoming ray (two-sided surfaces)
            facing = np.where(_dot(ng, D)[:, None] > 0, -1.0, 1.0)
            ngf = ng * facing
            nsf = ns * np.sign(_dot(ns, ngf))[:, None]
            nsf = np.where(np.isfinite(nsf) & (np.abs(nsf).sum(1, keepdims=True) > 0), nsf, ngf)
            # -- local shading: ambient + direct light with hard shadows --
            kd = scene.kd[mat]
            local = kd * ambient
            if passes["shadow"]:
                ks = scene.ks[mat][:, None]
                shin = scene.shininess[mat]
                V = -D
                for L in scene.lights:
                    if L["type"] == "point":
                        to = L["position"] - P
                        dist = np.linalg.norm(to, axis=1)
                        ldir = to / np.maximum(dist, 1e-300)[:, None]
                        E = L["intensity"] / np.maximum(dist * dist, 1e-300)[:, None]
                    else:
                        ldir = np.broadcast_to(-L["direction"], P.shape)
                        dist = np.full(len(P), np.inf)
                        E = np.broadcast_to(L["irradiance"], P.shape)
                    cos = _dot(nsf, ldir)
                    # a material without a diffuse or specular term adds no light: no ray
                    lit = (cos > 0) & (_dot(ngf, ldir) > 0) & ~diel & \
                        ((kd > 0).any(axis=1) | (ks[:, 0] > 0))
                    if not lit.any():
                        continue
                    idx = np.flatnonzero(lit)
                    org = offset_origins(P[idx], ngf[idx], ldir[idx], tri_mag[prim[idx]], offset)
                    tm = np.linalg.norm(L["position"] - org, axis=1) if L["type"] == "point" \
                        else np.full(len(idx), np.inf)
                    rays["shadow"] += len(idx)
                    blocked = trace(org, ldir[idx], "shadow", tm)
                    vis = idx[~blocked]
                    c = cos[vis][:, None]
                    hv = _unit(ldir[vis] + V[vis])
                    spec = ks[vis] * ((shin[vis] + 8) / (8 * np.pi))[:, None] * \
                        np.maximum(_dot(nsf[vis], hv), 0)[:, None] ** shin[vis][:, None]
                    local[vis] += E[vis] * c * (kd[vis] / np.pi + spec)
            _accumulate(img, pix, wgt * local)
            if bounce + 1 >= passes["depth"]:
                break
            # -- secondary rays: mirror reflection, dielectric reflection/refraction --
            newO, newD, newW, newP, newK = [], [], [], [], []
            refl_d = D - 2 * _dot(D, nsf)[:, None] * nsf
            kr = scene.kr[mat]
            m = (kr.max(axis=1) > 0) & ~diel
            if m.any():
                w = wgt[m] * kr[m]
                newO.append(offset_origins(P[m], ngf[m], refl_d[m], tri_mag[prim[m]], offset))
                newD.append(refl_d[m]); newW.append(w); newP.append(pix[m])
                newK.append(np.zeros(m.sum(), np.int8))
            if diel.any():
                di = np.flatnonzero(diel)
                entering = _dot(D[di], ns[di]) < 0           # ns points out of the object
                n_in = np.where(entering[:, None], ns[di], -ns[di])
                eta_i = np.where(entering, 1.0, ior[di])
                eta_t = np.where(entering, ior[di], 1.0)
                cos_i = np.clip(-_dot(D[di], n_in), 0.0, 1.0)
                F, cos_t, tir = fresnel_dielectric(cos_i, eta_i, eta_t)
                rd = D[di] - 2 * _dot(D[di], n_in)[:, None] * n_in
                newO.append(offset_origins(P[di], ngf[di], rd, tri_mag[prim[di]], offset))
                newD.append(rd); newW.append(wgt[di] * F[:, None]); newP.append(pix[di])
                newK.append(np.zeros(len(di), np.int8))
                ok = ~tir
                if ok.any():
                    eta = (eta_i / eta_t)[ok]
                    td = _unit(refract(D[di][ok], n_in[ok], eta, cos_i[ok], cos_t[ok]))
                    newO.append(offset_origins(P[di][ok], ngf[di][ok], td, tri_mag[prim[di][ok]], offset))
                    newD.append(td); newW.append(wgt[di][ok] * (1 - F[ok])[:, None]); newP.append(pix[di][ok])
                    newK.append(np.ones(ok.sum(), np.int8))
            if not newO:
                break
            O = np.concatenate(newO)
            D = np.concatenate(newD)
            wgt = np.concatenate(newW)
            pix = np.concatenate(newP)
            K = np.concatenate(newK)
            keep = wgt.max(axis=1) >= scene.cutoff           # contribution cut-off
            O, D, wgt, pix, K = O[keep], D[keep], wgt[keep], pix[keep], K[keep]
            rays["reflection"] += int((K == 0).sum())
            rays["refraction"] += int((K == 1).sum())
            kind = "secondary"
    image = (img / spp).astype(np.float32).reshape(H, W, 3)
    return image, rays, depth_aov.reshape(H, W), normal_aov.reshape(H, W, 3), prim_aov.reshape(H, W)
