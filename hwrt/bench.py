"""Benchmarks: each figure is a median of repeated runs after warm-up, printed beside a peer
measured in the same process (SPEC 8)."""
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from hwbvh.errors import InputError
from .paths import default_mesh_dir, mesh_files


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
    return {"cpu": cpu, "cores": os.cpu_count(), "numba_threads": numba.get_num_threads(),
            "python": platform.python_version(), "numba": numba.__version__,
            "numpy": np.__version__, "embreex": emb}


def mesh_inputs(args):
    """[(name, loader)] from explicit paths, --mesh-dir, the default directory, or generated."""
    from hwbvh.primitives import load_mesh_arrays
    from scenes.meshes import GENERATED

    paths = [Path(m) for m in args.meshes]
    if not paths:
        d = Path(args.mesh_dir) if args.mesh_dir else default_mesh_dir()
        if d is not None:
            if not d.is_dir():
                raise InputError(d, "mesh directory does not exist")
            paths = mesh_files(d)
    if paths:
        return [(p.stem, (lambda p=p: load_mesh_arrays(p))) for p in paths]

    def indexed(fn):
        tris = fn()
        return tris.reshape(-1, 3).astype(np.float64), np.arange(3 * len(tris)).reshape(-1, 3)
    return [(name, (lambda fn=fn: indexed(fn))) for name, fn in GENERATED.items()]


def _median_time(fn, repeat):
    fn()  # warm-up (JIT compilation, caches)
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), times


def bench_build(args):
    from tqdm import tqdm
    from hwbvh.api import build
    from hwbvh.primitives import as_triangles
    from traversal.embree_ref import embree_scene

    rows = []
    for name, load in tqdm(mesh_inputs(args), desc="bench build", file=sys.stderr, unit="mesh"):
        verts, faces = load()
        tris = as_triangles(verts[faces], source=name)
        v32 = verts.astype(np.float32)
        f32 = faces.astype(np.int32)
        ours, ours_all = _median_time(lambda: build(tris), args.repeat)
        emb, emb_all = _median_time(lambda: embree_scene(v32, f32), args.repeat)
        bvh = build(tris)
        rows.append({"mesh": name, "triangles": int(len(tris)), "hwbvh_seconds": ours,
                     "embree_seconds": emb, "ratio": ours / emb,
                     "hwbvh_spread": [min(ours_all), max(ours_all)],
                     "embree_spread": [min(emb_all), max(emb_all)],
                     "sah_cost": bvh.meta["sah_cost"], "nodes": bvh.meta["nodes"]})
    return {"meshes": rows, "machine": machine(), "repeat": args.repeat}


def human(what):
    def fmt(r):
        if what == "build":
            lines = [f"{'mesh':<18}{'tris':>10}{'hwbvh ms':>11}{'embree ms':>11}{'ratio':>8}{'SAH':>9}"]
            for m in r["meshes"]:
                lines.append(f"{m['mesh']:<18}{m['triangles']:>10}{m['hwbvh_seconds']*1e3:>11.1f}"
                             f"{m['embree_seconds']*1e3:>11.1f}{m['ratio']:>8.2f}{m['sah_cost']:>9.2f}")
            return "\n".join(lines)
        if what in ("tti", "accuracy"):
            return "wrote " + ", ".join(r["files"])
        if what == "render":
            lines = [f"{'path':<16}{'build s':>9}{'render s':>10}{'total s':>9}"]
            for m in r["rows"]:
                lines.append(f"{m['builder'] + '+' + m['traversal']:<16}{m['build_seconds']:>9.3f}"
                             f"{m['render_seconds']:>10.3f}{m['total_seconds']:>9.3f}")
            lines.append(f"ratio (ours / embree): {r['ratio']:.2f}")
            return "\n".join(lines)
        if what == "trace":
            lines = [f"{'mesh':<14}{'set':<12}{'rays':>9}{'ours Mr/s':>11}{'embreex':>9}{'ratio':>7}{'open3d':>8}"]
            for m in r["meshes"]:
                for k, s in m["sets"].items():
                    o3 = f"{s['open3d_mrays']:>8.2f}" if "open3d_mrays" in s else f"{'-':>8}"
                    lines.append(f"{m['mesh']:<14}{k:<12}{s['rays']:>9}{s['ours_mrays']:>11.2f}"
                                 f"{s['embreex_mrays']:>9.2f}{s['ratio_vs_embreex']:>7.2f}{o3}")
            return "\n".join(lines)
        if what == "model":
            f = r["fit"]
            lines = [f"control latency: shipped {f['shipped']}, fitted here {f.get('fitted', '-')} "
                     f"(range {f.get('fitted_range', '-')}) on {f['subtrees']} subtrees; Marbles rate "
                     f"{f['target_cycles_per_primitive']:.2f} cycles/primitive",
                     f"{'mesh':<16}{'preset':<10}{'text-only ms':>13}{'calibrated ms':>15}{'thesis ms':>11}"
                     f"{'ratios':>14}"]
            for m in r["rows"]:
                th = f"{m['thesis_seconds']*1e3:>11.2f}" if "thesis_seconds" in m else f"{'-':>11}"
                ra = (f"{m['text_only_ratio']:>7.2f}{m['calibrated_ratio']:>7.2f}"
                      if "thesis_seconds" in m else f"{'-':>14}")
                lines.append(f"{m['mesh']:<16}{m['preset']:<10}{m['text_only_seconds']*1e3:>13.2f}"
                             f"{m['calibrated_seconds']*1e3:>15.2f}{th}{ra}")
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
    from tqdm import tqdm
    from hwbvh.api import build
    from hwbvh.format import validate
    from hwbvh.primitives import primitive_boxes
    from scenes.meshes import bumpy_sphere

    sizes = [10_000, 30_000, 100_000, 300_000, 1_000_000, 2_000_000]
    rows = []
    for n in tqdm(sizes, desc="bench scale", file=sys.stderr):
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


