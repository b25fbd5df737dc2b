"""Whitted-style ray tracing (Whitted 1980; thesis 2.2.2) on the simulated hardware's trees.

The frame is cut into bands of rows (``band_rows``); a band goes through every sample pass and
bounce on one thread, its rays travelling as wavefronts through compiled stages
(``raytracer.stages``): generate camera rays, intersect, shade (direct light with one shadow
ray per light, spawn secondary rays), join, occluded, accumulate. The tracer (our traversal of
the hwbvh tree, or Embree) answers
the ``intersect`` and ``occluded`` queries; everything else is the same compiled code for
both, so a comparison of the two measures their trees and traversals. Shading per hit:

    L = kd * ambient + sum_lights V * E * (kd/pi * cos + ks * (s+8)/(8 pi) * cos_h^s * cos)
        + kr * L(reflected)                                   (mirrors, plastics)
    L = F * L(reflected) + (1 - F) * L(refracted)             (dielectrics, exact Fresnel)

with E = I / r^2 for a point light of intensity I and E = irradiance for a directional light,
V the hard-shadow visibility (one ``occluded`` ray per light, cast only from a surface with a
diffuse or specular term: ``takes_direct_light``), Blinn-Phong highlights, total
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
from typing import NamedTuple

import numpy as np

from hwbvh.config import DEFAULT_BINS, DEFAULT_LEAF_SIZE
from hwbvh.errors import ParameterError, is_integer
from traversal.camera import TILE, check_camera, look_at_basis
from traversal.config import F32_UNIT_MAX_PRODUCT, F32_UNIT_MIN_SPAN
from traversal.offset import STRATEGY_CODES
from traversal.api import ACCELS, PRECISIONS, release_kept_bounds  # noqa: F401 (ACCELS: accel=)
from traversal.tracers import check_tracer, run_as_tracer_allows
from traversal.triangle_unit import coordinate_box, f32_unit_reach, span_of
from . import pcg64, stages
from .config import BAND_PIXELS, BLOCK, CHILD_COMPILE_TIMEOUT, MAX_PIXELS, MIN_BANDS, PIXEL
from hwbvh.parallel import run_ranges, usable_cores
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


def traversal_cached():
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
    if numba.config.DISABLE_JIT or usable_cores() < 2 or traversal_cached():
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


def warm_up(builder=None, traversal=None, parallel_build=False, precision="float32"):
    """Load (or, the first time ever, compile) the Numba kernels a render uses, on a tiny
    input, so that build and render timings measure work, not JIT start-up. Returns seconds.
    ``parallel_build`` also loads the data-parallel builder kernels that meshes above
    SEQUENTIAL_MAX_PRIMS use (benchmarks want them; a first render of a small scene does not);
    ``precision`` "float64" also the wider units' kernels, which compile on their own.
    The first time, the traversal kernel compiles in a child process meanwhile
    (``_compile_traversal_beside``), and the shading stages compile on a render through
    Embree, whose hits have the same types as ours."""
    t = time.perf_counter()
    builder, traversal = builder_and_traversal(builder, traversal)      # as make_tracer pairs them
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
        if precision != "float32" and builder != "embree" and traversal == "numba":
            render(indexed, make_tracer(indexed, builder, traversal, precision=precision)[0])
    finally:
        if beside is not None and beside.poll() is None:
            beside.kill()
            beside.wait()
    return time.perf_counter() - t


TRAVERSALS = ("numba", "embree")        # who traverses a BVH (traversal=): our units or Embree


def builder_and_traversal(builder=None, traversal=None):
    """The (builder, traversal) pair with what was not given (None) filled in: Embree's tree
    goes with Embree's traversal only, so "embree" on one side brings it on the other; else
    the hardware's tree on our units."""
    embree = "embree" in (builder, traversal)
    return ("embree" if embree else "hwbvh") if builder is None else builder, \
        ("embree" if embree else "numba") if traversal is None else traversal


