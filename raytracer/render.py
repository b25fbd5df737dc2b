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
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from hwbvh.errors import ParameterError
from traversal.camera import look_at_basis, tile_order
from traversal.offset import STRATEGY_CODES
from . import stages
from hwbvh.parallel import run_ranges
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


def usable_cores():
    """The cores this process may run on (its CPU affinity where the OS reports one)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _traversal_cached():
    """Whether Numba's on-disk cache holds the traversal kernel (or this process has it)."""
    from traversal.traverse import trace_chunks
    if trace_chunks.signatures:
        return True
    try:
        return bool(trace_chunks._cache._cache_file._load_index())
    except Exception:              # a Numba without this cache layout: assume it is there
        return True


def _compile_traversal_beside():
    """On a first run (the traversal kernel not in Numba's cache), a child process that compiles
    it into the cache while this process compiles the builder and the shading stages: the
    first render's compilation on two cores instead of one. None when the kernel is cached,
    the cache cannot be written, JIT compilation is off, there is one core, or no child
    process can be started. The child runs on this process' import path and ends if this
    process ends."""
    import numba
    if numba.config.DISABLE_JIT or usable_cores() < 2 or _traversal_cached():
        return None
    from traversal.traverse import trace_chunks
    try:
        cache_dir = trace_chunks._cache._cache_path
    except Exception:
        return None
    if not (os.path.isdir(cache_dir) and os.access(cache_dir, os.W_OK)):
        return None
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    try:
        return subprocess.Popen([sys.executable, "-P", "-c",
                                 "from raytracer.render import _compile_in_child; "
                                 f"_compile_in_child({os.getpid()})"],
                                env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
    except OSError:
        return None


def _compile_in_child(parent):
    """The child of ``_compile_traversal_beside``: compile the traversal kernel, and exit at
    once if the parent is gone (a terminated render leaves no compiler behind)."""
    def watch():
        while os.getppid() == parent:
            time.sleep(0.2)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()
    from traversal.api import compile_kernels
    compile_kernels()


CHILD_COMPILE_TIMEOUT = 600     # seconds; a child that takes longer is stuck (the parent compiles)


def warm_up(builder="hwbvh", traversal="numba", parallel_build=False):
    """Load (or, the first time ever, compile) the Numba kernels a render uses, on a tiny
    input, so that build and render timings measure work, not JIT start-up. Returns seconds.
    ``parallel_build`` also loads the data-parallel builder kernels that meshes above
    SEQUENTIAL_MAX_PRIMS use (benchmarks want them; a first render of a small scene does not).
    The first time, the traversal kernel compiles in a child process meanwhile
    (``_compile_traversal_beside``), and the shading stages compile on a render through
    Embree, whose hits have the same types as ours."""
    t = time.perf_counter()
    beside = _compile_traversal_beside() if builder != "embree" and traversal == "numba" \
        else None
    try:
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
        if beside is not None:
            render(indexed, make_tracer(indexed, "embree", "embree")[0])
            try:
                beside.wait(timeout=CHILD_COMPILE_TIMEOUT)
            except subprocess.TimeoutExpired:
                pass                                # killed below; the render compiles it
        render(indexed, tracer)
    finally:
        if beside is not None and beside.poll() is None:
            beside.kill()
            beside.wait()
    return time.perf_counter() - t


ACCELS = ("bvh", "grid", "kdtree")      # the acceleration structures make_tracer builds (accel=)


def make_tracer(scene, builder="hwbvh", traversal="numba", leaf_size=4, bins=16,
                precision="float32", watertight=False, accel="bvh"):
    """(tracer, build_seconds, build_info). ``accel``: "bvh" (builders hwbvh, sweep, embree),
    "grid" (``traversal.grid.GridTracer``) or "kdtree" (``traversal.kdtree.KdTreeTracer``); the
    last two with traversal "numba" and the default builder only."""
    if accel in ("grid", "kdtree"):
        if builder != "hwbvh" or traversal != "numba":
            raise ParameterError("accel", f"the {accel} has its own build and traversal "
                                 f"(accel '{accel}' needs the default builder and traversal 'numba')")
        if precision != "float32" or watertight:
            raise ParameterError("accel", f"the {accel} traces with the float32 Moller-Trumbore "
                                 f"unit only (accel '{accel}' needs precision 'float32', "
                                 "watertight False)")
        if accel == "grid":
            from traversal.grid import GridTracer as Structure
        else:
            from traversal.kdtree import KdTreeTracer as Structure
        t = time.perf_counter()
        tr = Structure(scene.triangles)
        return tr, time.perf_counter() - t, dict(tr.stats(), accel=accel)
    if accel != "bvh":
        raise ParameterError("accel", f"unknown acceleration structure {accel!r} "
                                      f"(choose from {', '.join(ACCELS)})")
    if builder == "embree":
        if traversal != "embree":
            raise ParameterError("traversal", "Embree's tree can only be traversed by Embree "
                                              "(builder 'embree' needs traversal 'embree')")
        from traversal.embree_ref import EmbreeTracer, shared_vertices
        vertices, faces = shared_vertices(scene.vertices, scene.faces)   # not part of the build
        t = time.perf_counter()
        tr = EmbreeTracer(vertices, faces)
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
        raise ParameterError("traversal", "Embree traverses its own tree only "
                                          "(traversal 'embree' needs builder 'embree')")
    raise ParameterError("traversal", f"unknown traversal {traversal!r}")


def scene_passes(scene):
    """Which passes a scene needs: shadow rays (lights and a material that takes direct light),
    reflection and refraction rays, and the bounce depth (1 when nothing reflects or refracts)."""
    used = np.unique(scene.material)
    reflective = bool((scene.kr[used].max(axis=1) > 0).any() or (scene.ior[used] > 0).any())
    refractive = bool((scene.ior[used] > 0).any())
    shades = bool(((scene.kd[used].max(axis=1) > 0) | (scene.ks[used] > 0)).any())
    return {"shadow": bool(scene.lights) and shades, "reflection": reflective,
            "refraction": refractive,
            "depth": scene.max_depth if (reflective or refractive) else 1}


class _Buffers:
    """The wavefront's arrays, allocated once per render and grown (never shrunk) when a bounce
    spawns more rays than they hold. ``cur``/``nxt``: the current and the next wavefront
    (O, D, wgt, pix, Ot, Dt; see ``raytracer.stages``), swapped after each bounce. The block
    regions (shadow rays ``sh``, their dense queue ``shq``, secondary rays ``sp``) are sized
    for the current wavefront. ``film`` and ``jitter`` are the frame's radiance sums and one
    pass's pixel offsets; ``order``: the tile order of the last frame size."""

    def __init__(self, n, n_lights, ray_dtype):
        self.L = n_lights
        self.rd = ray_dtype
        self.cur = self._wavefront(n)
        self.nxt = self._wavefront(n)
        self.cap = 0
        self.ensure_slots(n)
        self.film = np.empty((0, 3))
        self.jitter = np.empty(0)
        self.order = np.empty(0, np.int64)
        self.order_size = None

    def frame(self, width, height):
        """(film zeroed, jitter buffer, tile order) for a width x height frame."""
        npix = width * height
        if len(self.film) < npix:
            self.film = np.empty((npix, 3))
            self.jitter = np.empty(2 * npix)
        if self.order_size != (width, height):
            self.order = tile_order(width, height)   # camera rays in 4x4 tiles: coherent packets
            self.order_size = (width, height)
        film = self.film[:npix]
        film.fill(0.0)
        return film, self.jitter[:2 * npix], self.order

    def _wavefront(self, cap):
        f = lambda: np.empty((cap, 3))
        return [f(), f(), f(), np.empty(cap, np.int64), np.empty((cap, 3), self.rd),
                np.empty((cap, 3), self.rd)]

    def ensure_slots(self, n):
        if n <= self.cap:
            return
        nb = stages.n_blocks(max(n, int(self.cap * 1.5)))
        S = nb * stages.BLOCK
        L = self.L
        f, r = (lambda *shape: np.empty(shape)), (lambda *shape: np.empty(shape, self.rd))
        self.contrib = f(S, 3)
        self.sh = [r(L * S, 3), r(L * S, 3), r(L * S), f(L * S, 3), np.empty(L * S, np.int64),
                   np.zeros((nb, L), np.int64)]
        self.shq = [r(L * S, 3), r(L * S, 3), r(L * S)]
        self.sp = [f(2 * S, 3), f(2 * S, 3), f(2 * S, 3), np.empty(2 * S, np.int64),
                   np.zeros((nb, 2), np.int64)]
        self.cap = S

    def ensure_next(self, n):
        if n > len(self.nxt[3]):
            self.nxt = self._wavefront(max(n, int(len(self.nxt[3]) * 1.5)))


_kept = threading.local()


def _buffers(n, n_lights, ray_dtype):
    """This thread's wavefront buffers from its last render when they fit, else new ones.
    Fresh buffers of a 640x480 frame are ~200 MB of pages the kernel must map and zero on first
    touch: a quarter of the default scene's render time. ``release_buffers`` frees them."""
    buf = getattr(_kept, "buffers", None)
    if buf is None or buf.L != n_lights or buf.rd != ray_dtype:
        buf = _kept.buffers = _Buffers(n, n_lights, ray_dtype)
    else:
        buf.ensure_slots(n)
        buf.ensure_next(n)
        if len(buf.cur[3]) < n:
            buf.cur, buf.nxt = buf.nxt, buf.cur
            buf.ensure_next(n)
    return buf


_scratch = threading.local()


def _shade(b0, b1, *args):
    """``stages.shade`` with the calling thread's scratch (``stages.shade_scratch``)."""
    scratch = getattr(_scratch, "arrays", None)
    if scratch is None:
        scratch = _scratch.arrays = stages.shade_scratch()
    stages.shade(b0, b1, *args, *scratch)


def release_buffers():
    """Free the calling thread's kept wavefront buffers (see ``_buffers``)."""
    _kept.buffers = None


def _scene_arrays(scene, lights):
    """The compiled scene as the kernels read it: per-triangle unit geometric normals and
    coordinate magnitudes (for ray offsets), material tables, and a table of ``lights`` (the
    scene's, or none when it needs no shadow rays: the shading kernel sizes its shadow slots
    by this table)."""
    tris = np.ascontiguousarray(scene.triangles, np.float32)
    face_n = np.empty((len(tris), 3))
    tri_mag = np.empty(len(tris))
    run_ranges(stages.triangle_terms, len(tris), tris, face_n, tri_mag, min_items=4096)
    L = len(lights)
    kind = np.zeros(L, np.int64)
    pos = np.zeros((L, 3))
    ldir = np.zeros((L, 3))
    val = np.zeros((L, 3))
    for k, light in enumerate(lights):               # a handful of lights, not primitives
        if light["type"] == "point":
            kind[k] = stages.POINT
            pos[k] = light["position"]
            val[k] = light["intensity"]
        else:
            kind[k] = stages.DIRECTIONAL
            ldir[k] = -np.asarray(light["direction"], np.float64)
            val[k] = light["irradiance"]
    f64 = lambda a: np.ascontiguousarray(a, np.float64)
    return (face_n, np.ascontiguousarray(scene.normals, np.float32),
            np.ascontiguousarray(scene.material, np.int32), tri_mag, f64(scene.kd),
            f64(scene.kd) / np.pi, f64(scene.ks),
            f64(scene.shininess), f64(scene.kr), f64(scene.ior), kind, pos, ldir, val,
            f64(scene.ambient), f64(scene.background), float(scene.cutoff))


def _fill_uniform(lo, hi, state, out):
    bits = np.random.PCG64()
    bits.state = state
    bits.advance(lo)                          # one 64-bit draw per double
    np.random.Generator(bits).random(out=out[lo:hi])


def _jitter(seed, sample, npix, out):
    """The pixel offsets of one sample pass: ``default_rng([seed, sample])``'s first 2 * npix
    uniforms (x for every pixel, then y), drawn in parallel by advancing copies of the stream.
    Returns (x, y), views of ``out``."""
    state = np.random.default_rng([seed, sample]).bit_generator.state
    run_ranges(_fill_uniform, 2 * npix, state, out, min_items=1 << 16)
    return out[:npix], out[npix:]


def render(scene, tracer, seed=0, progress=None, offset="relative"):
    """Render a CompiledScene with ``tracer`` (anything with the ``intersect``/``occluded``
    interface of ``traversal.tracers``: our traversal, Embree, or a verifying, counting or
    recording wrapper of either). ``progress``: a callable(n) per finished sample pass.
    ``offset``: secondary-ray offset strategy (traversal.offset.STRATEGIES).
    stats: rays per kind, the passes the scene needs, and seconds per stage."""
    if offset not in STRATEGY_CODES:
        raise ParameterError("offset", f"unknown strategy {offset!r} (choose from {', '.join(STRATEGY_CODES)})")
    if int(seed) < 0:
        raise ParameterError("seed", f"must be non-negative, got {seed}")
    if len(scene.triangles) == 0:
        raise ParameterError("scene", "has no triangles to render")
    W, H, spp = scene.width, scene.height, scene.spp
    npix = W * H
    passes = scene_passes(scene)
    aov_depth = np.full(npix, np.inf, np.float32)
    aov_normal = np.zeros((npix, 3), np.float32)
    aov_prim = np.full(npix, -1, np.int32)
    rays = {"primary": 0, "shadow": 0, "reflection": 0, "refraction": 0}
    secs = dict.fromkeys(("generate", "intersect", "shade", "pack", "occluded", "accumulate"), 0.0)
    n_lights = len(scene.lights) if passes["shadow"] else 0
    sa = _scene_arrays(scene, scene.lights if n_lights else [])
    # rays go to the tracer in its own precision (float32 for the hardware units), so it
    # reads them as they are
    buf = _buffers(npix, n_lights, np.dtype(getattr(tracer, "dtype", np.float32)))
    cam = scene.camera
    cu, cv, cw = look_at_basis(cam["eye"], cam["target"], cam["up"])
    eye = np.asarray(cam["eye"], np.float64)
    half = float(np.tan(np.radians(cam["fov"]) / 2))
    film, jit_buf, order = buf.frame(W, H)
    gx = int(np.ceil(np.sqrt(spp)))
    gy = int(np.ceil(spp / gx))
    no_jitter = np.zeros(0)
    code = STRATEGY_CODES[offset]
    clock = time.perf_counter

    last = [clock()]

    def lap(stage):
        now = clock()
        secs[stage] += now - last[0]
        last[0] = now

    for s in range(spp):
        lap("generate")
        if scene.jitter:
            jx, jy = _jitter(seed, s, npix, jit_buf)
        else:
            jx = jy = no_jitter
        terms = stages.camera_terms(W, H, half, s % gx, s // gx, gx, gy)
        O, D, wgt, pix, Ot, Dt = buf.cur
        run_ranges(stages.generate_camera_rays, npix, order, W, jx, jy, scene.jitter, terms, eye,
                   cu, cv, cw, D, pix, Ot, Dt, min_items=4096)
        n = npix
        rays["primary"] += n
        lap("generate")
        for bounce in range(passes["depth"]):
            if n == 0:
                break
            buf.ensure_slots(n)
            nb = stages.n_blocks(n)
            O, D, wgt, pix, Ot, Dt = buf.cur
            sh_Ot, sh_Dt, sh_T, sh_C, sh_pix, sh_cnt = buf.sh
            sp_O, sp_D, sp_W, sp_pix, sp_cnt = buf.sp
            spawn = bounce + 1 < passes["depth"]
            lap("pack")
            h = tracer.intersect(Ot[:n], Dt[:n], normals=False)
            lap("intersect")
            run_ranges(_shade, nb, nb, O, D, wgt, pix, n, h.prim, h.t, h.u, h.v, *sa, code,
                       n_lights > 0, spawn, bounce == 0, eye, bounce == 0 and s == 0, aov_depth,
                       aov_normal, aov_prim, film, buf.contrib, sh_Ot, sh_Dt, sh_T, sh_C, sh_pix,
                       sh_cnt[:nb], sp_O, sp_D, sp_W, sp_pix, sp_cnt[:nb])
            lap("shade")
            no_runs = np.zeros(1, np.int64)
            sh_start = stages.run_starts(sh_cnt[:nb]) if n_lights else no_runs
            sp_start = stages.run_starts(sp_cnt[:nb]) if spawn else no_runs
            m = int(sh_start[-1])
            k = int(sp_start[-1])
            buf.ensure_next(k)
            n_sh = nb * n_lights
            qO, qD, qT = buf.shq
            run_ranges(stages.pack, n_sh + (2 * nb if spawn else 0), n_sh, sh_start, sh_cnt[:nb],
                       sh_Ot, sh_Dt, sh_T, qO, qD, qT, sp_start, sp_cnt[:nb], sp_O, sp_D, sp_W,
                       sp_pix, *buf.nxt, min_items=8)
            lap("pack")
            if n_lights:
                blocked = np.ascontiguousarray(tracer.occluded(qO[:m], qD[:m], 0.0, qT[:m]))
                lap("occluded")
                if bounce == 0:
                    run_ranges(stages.accumulate_unblocked, nb, sh_start, sh_cnt[:nb], sh_C,
                               sh_pix, blocked, film, True, min_items=64)
                else:
                    stages.accumulate_unblocked(0, nb, sh_start, sh_cnt[:nb], sh_C, sh_pix,
                                                blocked, film, False)
                rays["shadow"] += m
            if bounce > 0:                          # the camera wavefront added its own
                stages.accumulate(film, pix, buf.contrib, n)
            lap("accumulate")
            if not spawn:
                break
            refl = int(sp_start[nb])
            rays["reflection"] += refl
            rays["refraction"] += k - refl
            buf.cur, buf.nxt = buf.nxt, buf.cur
            n = k
        if progress:
            progress(1)
    image = (film / spp).astype(np.float32).reshape(H, W, 3)
    stats = {"rays": rays, "passes": passes, "stage_seconds": secs}
    return RenderResult(image=image, depth=aov_depth.reshape(H, W),
                        normal=aov_normal.reshape(H, W, 3), prim=aov_prim.reshape(H, W), stats=stats)
