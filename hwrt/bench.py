"""Benchmarks: each figure is a median of repeated runs after warm-up, printed beside a peer
measured in the same process (SPEC 8)."""
import os
import platform
import statistics
import time
from collections import Counter
from pathlib import Path
from typing import Callable, NamedTuple, Optional

import numpy as np

from hwbvh.errors import InputError, ParameterError
from hwbvh.files import absent, file_identity, write_files
from hwbvh.primitives import MESH_EXTENSIONS
from .paths import MESH_DIR_ENV, default_mesh_dir, mesh_files
from .progress import progress_over
from .report import name_width


def medians_of(n, runs="runs"):
    """How a figure over ``n`` runs was taken: "medians of 7 runs", "one run" (``runs``: the
    plural noun)."""
    return f"medians of {n} {runs}" if n != 1 else f"one {runs[:-1] if runs.endswith('s') else runs}"


def machine():
    import numba
    try:
        import embreex
        emb = getattr(embreex, "__version__", None)
    except Exception:  # pragma: no cover
        emb = None
    if emb is None:
        try:
            from importlib.metadata import version
            emb = version("embreex")
        except Exception:
            emb = "unknown"
    cpu = platform.processor() or ""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    from hwbvh.parallel import THREADING
    return {"cpu": cpu, "cores": os.cpu_count(), "numba_threads": numba.get_num_threads(),
            "threading": THREADING, "python": platform.python_version(), "numba": numba.__version__,
            "numpy": np.__version__, "embreex": emb}


class MeshInput(NamedTuple):
    """One benchmark mesh. ``name`` names its rows (see :func:`mesh_names`); ``path`` is its
    file, None for a generated mesh; ``stem`` the file's stem or the generated mesh's name
    (what the thesis' scenes are looked up by); ``load()`` gives (vertices, faces)."""
    name: str
    path: Optional[Path]
    stem: str
    load: Callable

    @property
    def source(self):
        """What errors about the mesh name: its file, or the generated mesh's name."""
        return self.name if self.path is None else str(self.path)


def _one_file(path):
    """What tells one file from another however it is spelled (a symbolic link, another
    relative path, a hard link: ``hwbvh.files.file_identity``); a path that names no file, the
    path it resolves to (its own check refuses it)."""
    return file_identity(path) or os.path.realpath(path)


def check_distinct_scenes(specs):
    """Refuse a scene or file given twice among a benchmark's SCENE arguments (built-in names
    or files, a file however it is spelled): its rows would be the same scene's twice."""
    seen = set()
    for spec in specs:
        key = _one_file(spec) if os.path.exists(spec) else str(spec)
        if key in seen:
            raise InputError(spec, "given twice")
        seen.add(key)


def told_apart(rows):
    """``rows`` (each with its "scene" name and its "source", the scene or file as given), a
    row whose name another row shares renamed to its source, until no two share one: a scene
    file may carry a built-in scene's name, and two rows of one name could not be told apart
    on the page. (The sources differ: ``check_distinct_scenes``.)"""
    while True:
        names = [r["scene"] for r in rows]
        shared = [r for r in rows
                  if names.count(r["scene"]) > 1 and r["scene"] != str(r["source"])]
        if not shared:
            return rows
        for r in shared:
            r["scene"] = str(r["source"])


def traceable(source, scene=None, triangles=None, points=None):
    """Refuse, naming ``source`` (a scene or mesh file as the user gave it), a compiled
    ``scene``, or ``triangles`` with rays from or toward ``points``, that the float32 units
    cannot trace: too large or too small (``raytracer.render.check_float32_reach``). Every
    benchmark path traces in float32, so this comes before the scene's work."""
    from raytracer.render import check_float32_reach, check_float32_reach_from

    try:
        if scene is not None:
            check_float32_reach(scene)
        else:
            check_float32_reach_from(triangles, points)
    except ParameterError as e:
        raise InputError(source, e.problem) from None


def mesh_names(paths, base=None):
    """Each mesh file's name: its stem, unless another of ``paths`` shares the stem (a/bunny.ply
    and b/bunny.ply, bunny.ply and bunny.obj), then its path (relative to ``base``, the
    directory the files were found in). A file given twice is refused: its rows would be one."""
    paths = [Path(p) for p in paths]
    seen = set()
    for p in paths:
        real = _one_file(p)                         # one file however it is spelled
        if real in seen:
            raise InputError(p, "given twice")
        seen.add(real)
    stems = Counter(p.stem for p in paths)
    return [p.stem if stems[p.stem] == 1 else str(p.relative_to(base) if base else p) for p in paths]


def mesh_directory(mesh_dir):
    """(directory, its mesh files, its name in messages) of the directory asked for:
    ``mesh_dir``, else $HWRT_MESHES, else the default directory when it is there (None: no
    directory asked for, none by default). A directory asked for must exist and hold mesh
    files (errors name the parameter or the environment variable); so must the default one,
    when it is there."""
    if mesh_dir:
        d = Path(mesh_dir)
        named = str(d)

        def refuse(problem):
            raise ParameterError("mesh_dir", f"{d}: {problem}")
    else:
        env = os.environ.get(MESH_DIR_ENV)
        d = Path(env) if env else default_mesh_dir()
        if d is None:
            return None
        named = f"${MESH_DIR_ENV} {d}" if env else str(d)

        def refuse(problem):
            raise InputError(named, problem)
    if not d.exists():
        refuse("no such directory")
    if not d.is_dir():
        refuse("not a directory")
    files = mesh_files(d)
    if not files:
        refuse(f"has no mesh files ({', '.join(MESH_EXTENSIONS)})")
    return d, files, named


def mesh_inputs(args):
    """[MeshInput] of the mesh files ``args.meshes``, else of the mesh directory
    (:func:`mesh_directory` of ``args.mesh_dir``), else the generated meshes. Every file is
    checked to be there before any is loaded."""
    from hwbvh.primitives import load_mesh_arrays
    from scenes.meshes import GENERATED

    from scenes.builtin import BUILTIN

    paths = [Path(m) for m in args.meshes]
    if paths and getattr(args, "mesh_dir", None):
        raise ParameterError("mesh_dir", "not read when mesh files are given: give the files "
                                         "or the directory")
    for p in paths:
        if not p.exists():
            raise InputError(p, absent(p, "no such file") + (
                f"; {p} is a built-in scene: this benchmark takes mesh files (those that render "
                "pick their built-in scenes themselves)" if str(p) in BUILTIN else ""))
        if p.is_dir():
            raise InputError(p, "is a directory, not a mesh file")
    base = None
    if not paths:
        found = mesh_directory(args.mesh_dir)
        if found is not None:
            base, paths, _ = found
    if paths:
        return [MeshInput(name, p, p.stem, (lambda p=p: load_mesh_arrays(p)))
                for name, p in zip(mesh_names(paths, base), paths)]

    def indexed(fn):
        tris = fn()
        return tris.reshape(-1, 3).astype(np.float64), np.arange(3 * len(tris)).reshape(-1, 3)
    return [MeshInput(name, None, name, (lambda fn=fn: indexed(fn))) for name, fn in GENERATED.items()]


