"""The ``hwrt`` command line (SPEC section 8).

Every subcommand takes ``--json`` and then prints exactly one JSON object on stdout; progress
and logs go to stderr. Exit status: 0 success, 2 bad input (one-line error on stderr), 1 other.
"""
import argparse
import json
import os
import sys

from hwbvh import config
from hwbvh.errors import InputError


def _emit(args, result, human):
    if args.json:
        sys.stdout.write(json.dumps(result) + "\n")
    else:
        sys.stdout.write(human(result) + "\n")
    sys.stdout.flush()


def _kv(result, keys):
    return "\n".join(f"{k:>18}: {result[k]}" for k in keys if k in result)


# --------------------------------------------------------------------------------------
def cmd_build(args):
    from hwbvh.api import build, save, write_files
    from hwbvh.primitives import pack_records, primitive_boxes

    if args.builder == "embree":
        from traversal.embree_ref import embree_build_seconds
        from hwbvh.primitives import load_mesh_arrays, as_triangles
        verts, faces = load_mesh_arrays(args.mesh)
        as_triangles(verts[faces], source=args.mesh)
        if args.out or args.dump_aabbs or args.dump_handoff:
            raise InputError("--builder embree", "Embree's tree is internal to Embree: "
                             "--out and the dumps need --builder hwbvh or sweep")
        secs = embree_build_seconds(verts, faces)
        result = {"triangles": int(len(faces)), "nodes": None, "leaves": None, "max_depth": None,
                  "sah_cost": None, "build_seconds": secs, "fallback_splits": None,
                  "builder": "embree"}
        return _emit(args, result, lambda r: _kv(r, r.keys()))
    bvh = build(args.mesh, builder=args.builder, leaf_size=args.leaf_size, bins=args.bins,
                capacity=args.capacity, subtree_builders=args.subtree_builders,
                block_nodes=args.block_nodes, validate_tree=True)
    result = dict(bvh.meta)
    outputs = []
    if args.dump_aabbs or args.dump_handoff:
        boxes = primitive_boxes(bvh.triangles)
        files = []
        if args.dump_aabbs:
            files.append((args.dump_aabbs, pack_records(boxes)))
        if args.dump_handoff:
            order, sizes = bvh.handoff_order()
            files.append((args.dump_handoff, pack_records(boxes, order)))
            files.append((args.dump_handoff + ".json",
                          json.dumps({"record_bytes": config.PRIMITIVE_RECORD_BYTES,
                                      "handoff_sizes": [int(x) for x in sizes]}) + "\n"))
            result["handoff_sizes"] = [int(x) for x in sizes]
        write_files(files)
        outputs += [f for f, _ in files]
    if args.out:
        outputs += save(bvh, args.out)
    result["outputs"] = outputs
    keys = ["builder", "triangles", "nodes", "leaves", "max_depth", "sah_cost", "fallback_splits",
            "build_seconds", "handoffs", "outputs"]
    _emit(args, result, lambda r: _kv(r, keys))


def _scene_geometry(name):
    """(label, triangles f32, vertices f32, faces i32) of a scene name/file or mesh file."""
    from hwbvh.primitives import as_triangles, load_mesh_arrays
    import numpy as np
    try:
        from scenes import is_scene, load_scene_geometry
    except ImportError:          # scenes not available: meshes only
        is_scene = None
    if is_scene is not None and is_scene(name):
        return load_scene_geometry(name)
    verts, faces = load_mesh_arrays(name)
    tris = as_triangles(verts[faces], source=name)
    return os.path.splitext(os.path.basename(name))[0], tris, verts.astype(np.float32), \
        faces.astype(np.int32)


def _replay(path, tris, verts, faces):
    """Re-trace the rays of a mismatch file with both tracers and the float64 reference."""
    import numpy as np
    import hwbvh
    from traversal import Tracer
    from traversal.embree_ref import embree_intersect, embree_scene
    from traversal.verify import classify

    try:
        data = np.load(path)
        O, D, tmax = data["origins"], data["dirs"], data["tmax"]
    except (OSError, KeyError, ValueError) as e:
        raise InputError(path, f"not a mismatch file from hwrt verify ({e})") from None
    h = Tracer(hwbvh.build(tris)).intersect(O, D, 0.0, tmax)
    te, pe, *_ = embree_intersect(embree_scene(verts, faces), O, D,
                                  None if np.isinf(tmax).all() else tmax)
    counts, labels = classify(tris, O, D, 0.0, tmax, h.prim.astype(np.int64), h.t, pe, te)
    names = {0: "agree", 1: "tie", 2: "mismatch"}
    rows = [{"origin": O[i].tolist(), "dir": D[i].tolist(), "ours": [int(h.prim[i]), float(h.t[i])],
             "embree": [int(pe[i]), float(te[i])], "class": names[int(labels[i])]}
            for i in range(len(O))]
    return dict(counts, replayed=rows, file=str(path))


