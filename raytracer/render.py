"""Whitted-style ray tracing (Whitted 1980; thesis 2.2.2) on the simulated hardware's trees.

Rays travel as wavefronts through compiled stages (``raytracer.stages``): generate camera
rays, intersect, shade (direct light with one shadow ray per light, spawn secondary rays),
compact, occluded, accumulate. The tracer (our traversal of the hwbvh tree, or Embree) answers
the ``intersect`` and ``occluded`` queries; everything else is the same compiled code for
both, so a comparison of the two measures their trees and traversals. Shading per hit:

    L = kd * ambient + sum_lights V * E * (kd/pi * cos + ks * (s+8)/(8 pi) * cos_h^s * cos)
        + kr * L(reflected)                                   (mirrors, plastics)
    L = F * L(reflected) + (1 - F) * L(refracted)             (dielectrics, exact Fresnel)

with E = I / r^2 for a point light of intensity I and E = irradiance for a directional light,
V the hard-shadow visibility (one ``occluded`` ray per light), Blinn-Phong highlights, total
internal reflection, a recursion depth limit and a contribution cut-off. Dielectrics block
shadow rays (classic Whitted). Supersampling uses stratified jitter from a seeded generator,
so a render is reproducible, and the film is accumulated in a fixed order, so it does not
depend on the thread count.

Only the passes a scene calls for exist: no shadow rays without lights, no reflection rays
without a reflective material, no refraction rays without a dielectric, and no bounce past the
first when nothing reflects or refracts.
"""
import time
from dataclasses import dataclass, field

import numpy as np

from traversal.camera import look_at_basis, tile_order
from traversal.offset import STRATEGY_CODES
from . import stages
from .stages import fresnel_dielectric  # noqa: F401  (the shading model's Fresnel term)


@dataclass
class RenderResult:
    image: np.ndarray                 # (h, w, 3) float32 radiance
    depth: np.ndarray                 # (h, w) float32 first-hit distance (inf: miss)
    normal: np.ndarray                # (h, w, 3) float32 first-hit shading normal
    prim: np.ndarray                  # (h, w) int32 first-hit primitive (-1: miss)
    stats: dict = field(default_factory=dict)


def _tiny_scene():
    """Two facing quads (a diffuse floor, a glass pane), a point and a directional light: enough
    to run every stage kernel once."""
    from types import SimpleNamespace

    floor = np.array([[[-1, 0, -1], [1, 0, -1], [1, 0, 1]], [[-1, 0, -1], [1, 0, 1], [-1, 0, 1]]], np.float32)
    pane = floor[:, :, [0, 2, 1]] + np.float32([0, 0, -0.5])
    pane[:, :, 1] += 1
    tris = np.concatenate([floor, pane])
    ng = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    return SimpleNamespace(
        triangles=tris, normals=np.repeat(ng[:, None], 3, axis=1).astype(np.float32),
        material=np.array([0, 0, 1, 1], np.int32), kd=np.array([[0.5] * 3, [0.0] * 3]),
        ks=np.array([0.2, 0.0]), shininess=np.array([32.0, 32.0]),
        kr=np.array([[0.1] * 3, [0.0] * 3]), ior=np.array([0.0, 1.5]),
        lights=[{"type": "point", "position": np.array([0.0, 2.0, 0.0]), "intensity": np.ones(3)},
                {"type": "directional", "direction": np.array([0.0, -1.0, 0.0]), "irradiance": np.ones(3)}],
        camera={"eye": np.array([0.0, 1.0, 2.0]), "target": np.zeros(3), "up": np.array([0.0, 1.0, 0.0]),
                "fov": 60.0},
        width=8, height=8, spp=1, max_depth=3, ambient=np.full(3, 0.05), background=np.full(3, 0.1),
        cutoff=1e-3, jitter=True)