def round_order(items, i):
    """``items`` in round i's order: rotated by i, so that over the rounds each item takes each
    place in turn and drift in the machine's speed falls on all alike."""
    k = i % len(items)
    return items[k:] + items[:k]


def _median_time(fn, repeat):
    fn()  # warm-up (JIT compilation, caches)
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), times


def _alternating_times(first, second, repeat):
    """Seconds of ``repeat`` runs of each of two functions, after a warm-up run of each, the
    two alternating run by run and taking turns to go first: a drift in a shared machine's
    speed falls on both, and the median of the runs' ratios cancels it."""
    first()
    second()
    times = ([], [])
    for i in range(repeat):
        for k in ((0, 1) if i % 2 == 0 else (1, 0)):
            fn = (first, second)[k]
            t = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t)
    return times


def bench_build(args):
    from hwbvh.api import build
    from hwbvh.primitives import as_triangles
    from traversal.embree_ref import embree_scene

    rows = []
    for mesh in progress_over(mesh_inputs(args), "bench build", "mesh"):
        verts, faces = mesh.load()
        tris = as_triangles(verts[faces], source=mesh.source)
        v32 = verts.astype(np.float32)
        f32 = faces.astype(np.int32)
        ours_all, emb_all = _alternating_times(lambda: build(tris),
                                               lambda: embree_scene(v32, f32), args.repeat)
        bvh = build(tris)
        rows.append({"mesh": mesh.name, "triangles": int(len(tris)),
                     "hwbvh_seconds": statistics.median(ours_all),
                     "embree_seconds": statistics.median(emb_all),
                     "ratio": statistics.median(o / e for o, e in zip(ours_all, emb_all)),
                     "hwbvh_spread": [min(ours_all), max(ours_all)],
                     "embree_spread": [min(emb_all), max(emb_all)],
                     "sah_cost": bvh.meta["sah_cost"], "nodes": bvh.meta["nodes"]})
    return {"meshes": rows, "machine": machine(), "repeat": args.repeat}


def human(what):
    def fmt(r):
        if what == "build":
            w = name_width([m["mesh"] for m in r["meshes"]], 18)
            lines = [f"{'mesh':<{w}}{'tris':>10}{'hwbvh ms':>11}{'embree ms':>11}{'ratio':>8}{'SAH':>9}"]
            for m in r["meshes"]:
                lines.append(f"{m['mesh']:<{w}}{m['triangles']:>10}{m['hwbvh_seconds']*1e3:>11.1f}"
                             f"{m['embree_seconds']*1e3:>11.1f}{m['ratio']:>8.2f}{m['sah_cost']:>9.2f}")
            lines.append(f"times: {medians_of(r['repeat'])} each, the two builders alternating "
                         "run by run; ratio: the median of the runs' hwbvh / embree")
            lines.append("hwbvh: the tree as the hardware writes it (nodes and index list); embree: "
                         "its scene built and committed, ready to trace (our tracer's set-up, the "
                         "rest of our way to tracing, counts in bench render's and bench tti's "
                         "build)")
            return "\n".join(lines)
        if what in ("tti", "accuracy"):
            from .study import human_accuracy, human_tti
            return (human_tti if what == "tti" else human_accuracy)(r)
        if what == "render":
            return _render_human(r)
        if what == "trace":
            w = name_width([m["mesh"] for m in r["meshes"]], 14)
            lines = [f"{'mesh':<{w}}{'set':<12}{'rays':>9}{'ours Mr/s':>11}{'embreex':>9}{'ratio':>7}{'open3d':>8}"]
            for m in r["meshes"]:
                for k, s in m["sets"].items():
                    o3 = f"{s['open3d_mrays']:>8.2f}" if "open3d_mrays" in s else f"{'-':>8}"
                    lines.append(f"{m['mesh']:<{w}}{k:<12}{s['rays']:>9}{s['ours_mrays']:>11.2f}"
                                 f"{s['embreex_mrays']:>9.2f}{s['ratio_vs_embreex']:>7.2f}{o3}")
            lines.append(f"rates: {medians_of(r['repeat'])} each, ours and embreex alternating "
                         "run by run; ratio: the median of the runs' ours / embreex rate"
                         + (f"; open3d: {r['open3d_missing']}" if r.get("open3d_missing")
                            else ""))
            if r.get("accels"):
                lines += ["", f"{'mesh':<{w}}{'accel':<8}{'build ms':>10}{'x sweep':>8}{'MiB':>8}"
                              f"{'refs/tri':>9}{'set':>12}{'Mr/s':>8}{'vs bvh':>8}"]
                for m in r["meshes"]:
                    for a, st in m["accels"].items():
                        for k, s in st["sets"].items():
                            lines.append(f"{m['mesh']:<{w}}{a:<8}{st['build_seconds']*1e3:>10.1f}"
                                         f"{st['build_vs_sweep_bvh']:>8.2f}"
                                         f"{st['memory_bytes']/2**20:>8.2f}"
                                         f"{st['references_per_triangle']:>9.2f}{k:>12}"
                                         f"{s['mrays']:>8.2f}{s['ratio_vs_bvh']:>8.2f}")
            return "\n".join(lines)
        if what == "model":
            f = r["fit"]
            w = name_width([m["mesh"] for m in r["rows"]], 16)
            lines = [f"control latency: shipped {f['shipped']}, fitted here {f.get('fitted', '-')} "
                     f"(range {f.get('fitted_range', '-')}) on {f['subtrees']} subtrees; Marbles rate "
                     f"{f['target_cycles_per_primitive']:.2f} cycles/primitive",
                     f"{'mesh':<{w}}{'preset':<10}{'text-only ms':>13}{'calibrated ms':>15}{'thesis ms':>11}"
                     f"{'ratios':>14}"]
            for m in r["rows"]:
                th = f"{m['thesis_seconds']*1e3:>11.2f}" if "thesis_seconds" in m else f"{'-':>11}"
                ra = (f"{m['text_only_ratio']:>7.2f}{m['calibrated_ratio']:>7.2f}"
                      if "thesis_seconds" in m else f"{'-':>14}")
                lines.append(f"{m['mesh']:<{w}}{m['preset']:<10}{m['text_only_seconds']*1e3:>13.2f}"
                             f"{m['calibrated_seconds']*1e3:>15.2f}{th}{ra}")
            lines.append(MODEL_COLUMNS)
            lines += _thesis_table_lines(r)
            fs = r["fill_share"]
            if fs:
                lines.append(f"fill share on {fs['mesh']} (thesis 3.6% mean, 8.8% max): text-only "
                             f"{fs['text_only']['mean']:.1%} / {fs['text_only']['max']:.1%}, calibrated "
                             f"{fs['calibrated']['mean']:.1%} / {fs['calibrated']['max']:.1%}")
            return "\n".join(lines)
        if what == "scale":
            lines = [f"{'triangles':>10}{'build s':>10}{'SAH':>9}{'max RSS MiB':>13}"]
            for m in r["rows"]:
                lines.append(f"{m['triangles']:>10}{m['hwbvh_seconds']:>10.3f}{m['sah_cost']:>9.2f}"
                             f"{m['max_rss_mib']:>13.0f}")
            lines.append(f"exponent {r['exponent']:.3f} (N log N over this range: "
                         f"{r['nlogn_exponent_same_range']:.3f})")
            return "\n".join(lines)
        return str(r)
    return fmt


