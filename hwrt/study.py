"""The figures the project exists to show (issue 6).

``bench_tti``: time to image (thesis Eq. 4.1: construction + rendering) per scene and
acceleration path. ``bench_accuracy``: what each accuracy knob costs in time and buys in
correctness and image quality.

Both take a mesh directory (default ../shared/meshes when present, else generated meshes),
show a progress bar, print the machine into their results, and resume after an interruption:
every finished cell is appended to ``OUT/<name>.jsonl`` at once, and a rerun skips the cells
already there (``--fresh`` starts over).
"""
import csv
import io
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from hwbvh.files import json_text, write_files
from .bench import machine
from .paths import default_mesh_dir, mesh_files

TTI_PATHS = ("hwbvh-C", "hwbvh-HP", "hwbvh-sw", "sweep", "embree")


def output_names(name):
    """The files a study called ``name`` writes in its output directory."""
    return [f"{name}{ext}" for ext in (".jsonl", ".csv", ".json", ".md", ".png")]


class Cells:
    """Finished cells on disk, one JSON object per line, keyed by ``key``.

    An interruption can cut the last line short. Such a line is dropped when the file is
    opened (its cell runs again), so that the next record starts on a line of its own."""

    def __init__(self, path, fresh=False):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.done = {}
        if fresh and self.path.exists():
            self.path.unlink()
        if self.path.exists():
            self._load()

    def _load(self):
        data = self.path.read_bytes()
        lines = data.split(b"\n")
        complete, last = lines[:-1], lines[-1]      # ``last`` is b"" when the file ends in \n
        if last:
            try:
                json.loads(last)
                complete.append(last)                   # whole, only its newline is missing
                with open(self.path, "ab") as f:
                    f.write(b"\n")
            except ValueError:                          # cut short: cut it off
                os.truncate(self.path, len(data) - len(last))
        for line in complete:
            try:
                row = json.loads(line)
            except ValueError:                          # damaged: that cell runs again
                continue
            if isinstance(row, dict) and "key" in row:
                self.done[row["key"]] = row

    def get(self, key):
        return self.done.get(key)

    def add(self, row):
        self.done[row["key"]] = row
        with open(self.path, "a") as f:
            f.write(json_text(row) + "\n")
            f.flush()
            os.fsync(f.fileno())


def _scene_specs(args, quick):
    """[(name, loader returning a scene dict)]: built-in scenes, then meshes."""
    from scenes import load_scene, mesh_scene
    from scenes.builtin import BUILTIN
    from scenes.meshes import GENERATED

    specs = [(n, (lambda n=n: load_scene(n))) for n in (["cornell"] if quick else list(BUILTIN))]
    paths = [Path(m) for m in getattr(args, "meshes", [])]
    if not paths:
        d = Path(args.mesh_dir) if args.mesh_dir else default_mesh_dir()
        if d is not None and d.is_dir():
            paths = mesh_files(d)
    if quick:
        paths = sorted(paths, key=lambda p: p.stat().st_size)[:1]
    if paths:
        specs += [(p.stem, (lambda p=p: mesh_scene(str(p)))) for p in paths]
    else:
        import tempfile
        import trimesh
        tmp = Path(tempfile.mkdtemp(prefix="hwrt-gen-"))
        for name, fn in list(GENERATED.items())[:1 if quick else None]:
            tris = fn()
            f = tmp / f"{name}.ply"
            trimesh.Trimesh(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3),
                            process=False).export(f)
            specs.append((name, (lambda f=f: mesh_scene(str(f)))))
    return specs


def _setting(d, width, height, spp, depth):
    d = dict(d)
    d["film"] = dict(d.get("film", {}), width=width, height=height, spp=spp)
    d["integrator"] = dict(d.get("integrator", {"type": "whitted"}), max_depth=depth)
    return d


def _median(xs):
    return statistics.median(xs), [min(xs), max(xs)]


