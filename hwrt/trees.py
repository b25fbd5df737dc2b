"""``hwrt bench trees``: does the render time show the tree?

The hardware builder (16 bins, fixed split rules) and the full-sweep SAH builder give trees of
different quality for the same scene. A renderer measures trees only if its render time moves
with the traversal work the tree causes. For each scene this benchmark renders with both trees
(alternating run by run; a ratio is the median of the rounds' ratios) and counts the nodes
visited and triangles tested per ray over every query of the render, closest-hit and shadow
alike, as the path runs them (a ray traced in a packet counts every node and triangle its
packet tests). It reports the ratio sweep/hwbvh of render time, of trace-only time (the same
rays traced again alone) and of (nodes + triangles) per ray, with packets (as the renderer
runs) and with the single-ray unit alone.

Where the render's time goes: its closest-hit queries, its shadow queries and its other
stages (camera rays, ray queues, shading, accumulation), each with its share and its time
ratio, and the gap to the work ratio that the other stages alone leave, were the queries'
time to follow the work ratio exactly: the part of the gap that no tree can change.

Where the trace time goes: the render's queries, split by kind (closest hit, shadow) and by path
(rays in packets, rays traced one by one), are traced again class by class with both trees,
each class with its work ratio, its trace ratio, its share of the trace time and its time per
unit of work. A unit of work does not cost the same on both paths, so a render's time follows
the work of the classes that hold its time, not the sum of the work.

What a unit costs: per class, each query of both trees is timed alone on one thread and the
times are fitted by non-negative least squares as node visits x a + triangle tests x b +
rays x c + d, so a node visit, a triangle test and a ray's fixed cost get a price each. Where
a and b differ, a tree that saves nodes saves less time than one that saves as many triangles.
"""
import contextlib
import itertools
import statistics
import time

import numpy as np

from .report import name_width

DEFAULT_SCENES = ("cornell", "marbles")
BUILDERS = ("hwbvh", "sweep")


def _scene(spec, args):
    from scenes import compile_scene, load_scene, with_frame

    return compile_scene(with_frame(load_scene(spec), **{key: getattr(args, key, None)
                                                         for key in ("width", "height", "spp")}))


def _alternating(rounds):
    """The trees, round by round, which goes first swapping each round: both trees alternate
    run by run, so a drift in the machine's speed falls on both."""
    for i in range(rounds):
        yield from BUILDERS[::1 - 2 * (i % 2)]


def _quotient(a, b):
    """a / b, or None where b is 0 (a scene whose rays visit no node does no work to compare)."""
    return a / b if b else None


def _gap(ratio, work_ratio):
    """How far a time ratio sits from the work ratio (ratio / work ratio - 1), or None."""
    return ratio / work_ratio - 1 if work_ratio else None


def _paired_ratio(seconds):
    """The median over rounds of sweep / hwbvh, each round's two runs side by side: a drift in
    the machine's speed between rounds (a shared virtual machine's speed moves by tens of
    percent over seconds) cancels in each round's ratio, where it would not in a ratio of
    medians."""
    return statistics.median(s / h for s, h in zip(seconds["sweep"], seconds["hwbvh"]))