def bench_scale(args):
    """Build time from 10k to 2M generated triangles; the log-log slope is the exponent."""
    import resource
    from hwbvh.api import build
    from hwbvh.format import validate
    from hwbvh.primitives import primitive_boxes
    from scenes.meshes import bumpy_sphere

    sizes = [10_000, 30_000, 100_000, 300_000, 1_000_000, 2_000_000]
    rows = []
    for n in progress_over(sizes, "bench scale", "size"):
        tris = bumpy_sphere(n)
        med, all_t = _median_time(lambda: build(tris), args.repeat)
        bvh = build(tris)
        validate(bvh.nodes, bvh.indices, len(tris), 4, primitive_boxes(tris))
        rows.append({"triangles": int(len(tris)), "hwbvh_seconds": med,
                     "spread": [min(all_t), max(all_t)], "sah_cost": bvh.meta["sah_cost"],
                     "nodes": bvh.meta["nodes"], "validated": True,
                     "max_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024})
    n = np.array([r["triangles"] for r in rows], float)
    t = np.array([r["hwbvh_seconds"] for r in rows], float)
    slope = float(np.polyfit(np.log(n), np.log(t), 1)[0])
    nlogn = float(np.polyfit(np.log(n), np.log(n * np.log(n)), 1)[0])
    return {"rows": rows, "exponent": slope, "nlogn_exponent_same_range": nlogn, "machine": machine()}


def _open3d_importable():
    import importlib.util
    return importlib.util.find_spec("open3d") is not None


def _open3d_scene(verts, faces):
    try:
        import open3d as o3d
    except Exception:
        return None
    sc = o3d.t.geometry.RaycastingScene()
    sc.add_triangles(o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32)))
    return sc


def _open3d_phase(cells, repeat):
    """Open3D's column, timed after all of ours (see bench_trace). Returns None when Open3D
    was timed, else why not, for the page."""
    if not _open3d_importable():
        return "not installed (pip install open3d)"
    try:
        import open3d as o3
    except Exception as e:
        return f"cannot be imported ({type(e).__name__})"
    current, sc = None, None
    for row, v32, f32, O32, D32, tm32, t_ours in cells:
        if current is not v32:                      # one mesh's scene alive at a time
            current, sc = v32, _open3d_scene(v32, f32)
        if tm32 is None:
            r = o3.core.Tensor(np.hstack([O32, D32]))
            f = lambda: sc.cast_rays(r)
        else:
            r = o3.core.Tensor(np.hstack([O32, D32 * tm32[:, None]]))
            f = lambda: sc.test_occlusions(r, tfar=1.0)
        t_o3, _ = _median_time(f, repeat)
        row["open3d_mrays"] = len(O32) / t_o3 / 1e6
        row["ratio_vs_open3d"] = t_o3 / t_ours
    return None


def warm_up_accel(accel):
    """Load (or, the first time ever, compile) the kernels of acceleration structure ``accel``
    (build, intersect with and without normals, occluded) on a tiny input, so that timings
    measure work, not JIT start-up. The BVH's are loaded by ``raytracer.render.warm_up``.
    Returns seconds."""
    from types import SimpleNamespace
    from raytracer.render import make_tracer

    t = time.perf_counter()
    tris = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 0, 1], [0, 1, 1]]], np.float32)
    verts = tris.reshape(-1, 3)
    scene = SimpleNamespace(triangles=tris, vertices=verts,
                            faces=np.arange(len(verts), dtype=np.int32).reshape(-1, 3))
    tracer, _, _ = make_tracer(scene, accel=accel)
    o = np.array([[0.25, 0.25, 2.0], [0.25, 0.25, -1.0]], np.float32)
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]], np.float32)
    tracer.intersect(o, d)
    tracer.intersect(o, d, normals=False)
    tracer.occluded(o, d, 0.0, np.full(2, 10.0, np.float32))
    return time.perf_counter() - t


def structure_figures(tracer, n_tris):
    """{memory_bytes, references_per_triangle} of the structure behind ``tracer``: what the
    structure reports (``stats()``), or for our BVH its nodes, 24-bit index list,
    preprocessed triangles and their row map (what the grid counts is its cells, references
    and triangles)."""
    stats = getattr(tracer, "stats", None)
    if callable(stats):
        s = stats()
        return {k: s[k] for k in ("memory_bytes", "references_per_triangle") if k in s}
    from hwbvh.config import INDEX_PAD
    from hwbvh.format import unpack_indices
    refs = int(np.count_nonzero(unpack_indices(tracer.index_bytes) != INDEX_PAD))
    return {"memory_bytes": int(tracer.nodes.nbytes + tracer.index_bytes.nbytes + tracer.tris.nbytes
                                + tracer.row_of.nbytes),
            "references_per_triangle": refs / max(n_tris, 1)}