def _write_outputs(out_dir, name, rows, md, plot_files, extra):
    buf = io.StringIO()
    flat = [{k: (json_text(v) if isinstance(v, (dict, list)) else v) for k, v in r.items()} for r in rows]
    keys = sorted({k for r in flat for k in r})
    w = csv.DictWriter(buf, fieldnames=keys)
    w.writeheader()
    w.writerows(flat)
    result = {"rows": rows, "machine": machine()}
    result.update(extra)
    files = [(os.path.join(out_dir, f"{name}.csv"), buf.getvalue()),
             (os.path.join(out_dir, f"{name}.json"), json_text(result, indent=1) + "\n"),
             (os.path.join(out_dir, f"{name}.md"), md)] + plot_files
    write_files(files)
    result["files"] = [f for f, _ in files]
    return result


# --------------------------------------------------------------------------------------
# time to image
# --------------------------------------------------------------------------------------
def bench_tti(args):
    from tqdm import tqdm
    from raytracer.render import make_tracer, render, warm_up
    from scenes import compile_scene
    from traversal.tracers import VerifyingTracer

    quick = args.quick
    W, H = args.width, args.height
    spp, depth = args.spp, args.max_depth
    repeat = args.repeat
    out_dir = args.out_dir
    cells = Cells(os.path.join(out_dir, "tti.jsonl"), fresh=args.fresh)
    for b, t in (("hwbvh", "numba"), ("sweep", "numba"), ("embree", "embree")):
        warm_up(b, t, parallel_build=True)
    specs = _scene_specs(args, quick)
    bar = tqdm(total=len(specs) * 3, desc="bench tti", file=sys.stderr, unit="cell")
    for name, load in specs:
        scene = compile_scene(_setting(load(), W, H, spp, depth))
        for builder, traversal in (("hwbvh", "numba"), ("sweep", "numba"), ("embree", "embree")):
            key = json.dumps([name, builder, W, H, spp, depth, repeat])
            if cells.get(key):
                bar.update(1)
                continue
            builds, renders = [], []
            for _ in range(repeat):
                tracer, b, info = make_tracer(scene, builder, traversal)
                t0 = time.perf_counter()
                res = render(scene, tracer)
                renders.append(time.perf_counter() - t0)
                builds.append(b)
            clean = None
            if traversal == "numba":        # --verify at a small size: every ray vs Embree
                small = compile_scene(_setting(load(), 64, 48, 1, depth))
                tr, _, _ = make_tracer(small, builder, traversal)
                checked = VerifyingTracer(tr, small.triangles, small.vertices, small.faces)
                render(small, checked)
                clean = checked.summary()["mismatch"] == 0
            b_med, b_spread = _median(builds)
            r_med, r_spread = _median(renders)
            cells.add({"key": key, "scene": name, "builder": builder, "traversal": traversal,
                       "triangles": int(len(scene.triangles)), "build_seconds": b_med,
                       "build_spread": b_spread, "render_seconds": r_med, "render_spread": r_spread,
                       "rays": int(sum(res.stats["rays"].values())), "ray_kinds": res.stats["rays"],
                       "sah_cost": info.get("sah_cost"), "verify_clean": clean,
                       "simulated_build_seconds": info.get("simulated_build_seconds")})
            bar.update(1)
    bar.close()
    rows, summary = _tti_rows(cells, specs, W, H, spp, depth, repeat)
    md = _tti_markdown(rows, summary, W, H, spp, depth)
    plots = _tti_plot(rows, out_dir)
    return _write_outputs(out_dir, "tti", rows, md, plots,
                          {"setting": {"width": W, "height": H, "spp": spp, "max_depth": depth,
                                       "repeat": repeat}, "break_even": summary})