def cmd_verify(args):
    import numpy as np
    from traversal.verify import verify_mesh
    from hwbvh.api import write_files
    import io

    if args.rays < 1:
        raise InputError("--rays", "must be at least 1")
    label, tris, verts, faces = _scene_geometry(args.scene)
    if args.replay:
        return _emit(args, _replay(args.replay, tris, verts, faces),
                     lambda r: "\n".join(json.dumps(x) for x in r["replayed"]))
    counts, labels, (O, D, tmax), h, (te, pe) = verify_mesh(tris, verts, faces, args.kind, args.rays)
    result = dict(counts)
    result.update({"kind": args.kind, "scene": label})
    bad = np.flatnonzero(labels == 2)
    if len(bad):
        out = args.mismatches or os.path.join("renders", f"verify-{label}-{args.kind}-mismatches.npz")
        buf = io.BytesIO()
        np.savez(buf, origins=O[bad], dirs=D[bad], ours_prim=h.prim[bad], ours_t=h.t[bad],
                 embree_prim=pe[bad], embree_t=te[bad],
                 tmax=(np.full(len(bad), np.inf) if tmax is None else np.asarray(tmax)[bad]))
        write_files([(out, buf.getvalue())])
        result["mismatch_file"] = out
    _emit(args, result, lambda r: _kv(r, ["scene", "kind", "rays", "agree", "tie", "mismatch",
                                          "mismatch_file"]))


def cmd_simulate(args):
    from hwbvh.cycle_model import simulate_mesh, sweep

    if args.sweep:
        from hwbvh.cycle_model import params_for
        ctl = params_for(args.preset, control_latency=args.control_latency).control_latency
        result = sweep(args.mesh, args.out_dir, leaf_sizes=args.leaf_sizes, jobs=args.jobs,
                       control_latency=ctl)
        return _emit(args, result, lambda r: f"wrote {r['csv']} and {', '.join(r['plots'])}")
    from hwbvh.errors import ParameterError
    try:
        result = simulate_mesh(args.mesh, args.preset, w=args.w, tsize=args.tsize, psize=args.psize,
                               subtree_builders=args.subtree_builders, ram_pairs=args.ram_pairs,
                               clock_mhz=args.clock_mhz, leaf_size=args.leaf_size, bins=args.bins,
                               control_latency=args.control_latency)
    except ParameterError as e:         # the library names its parameter; the user typed a flag
        raise InputError(f"--{e.parameter.replace('_', '-')}", e.problem) from None
    _emit(args, result, lambda r: _kv(r, ["preset", "triangles", "cycles", "seconds", "energy_joules",
                                          "area_mm2", "active_power_w", "traffic_bytes",
                                          "footprint_bytes", "utilisation", "sah_cost"]))


def cmd_render(args):
    import time
    from raytracer.render import make_tracer, render, warm_up
    from raytracer.output import write_exr, write_png
    from scenes import compile_scene, load_scene

    t_start = time.perf_counter()
    d = load_scene(args.scene)
    film = d.setdefault("film", {})
    integ = d.setdefault("integrator", {"type": "whitted"})
    for key, val, tgt in (("width", args.width, film), ("height", args.height, film),
                          ("spp", args.spp, film), ("max_depth", args.max_depth, integ)):
        if val is not None:
            if val < 1:
                raise InputError(f"--{key.replace('_', '-')}", f"must be at least 1, got {val}")
            tgt[key] = val
    scene = compile_scene(d)
    out = args.output or os.path.join("renders", f"{scene.name}.exr")
    if not out.lower().endswith(".exr"):
        raise InputError("-o", f"{out}: the output must be an .exr file")
    startup_s = warm_up(args.builder, args.traversal)
    tracer, build_s, info = make_tracer(scene, args.builder, args.traversal)
    verify = None
    if args.verify:
        if args.traversal == "embree":
            raise InputError("--verify", "checks our traversal against Embree; use --traversal numba")
        from traversal.embree_ref import embree_scene
        verify = embree_scene(scene.vertices, scene.faces)
    from tqdm import tqdm
    bar = tqdm(total=scene.spp, desc=f"render {scene.name}", unit="spp", file=sys.stderr,
               disable=not sys.stderr.isatty() and not os.environ.get("HWRT_PROGRESS"))
    t0 = time.perf_counter()
    res = render(scene, tracer, seed=args.seed, verify=verify, progress=bar.update)
    render_s = time.perf_counter() - t0
    bar.close()
    result = {"output": out, "scene": scene.name, "builder": args.builder, "traversal": args.traversal,
              "triangles": int(len(scene.triangles)), "width": scene.width, "height": scene.height,
              "spp": scene.spp, "max_depth": scene.max_depth,
              "build_seconds": build_s, "render_seconds": render_s,
              "time_to_image_seconds": build_s + render_s,
              "simulated_build_seconds": info.get("simulated_build_seconds"),
              "startup_seconds": startup_s,
              "rays": res.stats["rays"],
              "passes": res.stats["passes"]}
    result.update({k: v for k, v in info.items() if k in ("nodes", "sah_cost")})
    sim = info.get("simulated_build_seconds")
    if sim:
        result["time_to_image_simulated_seconds"] = {k: v + render_s for k, v in sim.items()}
    if "verify" in res.stats:
        result["verify"] = res.stats["verify"]
    meta = {"scene": scene.name, "builder": args.builder, "traversal": args.traversal,
            "build_seconds": build_s, "render_seconds": render_s, "spp": scene.spp,
            "max_depth": scene.max_depth}
    meta.update({f"rays_{k}": v for k, v in res.stats["rays"].items()})
    write_exr(out, res, meta, layers=not args.no_layers)
    if args.png:
        png = os.path.splitext(out)[0] + ".png"
        write_png(png, res.image)
        result["png"] = png
    result["wall_seconds"] = time.perf_counter() - t_start
    _emit(args, result, lambda r: _kv(r, ["output", "png", "scene", "triangles", "build_seconds",
                                          "render_seconds", "time_to_image_seconds", "rays", "verify"]))