def bench_trace(args):
    """Throughput (Mrays/s) of our intersect/occluded against embreex (and Open3D when it is
    importable) on identical ray sets: primary, incoherent, shadow.

    ``args.accel`` (a list of names from ``raytracer.render.ACCELS``; empty or None: none)
    traces the same ray sets with each of those acceleration structures too, built by
    ``make_tracer`` after a warm-up: per structure its build seconds (median of ``repeat``
    builds) and that time over the sweep BVH builder's (``build_vs_sweep_bvh``, timed the same
    way), memory bytes, references per triangle and, per ray set, Mrays/s and the speed
    relative to our BVH (``ratio_vs_bvh`` > 1: faster than the BVH).

    Open3D is timed in a second phase, after every mesh's ours/embreex figures: its TBB worker
    threads keep spinning after a call and, timed in between, took CPU from the next
    measurement (up to a quarter of ours on two cores)."""
    from types import SimpleNamespace
    import hwbvh
    from hwbvh.primitives import as_triangles
    from raytracer.render import make_tracer
    from traversal import Tracer, raysets
    from traversal.embree_ref import embree_intersect, embree_occluded, embree_scene

    n = args.rays
    open3d = _open3d_importable()
    accels = list(dict.fromkeys(getattr(args, "accel", None) or []))
    for accel in accels:
        warm_up_accel(accel)
    rows, later = [], []
    for mesh in progress_over(mesh_inputs(args), "bench trace", "mesh"):
        name = mesh.name
        verts, faces = mesh.load()
        tris = as_triangles(verts[faces], source=mesh.source)
        raysets.check_extent(tris, mesh.source)         # the primary set frames the mesh
        traceable(mesh.source, triangles=tris, points=raysets.points_beyond(tris))
        v32, f32 = verts.astype(np.float32), faces.astype(np.int32)
        tracer = Tracer(hwbvh.build(tris))
        emb = embree_scene(v32, f32)
        structures = {}
        # the software builders' reference: the sweep BVH builder and its tracer's set-up,
        # timed as make_tracer times a structure
        sweep_s = _median_time(lambda: Tracer(hwbvh.build(tris, builder="sweep")),
                               args.repeat)[0] if accels else None
        for accel in accels:
            scene = SimpleNamespace(triangles=tris, vertices=v32, faces=f32)
            built = []
            build_s, spread_b = _median_time(lambda: built.append(make_tracer(scene, accel=accel)),
                                             args.repeat)
            st = built[-1][0]
            structures[accel] = (st, {"build_seconds": build_s,
                                      "build_spread_s": [min(spread_b), max(spread_b)],
                                      "build_vs_sweep_bvh": build_s / sweep_s,
                                      **structure_figures(st, len(tris)), "sets": {}})
            del built[:-1]
        # one set alive at a time, made as the tracers take it (float32; Open3D's phase keeps
        # them, when it runs): 2^26 rays of three sets in float64 and float32 held 20 GB
        makers = {"primary": lambda: (*raysets.primary(tris, n, np.float32), None),
                  "incoherent": lambda: (*raysets.incoherent(tris, n, dtype=np.float32), None),
                  "shadow": lambda: raysets.shadow(tracer, tris, n, np.float32)}
        out = {}
        for kind, make in makers.items():
            O32, D32, tm32 = make()
            query = (lambda tr: (lambda: tr.intersect(O32, D32))) if tm32 is None else \
                (lambda tr: (lambda: tr.occluded(O32, D32, 0.0, tm32)))
            ours = query(tracer)
            if tm32 is None:
                peer = lambda: embree_intersect(emb, O32, D32)
            else:
                peer = lambda: embree_occluded(emb, O32, D32, tm32)
            spread_o, spread_e = _alternating_times(ours, peer, args.repeat)
            t_ours, t_emb = statistics.median(spread_o), statistics.median(spread_e)
            out[kind] = {"rays": int(len(O32)), "ours_mrays": len(O32) / t_ours / 1e6,
                         "embreex_mrays": len(O32) / t_emb / 1e6,
                         "ratio_vs_embreex": statistics.median(e / o for o, e in
                                                              zip(spread_o, spread_e)),
                         "ours_spread_s": [min(spread_o), max(spread_o)],
                         "embreex_spread_s": [min(spread_e), max(spread_e)]}
            if open3d:
                later.append((out[kind], v32, f32, O32, D32, tm32, t_ours))
            for accel, (st, row) in structures.items():
                t_st, spread_s = _median_time(query(st), args.repeat)
                row["sets"][kind] = {"mrays": len(O32) / t_st / 1e6, "ratio_vs_bvh": t_ours / t_st,
                                     "spread_s": [min(spread_s), max(spread_s)]}
            O32 = D32 = tm32 = None         # before the next set is made
        row = {"mesh": name, "triangles": int(len(tris)), "sets": out}
        if accels:
            row["accels"] = {accel: r for accel, (_, r) in structures.items()}
            row["sweep_bvh_build_seconds"] = sweep_s
        structures.clear()
        rows.append(row)
    result = {"meshes": rows, "machine": machine(), "repeat": args.repeat,
              "open3d_missing": _open3d_phase(later, args.repeat)}
    if accels:
        result["accels"] = accels
    return result


RENDER_PATHS = (("hwbvh", "numba"), ("embree", "embree"))


def _render_setting(d, args):
    """The scene dict with --width/--height/--spp/--max-depth applied (unset keeps the scene's)."""
    from scenes import with_frame
    given = {key: getattr(args, key, None) for key in ("width", "height", "spp", "max_depth")}
    for key, val in given.items():
        if val is not None and val < 1:
            raise InputError(f"--{key.replace('_', '-')}", f"must be at least 1, got {val}")
    return with_frame(d, **given)


def _peer_variants(specs):
    """{variant: (usable, reason)} for the Mitsuba variants, when a mesh scene is in ``specs``."""
    from scenes import is_scene
    from . import mitsuba_peer as mp

    if all(is_scene(s) for s in specs):
        return {}
    return {v: mp.variant_status(v) for v in mp.VARIANTS}


