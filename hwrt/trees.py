"""``hwrt bench trees``: does the render time show the tree?

The hardware builder (16 bins, fixed split rules) and the full-sweep SAH builder give trees of
different quality for the same scene. A renderer measures trees only if its render time moves
with the traversal work the tree causes. For each scene this benchmark renders with both trees
(alternating run by run; a ratio is the median of the rounds' ratios) and counts, with the
single-ray unit's counters, the nodes visited and triangles tested per ray over every query of
the render, closest-hit and shadow alike. It reports the ratio sweep/hwbvh of render time, of
trace-only time (the same rays traced again alone) and of (nodes + triangles) per ray.
"""
import statistics
import time

DEFAULT_SCENES = ("cornell", "marbles")
BUILDERS = ("hwbvh", "sweep")


def _scene(spec, args):
    from scenes import compile_scene, load_scene

    d = load_scene(spec)
    film = d.setdefault("film", {})
    for key in ("width", "height", "spp"):
        if getattr(args, key, None) is not None:
            film[key] = getattr(args, key)
    return compile_scene(d)


def _paired_ratio(seconds):
    """The median over rounds of sweep / hwbvh, each round's two runs side by side: a drift in
    the machine's speed between rounds (a shared virtual machine's speed moves by tens of
    percent over seconds) cancels in each round's ratio, where it would not in a ratio of
    medians."""
    return statistics.median(s / h for s, h in zip(seconds["sweep"], seconds["hwbvh"]))


def bench_trees(args):
    from raytracer.render import make_tracer, render, warm_up
    from traversal.tracers import CountingTracer, RecordingTracer

    warm_up("hwbvh", "numba", parallel_build=True)
    rows = []
    for spec in args.meshes or DEFAULT_SCENES:
        scene = _scene(spec, args)
        tracers, sah = {}, {}
        for b in BUILDERS:
            tracers[b], _, info = make_tracer(scene, b, "numba")
            sah[b] = info.get("sah_cost")
        row = {"scene": scene.name, "width": scene.width, "height": scene.height, "spp": scene.spp,
               "sah_cost": sah}
        # packets (as the renderer runs them), then the single-ray unit alone; each against
        # the work it does
        for mode, packets in (("packets", True), ("single_ray", False)):
            work = {}
            for b in BUILDERS:
                tracers[b].packets = packets
                counting = CountingTracer(tracers[b], as_run=True)
                render(scene, counting)
                w = counting.work("all")
                work[b] = dict(w, work_per_ray=w["nodes_per_ray"] + w["tris_per_ray"])
            work_ratio = work["sweep"]["work_per_ray"] / work["hwbvh"]["work_per_ray"]
            recordings = {}
            for b in BUILDERS:
                recordings[b] = RecordingTracer(tracers[b])
                render(scene, recordings[b])          # also the warm-up render of this mode
            renders, replays = {b: [] for b in BUILDERS}, {b: [] for b in BUILDERS}
            for i in range(args.repeat):              # both trees alternate, run by run,
                for b in BUILDERS[::1 - 2 * (i % 2)]:   # which goes first swapping each round
                    t = time.perf_counter()
                    render(scene, tracers[b])
                    renders[b].append(time.perf_counter() - t)
                    replays[b].append(recordings[b].replay_seconds())
            render_s = {b: statistics.median(renders[b]) for b in BUILDERS}
            trace_only = {b: statistics.median(replays[b]) for b in BUILDERS}
            render_ratio, trace_ratio = _paired_ratio(renders), _paired_ratio(replays)
            row[mode] = {"work": work, "work_ratio": work_ratio,
                         "render_seconds": render_s, "trace_only_seconds": trace_only,
                         "render_ratio": render_ratio, "trace_ratio": trace_ratio,
                         "render_vs_work": render_ratio / work_ratio - 1,
                         "trace_vs_work": trace_ratio / work_ratio - 1}
        rows.append(row)
    return {"rows": rows, "repeat": args.repeat}


def human(r):
    lines = [f"{'scene':<10}{'SAH hw/sweep':>14}  {'path':<11}{'work/ray hw':>12}{'sweep':>7}"
             f"{'work':>7}{'render':>7}{'trace':>7}{'render vs':>10}{'trace vs':>9}",
             f"{'':<10}{'':>14}  {'':<11}{'':>12}{'':>7}{'ratio':>7}{'ratio':>7}{'ratio':>7}"
             f"{'work':>10}{'work':>9}"]
    for x in r["rows"]:
        for k, mode in enumerate(("packets", "single_ray")):
            m = x[mode]
            head = f"{x['scene']:<10}{x['sah_cost']['hwbvh']:>7.1f}/{x['sah_cost']['sweep']:<6.1f}" \
                if k == 0 else " " * 24
            lines.append(f"{head}  {mode.replace('_', '-'):<11}"
                         f"{m['work']['hwbvh']['work_per_ray']:>12.1f}{m['work']['sweep']['work_per_ray']:>7.1f}"
                         f"{m['work_ratio']:>7.3f}{m['render_ratio']:>7.3f}{m['trace_ratio']:>7.3f}"
                         f"{100 * m['render_vs_work']:>+9.1f}%{100 * m['trace_vs_work']:>+8.1f}%")
    lines.append("ratios are sweep / hwbvh; work = nodes visited + triangles tested per ray as the "
                 "path runs them (a packet's rays each count the packet's tests), over closest-hit "
                 "and shadow rays; trace = the render's rays traced again alone")
    return "\n".join(lines)