def cmd_animate(args):
    from . import animate
    _emit(args, animate.cmd_animate(args), animate.human)


def cmd_bench(args):
    from . import bench
    from . import study
    fn = {"build": bench.bench_build, "scale": bench.bench_scale,
          "trace": bench.bench_trace, "render": bench.bench_render,
          "tti": study.bench_tti, "accuracy": study.bench_accuracy,
          "model": bench.bench_model}.get(args.what)
    if args.what == "animation":
        from . import animate
        return _emit(args, animate.bench_animation(args), animate.human_bench)
    if fn is None:
        raise InputError("bench", f"'{args.what}' is not available yet")
    result = fn(args)
    _emit(args, result, bench.human(args.what))


# --------------------------------------------------------------------------------------
def _positive(v):
    try:
        i = int(v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{v!r} is not an integer")
    return i


def make_parser():
    p = argparse.ArgumentParser(prog="hwrt", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)

    b = sub.add_parser("build", help="build a BVH over a mesh (SPEC 8)")
    b.add_argument("mesh")
    b.add_argument("--builder", choices=["hwbvh", "sweep", "embree"], default="hwbvh")
    b.add_argument("--leaf-size", type=_positive, default=config.DEFAULT_LEAF_SIZE)
    b.add_argument("--bins", type=_positive, default=config.DEFAULT_BINS)
    b.add_argument("--capacity", type=_positive, default=config.DEFAULT_CAPACITY,
                   help="subtree capacity w*Psize (placement only; the tree never changes)")
    b.add_argument("--subtree-builders", type=_positive, default=1)
    b.add_argument("--block-nodes", type=_positive, default=config.DEFAULT_BLOCK_NODES)
    b.add_argument("--out", metavar="PREFIX", help="write PREFIX.nodes/.indices/.json")
    b.add_argument("--dump-aabbs", metavar="F", help="primitive records as the hardware reads them")
    b.add_argument("--dump-handoff", metavar="F", help="records in upper-builder hand-off order")
    b.add_argument("--json", action="store_true")
    b.set_defaults(func=cmd_build)

    s = sub.add_parser("simulate", help="cycles, traffic, footprint and energy of the hardware build")
    s.add_argument("mesh")
    s.add_argument("--preset", default="HWBVH-C", choices=["HWBVH-C", "HWBVH-HP"])
    for name in ("w", "tsize", "psize", "subtree-builders", "ram-pairs", "leaf-size", "bins"):
        s.add_argument(f"--{name}", type=_positive)
    s.add_argument("--clock-mhz", type=float)
    s.add_argument("--control-latency", type=_positive, metavar="CYCLES",
                   help="control cycles per split beyond Table 3.3 (default: the calibrated "
                        "value; 0 = the text-only model)")
    s.add_argument("--sweep", action="store_true",
                   help="design-space sweep (thesis 4.2.1): w, Tsize in {2,4,8,16} x leaf sizes")
    s.add_argument("--leaf-sizes", type=_positive, nargs="+", default=[4, 8, 16, 32, 64])
    s.add_argument("--out-dir", default="renders/sweep")
    s.add_argument("--jobs", type=_positive, default=os.cpu_count() or 1)
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_simulate)

    r = sub.add_parser("render", help="render a scene (Whitted) to EXR")
    r.add_argument("scene", nargs="?", default="cornell",
                   help="built-in scene (cornell, marbles, cloth, room), scene file, or mesh file")
    r.add_argument("-o", "--output", help="EXR path (default renders/<scene>.exr)")
    r.add_argument("--width", type=_positive)
    r.add_argument("--height", type=_positive)
    r.add_argument("--spp", type=_positive)
    r.add_argument("--max-depth", type=_positive)
    r.add_argument("--builder", choices=["hwbvh", "sweep", "embree"], default="hwbvh")
    r.add_argument("--traversal", choices=["numba", "embree"], default="numba")
    r.add_argument("--verify", action="store_true", help="check every ray against Embree")
    r.add_argument("--png", action="store_true", help="also write a tone-mapped PNG preview")
    r.add_argument("--no-layers", action="store_true", help="RGB only (no Z, N, prim.id)")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--json", action="store_true")
    r.set_defaults(func=cmd_render)

    v = sub.add_parser("verify", help="trace rays with our units and with Embree; classify each")
    v.add_argument("scene", help="built-in scene name, scene file, or mesh file")
    v.add_argument("--rays", type=_positive, default=100_000)
    v.add_argument("--kind", choices=["primary", "random", "bounces", "shadow"], default="random")
    v.add_argument("--mismatches", metavar="F.npz", help="where mismatching rays are written")
    v.add_argument("--replay", metavar="F.npz", help="re-trace the rays of a mismatch file")
    v.add_argument("--json", action="store_true")
    v.set_defaults(func=cmd_verify)

    an = sub.add_parser("animate", help="render an animation, a tree per frame, one EXR per frame")
    an.add_argument("scene", help="built-in animation (exploding, cloth, marbles, flythrough), "
                                  "scene file, or frame pattern of mesh files ('f_%%04d.ply' or a glob)")
    an.add_argument("--frames", type=_positive, help="frames to render (default: the animation's)")
    an.add_argument("--fps", type=float, help="frames per second of animation time (default 30)")
    an.add_argument("--strategy", default="rebuild",
                    help="tree update per frame: rebuild, refit, adaptive or embree")
    an.add_argument("--threshold", type=float,
                    help="adaptive: rebuild when the SAH cost grows past this factor of the last rebuild's")
    an.add_argument("--width", type=_positive)
    an.add_argument("--height", type=_positive)
    an.add_argument("--spp", type=_positive)
    an.add_argument("--max-depth", type=_positive)
    an.add_argument("--mesh", help="exploding: the mesh that breaks (default: bunny, else generated)")
    an.add_argument("--triangles", type=_positive, help="generated animations: about this many triangles")
    an.add_argument("--physics", help="marbles: pybullet, analytic or auto (default)")
    an.add_argument("--verify", action="store_true", help="check every camera ray against Embree")
    an.add_argument("--seed", type=int, default=0)
    an.add_argument("-o", "--output", metavar="DIR", help="default renders/animate-<scene>-<strategy>")
    an.add_argument("--json", action="store_true")
    an.set_defaults(func=cmd_animate)

    be = sub.add_parser("bench", help="benchmarks against peers measured in the same run")
    be.add_argument("what", choices=["build", "scale", "trace", "render", "tti", "accuracy", "model",
                                     "animation"])
    be.add_argument("meshes", nargs="*", help="mesh files (default: every mesh in --mesh-dir)")
    be.add_argument("--mesh-dir", help="default: $HWRT_MESHES or ../shared/meshes, else generated")
    be.add_argument("--repeat", type=_positive, default=5)
    be.add_argument("--rays", type=_positive, default=500_000, help="rays per set (bench trace)")
    be.add_argument("--quick", action="store_true", help="tti/accuracy: a few small cells (< 3 min)")
    be.add_argument("--fresh", action="store_true", help="tti/accuracy: ignore finished cells")
    be.add_argument("--out-dir", default="renders/bench", help="tti/accuracy results")
    be.add_argument("--width", type=_positive, default=320)
    be.add_argument("--height", type=_positive, default=240)
    be.add_argument("--spp", type=_positive, default=1)
    be.add_argument("--max-depth", type=_positive, default=5)
    be.add_argument("--frames", type=_positive, help="animation: frames per animation (default 60)")
    be.add_argument("--json", action="store_true")
    be.set_defaults(func=cmd_bench)
    return p


def main(argv=None):
    parser = make_parser()
    args = parser.parse_args(argv)
    try:
        args.func(args)
    except InputError as e:
        print(f"hwrt: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("hwrt: interrupted", file=sys.stderr)
        return 1
    except Exception as e:  # anything else is our fault, not the input's
        print(f"hwrt: internal error: {type(e).__name__}: {e}", file=sys.stderr)
        if os.environ.get("HWRT_DEBUG"):
            raise
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
