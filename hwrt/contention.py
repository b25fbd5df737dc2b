"""``hwrt bench contention``: build + render beside a busy competitor, for each threading set-up.

A workstation is rarely idle. The question is not how fast a render runs alone but how much a
competing job slows it, against how much the same job slows Embree (TBB's work-stealing pool).
For each threading set-up of ``hwbvh.parallel`` a child process (the set-up must be chosen
before the first parallel region) measures, after warm-up, our build + render and Embree's
build + render of one scene, alternating run by run, first alone and then beside a competitor:
one process per core, each sorting an array in NumPy without pause, so every core is kept busy
by another program.
"""
import json
import os
import statistics
import subprocess
import sys
import time

COMPETITOR = """
import numpy as np
a = np.random.default_rng(0).random(1 << 20)
while True:
    np.sort(a)
"""


def _measure(scene, repeat):
    """Median build and render seconds of both paths (ours, Embree), alternating run by run."""
    from raytracer.render import make_tracer, render

    runs = {"hwbvh": ([], []), "embree": ([], [])}
    for _ in range(repeat):
        for path, traversal in (("hwbvh", "numba"), ("embree", "embree")):
            tracer, b, _ = make_tracer(scene, path, traversal)
            t = time.perf_counter()
            render(scene, tracer)
            runs[path][0].append(b)
            runs[path][1].append(time.perf_counter() - t)
    return {p: {"build_seconds": statistics.median(b), "render_seconds": statistics.median(r),
                "total_seconds": statistics.median([x + y for x, y in zip(b, r)])}
            for p, (b, r) in runs.items()}


def child(scene_spec, repeat, width, height, spp):
    """One set-up (chosen by HWRT_THREADING before import): quiet, then busy. Prints JSON."""
    import numba
    from raytracer.render import make_tracer, render, warm_up
    from scenes import compile_scene, load_scene, with_frame

    scene = compile_scene(with_frame(load_scene(scene_spec), width, height, spp))
    for path, traversal in (("hwbvh", "numba"), ("embree", "embree")):
        warm_up(path, traversal, parallel_build=True)
        render(scene, make_tracer(scene, path, traversal)[0])
    quiet = _measure(scene, repeat)
    competitors = [subprocess.Popen([sys.executable, "-c", COMPETITOR])
                   for _ in range(os.cpu_count() or 2)]
    try:
        time.sleep(0.5)                       # let the competitors start
        busy = _measure(scene, repeat)
    finally:
        for p in competitors:
            p.kill()
            p.wait()
    from hwbvh.parallel import THREADING
    print(json.dumps({"setup": THREADING, "layer": numba.threading_layer(), "quiet": quiet,
                      "busy": busy}))


def bench_contention(args, setups=None):
    """Every threading set-up in a child process; slowdown = busy / quiet time to image."""
    from hwbvh.config import DEFAULT_THREADING
    from hwbvh.errors import InputError
    from hwbvh.parallel import THREADING_SETUPS

    from scenes import compile_scene, load_scene, with_frame
    from .bench import machine, traceable

    scene = args.meshes[0] if args.meshes else "cornell"
    # read and checked here, as each child will read it, so that a bad scene or setting is
    # refused once, before any child starts, with the error naming what the user gave
    traceable(scene, compile_scene(with_frame(load_scene(scene), args.width, args.height,
                                              args.spp)))
    rows = []
    for setup in setups or list(THREADING_SETUPS):
        env = dict(os.environ, HWRT_THREADING=setup)
        env.pop("NUMBA_THREADING_LAYER", None)
        env.pop("OMP_WAIT_POLICY", None)
        code = (f"from hwrt.contention import child; child({scene!r}, {args.repeat}, "
                f"{args.width}, {args.height}, {args.spp})")
        p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
        if p.returncode != 0:
            last = (p.stderr.strip().splitlines() or ["no output"])[-1]
            raise InputError(scene, f"contention run with {setup} failed: {last}")
        r = json.loads(p.stdout.strip().splitlines()[-1])
        for path in ("hwbvh", "embree"):
            r[path + "_slowdown"] = r["busy"][path]["total_seconds"] / r["quiet"][path]["total_seconds"]
        r["slowdown_ratio"] = r["hwbvh_slowdown"] / r["embree_slowdown"]
        rows.append(r)
    return {"scene": scene, "width": args.width, "height": args.height, "spp": args.spp,
            "repeat": args.repeat, "default_setup": DEFAULT_THREADING, "rows": rows,
            "machine": machine()}


def human(r):
    lines = [f"{r['scene']} {r['width']}x{r['height']} {r['spp']} spp, build + render, median of "
             f"{r['repeat']}; busy = a competitor on every core",
             f"{'set-up':<12} {'ours quiet':>10} {'ours busy':>10} {'slowdown':>9} "
             f"{'Embree quiet':>12} {'Embree busy':>11} {'slowdown':>9} {'ratio':>6}"]
    for x in r["rows"]:
        mark = " (default)" if x["setup"] == r["default_setup"] else ""
        lines.append(f"{x['setup']:<12} {x['quiet']['hwbvh']['total_seconds']:>10.3f} "
                     f"{x['busy']['hwbvh']['total_seconds']:>10.3f} {x['hwbvh_slowdown']:>9.2f} "
                     f"{x['quiet']['embree']['total_seconds']:>12.3f} "
                     f"{x['busy']['embree']['total_seconds']:>11.3f} {x['embree_slowdown']:>9.2f} "
                     f"{x['slowdown_ratio']:>6.2f}{mark}")
    return "\n".join(lines)