def bench_trees(args):
    from raytracer.render import make_tracer, render, warm_up
    from traversal.tracers import CountingTracer, RecordingTracer

    from .bench import check_distinct_scenes, machine, told_apart, traceable

    check_distinct_scenes([str(s) for s in args.meshes])
    # every scene read and checked before any work: both trees trace in float32
    scenes = [(spec, _scene(spec, args)) for spec in args.meshes or DEFAULT_SCENES]
    for spec, scene in scenes:
        traceable(str(spec), scene)
    warm_up("hwbvh", "numba", parallel_build=True)
    rows = []
    for spec, scene in scenes:
        tracers, sah = {}, {}
        for b in BUILDERS:
            tracers[b], _, info = make_tracer(scene, b, "numba")
            sah[b] = info.get("sah_cost")
        row = {"scene": scene.name, "source": str(spec), "width": scene.width,
               "height": scene.height, "spp": scene.spp,
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
                work[b] = dict(w, work_per_ray=w["nodes_per_ray"] + w["tris_per_ray"],
                               by_kind={k: counting.work(k) for k in ("closest", "shadow")})
            work_ratio = _quotient(work["sweep"]["work_per_ray"], work["hwbvh"]["work_per_ray"])
            kind_ratio = {}
            for kind in ("closest", "shadow"):
                per_ray = {b: w["by_kind"][kind]["nodes_per_ray"] + w["by_kind"][kind]["tris_per_ray"]
                           for b, w in work.items()}
                kind_ratio[kind] = _quotient(per_ray["sweep"], per_ray["hwbvh"])
            recordings = {}
            for b in BUILDERS:
                recordings[b] = RecordingTracer(tracers[b])
                render(scene, recordings[b])          # also the warm-up render of this mode
            renders, replays = {b: [] for b in BUILDERS}, {b: [] for b in BUILDERS}
            stage_runs = {b: [] for b in BUILDERS}
            for b in _alternating(args.repeat):
                t = time.perf_counter()
                stats = render(scene, tracers[b]).stats
                renders[b].append(time.perf_counter() - t)
                stage_runs[b].append(stats["stage_seconds"])
                replays[b].append(recordings[b].replay_seconds())
            render_s = {b: statistics.median(renders[b]) for b in BUILDERS}
            trace_only = {b: statistics.median(replays[b]) for b in BUILDERS}
            render_ratio, trace_ratio = _paired_ratio(renders), _paired_ratio(replays)
            if packets:
                row["by_path"] = _by_path(tracers, recordings, args.repeat)
            row[mode] = {"work": work, "work_ratio": work_ratio,
                         "render_seconds": render_s, "trace_only_seconds": trace_only,
                         "render_ratio": render_ratio, "trace_ratio": trace_ratio,
                         "render_vs_work": _gap(render_ratio, work_ratio),
                         "trace_vs_work": _gap(trace_ratio, work_ratio),
                         "stages": _stage_split(stage_runs, kind_ratio, work_ratio)}
        rows.append(row)
    return {"rows": told_apart(rows), "repeat": args.repeat, "machine": machine()}


KINDS = {"intersect": "closest", "occluded": "shadow"}


def _stage_split(runs, kind_ratio, work_ratio):
    """Where the render's time goes, from each timed render's seconds per stage (summed over
    the threads): the closest-hit queries, the shadow queries and the other stages together
    (camera rays, ray queues, shading, accumulation), each with its share of hwbvh's time and
    its time ratio (median over rounds, as ``_paired_ratio``), each query stage beside its
    kind's work ratio. ``floor_vs_work``: how far the render's ratio would sit from the work
    ratio were the queries' time to follow the work ratio exactly and the other stages to take
    the time they took: what the stages that do not trace add to the gap, which no tree can
    change."""
    parts = {KINDS[st]: [st] for st in KINDS}
    parts["other"] = [st for st in runs["hwbvh"][0] if st not in KINDS]
    out = {}
    for name, stages in parts.items():
        seconds = {b: [sum(run[st] for st in stages) for run in runs[b]] for b in BUILDERS}
        out[name] = {"seconds": statistics.median(seconds["hwbvh"]),
                     "ratio": _paired_ratio(seconds) if all(seconds["hwbvh"]) else None,
                     "work_ratio": kind_ratio.get(name)}
    total = sum(p["seconds"] for p in out.values())
    for p in out.values():
        p["share"] = p.pop("seconds") / total if total > 0 else None
    other = out["other"]
    floor = None
    if work_ratio and other["share"] is not None and (other["share"] == 0 or other["ratio"]):
        followed = (1 - other["share"]) * work_ratio + other["share"] * (other["ratio"] or 0)
        floor = _gap(followed, work_ratio)
    out["floor_vs_work"] = floor
    return out


PATHS = ("packets", "one by one")


def _split_queries(queries):
    """The recorded queries as {(kind, path): [query, ...]}: each query's packet rays and its
    other rays as two queries (empty parts dropped)."""
    from traversal.packet import packet_rays

    classes = {}
    for kind, o, d, lo, hi, normals in queries:
        in_packets = packet_rays(d)
        for path, rays in zip(PATHS, (in_packets, ~in_packets)):
            if rays.any():
                part = (kind, o[rays], d[rays], lo if np.ndim(lo) == 0 else lo[rays],
                        hi if np.ndim(hi) == 0 else hi[rays], normals)
                classes.setdefault((KINDS[kind], path), []).append(part)
    return classes


def _query_work(tracer, queries):
    """(nodes, triangles, rays) of each query of ``queries`` as the path runs them, (n, 3)."""
    from traversal.tracers import CountingTracer, replay

    rows = np.zeros((len(queries), 3), np.int64)
    for k, q in enumerate(queries):
        counting = CountingTracer(tracer, as_run=True)
        replay(counting, [q])
        c = counting.counts("all")
        rows[k] = c["nodes"], c["triangles"], c["rays"]
    return rows


FIT_MIN_QUERIES = 20             # a fit of four prices needs queries well beyond four


@contextlib.contextmanager
def _one_thread():
    """The calling thread's kernels run on it alone meanwhile (Numba's thread count is per
    calling thread)."""
    import numba

    was = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(was)


def nonnegative_least_squares(X, y):
    """argmin |X p - y| over p >= 0, for a few columns: the least-squares fit on every subset
    of the columns, the best of those whose prices are all non-negative (a price below zero
    is a fit bending round terms that move together, not a cost)."""
    best, best_res = np.zeros(X.shape[1]), float((y ** 2).sum())
    for subset in itertools.product((False, True), repeat=X.shape[1]):
        cols = np.flatnonzero(subset)
        if len(cols) == 0:
            continue
        p, *_ = np.linalg.lstsq(X[:, cols], y, rcond=None)
        if (p < 0).any():
            continue
        res = float(((X[:, cols] @ p - y) ** 2).sum())
        if res < best_res:
            best = np.zeros(X.shape[1])
            best[cols] = p
            best_res = res
    return best


def _prices(X, y):
    """{"ns_per_node", "ns_per_triangle", "ns_per_ray", "us_per_query", "r2"} of the
    non-negative least-squares fit y ~ X p (columns: nodes, triangles, rays, 1)."""
    price = nonnegative_least_squares(X, y)
    spread = float(((y - y.mean()) ** 2).sum())
    r2 = 1 - float(((y - X @ price) ** 2).sum()) / spread if spread > 0 else None
    return {"ns_per_node": 1e9 * price[0], "ns_per_triangle": 1e9 * price[1],
            "ns_per_ray": 1e9 * price[2], "us_per_query": 1e6 * price[3], "r2": r2}, price


def _cost_fit(tracers, queries, work, repeat):
    """Prices of one class's work, from every query of both trees timed alone on one thread
    (the fastest of ``repeat`` runs): seconds = nodes * a + triangles * b + rays * c + d, fitted
    by non-negative least squares over both trees' queries, and for each tree apart. ``work``:
    each tree's ``_query_work`` of its ``queries``.

    Returns the shared prices ({"ns_per_node", "ns_per_triangle", "ns_per_ray",
    "us_per_query", "r2"}) with "queries"; "one_thread_ratio", the class's time sweep / hwbvh
    as timed here; "priced_ratio", the ratio the shared prices give the two trees' work (what
    the time ratio would be if a unit cost the same in both trees); and "by_tree", each tree's
    own prices (``_own_prices``). None with fewer than FIT_MIN_QUERIES queries."""
    from traversal.tracers import replay

    # the trees' queries taken in turn, so that a drift in the machine's speed falls on both
    turns = [(b, *qw) for pair in itertools.zip_longest(*(zip(queries[b], work[b])
                                                        for b in BUILDERS))
             for b, qw in zip(BUILDERS, pair) if qw is not None and len(qw[0][1])]
    rows, seconds, tree = [], [], []
    with _one_thread():
        for b, q, (nodes, triangles, rays) in turns:
            rows.append([nodes, triangles, rays, 1.0])
            best = np.inf
            for _ in range(max(1, repeat)):
                t = time.perf_counter()
                replay(tracers[b], [q])
                best = min(best, time.perf_counter() - t)
            seconds.append(best)
            tree.append(b)
    if len(rows) < FIT_MIN_QUERIES:
        return None
    X, y, tree = np.array(rows, float), np.array(seconds), np.array(tree)
    fit, price = _prices(X, y)
    mine = {b: tree == b for b in BUILDERS}
    fit.update(queries=len(rows),
               one_thread_ratio=float(y[mine["sweep"]].sum() / y[mine["hwbvh"]].sum()),
               priced_ratio=float((X[mine["sweep"]] @ price).sum() /
                                  (X[mine["hwbvh"]] @ price).sum()),
               by_tree={b: _own_prices(X[mine[b]], y[mine[b]]) for b in BUILDERS})
    return fit


def _own_prices(X, y):
    """One tree's own prices, or None from fewer than FIT_MIN_QUERIES queries. Within one tree
    its node visits and triangle tests grow together, so how the fit shares their cost out is
    loose: only the shared prices compare the trees."""
    if len(y) < FIT_MIN_QUERIES:
        return None
    return dict(_prices(X, y)[0], queries=len(y))


def _by_path(tracers, recordings, repeat):
    """Per (kind, path) class of the render's queries: rays, work per ray of each tree, the
    work ratio, the trace-time ratio (both trees alternating, median of the rounds' ratios)
    and the class's share of hwbvh's trace time."""
    from traversal.tracers import replay_seconds

    split = {b: _split_queries(recordings[b].queries) for b in BUILDERS}
    out = []
    for key in sorted(set(split["hwbvh"]) & set(split["sweep"]),
                      key=lambda k: (k[0], PATHS.index(k[1]))):
        queries = {b: split[b][key] for b in BUILDERS}
        was = {b: tracers[b].packets for b in BUILDERS}
        try:
            per_query = {}
            for b in BUILDERS:
                # a ray left out of a packet stays out: its class is traced with packets off
                tracers[b].packets = key[1] == "packets"
                per_query[b] = _query_work(tracers[b], queries[b])
            seconds = {b: [] for b in BUILDERS}
            for b in _alternating(repeat):
                seconds[b].append(replay_seconds(tracers[b], queries[b]))
            fit = _cost_fit(tracers, queries, per_query, min(repeat, 5))
        finally:
            for b in BUILDERS:
                tracers[b].packets = was[b]
        nodes, triangles, rays = ({b: int(per_query[b][:, c].sum()) for b in BUILDERS}
                                  for c in range(3))
        work = {b: (nodes[b] + triangles[b]) / rays[b] for b in BUILDERS}
        trace_seconds = {b: statistics.median(seconds[b]) for b in BUILDERS}
        out.append({"kind": key[0], "path": key[1], "rays": rays["hwbvh"], "work_per_ray": work,
                    "work_ratio": _quotient(work["sweep"], work["hwbvh"]),
                    "trace_seconds": trace_seconds,
                    "trace_ratio": _paired_ratio(seconds),
                    "ns_per_unit": 1e9 * trace_seconds["hwbvh"] / (rays["hwbvh"] * work["hwbvh"])
                    if work["hwbvh"] else None,
                    "nodes_ratio": nodes["sweep"] / nodes["hwbvh"] if nodes["hwbvh"] else None,
                    "triangles_ratio": triangles["sweep"] / triangles["hwbvh"]
                    if triangles["hwbvh"] else None,
                    "cost_fit": fit})
    total = sum(c["trace_seconds"]["hwbvh"] for c in out)
    for c in out:
        c["time_share"] = c["trace_seconds"]["hwbvh"] / total if total > 0 else None
    return out


def _class_rows(r, w):
    """(row head, class) for each class of each scene's time split; the scene named on its
    first class only, in a column ``w`` wide."""
    for x in r["rows"]:
        for k, c in enumerate(x.get("by_path", [])):
            yield f"{x['scene'] if k == 0 else '':<{w}}{c['kind'] + ', ' + c['path']:<20}", c


def _class_table(title, w, *columns):
    """A blank line, ``title`` and the two heading lines of a table of classes (``_class_rows``)
    whose columns after the scene (``w`` wide) and the class are (top, bottom, format spec)."""
    columns = (("scene", "", f"<{w}"), ("class", "", "<20")) + columns
    return ["", title] + ["".join(f"{c[i]:{c[2]}}" for c in columns) for i in (0, 1)]


def _ratio(x):
    return "-" if x is None else f"{x:.3f}"


def _share(x):
    return "-" if x is None else f"{100 * x:.0f}%"


def _percent(x):
    return "-" if x is None else f"{100 * x:+.1f}%"


def human(r):
    w = name_width([x["scene"] for x in r["rows"]], 10)
    lines = [f"{'scene':<{w}}{'SAH hw/sweep':>14}  {'path':<11}{'work/ray hw':>12}{'sweep':>7}"
             f"{'work':>7}{'render':>7}{'trace':>7}{'render vs':>10}{'trace vs':>9}",
             f"{'':<{w}}{'':>14}  {'':<11}{'':>12}{'':>7}{'ratio':>7}{'ratio':>7}{'ratio':>7}"
             f"{'work':>10}{'work':>9}"]
    for x in r["rows"]:
        for k, mode in enumerate(("packets", "single_ray")):
            m = x[mode]
            head = f"{x['scene']:<{w}}{x['sah_cost']['hwbvh']:>7.1f}/{x['sah_cost']['sweep']:<6.1f}" \
                if k == 0 else " " * (w + 14)
            lines.append(f"{head}  {mode.replace('_', '-'):<11}"
                         f"{m['work']['hwbvh']['work_per_ray']:>12.1f}{m['work']['sweep']['work_per_ray']:>7.1f}"
                         f"{_ratio(m['work_ratio']):>7}{m['render_ratio']:>7.3f}{m['trace_ratio']:>7.3f}"
                         f"{_percent(m['render_vs_work']):>10}{_percent(m['trace_vs_work']):>9}")
    lines.append("ratios are sweep / hwbvh; work = nodes visited + triangles tested per ray as the "
                 "path runs them (a packet's rays each count the packet's tests), over closest-hit "
                 "and shadow rays; trace = the render's rays traced again alone")
    lines += ["", "where the render's time goes (its stages' seconds over all threads, as timed "
                  "above):",
              f"{'scene':<{w}}{'path':<11}{'closest':>24}{'shadow':>24}{'other stages':>15}"
              f"{'render vs':>11}",
              f"{'':<{w}}{'':<11}" + f"{'share':>8}{'time':>8}{'work':>8}" * 2
              + f"{'share':>8}{'time':>7}{'work if':>11}",
              f"{'':<{w}}{'':<11}" + f"{'':>8}{'ratio':>8}{'ratio':>8}" * 2
              + f"{'':>8}{'ratio':>7}{'followed':>11}"]
    for x in r["rows"]:
        for k, mode in enumerate(("packets", "single_ray")):
            st = x[mode]["stages"]
            cells = "".join(f"{_share(st[kind]['share']):>8}{_ratio(st[kind]['ratio']):>8}"
                            f"{_ratio(st[kind]['work_ratio']):>8}" for kind in ("closest", "shadow"))
            lines.append(f"{x['scene'] if k == 0 else '':<{w}}{mode.replace('_', '-'):<11}{cells}"
                         f"{_share(st['other']['share']):>8}{_ratio(st['other']['ratio']):>7}"
                         f"{_percent(st['floor_vs_work']):>11}")
    lines.append("closest, shadow: the render's closest-hit and shadow queries; other stages: camera "
                 "rays, ray queues, shading, accumulation; share of hwbvh's render; render vs work "
                 "if followed: the render's gap to the work ratio were its queries' time to follow "
                 "the work ratio and the other stages to take the time they took, what the stages "
                 "that do not trace add to the gap, which no tree can change")
    lines += _class_table("where the trace time goes (the packet render's queries by kind and "
                          "path, traced again class by class):", w,
                          ("rays", "", ">9"), ("share of", "hw trace", ">10"),
                          ("ns per", "unit hw", ">8"), ("work/ray hw", "", ">12"),
                          ("sweep", "", ">7"), ("work", "ratio", ">7"), ("trace", "ratio", ">7"),
                          ("trace vs", "work", ">9"))
    for head, c in _class_rows(r, w):
        share = "-" if c["time_share"] is None else f"{100 * c['time_share']:.0f}%"
        unit = "-" if c["ns_per_unit"] is None else f"{c['ns_per_unit']:.2f}"
        gap = _percent(_gap(c["trace_ratio"], c["work_ratio"]))
        lines.append(f"{head}{c['rays']:>9}{share:>10}{unit:>8}{c['work_per_ray']['hwbvh']:>12.1f}"
                     f"{c['work_per_ray']['sweep']:>7.1f}{_ratio(c['work_ratio']):>7}"
                     f"{c['trace_ratio']:>7.3f}{gap:>9}")
    lines.append("ns per unit = the class's trace time (all threads, wall) per node visit or "
                 "triangle test; a class's rays traced one by one are traced with packets off; "
                 "each class pays a fixed cost per query, which dominates a class of few rays")
    lines += _class_table("what a unit costs (each query of both trees timed alone on one "
                          "thread, fitted as nodes x a + triangles x b + rays x c + d with no "
                          "price below 0):", w,
                          ("queries", "", ">8"), ("a ns per", "node", ">9"),
                          ("b ns per", "triangle", ">9"), ("c ns per", "ray", ">9"),
                          ("d us per", "query", ">9"), ("R2", "", ">6"), ("nodes", "ratio", ">7"),
                          ("triangles", "ratio", ">10"), ("priced", "ratio", ">7"),
                          ("1-thread", "ratio", ">9"))
    for head, c in _class_rows(r, w):
        f = c.get("cost_fit")
        ratios = f"{_ratio(c['nodes_ratio']):>7}{_ratio(c['triangles_ratio']):>10}"
        if f is None:
            lines.append(f"{head}{'too few queries to fit':>50}{ratios}")
            continue
        r2 = "-" if f["r2"] is None else f"{f['r2']:.2f}"
        lines.append(f"{head}{f['queries']:>8}{f['ns_per_node']:>9.2f}"
                     f"{f['ns_per_triangle']:>9.2f}{f['ns_per_ray']:>9.2f}"
                     f"{f['us_per_query']:>9.1f}{r2:>6}{ratios}"
                     f"{f['priced_ratio']:>7.3f}{f['one_thread_ratio']:>9.3f}")
    lines.append("nodes and triangles count each ray's share as the path runs them (a packet's "
                 "rays each count the packet's tests); ratios are sweep / hwbvh; priced = the "
                 "time ratio the prices give the two trees' work, 1-thread = the time ratio as "
                 "timed for the fit (the JSON has each tree's own prices, loose: within one tree "
                 "nodes and triangles grow together); where terms move together (rays traced "
                 "one by one: work in proportion to rays) the fit cannot part them, and a price "
                 "of 0 means its term's cost went to the others")
    return "\n".join(lines)