def _open3d_scene(verts, faces):
    try:
        import open3d as o3d
    except Exception:
        return None
    sc = o3d.t.geometry.RaycastingScene()
    sc.add_triangles(o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32)))
    return sc


def _open3d_phase(cells, repeat):
    """Open3D's column, timed after all of ours (see bench_trace)."""
    try:
        import open3d as o3
    except Exception:
        return
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


def bench_trace(args):
    """Throughput (Mrays/s) of our intersect/occluded against embreex (and Open3D when it is
    importable) on identical ray sets: primary, incoherent, shadow.

    Open3D is timed in a second phase, after every mesh's ours/embreex figures: its TBB worker
    threads keep spinning after a call and, timed in between, took CPU from the next
    measurement (up to 25% of ours on this 2-core machine)."""
    from tqdm import tqdm
    import hwbvh
    from hwbvh.primitives import as_triangles
    from traversal import Tracer, raysets
    from traversal.embree_ref import embree_intersect, embree_occluded, embree_scene

    n = args.rays
    rows, later = [], []
    for name, load in tqdm(mesh_inputs(args), desc="bench trace", file=sys.stderr, unit="mesh"):
        verts, faces = load()
        tris = as_triangles(verts[faces], source=name)
        v32, f32 = verts.astype(np.float32), faces.astype(np.int32)
        tracer = Tracer(hwbvh.build(tris))
        emb = embree_scene(v32, f32)
        sets = {}
        O, D = raysets.primary(tris, n)
        sets["primary"] = (O, D, None)
        O, D = raysets.incoherent(tris, n)
        sets["incoherent"] = (O, D, None)
        O, D, tmax = raysets.shadow(tracer, tris, n)
        sets["shadow"] = (O, D, tmax)
        out = {}
        for kind, (O, D, tmax) in sets.items():
            O32 = np.ascontiguousarray(O, np.float32)
            D32 = np.ascontiguousarray(D, np.float32)
            tm32 = None if tmax is None else np.ascontiguousarray(tmax, np.float32)
            if tmax is None:
                ours = lambda: tracer.intersect(O32, D32)
                peer = lambda: embree_intersect(emb, O32, D32)
            else:
                ours = lambda: tracer.occluded(O32, D32, 0.0, tm32)
                peer = lambda: embree_occluded(emb, O32, D32, tm32)
            t_ours, spread_o = _median_time(ours, args.repeat)
            t_emb, spread_e = _median_time(peer, args.repeat)
            out[kind] = {"rays": int(len(O)), "ours_mrays": len(O) / t_ours / 1e6,
                         "embreex_mrays": len(O) / t_emb / 1e6, "ratio_vs_embreex": t_emb / t_ours,
                         "ours_spread_s": [min(spread_o), max(spread_o)],
                         "embreex_spread_s": [min(spread_e), max(spread_e)]}
            later.append((out[kind], v32, f32, O32, D32, tm32, t_ours))
        rows.append({"mesh": name, "triangles": int(len(tris)), "sets": out})
    _open3d_phase(later, args.repeat)
    return {"meshes": rows, "machine": machine(), "repeat": args.repeat}