def bench_render(args, commit=write_files):
    """Time to image (build + render) of each scene (default: cornell) with our build and
    traversal against Embree's, through the same renderer, and for a mesh scene against
    Mitsuba 3 (``scalar_rgb`` and ``llvm_ad_rgb``) when it is installed.

    Every path is warm (one untimed build + render first); the paths alternate run by run, in an
    order that rotates each round, so drift in the machine's speed falls on all alike; figures
    are medians of ``--repeat`` rounds. Right after each of our renders, the rays it traced
    (recorded in the warm-up render) are traced again alone: render / trace-only, the
    renderer's overhead over its traversal, is the median of the rounds' own ratios, so that a
    drift in the machine's speed between rounds cancels in each round's ratio, where it would
    not in a ratio of medians.

    Against Mitsuba, both renderers render the scene with ambient 0 and a black background
    (Mitsuba has neither), with its ``direct`` integrator (one emitter sample, no BSDF sample),
    and Mitsuba's time to image is its load (mesh + ``mi.load_dict``, which builds its BVH) plus
    its render. Its rays/s count the rays ours traced for the same image (camera + shadow rays):
    Mitsuba traces at least those (it also sends a shadow ray from surfaces that face away from
    the light, and from black ones), so its rate is a lower bound. Image agreement: relative
    RMSE of our image against Mitsuba's (seed 1), over Mitsuba's seed 1 against seed 2. With ``args.out_dir``,
    render.json and render.md are written in one set through ``commit(files)`` (the command
    line's also marks the run done)."""
    import json
    from hwbvh.files import check_output_dir, jsonable
    from raytracer.render import warm_up
    from scenes import compile_scene, is_scene, load_scene
    from . import mitsuba_peer as mp

    specs = [str(s) for s in args.meshes] or ["cornell"]
    check_distinct_scenes(specs)
    if args.repeat < 1:
        raise InputError("--repeat", f"must be at least 1, got {args.repeat}")
    out_dir = getattr(args, "out_dir", None)
    if out_dir:
        check_output_dir(out_dir, ["render.json", "render.md"], inputs=specs)
    scenes = [(spec, compile_scene(_render_setting(load_scene(spec), args))) for spec in specs]
    for spec, scene in scenes:          # every path traces in float32: refused before any work
        traceable(spec, scene)
    for builder, traversal in RENDER_PATHS:
        warm_up(builder, traversal, parallel_build=True)
    variants = _peer_variants(specs)
    results = []
    for spec, scene in progress_over(scenes, "bench render", "scene"):
        peer_info = None
        if not is_scene(spec):
            skipped = mp.unsupported(scene) if mp.installed() else \
                "mitsuba is not installed (pip install 'mitsuba>=3.5')"
            if skipped is None:
                scene = mp.neutral_scene(scene)
            peer_info = {"skipped": skipped, "variants": []}
        compared = peer_info is not None and not peer_info["skipped"]
        results.append(_render_scene(spec, scene, variants if compared else {}, peer_info,
                                     args.repeat))
    result = jsonable({"scenes": told_apart(results), "repeat": args.repeat,
                       "machine": machine()})
    if out_dir:
        files = [(os.path.join(out_dir, "render.json"), json.dumps(result, indent=1) + "\n"),
                 (os.path.join(out_dir, "render.md"), _render_markdown(result, args))]
        commit(files)
        result["files"] = [f for f, _ in files]
    return result


def _render_scene(spec, scene, variants, peer_info, repeat):
    """One scene's rows (see bench_render)."""
    from raytracer.render import make_tracer, render
    from traversal.tracers import RecordingTracer
    from . import mitsuba_peer as mp

    # warm-up: one untimed build + render per path, recording the rays it traces
    recorded = {}
    for p in RENDER_PATHS:
        tracer, _, _ = make_tracer(scene, *p)
        rec = RecordingTracer(tracer)
        res = render(scene, rec, seed=0)
        rec.replay_seconds(tracer)
        recorded[p] = (rec, res)
    ours_image = recorded[RENDER_PATHS[0]][1].image
    ours_rays = recorded[RENDER_PATHS[0]][1].stats["rays"]
    peers, agreement = {}, {}
    for v, (ok, _) in variants.items():
        if not ok:
            continue
        peers[v] = mp.MitsubaPeer(scene, v)
        peers[v].time_to_image(seed=0)                       # warm-up (kernels, caches)
        agreement[v] = mp.image_agreement(ours_image, peers[v])
    # timed rounds: every path once per round, the order rotating round by round
    order = list(RENDER_PATHS) + list(peers)
    runs = {k: {"build": [], "render": [], "trace": [], "stages": []} for k in order}
    for i in range(repeat):
        for k in round_order(order, i):
            r = runs[k]
            if k in peers:
                t = peers[k].time_to_image(seed=0)
                r["build"].append(t["load_seconds"])
                r["render"].append(t["render_seconds"])
                continue
            tracer, b, _ = make_tracer(scene, *k)
            t0 = time.perf_counter()
            res = render(scene, tracer, seed=0)
            r["render"].append(time.perf_counter() - t0)
            r["stages"].append(res.stats["stage_seconds"])
            r["build"].append(b)
            r["trace"].append(recorded[k][0].replay_seconds(tracer))
            del tracer
    med = statistics.median
    rows = []
    for (builder, traversal) in RENDER_PATHS:
        r = runs[(builder, traversal)]
        rays = recorded[(builder, traversal)][1].stats["rays"]
        total_rays = int(sum(rays.values()))
        render_s, trace_s = med(r["render"]), med(r["trace"])
        # each round's render over the same round's trace-only run
        over_trace = [a / b for a, b in zip(r["render"], r["trace"])] if min(r["trace"]) > 0 \
            else None
        rows.append({"builder": builder, "traversal": traversal,
                     "build_seconds": med(r["build"]), "render_seconds": render_s,
                     "total_seconds": med(np.add(r["build"], r["render"])),
                     "render_spread": [min(r["render"]), max(r["render"])],
                     "trace_only_seconds": trace_s,
                     "render_over_trace_only": med(over_trace) if over_trace else None,
                     "render_over_trace_only_rounds": over_trace,
                     "render_over_trace_only_spread": _spread(over_trace) if over_trace else None,
                     # where the render's time goes: each stage's seconds summed over the
                     # threads, the median over the rounds
                     "stage_seconds": {st: med([x[st] for x in r["stages"]])
                                       for st in r["stages"][0]},
                     "rays": rays, "mrays_per_second": total_rays / render_s / 1e6})
    out = {"scene": scene.name, "source": spec, "triangles": int(len(scene.triangles)),
           "width": scene.width, "height": scene.height, "spp": scene.spp,
           "max_depth": scene.max_depth, "rows": rows,
           "ratio": rows[0]["total_seconds"] / rows[1]["total_seconds"]}
    if peer_info is not None:
        ours = rows[0]
        estimate = int(ours_rays.get("primary", 0) + ours_rays.get("shadow", 0))
        for v, (ok, why) in variants.items():
            if not ok:
                peer_info["variants"].append({"variant": v, "available": False, "reason": why})
                continue
            peer, r = peers[v], runs[v]
            load_s, render_s = med(r["build"]), med(r["render"])
            total_s = med(np.add(r["build"], r["render"]))
            peer_info["variants"].append({
                "variant": v, "available": True, "load_seconds": load_s,
                "render_seconds": render_s, "total_seconds": total_s,
                "render_spread": [min(r["render"]), max(r["render"])],
                "sampler": peer.sampler, "rays_estimate": estimate,
                "mrays_per_second_estimate": estimate / render_s / 1e6,
                "agreement": agreement[v],
                "ours_over_peer": {"total": ours["total_seconds"] / total_s,
                                   "build": ours["build_seconds"] / load_s,
                                   "render": ours["render_seconds"] / render_s}})
        if peers:
            peer_info["versions"] = mp.versions()
        if variants:
            peer_info["changes"] = "ambient 0 and background 0 in both renderers (Mitsuba has neither)"
        out["mitsuba"] = peer_info
    return out