def make_tracer(scene, builder=None, traversal=None, leaf_size=DEFAULT_LEAF_SIZE,
                bins=DEFAULT_BINS,
                precision="float32", watertight=False, accel="bvh"):
    """(tracer, build_seconds, build_info). ``builder``: "hwbvh" (default), "sweep" or
    "embree"; ``traversal``: "numba" (our units, default) or "embree". Embree's tree goes with
    Embree's traversal only, so either one given as "embree" makes the other "embree" too.
    ``accel``: "bvh" (builders hwbvh, sweep, embree), "grid" (``traversal.grid.GridTracer``)
    or "kdtree" (``traversal.kdtree.KdTreeTracer``); the last two with traversal "numba" and
    the default builder only. Every argument is checked before any build. The ``build_info``
    of our builders' BVH has its nodes and SAH cost, and, for the hardware's tree at the default
    leaf size and bins (those of HWBVH-C and HWBVH-HP), ``simulated_build_seconds`` of both
    presets (``hwbvh.cycle_model.simulate`` takes other configurations)."""
    builder, traversal = builder_and_traversal(builder, traversal)
    if accel not in ACCELS:
        raise ParameterError("accel", f"unknown acceleration structure {accel!r} "
                                      f"(choose from {', '.join(ACCELS)})")
    if traversal not in TRAVERSALS:
        raise ParameterError("traversal", f"unknown traversal {traversal!r} "
                                          f"(choose from {', '.join(TRAVERSALS)})")
    if not isinstance(watertight, (bool, np.bool_)):
        raise ParameterError("watertight", f"expected True or False, got {watertight!r}")
    if precision not in PRECISIONS:
        raise ParameterError("precision", f"must be one of {', '.join(PRECISIONS)}, got "
                                          f"{precision!r}")
    if not hasattr(scene, "triangles"):
        raise ParameterError("scene", f"expected a compiled scene (scenes.compile_scene), got "
                                      f"{type(scene).__name__}")
    if (accel != "bvh" or builder != "hwbvh") and \
            (leaf_size, bins) != (DEFAULT_LEAF_SIZE, DEFAULT_BINS):
        raise ParameterError("leaf_size" if leaf_size != DEFAULT_LEAF_SIZE else "bins",
                             "applies to the hardware's builder only (accel 'bvh', builder "
                             "'hwbvh'; the sweep builder makes its leaves where the full SAH "
                             "stops splitting)")
    if precision == "float32":              # every structure but the float64 BVH
        check_float32_reach(scene)
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
    if builder == "embree":
        if traversal != "embree":
            raise ParameterError("traversal", "Embree's tree can only be traversed by Embree "
                                              "(builder 'embree' needs traversal 'embree')")
        from traversal.embree_ref import EmbreeTracer, shared_vertices
        vertices, faces = shared_vertices(scene.vertices, scene.faces)   # not part of the build
        t = time.perf_counter()
        tr = EmbreeTracer(vertices, faces)
        seconds = time.perf_counter() - t
        tr.triangles                    # gathered now, for render's check, outside the build
        return tr, seconds, {"builder": "embree"}
    if traversal == "embree":
        raise ParameterError("traversal", "Embree traverses its own tree only "
                                          "(traversal 'embree' needs builder 'embree')")
    import hwbvh
    from traversal import Tracer
    # timed up to a tracer ready to trace (its triangle rows and checks included), as the
    # grid's, the kd-tree's and Embree's set-ups are
    t = time.perf_counter()
    bvh = hwbvh.build(scene.triangles, builder=builder, leaf_size=leaf_size, bins=bins)
    built = time.perf_counter()
    tracer = Tracer(bvh, precision=precision, watertight=watertight)
    ready = time.perf_counter()
    info = {"builder": builder, "nodes": bvh.meta["nodes"], "sah_cost": bvh.meta["sah_cost"],
            "build_seconds_core": bvh.meta["build_seconds"],
            # the software work between a built tree and tracing (the triangle rows in index
            # order, the checks), which a hardware build would leave to do too
            "tracer_setup_seconds": ready - built}
    if builder == "hwbvh" and leaf_size == DEFAULT_LEAF_SIZE and bins == DEFAULT_BINS:
        # the simulated hardware build time of the thesis' instantiations (Table 4.1)
        from hwbvh.cycle_model import PRESETS, simulate
        info["simulated_build_seconds"] = {name: simulate(bvh.tree, p)["seconds"]
                                           for name, p in PRESETS.items()}
    return tracer, ready - t, info


def simulated_ready_seconds(info):
    """{preset: seconds} from a tree to a tracer ready to trace with a simulated hardware build
    (``make_tracer``'s info): each preset's build time plus our tracer's set-up in software;
    None where the info has no simulated builds (none, or a preset's entry null)."""
    sim = info.get("simulated_build_seconds")
    if not sim or any(v is None for v in sim.values()):
        return None
    return {k: v + (info.get("tracer_setup_seconds") or 0.0) for k, v in sim.items()}


def takes_direct_light(scene):
    """Per material, whether a hit on it casts shadow rays: a material with a diffuse or a
    specular term that is not a dielectric. A perfect mirror (or a black surface) would add
    0 for every light, so it casts none, as a renderer samples no light for a purely
    specular surface; a dielectric takes no direct light (classic Whitted)."""
    return ~(np.asarray(scene.ior) > 0) & \
        ((np.asarray(scene.kd) > 0).any(axis=1) | (np.asarray(scene.ks) > 0))


def scene_passes(scene):
    """Which passes a scene needs: shadow rays (lights and a material that takes direct light),
    reflection and refraction rays, and the bounce depth (1 when nothing reflects or refracts)."""
    used = np.unique(scene.material)
    reflective = bool((scene.kr[used].max(axis=1) > 0).any() or (scene.ior[used] > 0).any())
    refractive = bool((scene.ior[used] > 0).any())
    shades = bool(takes_direct_light(scene)[used].any())
    return {"shadow": bool(scene.lights) and shades, "reflection": reflective,
            "refraction": refractive,
            "depth": scene.max_depth if (reflective or refractive) else 1}