def warm_up(builder="hwbvh", traversal="numba", parallel_build=False):
    """Load (or, the first time ever, compile) the Numba kernels a render uses, on a tiny
    input, so that build and render timings measure work, not JIT start-up. Returns seconds.
    ``parallel_build`` also loads the data-parallel builder kernels that meshes above
    SEQUENTIAL_MAX_PRIMS use (benchmarks want them; a first render of a small scene does not)."""
    t = time.perf_counter()
    scene = _tiny_scene()
    if builder != "embree" and parallel_build:
        import hwbvh
        rng = np.random.default_rng(0)
        soup = rng.random((300, 1, 3)) + rng.normal(scale=0.02, size=(300, 3, 3))
        hwbvh.build(soup.astype(np.float32), task_prims=16)
    from types import SimpleNamespace
    V = scene.triangles.reshape(-1, 3)
    indexed = SimpleNamespace(**vars(scene), vertices=V,
                              faces=np.arange(len(V), dtype=np.int32).reshape(-1, 3))
    tracer, _, _ = make_tracer(indexed, builder, traversal)
    render(indexed, tracer)
    return time.perf_counter() - t


def make_tracer(scene, builder="hwbvh", traversal="numba", leaf_size=4, bins=16,
                precision="float32", watertight=False):
    """(tracer, build_seconds, build_info). Builders: hwbvh, sweep, embree."""
    from hwbvh.errors import InputError

    if builder == "embree":
        if traversal != "embree":
            raise InputError("traversal", "Embree's tree can only be traversed by Embree "
                             "(builder 'embree' needs traversal 'embree')")
        from traversal.embree_ref import EmbreeTracer
        t = time.perf_counter()
        tr = EmbreeTracer(scene.vertices, scene.faces)
        return tr, time.perf_counter() - t, {"builder": "embree"}
    import hwbvh
    from traversal import Tracer
    t = time.perf_counter()
    bvh = hwbvh.build(scene.triangles, builder=builder, leaf_size=leaf_size, bins=bins)
    secs = time.perf_counter() - t
    info = {"builder": builder, "nodes": bvh.meta["nodes"], "sah_cost": bvh.meta["sah_cost"],
            "build_seconds_core": bvh.meta["build_seconds"]}
    if builder == "hwbvh" and leaf_size == 4 and bins == 16:
        # the simulated hardware build time of the thesis' instantiations (Table 4.1)
        from hwbvh.cycle_model import PRESETS, simulate
        info["simulated_build_seconds"] = {name: simulate(bvh.tree, p)["seconds"]
                                           for name, p in PRESETS.items()}
    if traversal == "numba":
        return Tracer(bvh, precision=precision, watertight=watertight), secs, info
    if traversal == "embree":
        raise InputError("traversal", "Embree traverses its own tree only "
                         "(traversal 'embree' needs builder 'embree')")
    raise InputError("traversal", f"unknown traversal {traversal!r}")


def scene_passes(scene):
    used = np.unique(scene.material)
    reflective = bool((scene.kr[used].max(axis=1) > 0).any() or (scene.ior[used] > 0).any())
    refractive = bool((scene.ior[used] > 0).any())
    shades = bool(((scene.kd[used].max(axis=1) > 0) | (scene.ks[used] > 0)).any())
    return {"shadow": bool(scene.lights) and shades, "reflection": reflective,
            "refraction": refractive,
            "depth": scene.max_depth if (reflective or refractive) else 1}




class _Buffers:
    """The wavefront's queues, allocated once per render and grown (never shrunk) when a bounce
    spawns more rays than they hold: ``cur``/``nxt`` are the current and next wavefront
    (O, D, wgt, pix), swapped after each bounce; the slot arrays (``contrib``, shadow slots
    ``sh``, shadow queue ``shq``, spawn slots ``sp``, compaction indices ``idx``) are sized for
    the current wavefront."""

    def __init__(self, n, n_lights):
        self.n_lights = max(n_lights, 1)
        self.cur = self._wavefront(n)
        self.nxt = self._wavefront(n)
        self.slot_cap = 0
        self.ensure_slots(n)

    @staticmethod
    def _wavefront(cap):
        return [np.empty((cap, 3)), np.empty((cap, 3)), np.empty((cap, 3)), np.empty(cap, np.int64)]

    def ensure_slots(self, n):
        if n <= self.slot_cap:
            return
        cap = max(n, int(self.slot_cap * 1.5))
        L = self.n_lights
        f = lambda *shape: np.empty(shape, np.float64)
        self.contrib = f(cap, 3)
        self.sh = [f(L * cap, 3), f(L * cap, 3), f(L * cap), f(L * cap, 3), np.zeros(L * cap, np.uint8)]
        self.shq = [f(L * cap, 3), f(L * cap, 3), f(L * cap), f(L * cap, 3), np.empty(L * cap, np.int64)]
        self.sp = [f(2 * cap, 3), f(2 * cap, 3), f(2 * cap, 3), np.zeros(2 * cap, np.uint8)]
        self.idx = np.empty(max(L, 2) * cap, np.int64)
        self.slot_cap = cap

    def ensure_next(self, n):
        if n > len(self.nxt[3]):
            self.nxt = self._wavefront(max(n, int(len(self.nxt[3]) * 1.5)))