def _spread(values):
    return [float(min(values)), float(max(values))]


def _ratio_text(row):
    """render / trace-only of a row, with the spread of the rounds' own ratios."""
    rt, sp = row["render_over_trace_only"], row.get("render_over_trace_only_spread")
    if rt is None:
        return "-"
    return f"{rt:.2f} ({sp[0]:.2f}-{sp[1]:.2f})" if sp else f"{rt:.2f}"


def _render_human(r):
    lines = []
    for s in r["scenes"]:
        lines.append(f"{s['scene']}: {s['triangles']} triangles, {s['width']}x{s['height']}, "
                     f"{s['spp']} spp, depth {s['max_depth']}; {medians_of(r['repeat'])}")
        lines.append(f"{'path':<22}{'build s':>9}{'render s':>10}{'total s':>9}{'Mrays/s':>9}"
                     f"{'trace s':>9}  render/trace (rounds)")
        for m in s["rows"]:
            lines.append(f"{m['builder'] + '+' + m['traversal']:<22}{m['build_seconds']:>9.3f}"
                         f"{m['render_seconds']:>10.3f}{m['total_seconds']:>9.3f}"
                         f"{m['mrays_per_second']:>9.2f}{m['trace_only_seconds']:>9.3f}"
                         f"  {_ratio_text(m)}")
        lines.append(f"ratio (ours / embree): {s['ratio']:.2f}")
        for m in s["rows"]:
            lines.append(f"  stages, {m['builder'] + '+' + m['traversal']} (s over all threads): "
                         + ", ".join(f"{k} {v:.3f}" for k, v in m["stage_seconds"].items()))
        peer = s.get("mitsuba")
        if peer is None:
            continue
        if peer["skipped"]:
            lines.append(f"mitsuba: not compared: {peer['skipped']}")
            continue
        for v in peer["variants"]:
            if not v["available"]:
                lines.append(f"mitsuba {v['variant']}: unavailable ({v['reason']})")
                continue
            a, o = v["agreement"], v["ours_over_peer"]
            ratio = f"{a['ratio']:.2f}" if a["ratio"] is not None else "-"
            lines.append(f"{'mitsuba ' + v['variant']:<22}{v['load_seconds']:>9.3f}"
                         f"{v['render_seconds']:>10.3f}{v['total_seconds']:>9.3f}"
                         f"{v['mrays_per_second_estimate']:>9.2f}*")
            lines.append(f"  ours / mitsuba {v['variant']}: time to image {o['total']:.2f}, "
                         f"build/load {o['build']:.2f}, render {o['render']:.2f}; image rel. RMSE "
                         f"{a['ours_vs_mitsuba']:.4f} vs its seed-to-seed {a['mitsuba_vs_mitsuba']:.4f} "
                         f"(ratio {ratio})")
        if any(v["available"] for v in peer["variants"]):
            ver = peer["versions"]
            lines.append(f"  ({peer['changes']}; * Mitsuba's rays/s counts the camera + shadow rays "
                         f"ours traced for the same image: a lower bound; Mitsuba {ver['mitsuba']}, "
                         f"Dr.Jit {ver['drjit']}, LLVM {ver['llvm'] or '-'})")
    return "\n".join(lines)