class _Buffers:
    """One thread's wavefront arrays, allocated once and grown (never shrunk) when a bounce
    spawns more rays than they hold. ``cur``/``nxt``: the current and the next wavefront
    (O, D, wgt, pix, Ot, Dt, order; see ``raytracer.stages``), swapped after each bounce; a
    secondary wavefront holds its reflections from row 0 and its refractions from the row of
    the last queue's length (``stages.shade``), so it is given twice that many rows, and its
    contributions ``contrib`` a row each. Sized for ``cap`` rays of the current queue: the
    shadow queue ``sh`` (per light a region of ``cap``: the tracer's origin, direction and
    t_max, the light brought, the pixel; then the counts per light). ``spawned``: the counts
    of reflections and refractions. ``jitter``: one band's pixel offsets of one sample
    pass; ``screen``: its camera rays' screen points (``stages.generate_camera_rays``)."""

    def __init__(self, n, n_lights, ray_dtype):
        self.L = n_lights
        self.rd = ray_dtype
        self.cur = self._wavefront(n)
        self.nxt = self._wavefront(n)
        self.cap = 0
        self.contrib = np.empty((0, 3))
        self.ensure_slots(n, n)
        self.spawned = np.zeros(2, np.int64)
        self.jitter = np.empty(2 * n)
        self.screen = np.empty(n), np.empty(n)

    def _wavefront(self, cap):
        f = lambda: np.empty((cap, 3), self.rd)
        return [f(), f(), np.empty((cap, 3)), np.empty(cap, PIXEL), np.empty((cap, 3), self.rd),
                np.empty((cap, 3), self.rd), np.empty(cap, PIXEL)]

    def ensure_slots(self, n, rows):
        """Room for a queue of ``n`` rays over ``rows`` wavefront rows."""
        if rows > len(self.contrib):
            self.contrib = np.empty((max(rows, int(len(self.contrib) * 1.5)), 3))
        if n <= self.cap:
            return
        S = stages.n_blocks(max(n, int(self.cap * 1.5))) * BLOCK
        L = self.L
        r = lambda *shape: np.empty(shape, self.rd)
        self.sh = [r(L * S, 3), r(L * S, 3), r(L * S), np.empty((L * S, 3)),
                   np.empty(L * S, PIXEL), np.zeros(L, np.int64)]
        self.cap = S

    def ensure_next(self, n):
        if n > len(self.nxt[3]):
            self.nxt = self._wavefront(max(n, int(len(self.nxt[3]) * 1.5)))


_kept = threading.local()
_generation = [0]                 # bumped by release_buffers: older kept arrays are dropped


def _kept_current():
    """This thread's kept arrays, emptied if ``release_buffers`` ran since they were kept."""
    if getattr(_kept, "generation", None) != _generation[0]:
        _kept.buffers = _kept.film = _kept.scratch = _kept.records = None
        _kept.generation = _generation[0]
    return _kept


def _buffers(n, n_lights, ray_dtype):
    """This thread's wavefront buffers from its last band when they fit, else new ones: fresh
    pages cost a first touch each, so a thread keeps its buffers from band to band and from
    render to render. ``release_buffers`` frees them."""
    buf = getattr(_kept_current(), "buffers", None)
    if buf is None or buf.L != n_lights or buf.rd != ray_dtype:
        buf = _kept.buffers = _Buffers(n, n_lights, ray_dtype)
    else:
        buf.ensure_slots(n, n)
        buf.ensure_next(n)
        if len(buf.cur[3]) < n:
            buf.cur, buf.nxt = buf.nxt, buf.cur
            buf.ensure_next(n)
        if len(buf.jitter) < 2 * n:
            buf.jitter = np.empty(2 * n)
        if len(buf.screen[0]) < n:
            buf.screen = np.empty(n), np.empty(n)
    return buf


def _film(npix):
    """The calling thread's radiance sums for a frame of ``npix`` pixels (float64, (npix, 3)),
    kept from its last render: a fresh 640x480 film is 7 MB of pages to map on first touch.
    Not cleared: the first sample pass' camera rays store each pixel's first sum
    (``stages.accumulate`` with ``first``)."""
    film = getattr(_kept_current(), "film", None)
    if film is None or len(film) < npix:
        film = _kept.film = np.empty((npix, 3))
    return film[:npix]


def _shade(*args):
    """``stages.shade`` with the calling thread's kept scratch (``stages.shade_scratch``)."""
    kept = _kept_current()
    scratch = getattr(kept, "scratch", None)
    if scratch is None:
        scratch = kept.scratch = stages.shade_scratch()
    return stages.shade(*args, *scratch)