def _tti_rows(cells, specs, W, H, spp, depth, repeat):
    rows, summary = [], []
    for name, _ in specs:
        got = {b: cells.get(json.dumps([name, b, W, H, spp, depth, repeat])) for b in ("hwbvh", "sweep", "embree")}
        if not all(got.values()):
            continue
        hw = got["hwbvh"]
        sim = hw["simulated_build_seconds"] or {}
        for path, build, src in (("hwbvh-C", sim.get("HWBVH-C"), hw), ("hwbvh-HP", sim.get("HWBVH-HP"), hw),
                                 ("hwbvh-sw", hw["build_seconds"], hw), ("sweep", got["sweep"]["build_seconds"], got["sweep"]),
                                 ("embree", got["embree"]["build_seconds"], got["embree"])):
            rows.append({"scene": name, "path": path, "triangles": src["triangles"],
                         "build_seconds": build, "render_seconds": src["render_seconds"],
                         "total_seconds": (build or 0) + src["render_seconds"],
                         "render_spread": src["render_spread"], "rays": src["rays"],
                         "sah_cost": src["sah_cost"], "verify_clean": src["verify_clean"],
                         "traversal": src["traversal"]})
        # at what ray budget does the hardware's build pay for itself against Embree's build?
        e = got["embree"]
        c_hw = hw["render_seconds"] / max(hw["rays"], 1)
        c_e = e["render_seconds"] / max(e["rays"], 1)
        for preset in ("HWBVH-C", "HWBVH-HP"):
            if preset not in sim:
                continue
            saved = e["build_seconds"] - sim[preset]
            if saved <= 0:
                be = 0.0
            elif c_hw <= c_e:
                be = float("inf")
            else:
                be = saved / (c_hw - c_e)
            summary.append({"scene": name, "preset": preset, "build_saved_seconds": saved,
                            "seconds_per_ray_ours": c_hw, "seconds_per_ray_embree": c_e,
                            "break_even_rays": be,
                            "break_even_rays_same_traversal": float("inf") if saved > 0 else 0.0})
    return rows, summary


def _tti_markdown(rows, summary, W, H, spp, depth):
    lines = [f"Time to image (build + render), Whitted {W}x{H}, {spp} spp, depth {depth}.\n",
             "Medians of the repeated runs; the render spread is min-max over them.\n",
             "| scene | path | build s | render s (spread) | total s | rays | SAH | verify |",
             "|---|---|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        sah = f"{r['sah_cost']:.1f}" if r["sah_cost"] else "-"
        ver = {True: "clean", False: "MISMATCH", None: "n/a"}[r["verify_clean"]]
        lo, hi = r["render_spread"]
        lines.append(f"| {r['scene']} | {r['path']} | {r['build_seconds']:.4f} | {r['render_seconds']:.3f} "
                     f"({lo:.3f}-{hi:.3f}) | {r['total_seconds']:.3f} | {r['rays']} | {sah} | {ver} |")
    lines += ["", "Break-even ray budget: the hardware build saves `build_saved` seconds against Embree's "
              "build; with our slower traversal it stays ahead up to `break_even_rays` rays.", "",
              "| scene | preset | build saved s | break-even rays |", "|---|---|---:|---:|"]
    for s in summary:
        be = "never behind" if s["break_even_rays"] == float("inf") else f"{s['break_even_rays']:.3g}"
        lines.append(f"| {s['scene']} | {s['preset']} | {s['build_saved_seconds']:.4f} | {be} |")
    return "\n".join(lines) + "\n"


def _tti_plot(rows, out_dir):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    if not scenes:
        return []
    fig, ax = plt.subplots(figsize=(max(8, len(scenes) * 1.2), 5))
    width = 0.16
    x = np.arange(len(scenes))
    for k, path in enumerate(TTI_PATHS):
        b = [next((r["build_seconds"] for r in rows if r["scene"] == s and r["path"] == path), 0) or 0 for s in scenes]
        rd = [next((r["render_seconds"] for r in rows if r["scene"] == s and r["path"] == path), 0) for s in scenes]
        pos = x + (k - 2) * width
        ax.bar(pos, b, width, color=f"C{k}", alpha=0.45)
        ax.bar(pos, rd, width, bottom=b, color=f"C{k}", label=path)
    ax.set_xticks(x, scenes, rotation=45, ha="right")
    ax.set_ylabel("seconds (light: build, dark: render)")
    ax.set_title("Time to image = build + render")
    ax.legend(fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return [(os.path.join(out_dir, "tti.png"), buf.getvalue())]


# --------------------------------------------------------------------------------------
# accuracy
# --------------------------------------------------------------------------------------
KNOBS = {
    "bins": [2, 4, 8, 16, 32, 64],
    "leaf_size": [1, 2, 4, 8, 16, 32, 64],
    "builder": ["hwbvh", "sweep"],
    "precision": ["float32", "float64"],
    "triangle_test": ["moller-trumbore", "watertight"],
    "offset": ["relative", "fixed", "none"],
    # the same scene scaled: a fixed epsilon breaks, the relative offset does not
    "offset_at_scale": ["relative@0.001", "fixed@0.001", "relative@1000", "fixed@1000"],
    "max_depth": [1, 2, 3, 5, 8],
    "spp": [1, 2, 4, 8],
}
BASE = {"bins": 16, "leaf_size": 4, "builder": "hwbvh", "precision": "float32",
        "triangle_test": "moller-trumbore",
        "offset": "relative", "max_depth": 5, "spp": 1}


def _holes(setting):
    """Rays from inside a closed sphere at every vertex and edge midpoint: how many escape."""
    import hwbvh
    from scenes.meshes import uv_sphere
    from traversal import Tracer
    V, F = uv_sphere(24, 40)
    tris = V[F].astype(np.float32)
    bvh = hwbvh.build(tris, builder=setting["builder"], leaf_size=setting["leaf_size"],
                      bins=setting["bins"])
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]).astype(np.float64)
    targets = np.concatenate([V, e.mean(1)])
    h = Tracer(bvh, precision=setting["precision"],
               watertight=setting["triangle_test"] == "watertight").intersect(np.zeros_like(targets), targets)
    return int((h.prim < 0).sum()), int(len(targets))