def _render_markdown(r, args=None):
    """The results as a docs page."""
    from .report import command_of, made_by_lines
    m = r["machine"]
    lines = ["# hwrt bench render", ""] + made_by_lines(command_of(args)) + [
             f"Time to image, `hwrt bench render`: {medians_of(r['repeat'], 'warm runs')} per path, "
             f"the paths alternating run by run. {m.get('cpu', '')}, {m.get('cores')} cores, "
             f"{m.get('numba_threads')} Numba thread{'' if m.get('numba_threads') == 1 else 's'}. "
             f"Render / trace-only: the median of "
             f"the rounds' own ratios (each round renders, then traces the same rays alone), "
             f"and in brackets the lowest and highest of them. Build: up to a tracer ready to "
             f"trace (ours: the BVH build and the tracer's set-up, its triangle rows and "
             f"checks; Embree: building its scene).", ""]
    for s in r["scenes"]:
        lines += [f"### {s['scene']} ({s['triangles']} triangles, {s['width']}x{s['height']}, "
                  f"{s['spp']} spp, depth {s['max_depth']})", "",
                  "| path | build s | render s | total s | Mrays/s | trace-only s | "
                  "render / trace-only (rounds) |",
                  "|---|---:|---:|---:|---:|---:|---:|"]
        for row in s["rows"]:
            lines.append(f"| {row['builder']} build + {row['traversal']} traversal | "
                         f"{row['build_seconds']:.4f} | {row['render_seconds']:.3f} | "
                         f"{row['total_seconds']:.3f} | {row['mrays_per_second']:.2f} | "
                         f"{row['trace_only_seconds']:.3f} | {_ratio_text(row)} |")
        stages = list(s["rows"][0]["stage_seconds"])
        lines += ["", f"Ours / Embree (total): {s['ratio']:.2f}.", "",
                  "Where the render's time goes: seconds per stage, summed over the threads "
                  "(medians over the rounds; intersect and occluded are the tracer's queries).", "",
                  "| path | " + " | ".join(stages) + " |", "|---|" + "---:|" * len(stages)]
        for row in s["rows"]:
            lines.append(f"| {row['builder']} + {row['traversal']} | "
                         + " | ".join(f"{row['stage_seconds'][k]:.4f}" for k in stages) + " |")
        lines.append("")
        peer = s.get("mitsuba")
        if not peer:
            continue
        if peer["skipped"]:
            lines += [f"Mitsuba 3: not compared: {peer['skipped']}.", ""]
            continue
        lines += ["| Mitsuba 3 variant | load s | render s | total s | Mrays/s (lower bound) | "
                  "ours / it, total | ours / it, render | image rel. RMSE: ours / its own noise |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for v in peer["variants"]:
            if not v["available"]:
                lines.append(f"| {v['variant']} | unavailable: {v['reason']} | | | | | | |")
                continue
            a, o = v["agreement"], v["ours_over_peer"]
            ratio = f"{a['ratio']:.2f}" if a["ratio"] is not None else "-"
            lines.append(f"| {v['variant']} | {v['load_seconds']:.4f} | {v['render_seconds']:.3f} | "
                         f"{v['total_seconds']:.3f} | {v['mrays_per_second_estimate']:.1f} | "
                         f"{o['total']:.2f} | {o['render']:.2f} | {a['ours_vs_mitsuba']:.4f} / "
                         f"{a['mitsuba_vs_mitsuba']:.4f} = {ratio} |")
        if any(v["available"] for v in peer["variants"]):
            ver = peer["versions"]
            lines += ["", f"Mitsuba {ver['mitsuba']}, Dr.Jit {ver['drjit']}, LLVM {ver['llvm'] or '-'}. "
                      f"For this comparison: {peer['changes']}. Mitsuba's `direct` integrator with "
                      "one emitter sample and no BSDF sample: a camera ray and a shadow ray per "
                      "sample. Its rays/s count the camera and shadow rays ours traced for the "
                      "same image; it traces at least those.", ""]
    return "\n".join(lines) + "\n"


def _model_rows(name, stem, tris):
    """One cell of ``bench model``: a mesh's whole-scene build on both presets, with the
    text-only model (control latency 0) and the calibrated one. ``name`` names the rows (a
    path when stems collide); the thesis scene is looked up by the file's ``stem``."""
    from dataclasses import replace
    import hwbvh
    from hwbvh import calibration as cal
    from hwbvh.cycle_model import CONTROL_LATENCY, PRESETS, simulate

    bvh = hwbvh.build(tris)              # its tree for the model, its nodes for Table 4.4
    tree = bvh.tree
    scene = cal.THESIS_SCENE_OF_MESH.get(stem)
    rows = []
    tables = None
    for preset, p in PRESETS.items():
        row = {"mesh": name, "triangles": int(len(tris)), "preset": preset}
        for key, ctl in (("text_only", 0), ("calibrated", CONTROL_LATENCY)):
            t = time.perf_counter()
            r = simulate(tree, replace(p, control_latency=ctl))
            row[f"{key}_seconds"] = r["seconds"]
            row[f"{key}_simulation_seconds"] = time.perf_counter() - t
        row["traffic_bytes"] = r["traffic_total_bytes"]
        if scene:
            row["thesis_scene"] = scene
            row["thesis_seconds"] = cal.thesis_seconds(scene, preset)
            row["text_only_ratio"] = row["text_only_seconds"] / row["thesis_seconds"]
            row["calibrated_ratio"] = row["calibrated_seconds"] / row["thesis_seconds"]
            # Table 4.11: the calibrated build's energy (a preset draws Table 4.10's power)
            row["energy_joules"] = r["energy_joules"]
            row["thesis_energy_joules"] = cal.THESIS_ENERGY_J[scene][0 if preset == "HWBVH-C" else 1]
        rows.append(row)
    if scene:
        tables = _thesis_tree_tables(name, scene, tris, bvh.meta)
    return {"rows": rows, "thesis_tables": tables}


def _thesis_tree_tables(name, scene, tris, hw):
    """A thesis scene's footprint (Table 4.2) and trees (Tables 4.3-4.4), ours beside the
    thesis': the hardware's tree (``hw``, its build's meta) and the sweep builder's."""
    import hwbvh
    from hwbvh import calibration as cal
    from hwbvh.cycle_model import footprint_bytes

    sweep = hwbvh.build(tris, builder="sweep").meta
    hw_sah, hw_nodes, sw_sah, sw_nodes = cal.THESIS_TREES[scene]
    return {"mesh": name, "thesis_scene": scene,
            "footprint_mib": footprint_bytes(len(tris)) / 2**20,
            "thesis_footprint_mib": cal.THESIS_FOOTPRINT_MIB.get(scene),
            "hwbvh_sah": hw["sah_cost"], "hwbvh_nodes": int(hw["nodes"]),
            "sweep_sah": sweep["sah_cost"], "sweep_nodes": int(sweep["nodes"]),
            "thesis_hwbvh_sah": hw_sah, "thesis_hwbvh_nodes": hw_nodes,
            "thesis_sweep_sah": sw_sah, "thesis_sweep_nodes": sw_nodes,
            "sah_percent_of_sweep": 100 * hw["sah_cost"] / sweep["sah_cost"],
            "thesis_sah_percent_of_sweep": cal.THESIS_SAH_PERCENT_OF_SWEEP[scene]}


# What bench model's columns are: the thesis prints no build times, so its column is derived
MODEL_COLUMNS = ("thesis ms: the build time the thesis implies (it prints none): Table 4.11's "
                 "energy per build over Table 4.10's active power; ratios: text-only and "
                 "calibrated over it")


def _thesis_table_lines(result):
    """``bench model``'s lines for the meshes that are thesis scenes: Tables 4.2-4.4 and 4.11,
    ours beside the thesis'."""
    tables = result.get("thesis_tables") or []
    energies = [m for m in result["rows"] if "thesis_energy_joules" in m]
    if not (tables or energies):
        return []
    w = name_width([t["mesh"] for t in tables] + [m["mesh"] for m in energies], 16)
    lines = ["", "thesis tables, where a mesh is a thesis scene (ours | thesis):",
             f"{'mesh':<{w}}{'table':<7}{'quantity':<28}{'ours':>18}{'thesis':>18}"]

    def add(mesh, table, what, ours, theirs):
        lines.append(f"{mesh:<{w}}{table:<7}{what:<28}{ours:>18}{theirs:>18}")

    for t in tables:
        m = t["mesh"]
        if t["thesis_footprint_mib"] is not None:
            add(m, "4.2", "footprint MiB", f"{t['footprint_mib']:.2f}",
                f"{t['thesis_footprint_mib']:.2f}")
        add(m, "4.4", "HWBVH SAH / nodes", f"{t['hwbvh_sah']:.2f} / {t['hwbvh_nodes']:,}",
            f"{t['thesis_hwbvh_sah']:.2f} / {t['thesis_hwbvh_nodes']:,}")
        add(m, "4.4", "sweep SAH / nodes", f"{t['sweep_sah']:.2f} / {t['sweep_nodes']:,}",
            f"{t['thesis_sweep_sah']:.2f} / {t['thesis_sweep_nodes']:,}")
        add(m, "4.3", "HWBVH SAH, % of sweep's", f"{t['sah_percent_of_sweep']:.1f}%",
            f"{t['thesis_sah_percent_of_sweep']}%")
    for e in energies:
        add(e["mesh"], "4.11", f"energy mJ, {e['preset']}", f"{e['energy_joules'] * 1e3:.1f}",
            f"{e['thesis_energy_joules'] * 1e3:.1f}")
    return lines


MODEL_FIGURES = ("subtree_design_space.csv", "fig4_2_speedup.png", "fig4_3_leaf_size.png")


def bench_model(args, commit=write_files):
    """The hardware model against the thesis: the fit of its one calibrated constant (on
    subtrees cut from the given meshes, against Marbles' rate), then whole-scene build times
    for HWBVH-C and HWBVH-HP with the text-only model (control latency 0) and the calibrated
    one, beside the thesis' times, energies, footprints and trees where the mesh is a thesis
    scene, and the subtree builder's design space as thesis 4.2.1 explores it (Figs. 4.2-4.3,
    on subtrees of the bunny, or else of the first mesh) with the fill share (thesis: 3.6% on
    average). With ``args.out_dir``, model.md, model.json, the figures and their CSV are
    written in one set through ``commit(files)``."""
    import json
    import uuid
    from hwbvh.files import check_output_dir, jsonable
    from hwbvh import calibration as cal
    from hwbvh.cycle_model import CONTROL_LATENCY, subtree_design_space
    from hwbvh.primitives import as_triangles
    from .cluster import dask_client, run_cells
    from .explore import warm_up

    out_dir = getattr(args, "out_dir", None)
    if out_dir:
        check_output_dir(out_dir, ["model.md", "model.json", *MODEL_FIGURES],
                         inputs=[str(m) for m in args.meshes])
    meshes = []
    for mesh in progress_over(mesh_inputs(args), "bench model: load", "mesh"):
        verts, faces = mesh.load()
        meshes.append((mesh.name, mesh.stem, as_triangles(verts[faces], source=mesh.source)))
    subs = cal.fit_subtrees([t for _, _, t in meshes])
    target, (t_lo, t_hi) = cal.target_rate()
    fit = {"target_cycles_per_primitive": target, "target_range": [t_lo, t_hi],
           "subtrees": len(subs), "shipped": CONTROL_LATENCY}
    if subs:
        fit.update(fitted=cal.fit_control_latency(subs, target),
                   fitted_range=[cal.fit_control_latency(subs, t_lo), cal.fit_control_latency(subs, t_hi)],
                   rate_text_only=cal.model_rate(subs, 0), rate_shipped=cal.model_rate(subs, CONTROL_LATENCY))
    # one cell per mesh, on Dask (a local cluster unless $HWRT_SCHEDULER names one)
    run = uuid.uuid4().hex[:8]
    cells = [(f"model-{run}-{k}", _model_rows, m) for k, m in enumerate(meshes)]
    done = {}
    if cells:
        with dask_client(getattr(args, "scheduler", None), warm_up=warm_up) as client:
            run_cells(cells, done.__setitem__, client, desc="bench model: simulate")
    rows = [row for key, _, _ in cells for row in done[key]["rows"]]
    tables = [done[key]["thesis_tables"] for key, _, _ in cells if done[key]["thesis_tables"]]
    fill, figures = {}, []
    if meshes:
        name, _, tris = next((m for m in meshes if m[1] == "bunny"), meshes[0])
        for key, ctl in (("text_only", 0), ("calibrated", CONTROL_LATENCY)):
            space = subtree_design_space(tris, out_dir or ".", control_latency=ctl, write=False)
            fill[key] = space["fill_share"]
        fill["mesh"] = name
        fill["subtrees"] = space["subtrees"]
        figures = space["files"]                  # the calibrated model's
    result = jsonable({"fit": fit, "rows": rows, "thesis_tables": tables, "fill_share": fill,
                       "machine": machine()})
    if out_dir:
        files = [(os.path.join(out_dir, "model.json"), json.dumps(result, indent=1) + "\n"),
                 (os.path.join(out_dir, "model.md"), _model_markdown(result, args,
                                                                      [p for p, _ in figures]))]
        commit(files + figures)
        result["files"] = [p for p, _ in files + figures]
    return result


def _model_markdown(result, args, figures):
    from .report import command_of, made_by_lines
    fs = result["fill_share"]
    lines = ["# hwrt bench model", ""] + made_by_lines(command_of(args)) + [
        "```text", human("model")(result), "```", ""]
    if figures:
        sizes = ", ".join(f"{n:,}" for n in fs["subtrees"])
        lines += [f"The subtree builder's design space as thesis 4.2.1 explores it (Figs. 4.2 and "
                  f"4.3), on subtrees of {fs['mesh']} that the upper builder hands off ({sizes} "
                  f"primitives; the whole mesh when it has no hand-off of 4,096-8,192): the "
                  f"subtree builder alone, its capacity held as w varies, the fill factored out, "
                  f"the calibrated model. Cycles per point: {os.path.basename(figures[0])}.", ""]
        for p in figures[1:]:
            name = os.path.basename(p)
            lines += [f"![{os.path.splitext(name)[0].replace('_', ' ')}]({name})", ""]
    return "\n".join(lines) + "\n"