def bench_render(args):
    """The default scene (640x480, 4 spp, depth 5) with our build + traversal against
    Embree's build + traversal, in one process after warm-up; median of repeats. The two
    paths alternate run by run, so that drift in the machine's speed (about 10% on this 2-core
    VM) falls on both alike."""
    from raytracer.render import make_tracer, render, warm_up
    from scenes import compile_scene, load_scene

    scene = compile_scene(load_scene(args.meshes[0] if args.meshes else "cornell"))
    paths = (("hwbvh", "numba"), ("embree", "embree"))
    runs = {p: {"builds": [], "renders": [], "rays": None} for p in paths}
    for builder, traversal in paths:
        warm_up(builder, traversal, parallel_build=True)
        tracer, _, _ = make_tracer(scene, builder, traversal)
        render(scene, tracer)                          # first render of each path: warm-up
    for _ in range(args.repeat):
        for p in paths:
            tracer, b, _ = make_tracer(scene, *p)
            t = time.perf_counter()
            res = render(scene, tracer)
            runs[p]["renders"].append(time.perf_counter() - t)
            runs[p]["builds"].append(b)
            runs[p]["rays"] = res.stats["rays"]
    rows = []
    for (builder, traversal), r in runs.items():
        builds, renders = r["builds"], r["renders"]
        rows.append({"builder": builder, "traversal": traversal,
                     "build_seconds": statistics.median(builds),
                     "render_seconds": statistics.median(renders),
                     "total_seconds": statistics.median(np.add(builds, renders)),
                     "render_spread": [min(renders), max(renders)], "rays": r["rays"]})
    ratio = rows[0]["total_seconds"] / rows[1]["total_seconds"]
    return {"scene": scene.name, "rows": rows, "ratio": ratio, "machine": machine()}


def bench_model(args):
    """The hardware model against the thesis: the fit of its one calibrated constant (on
    subtrees cut from the given meshes, against Marbles' rate), then whole-scene build times
    for HWBVH-C and HWBVH-HP with the text-only model (control latency 0) and the calibrated
    one, beside the thesis' times where the mesh is a thesis scene, and the fill share of the
    design-space sweep (thesis 4.2: 3.6% on average)."""
    import tempfile
    from dataclasses import replace
    from tqdm import tqdm
    from hwbvh import calibration as cal
    from hwbvh.builder import build_canonical
    from hwbvh.cycle_model import CONTROL_LATENCY, PRESETS, simulate, sweep
    from hwbvh.primitives import as_triangles, primitive_boxes

    meshes = []
    for name, load in tqdm(mesh_inputs(args), desc="bench model: load", file=sys.stderr, unit="mesh"):
        verts, faces = load()
        meshes.append((name, as_triangles(verts[faces], source=name)))
    subs = cal.fit_subtrees([t for _, t in meshes])
    target, (t_lo, t_hi) = cal.target_rate()
    fit = {"target_cycles_per_primitive": target, "target_range": [t_lo, t_hi],
           "subtrees": len(subs), "shipped": CONTROL_LATENCY}
    if subs:
        fit.update(fitted=cal.fit_control_latency(subs, target),
                   fitted_range=[cal.fit_control_latency(subs, t_lo), cal.fit_control_latency(subs, t_hi)],
                   rate_text_only=cal.model_rate(subs, 0), rate_shipped=cal.model_rate(subs, CONTROL_LATENCY))
    rows = []
    for name, tris in tqdm(meshes, desc="bench model: simulate", file=sys.stderr, unit="mesh"):
        tree = build_canonical(primitive_boxes(tris))
        scene = cal.THESIS_SCENE_OF_MESH.get(name)
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
            rows.append(row)
    fill = {}
    if meshes:
        name, tris = next(((n, t) for n, t in meshes if n == "bunny"), meshes[0])
        with tempfile.TemporaryDirectory() as d:
            for key, ctl in (("text_only", 0), ("calibrated", CONTROL_LATENCY)):
                fill[key] = sweep(tris, d, control_latency=ctl)["fill_share"]
        fill["mesh"] = name
    return {"fit": fit, "rows": rows, "fill_share": fill, "machine": machine()}