def _scene_arrays(scene):
    """The compiled scene as the kernels read it: per-triangle unit geometric normals and
    coordinate magnitudes (for ray offsets), material tables, and a light table."""
    tris64 = scene.triangles.astype(np.float64)
    ng = np.cross(tris64[:, 1] - tris64[:, 0], tris64[:, 2] - tris64[:, 0])
    face_n = ng / np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)
    tri_mag = np.abs(scene.triangles).reshape(-1, 9).max(axis=1).astype(np.float64)
    L = len(scene.lights)
    kind = np.zeros(L, np.int64)
    pos = np.zeros((L, 3))
    ldir = np.zeros((L, 3))
    val = np.zeros((L, 3))
    for k, light in enumerate(scene.lights):         # a handful of lights, not primitives
        if light["type"] == "point":
            kind[k] = stages.POINT
            pos[k] = light["position"]
            val[k] = light["intensity"]
        else:
            kind[k] = stages.DIRECTIONAL
            ldir[k] = -np.asarray(light["direction"], np.float64)
            val[k] = light["irradiance"]
    f64 = lambda a: np.ascontiguousarray(a, np.float64)
    return dict(face_n=np.ascontiguousarray(face_n), shading_n=np.ascontiguousarray(scene.normals, np.float32),
                material=np.ascontiguousarray(scene.material, np.int32), tri_mag=tri_mag,
                kd=f64(scene.kd), ks=f64(scene.ks), shininess=f64(scene.shininess), kr=f64(scene.kr),
                ior=f64(scene.ior), light_kind=kind, light_pos=pos, light_dir=ldir, light_val=val,
                ambient=f64(scene.ambient), background=f64(scene.background), cutoff=float(scene.cutoff))