def release_buffers():
    """Free the kept wavefront buffers, films, shading scratch and triangle records (see
    ``_buffers``, ``_film``, ``_shade``, ``_records``): the calling thread's now, every other
    thread's when it next renders; and the tracer's kept ray bounds
    (``traversal.api.release_kept_bounds``)."""
    _generation[0] += 1
    _kept_current()
    release_kept_bounds()


class SceneArrays(NamedTuple):
    """A compiled scene as the shading kernel takes it, in the order of its arguments."""
    tri_rec: np.ndarray                 # (n * stages.TRI_WORDS,) per-triangle shading records
    ambient_light: np.ndarray           # (m, 3) kd * ambient per material
    kd_pi: np.ndarray                   # (m, 3) kd / pi
    ks: np.ndarray
    shininess: np.ndarray
    kr: np.ndarray
    ior: np.ndarray                     # > 0: a dielectric
    light_kind: np.ndarray              # the light table: stages.POINT or DIRECTIONAL
    light_pos: np.ndarray
    light_dir: np.ndarray               # toward a directional light
    light_val: np.ndarray               # intensity or irradiance
    background: np.ndarray
    cutoff: float


def _records(words, align=64):
    """The calling thread's array for a frame's triangle records: ``words`` float64, not
    initialised, the first starting a cache line; kept from its last render (grown, never
    shrunk), as a fresh one would be pages to map on first touch (on a mesh of 262k triangles,
    33 MB: 6 ms a render)."""
    kept = _kept_current()
    rec = getattr(kept, "records", None)
    if rec is None or len(rec) < words:
        buf = np.empty(words + align // 8)
        skip = (-buf.ctypes.data % align) // 8
        rec = kept.records = buf[skip:skip + words]
    return rec[:words]


def _scene_arrays(scene, lights, material):
    """The compiled scene as the kernels read it: a shading record per triangle (normals,
    plane, coordinate magnitude for ray offsets, material and what it does:
    ``stages.TRI_WORDS``),
    material tables, and a table of ``lights`` (the scene's, or none when it needs no shadow
    rays: the shading kernel sizes its shadow slots by this table). ``material``: the
    scene's material per triangle, unsigned."""
    tris = np.ascontiguousarray(scene.triangles, np.float32)
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
    kr, ior = f64(scene.kr), f64(scene.ior)
    rec = _records(len(tris) * stages.TRI_WORDS)
    run_ranges(stages.triangle_terms, len(tris), tris,
               np.ascontiguousarray(scene.normals, np.float32),
               material, takes_direct_light(scene),
               (ior > 0) | (kr.max(axis=1) > 0), rec, min_items=4096)
    return SceneArrays(
        rec, f64(scene.kd) * f64(scene.ambient),
        f64(scene.kd) / np.pi, f64(scene.ks), f64(scene.shininess), kr, ior, kind, pos, ldir, val,
        f64(scene.background), float(scene.cutoff))


def _band_jitter(words, npix, p0, p1, out):
    """The pixel offsets of pixels p0..p1 in one sample pass: of the pass' stream
    (``default_rng([seed, sample])``, ``words`` from ``pcg64.stream_words``), whose first
    2 * npix uniforms are x for every pixel, then y, the uniforms at p0..p1 and
    npix + p0..npix + p1. Returns (x, y), views of ``out``."""
    m = p1 - p0
    x, y = out[:m], out[m:2 * m]
    pcg64.uniforms(words, p0, x)
    pcg64.uniforms(words, npix + p0, y)
    return x, y


def band_rows(width, height):
    """Rows per band: about ``config.BAND_PIXELS`` pixels, at least ``config.MIN_BANDS`` bands
    where the frame has the rows, a multiple of the camera tiles' rows. Depends on the frame
    size only, so a render does not depend on the thread count."""
    rows = round(BAND_PIXELS / max(width, 1) / TILE) * TILE
    most = (height - 1) // (MIN_BANDS - 1) // TILE * TILE     # ceil(height / most) >= MIN_BANDS
    return max(TILE, min(rows, most))


def render(scene, tracer, seed=0, progress=None, offset="relative"):
    """Render a CompiledScene with ``tracer`` (anything with the ``intersect``/``occluded``
    interface of ``traversal.tracers``: our traversal, Embree, or a verifying, counting or
    recording wrapper of either). ``progress``: a callable(rows) per finished band of image
    rows, called from the threads that render bands, one call at a time. ``offset``:
    secondary-ray offset strategy (traversal.offset.STRATEGIES).

    The frame is rendered in bands of rows (``config.BAND_PIXELS``), each through every sample
    pass and bounce on one thread; a tracer that may be called from several threads at once
    (``concurrent``) gets the bands on all threads, each query traced on its band's thread;
    another (a recording wrapper) gets them one by one on this thread, each query on all
    threads (``traversal.tracers.run_as_tracer_allows``).
    The result is the same either way: every pixel belongs to one band, and a band's rays
    and its film additions come in a fixed order.

    stats: rays per kind, the passes the scene needs, seconds per stage, summed over the
    threads, and ``pixels_beyond_float32``: the pixels too bright for the float32 image,
    which hold +inf."""
    _check_render_arguments(scene, tracer, seed, progress)
    if offset not in STRATEGY_CODES:
        raise ParameterError("offset", f"unknown strategy {offset!r} (choose from {', '.join(STRATEGY_CODES)})")
    ray_dtype = np.dtype(getattr(tracer, "dtype", np.float32))
    if ray_dtype == np.float32:
        check_float32_reach(scene)
    W, H, spp = scene.width, scene.height, scene.spp
    npix = W * H
    passes = scene_passes(scene)
    n_lights = len(scene.lights) if passes["shadow"] else 0
    cam = scene.camera
    cu, cv, cw = look_at_basis(cam["eye"], cam["target"], cam["up"])
    gx = int(np.ceil(np.sqrt(spp)))            # sample passes on a gx x gy grid of strata
    gy = int(np.ceil(spp / gx))
    half = float(np.tan(np.radians(cam["fov"]) / 2))
    material = np.ascontiguousarray(scene.material, np.uint32)      # see config.PIXEL
    frame = _Frame(
        scene=scene, passes=passes, n_lights=n_lights, code=STRATEGY_CODES[offset],
        sa=_scene_arrays(scene, scene.lights if n_lights else [], material),
        material=material,
        # rays go to the tracer in its own precision (float32 for the hardware units), so it
        # reads them as they are
        ray_dtype=ray_dtype,
        basis=(cu, cv, cw), eye=np.asarray(cam["eye"], np.float64),
        camera_terms=[stages.camera_terms(W, H, half, s % gx, s // gx, gx, gy)
                      for s in range(spp)],              # each sample pass's stratum
        rows=band_rows(W, H),
        streams=[pcg64.stream_words(seed, s) for s in range(spp)]
        if scene.jitter else None,
        film=_film(npix), image=np.empty((npix, 3), np.float32),
        aov_depth=np.empty(npix, np.float32), aov_normal=np.empty((npix, 3), np.float32),
        aov_prim=np.empty(npix, np.int32), tracer=tracer,
        progress=_one_at_a_time(progress) if progress else None)
    n_bands = -(-H // frame.rows)
    band_stats = [None] * n_bands

    def bands(b0, b1):
        for b in range(b0, b1):
            band_stats[b] = _render_band(frame, b)

    # a band each: the last band ends soonest
    run_as_tracer_allows(tracer, bands, n_bands, parts=n_bands)
    rays = {k: sum(r[k] for r, _, _ in band_stats) for k in RAY_KINDS}
    secs = {k: sum(t[k] for _, t, _ in band_stats) for k in STAGES}
    stats = {"rays": rays, "passes": passes, "stage_seconds": secs,
             "pixels_beyond_float32": sum(over for _, _, over in band_stats)}
    return RenderResult(image=frame.image.reshape(H, W, 3), depth=frame.aov_depth.reshape(H, W),
                        normal=frame.aov_normal.reshape(H, W, 3),
                        prim=frame.aov_prim.reshape(H, W), stats=stats)


def verified_render(scene, tracer, seed=0, image=None, offset="relative", progress=None):
    """Render ``scene`` once more with every query ``tracer`` answers checked against Embree
    (``traversal.tracers.VerifyingTracer``): the closest hits and the ``occluded`` answers
    shading used. A render is deterministic, so this asks the queries of the render it
    checks, made apart so that Embree's time stays out of that render's time. ``image``: that
    render's image, which this one must equal bit for bit (``same_image`` in the summary).
    ``progress`` as for ``render``. Returns (``VerifyingTracer.summary()``, seconds of the
    checked render)."""
    from traversal.tracers import VerifyingTracer

    _check_render_arguments(scene, tracer, seed, progress)
    if image is not None:
        shape = (scene.height, scene.width, 3)
        if not isinstance(image, np.ndarray) or image.shape != shape or image.dtype != np.float32:
            got = (f"a {image.dtype} array of shape {image.shape}" if isinstance(image, np.ndarray)
                   else type(image).__name__)
            raise ParameterError("image", f"expected the render's image, a float32 array of "
                                          f"shape {shape}, got {got}")
    checked = VerifyingTracer(tracer, scene.triangles, scene.vertices, scene.faces)
    t = time.perf_counter()
    res = render(scene, checked, seed=seed, offset=offset, progress=progress)
    seconds = time.perf_counter() - t
    summary = checked.summary()
    if image is not None:
        summary["same_image"] = bool(np.array_equal(res.image, image, equal_nan=True))
    return summary, seconds


def _check_render_arguments(scene, tracer, seed, progress):
    """``render``'s arguments, before any work: a compiled scene with triangles and a film,
    a tracer with both queries, a seed that is an integer, a callable ``progress``."""
    if not all(hasattr(scene, a) for a in ("triangles", "width", "height", "spp", "camera")):
        raise ParameterError("scene", f"expected a compiled scene (scenes.compile_scene), got "
                                      f"{type(scene).__name__}")
    if len(scene.triangles) == 0:
        raise ParameterError("scene", "has no triangles to render")
    for key in ("width", "height", "spp", "max_depth"):
        v = getattr(scene, key, None)
        if not is_integer(v) or v < 1:
            raise ParameterError(f"scene.{key}", f"must be a positive integer, got {v!r}")
    if int(scene.width) * int(scene.height) > MAX_PIXELS:
        raise ParameterError("scene.width", f"{scene.width} x {scene.height} pixels is more "
                                            f"than the renderer's {MAX_PIXELS}")
    _check_camera(scene.camera)
    _check_materials(scene)
    _check_shading_arrays(scene)
    check_tracer(tracer, triangles=scene.triangles)
    if not is_integer(seed) or seed < 0:
        raise ParameterError("seed", f"must be a non-negative integer, got {seed!r}")
    if progress is not None and not callable(progress):
        raise ParameterError("progress", f"expected a callable or None, got {type(progress).__name__}")


def _check_materials(scene):
    """One material per triangle, each an index into the scene's material tables, which all
    have a row per material (as ``compile_scene`` makes them; checked again, as the shading
    kernels index with them unchecked)."""
    tables = ("kd", "ks", "shininess", "kr", "ior")
    rows = {k: np.shape(getattr(scene, k, None))[:1] for k in tables}
    if len(set(rows.values())) != 1 or rows["kd"] == ():
        got = ", ".join(f"{k} {v[0] if v else 'none'}" for k, v in rows.items())
        raise ParameterError("scene.kd", f"the material tables ({', '.join(tables)}) must "
                                         f"have a row per material, got {got}")
    n = rows["kd"][0]
    mat = np.asarray(getattr(scene, "material", None))
    if mat.shape != (len(scene.triangles),) or mat.dtype.kind not in "iu":
        raise ParameterError("scene.material", f"expected an integer per triangle "
                                               f"({len(scene.triangles)}), got {mat.dtype} "
                                               f"of shape {mat.shape}")
    if mat.min() < 0 or mat.max() >= n:
        raise ParameterError("scene.material", f"indices must lie in [0, {n}) (the scene's "
                                               f"materials), got {int(mat.min())}..{int(mat.max())}")


# What a compiled light holds, by its type: its place or direction, and its light
LIGHT_TERMS = {"point": ("position", "intensity"), "directional": ("direction", "irradiance")}


def _check_shading_arrays(scene):
    """The rest of what the shading kernels read unchecked, as ``compile_scene`` makes it
    (checked again, as the materials are): the vertex normals, one (3, 3) per triangle; the
    material tables' columns (kd and kr three per material, ks, shininess and ior one); the
    ambient light and background, three numbers each; each light a point (position,
    intensity) or directional one (direction, irradiance) of three numbers each. Numbers are
    finite (a NaN would make a NaN image without a word), except in the normals, where a NaN
    is a normal the shading cannot use and leaves for the geometric one."""
    n, m = len(scene.triangles), len(scene.kd)
    for key, shape in (("normals", (n, 3, 3)), ("kd", (m, 3)), ("kr", (m, 3)), ("ks", (m,)),
                       ("shininess", (m,)), ("ior", (m,)), ("ambient", (3,)),
                       ("background", (3,))):
        a = getattr(scene, key, None)
        a = np.asarray(a) if a is not None else None
        if a is None or a.shape != shape or a.dtype.kind not in "fiu":
            got = "None" if a is None else f"{a.dtype} of shape {a.shape}"
            raise ParameterError(f"scene.{key}", f"expected numbers of shape {shape}, got {got}")
        if key != "normals" and not np.isfinite(a).all():
            raise ParameterError(f"scene.{key}", "holds a number that is not finite")
    cutoff = getattr(scene, "cutoff", None)
    if isinstance(cutoff, (bool, np.bool_)) or not isinstance(cutoff, (int, float, np.number)) \
            or not np.isfinite(cutoff):
        raise ParameterError("scene.cutoff", f"must be a finite number, got {cutoff!r}")
    lights = scene.lights if isinstance(scene.lights, (list, tuple)) else None
    if lights is None:
        raise ParameterError("scene.lights", f"expected a list of lights, got "
                                             f"{type(scene.lights).__name__}")
    for k, light in enumerate(lights):
        keys = LIGHT_TERMS.get(light.get("type") if isinstance(light, dict) else None)
        if keys is None:
            raise ParameterError(f"scene.lights[{k}]", f"expected a point or directional light "
                                                       f"as compile_scene makes it, got {light!r}")
        for key in keys:
            v = light.get(key)
            v = np.asarray(v) if v is not None else None
            if v is None or v.shape != (3,) or v.dtype.kind not in "fiu" or \
                    not np.isfinite(v).all():
                raise ParameterError(f"scene.lights[{k}].{key}", f"expected three finite "
                                                                 f"numbers, got {light.get(key)!r}")


# ``check_camera``'s names for a compiled scene's camera
SCENE_CAMERA_NAMES = dict({k: f"scene.camera.{k}" for k in ("eye", "target", "up", "fov")},
                          apart="scene.camera")


def _check_camera(cam):
    """A compiled scene's camera as ``compile_scene`` makes it (checked again: a scene changed
    after compiling, by ``dataclasses.replace`` say, would render black from a NaN basis),
    as ``traversal.camera.check_camera`` checks a camera."""
    try:
        eye, target, up = (np.asarray(cam[k], np.float64) for k in ("eye", "target", "up"))
        fov = float(cam["fov"])
    except (KeyError, TypeError, ValueError):
        raise ParameterError("scene.camera", "expected the eye, target, up and fov of "
                                             "compile_scene's camera") from None
    check_camera(eye, target, up, fov, SCENE_CAMERA_NAMES)


def point_light_positions(lights):
    """The positions of the point lights among ``lights`` (where rays start or end)."""
    return [l["position"] for l in lights if l["type"] == "point"]


def check_float32_reach(scene, float64=None):
    """A float32 tracer's unit computes t from a product of three lengths (edge x edge x
    distance); a scene where that can pass float32's range would lose hits or shade from
    t = inf (NaN shadow rays), and one whose triangles span too little for it to stay a normal
    number would lose hits and shadows to rounding, so either is refused before any work
    (``make_tracer``, ``render``). The message tells the user to scale the scene, and, given
    ``float64`` (how the caller traces with the float64 units, e.g. an option to add), that
    too."""
    camera = getattr(scene, "camera", None)         # a bare mesh (benchmarks) has none
    points = ([camera["eye"]] if camera else []) + \
        point_light_positions(getattr(scene, "lights", ()))
    check_float32_reach_from(scene.triangles, points, float64)


def check_float32_reach_from(triangles, points, float64=None):
    """``check_float32_reach`` for ``triangles`` and rays that start at or head for ``points``
    (n, 3) or start within the triangles' box."""
    def remedy(way):
        return f"scale it {way}" + (f", or {float64}" if float64 else "")

    box = coordinate_box(triangles)
    reach = f32_unit_reach(triangles, points, box)
    if not reach <= F32_UNIT_MAX_PRODUCT:
        raise ParameterError("scene", f"too large for the float32 units: edge x edge x distance "
                                      f"reaches {reach:.3g}, beyond the {F32_UNIT_MAX_PRODUCT:.3g} "
                                      f"their products stay within ({remedy('down')})")
    span = span_of(box)
    if 0 < span < F32_UNIT_MIN_SPAN:          # all triangles at one point: nothing to lose
        raise ParameterError("scene", f"too small for the float32 units: its triangles span "
                                      f"{span:.3g}, below the {F32_UNIT_MIN_SPAN:.3g} their products "
                                      f"of three lengths need to stay normal numbers "
                                      f"({remedy('up')})")


def _checked_answers(tracer, n, n_triangles, hits=None, blocked=None):
    """A tracer's answers, checked before the shading kernels index with them: one per ray,
    and primitive ids in [-1, n_triangles) (a tracer built over other triangles would
    otherwise make shading read past the scene's arrays). A tracer that states its
    ``n_triangles`` (``traversal.tracers``), checked once against the scene, is taken at its
    word: this check costs about 1% of a render."""
    if getattr(tracer, "n_triangles", None) is not None:
        return
    answers = {"blocked": blocked} if hits is None else \
        {k: getattr(hits, k, None) for k in ("prim", "t", "u", "v")}
    for key, got in answers.items():
        if not isinstance(got, np.ndarray) or got.shape != (n,):
            raise ParameterError("tracer", f"{type(tracer).__name__} answered {key} of shape "
                                           f"{np.shape(got)} for {n} rays, expected ({n},)")
    prim = answers.get("prim")
    if prim is not None and prim.dtype.kind not in "iu":
        raise ParameterError("tracer", f"{type(tracer).__name__} answered primitive ids of type "
                                       f"{prim.dtype}, expected integers")
    if prim is not None and n and (prim.min() < -1 or prim.max() >= n_triangles):
        raise ParameterError("tracer", f"{type(tracer).__name__} answered primitive "
                                       f"{int(prim.max() if prim.max() >= n_triangles else prim.min())}"
                                       f", outside the scene's {n_triangles} triangles (a tracer "
                                       f"built over other triangles?)")


def _one_at_a_time(callback):
    lock = threading.Lock()

    def call(*args):
        with lock:
            callback(*args)
    return call


RAY_KINDS = ("primary", "shadow", "reflection", "refraction")
STAGES = ("generate", "queues", "intersect", "shade", "occluded", "accumulate")
NONE_BLOCKED = np.zeros(0, np.bool_)        # the shadow answers of a scene without lights


@dataclass
class _Frame:
    """What every band of one render reads, and the frame-wide outputs bands write (each
    its own pixels)."""
    scene: object
    passes: dict
    n_lights: int
    code: int
    sa: tuple
    material: np.ndarray              # per triangle, unsigned: accumulate's camera rays
    ray_dtype: np.dtype
    basis: tuple
    eye: np.ndarray
    camera_terms: list
    rows: int
    streams: list
    film: np.ndarray
    image: np.ndarray
    aov_depth: np.ndarray
    aov_normal: np.ndarray
    aov_prim: np.ndarray
    tracer: object
    progress: object


def _render_band(fr, band):
    """Rows band * fr.rows onward of the frame, every sample pass and bounce, on this thread.
    Returns (rays per kind, seconds per stage, pixels too bright for the float32 image)."""
    scene, tracer, sa = fr.scene, fr.tracer, fr.sa
    W, H = scene.width, scene.height
    ntri = len(scene.triangles)
    y0 = band * fr.rows
    y1 = min(H, y0 + fr.rows)
    q0, q1 = y0 * W, y1 * W          # whole rows of tiles: slots q0..q1 of the tile order
    npix = q1 - q0
    n_lights, passes, code = fr.n_lights, fr.passes, fr.code
    cu, cv, cw = fr.basis
    film, eye = fr.film, fr.eye
    buf = _buffers(npix, n_lights, fr.ray_dtype)
    rays = dict.fromkeys(RAY_KINDS, 0)
    secs = dict.fromkeys(STAGES, 0.0)
    no_jitter = np.zeros(0)
    clock = time.perf_counter
    last = [clock()]

    def lap(stage):
        now = clock()
        secs[stage] += now - last[0]
        last[0] = now

    for s in range(scene.spp):
        if fr.streams is not None:
            jx, jy = _band_jitter(fr.streams[s], W * H, q0, q1, buf.jitter)
        else:
            jx = jy = no_jitter
        _, _, wgt, pix, Ot, Dt, order = buf.cur
        stages.generate_camera_rays(y0, y1, W, jx, jy, scene.jitter, fr.camera_terms[s],
                                    eye, cu, cv, cw, pix, Ot, Dt, *buf.screen)
        n = npix
        gap, refr = n, 0             # the wavefront's rows: 0..n - refr, then gap..gap + refr
        rays["primary"] += n
        lap("generate")
        for bounce in range(passes["depth"]):
            if n == 0:
                break
            spawn = bounce + 1 < passes["depth"]
            buf.ensure_slots(n, gap + refr)
            if spawn:
                buf.ensure_next(2 * n)              # reflections, then refractions
            _, _, wgt, pix, Ot, Dt, order = buf.cur
            qO, qD, qT, sh_C, sh_pix, sh_cnt = buf.sh
            lap("queues")
            h = tracer.intersect(Ot[:n], Dt[:n], normals=False)
            _checked_answers(tracer, n, ntri, hits=h)
            lap("intersect")
            m = _shade(n, Ot, Dt, wgt, pix, h.prim, h.t, h.u, h.v, *sa, code, n_lights > 0, spawn,
                       bounce == 0, bounce == 0 and s == 0, fr.aov_depth, fr.aov_normal,
                       fr.aov_prim, buf.contrib, qO, qD, qT, sh_C, sh_pix, sh_cnt, buf.cap,
                       order, *buf.nxt, buf.spawned)
            lap("shade")
            blocked = NONE_BLOCKED
            if n_lights:
                blocked = np.ascontiguousarray(tracer.occluded(qO[:m], qD[:m], 0.0, qT[:m]))
                _checked_answers(tracer, m, ntri, blocked=blocked)
                lap("occluded")
                rays["shadow"] += m
            stages.accumulate(film, sh_cnt, buf.cap, sh_C, sh_pix, blocked, pix, buf.contrib,
                              n - refr, gap, refr, bounce == 0, bounce == 0 and s == 0, h.prim,
                              fr.material, sa.ambient_light, sa.background)
            lap("accumulate")
            if not spawn:
                break
            refl, refr = int(buf.spawned[0]), int(buf.spawned[1])
            rays["reflection"] += refl
            rays["refraction"] += refr
            buf.cur, buf.nxt = buf.nxt, buf.cur
            gap, n = n, refl + refr
    # the film is float64 and the image float32: a pixel past float32's largest number
    # (3.4e38: lights at the largest values close to a surface) is +inf in the image
    over = int(stages.finish_band(q0, q1, film, scene.spp, fr.image))
    lap("accumulate")
    if fr.progress:
        fr.progress(y1 - y0)
    return rays, secs, over