def bench_accuracy(args):
    from tqdm import tqdm
    from raytracer.render import make_tracer, render, warm_up
    from scenes import compile_scene, transform_scene
    from traversal.verify import classify
    from traversal.embree_ref import embree_intersect, embree_scene
    from traversal.tracers import CountingTracer
    from traversal import raysets

    quick = args.quick
    W, H = args.width, args.height
    repeat = args.repeat
    cells = Cells(os.path.join(args.out_dir, "accuracy.jsonl"), fresh=args.fresh)
    warm_up("hwbvh", "numba", parallel_build=True)
    warm_up("sweep", "numba")
    specs = _scene_specs(args, quick)[:1 if quick else 3]
    work = [(name, load, knob, val) for name, load in specs for knob, vals in KNOBS.items() for val in vals]
    refs = {}
    bar = tqdm(total=len(work), desc="bench accuracy", file=sys.stderr, unit="cell")
    for name, load, knob, val in work:
        setting = dict(BASE, **({knob: val} if knob != "offset_at_scale" else {}))
        scale = 1.0
        if knob == "offset_at_scale":
            strategy, scale = val.split("@")
            setting["offset"], scale = strategy, float(scale)
        key = json.dumps([name, knob, val, W, H, repeat])
        if cells.get(key):
            bar.update(1)
            continue
        ref_spp = 16 if knob == "spp" else setting["spp"]
        if (name, ref_spp) not in refs:      # high-accuracy reference: sweep, float64, depth 8
            rs = compile_scene(_setting(load(), W, H, ref_spp, 8))
            tr, _, _ = make_tracer(rs, "sweep", "numba", precision="float64")
            refs[(name, ref_spp)] = render(rs, tr, seed=0).image
        scene = compile_scene(_setting(transform_scene(load(), scale) if scale != 1.0 else load(),
                                       W, H, setting["spp"], setting["max_depth"]))
        builds, renders = [], []
        for _ in range(repeat):
            tracer, b, info = make_tracer(scene, setting["builder"], "numba", setting["leaf_size"],
                                          setting["bins"], setting["precision"],
                                          setting["triangle_test"] == "watertight")
            t0 = time.perf_counter()
            res = render(scene, tracer, seed=0, offset=setting["offset"])
            renders.append(time.perf_counter() - t0)
            builds.append(b)
        counting = CountingTracer(tracer)          # work per ray, outside the timed renders
        render(scene, counting, seed=0, offset=setting["offset"])
        per_ray = counting.work()
        err = res.image - refs[(name, ref_spp)]
        # disagreement with Embree on random rays through this tree and these units
        O, D = raysets.incoherent(scene.triangles, 20_000 if quick else 100_000)
        h = tracer.intersect(O, D)
        te, pe, *_ = embree_intersect(embree_scene(scene.vertices, scene.faces), O, D)
        counts, _ = classify(scene.triangles, O, D, 0.0, np.inf, h.prim.astype(np.int64), h.t, pe, te)
        holes, probes = _holes(setting)
        b_med, b_spread = _median(builds)
        r_med, r_spread = _median(renders)
        cells.add({"key": key, "scene": name, "knob": knob, "value": val, "build_seconds": b_med,
                   "render_seconds": r_med, "total_seconds": b_med + r_med,
                   "render_spread": r_spread, "sah_cost": info.get("sah_cost"),
                   "nodes_per_ray": per_ray["nodes_per_ray"], "tris_per_ray": per_ray["tris_per_ray"],
                   "mismatch_rate": counts["mismatch"] / counts["rays"],
                   "tie_rate": counts["tie"] / counts["rays"], "holes": holes, "hole_probes": probes,
                   "rmse": float(np.sqrt(np.mean(err ** 2))), "max_error": float(np.abs(err).max())})
        bar.update(1)
    bar.close()
    rows = [cells.get(json.dumps([n, k, v, W, H, repeat])) for n, _, k, v in work]
    rows = [r for r in rows if r]
    md = _accuracy_markdown(rows)
    plots = _accuracy_plots(rows, args.out_dir)
    return _write_outputs(args.out_dir, "accuracy", rows, md, plots,
                          {"setting": {"width": W, "height": H, "repeat": repeat, "base": BASE}})