def render(scene, tracer, seed=0, progress=None, offset="relative"):
    """Render a CompiledScene with ``tracer`` (anything with the ``intersect``/``occluded``
    interface of ``traversal.tracers``: our traversal, Embree, or a verifying, counting or
    recording wrapper of either). ``progress``: a callable(n) per finished sample pass.
    ``offset``: secondary-ray offset strategy (traversal.offset.STRATEGIES).
    stats: rays per kind, the passes the scene needs, and seconds per stage."""
    if offset not in STRATEGY_CODES:
        raise ValueError(f"offset: unknown strategy {offset!r}")
    if int(seed) < 0:
        raise ValueError(f"seed: must be non-negative, got {seed}")
    W, H, spp = scene.width, scene.height, scene.spp
    npix = W * H
    passes = scene_passes(scene)
    sa = _scene_arrays(scene)
    film = np.zeros((npix, 3))
    aov_depth = np.full(npix, np.inf, np.float32)
    aov_normal = np.zeros((npix, 3), np.float32)
    aov_prim = np.full(npix, -1, np.int32)
    rays = {"primary": 0, "shadow": 0, "reflection": 0, "refraction": 0}
    secs = dict.fromkeys(("generate", "intersect", "shade", "compact", "occluded", "accumulate"), 0.0)
    n_lights = len(scene.lights)
    buf = _Buffers(npix, n_lights)
    cam = scene.camera
    cu, cv, cw = look_at_basis(cam["eye"], cam["target"], cam["up"])
    eye = np.asarray(cam["eye"], np.float64)
    half = float(np.tan(np.radians(cam["fov"]) / 2))
    order = tile_order(W, H)                  # camera rays in 4x4 tiles: coherent packets
    gx = int(np.ceil(np.sqrt(spp)))
    gy = int(np.ceil(spp / gx))
    no_jitter = np.zeros(0)
    code = STRATEGY_CODES[offset]
    clock = time.perf_counter

    for s in range(spp):
        t0 = clock()
        if scene.jitter:
            rng = np.random.default_rng([seed, s])
            jx, jy = rng.random(npix), rng.random(npix)
        else:
            jx = jy = no_jitter
        O, D, wgt, pix = buf.cur
        stages.generate_camera_rays(order, W, H, jx, jy, float(s % gx), float(s // gx), float(gx),
                                    float(gy), scene.jitter, eye, cu, cv, cw, half, W / H,
                                    O, D, wgt, pix)
        n = npix
        rays["primary"] += n
        secs["generate"] += clock() - t0
        for bounce in range(passes["depth"]):
            if n == 0:
                break
            O, D, wgt, pix = buf.cur
            buf.ensure_slots(n)
            t0 = clock()
            h = tracer.intersect(O[:n], D[:n], normals=False)
            t1 = clock()
            secs["intersect"] += t1 - t0
            spawn = bounce + 1 < passes["depth"]
            shO, shD, shT, shC, sh_used = buf.sh
            spO, spD, spW, sp_used = buf.sp
            stages.shade(O, D, wgt, n, h.prim, h.t, h.u, h.v,
                         sa["face_n"], sa["shading_n"], sa["material"], sa["tri_mag"], sa["kd"],
                         sa["ks"], sa["shininess"], sa["kr"], sa["ior"], sa["light_kind"],
                         sa["light_pos"], sa["light_dir"], sa["light_val"], sa["ambient"],
                         sa["background"], sa["cutoff"], code, passes["shadow"], spawn,
                         bounce == 0 and s == 0, pix, aov_depth, aov_normal, aov_prim,
                         buf.contrib, shO, shD, shT, shC, sh_used, spO, spD, spW, sp_used)
            t2 = clock()
            secs["shade"] += t2 - t1
            if passes["shadow"] and n_lights:
                qO, qD, qT, qC, qpix = buf.shq
                m = stages.compact(sh_used, n_lights * n, buf.idx)
                stages.gather_shadow(buf.idx, m, n, pix, shO, shD, shT, shC, qO, qD, qT, qC, qpix)
                t3 = clock()
                secs["compact"] += t3 - t2
                blocked = tracer.occluded(qO[:m], qD[:m], 0.0, qT[:m]) if m else np.zeros(0, bool)
                t2 = clock()
                secs["occluded"] += t2 - t3
                rays["shadow"] += int(m)
                stages.accumulate_unblocked(film, qpix, qC, np.ascontiguousarray(blocked), m)
            stages.accumulate(film, pix, buf.contrib, n)
            t3 = clock()
            secs["accumulate"] += t3 - t2
            if not spawn:
                break
            k = stages.compact(sp_used, 2 * n, buf.idx)
            refl = int(np.searchsorted(buf.idx[:k], n))        # slots below n are reflections
            rays["reflection"] += refl
            rays["refraction"] += int(k) - refl
            buf.ensure_next(int(k))
            nO, nD, nW, npx = buf.nxt
            stages.gather_spawn(buf.idx, k, n, buf.cur[3], *buf.sp[:3], nO, nD, nW, npx)
            buf.cur, buf.nxt = buf.nxt, buf.cur
            n = int(k)
            secs["compact"] += clock() - t3
        if progress:
            progress(1)
    image = (film / spp).astype(np.float32).reshape(H, W, 3)
    stats = {"rays": rays, "passes": passes, "stage_seconds": secs}
    return RenderResult(image=image, depth=aov_depth.reshape(H, W),
                        normal=aov_normal.reshape(H, W, 3), prim=aov_prim.reshape(H, W), stats=stats)