def _accuracy_markdown(rows):
    lines = ["Medians of the repeated runs; the render spread is min-max over them.\n",
             "| scene | knob | value | build s | render s (spread) | SAH | nodes/ray | tris/ray | mismatch | tie | holes | RMSE | max err |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        f = lambda v, p=3: "-" if v is None else f"{v:.{p}f}"
        lo, hi = r["render_spread"]
        lines.append(f"| {r['scene']} | {r['knob']} | {r['value']} | {f(r['build_seconds'], 4)} | "
                     f"{f(r['render_seconds'])} ({lo:.3f}-{hi:.3f}) | {f(r['sah_cost'], 1)} | {f(r['nodes_per_ray'], 1)} | "
                     f"{f(r['tris_per_ray'], 1)} | {r['mismatch_rate']:.2e} | {r['tie_rate']:.2e} | "
                     f"{r['holes']}/{r['hole_probes']} | {r['rmse']:.4f} | {r['max_error']:.3f} |")
    return "\n".join(lines) + "\n"


def _pareto(points):
    """Indices of points not dominated in (time, error), both lower-better."""
    keep = []
    for i, (t, e) in enumerate(points):
        if not any((t2 <= t and e2 <= e) and (t2 < t or e2 < e) for j, (t2, e2) in enumerate(points) if j != i):
            keep.append(i)
    return keep


def _accuracy_plots(rows, out_dir):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    knobs = list(dict.fromkeys(r["knob"] for r in rows))
    if not knobs:
        return []
    fig, axes = plt.subplots(2, (len(knobs) + 1) // 2, figsize=(4 * ((len(knobs) + 1) // 2), 7), squeeze=False)
    for ax, knob in zip(axes.ravel(), knobs):
        sub = [r for r in rows if r["knob"] == knob]
        for k, scene in enumerate(dict.fromkeys(r["scene"] for r in sub)):
            pts = [(r["total_seconds"], r["rmse"], r["value"]) for r in sub if r["scene"] == scene]
            xs, ys, labels = zip(*pts)
            ax.scatter(xs, ys, color=f"C{k}", label=scene)
            for x, y, lab in pts:
                ax.annotate(str(lab), (x, y), fontsize=7)
            front = sorted(_pareto([(x, y) for x, y, _ in pts]), key=lambda i: xs[i])
            ax.plot([xs[i] for i in front], [ys[i] for i in front], color=f"C{k}", lw=1)
        ax.set_title(knob)
        ax.set_xlabel("build + render s")
        ax.set_ylabel("image RMSE vs reference")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    for ax in axes.ravel()[len(knobs):]:
        ax.axis("off")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return [(os.path.join(out_dir, "accuracy.png"), buf.getvalue())]
