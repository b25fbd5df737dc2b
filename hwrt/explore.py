"""Design-space exploration: every configuration of a grid on every mesh, with its build time,
energy and area, the Pareto fronts of time and energy against area, and thesis-style plots.

A cell is one (configuration, mesh): the cycle model's simulation of that build, with the area
and power of that configuration (``hwbvh.resources``). Cells are resumable: each finished cell
is appended to ``OUT/explore.jsonl`` and a rerun skips it (``fresh`` starts over); the key holds
the mesh's content hash and a hash of the model's source, so a changed mesh or model is
recomputed. Cells run in batches on Dask (``hwrt.cluster``). A batch holds configurations that
share one tree: the tree depends only on the mesh, the bins and the leaf size, never on w,
Tsize, Psize, the builder count, the RAM pairs or the clock, so a worker builds it once and
keeps the last few.

Fronts are computed per tree setting (bins, leaf size): a larger leaf builds faster on less
hardware but traces slower, which time and area alone do not show. "Overall" is the geometric
mean over the meshes.
"""
import csv
import hashlib
import io
import itertools
import json
import math
import os
import re
import time
import uuid
from collections import OrderedDict
from dataclasses import replace
from pathlib import Path

from hwbvh.files import content_digest, figure_png, write_files
from hwbvh import config
from hwbvh.cycle_model import PRESETS, check_params
from hwbvh.errors import InputError, ParameterError
from .config import BATCH_CONFIGS, DEFAULT_GRID, MAX_CONFIGURATIONS, TREE_CACHE
from .report import with_figures

KNOBS = ("bins", "leaf_size", "w", "tsize", "psize", "subtree_builders", "ram_pairs", "clock_mhz")
TREE_KNOBS = ("bins", "leaf_size")
BASE = PRESETS["HWBVH-C"]          # the value of every knob the grid leaves unset
_INTEGER = re.compile(r"[+-]?[0-9]+")
_DECIMAL = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?")
SIZE_CLASSES = ((50_000, "small (< 50k triangles)"), (150_000, "medium (50k-150k)"),
                (math.inf, "large (> 150k)"))
CELLS_NAME = "explore.jsonl"
# The fields of a row (``simulate_batch``): numbers (or null), then the others; a saved row with
# other fields, or another value in a number's place, is computed again (``study.RowSchema``).
ROW_NUMBERS = ("triangles", "cycles", "seconds", "energy_joules", "area_mm2", "active_power_w",
               "traffic_total_bytes", "footprint_bytes", "sah_cost", "handoffs")
ROW_OTHERS = ("mesh", "config", "traffic_bytes", "utilisation", "upper_builder_used")
OUTPUT_NAMES = ("explore.csv", "explore.json", "explore.md", "pareto_time_area.png",
                "pareto_energy_area.png")


# --------------------------------------------------------------------------------------
# the grid
# --------------------------------------------------------------------------------------
def parse_grid(specs):
    """``["w=2,4,8", "clock_mhz=250,500"]`` -> ``{"w": [2, 4, 8], ...}``. Raises ParameterError
    naming ``grid`` (a malformed item) or the knob (a bad value)."""
    grid = {}
    for spec in specs:
        name, sep, values = str(spec).partition("=")
        name = name.strip().replace("-", "_")
        if not sep or not name:
            raise ParameterError("grid", f"{spec!r} is not KNOB=V1,V2,... (knobs: {', '.join(KNOBS)})")
        if name not in KNOBS:
            raise ParameterError("grid", f"unknown knob {name!r} (knobs: {', '.join(KNOBS)})")
        if name in grid:
            raise ParameterError(name, "given twice; list all its values once")
        items = [v.strip() for v in values.split(",")]
        if not values.strip() or any(not v for v in items):
            raise ParameterError(name, f"empty value in {spec!r}")
        parsed = []
        for v in items:
            # written out in digits, as the command's integer options take them: Python's
            # int() and float() would also read "4_0" as 40 and "inf" as a clock
            clock = name == "clock_mhz"
            if not (_DECIMAL if clock else _INTEGER).fullmatch(v):
                kind = "a number" if clock else "an integer"
                raise ParameterError(name, f"{v!r} is not {kind}")
            x = float(v) if clock else int(v)
            if clock and not math.isfinite(x):
                raise ParameterError(name, f"{v!r} is not a finite clock")
            if x in parsed:
                raise ParameterError(name, f"value {v} listed twice")
            parsed.append(x)
        grid[name] = parsed
    count = math.prod(len(v) for v in grid.values())
    if count > MAX_CONFIGURATIONS:
        raise ParameterError("grid", f"{count:,} configurations, more than the "
                                     f"{MAX_CONFIGURATIONS:,} one exploration takes: give "
                                     f"fewer values, or explore the grid in parts")
    return grid


def config_of(p):
    return {k: getattr(p, k) for k in KNOBS}


def configurations(grid):
    """Every combination of the grid (unset knobs at HWBVH-C's value), each checked against the
    hardware's ranges, then the two presets if the grid does not hold them. Returns
    ``[(params, preset name or None)]``."""
    axes = [grid.get(k, [getattr(BASE, k)]) for k in KNOBS]
    out, seen = [], set()
    for values in itertools.product(*axes):
        p = check_params(replace(BASE, **dict(zip(KNOBS, values))))
        seen.add(tuple(config_of(p).values()))
        out.append(p)
    presets = {tuple(config_of(p).values()): name for name, p in PRESETS.items()}
    for key, name in presets.items():
        if key not in seen:
            out.append(PRESETS[name])
    return [(p, presets.get(tuple(config_of(p).values()))) for p in out]


def label(cfg, varied=KNOBS):
    """Short name of a configuration: the knobs that vary in this exploration."""
    short = {"bins": "bins", "leaf_size": "leaf", "w": "w", "tsize": "T", "psize": "P",
             "subtree_builders": "SB", "ram_pairs": "RP", "clock_mhz": "MHz"}
    parts = []
    for k in KNOBS:
        if k in varied:
            v = cfg[k]
            v = int(v) if float(v).is_integer() else v
            parts.append(f"{v}{short[k]}" if k == "clock_mhz" else f"{short[k]}{v}")
    return " ".join(parts)


def labeller(result):
    """``label`` for the configurations of an exploration's result: the knobs its
    configurations vary, and a preset's name before a preset's knobs ("HWBVH-HP: w8 ...")."""
    varied = [k for k in KNOBS if len({c[k] for c in result["configs"]}) > 1] or list(KNOBS)
    names = {tuple(c[k] for k in KNOBS): c["preset"] for c in result["configs"] if c.get("preset")}

    def lab(cfg):
        name = names.get(tuple(cfg[k] for k in KNOBS))
        return f"{name}: {label(cfg, varied)}" if name else label(cfg, varied)
    return lab


# --------------------------------------------------------------------------------------
# meshes and the model's identity
# --------------------------------------------------------------------------------------
def mesh_specs(paths):
    """``[{"name", "path", "digest", "triangles"}]`` for the mesh files, each loaded once here
    so a bad file fails before any cell runs. Named as the benchmarks name them
    (``bench.mesh_names``: the stem, or the path where stems are shared)."""
    from hwbvh.primitives import as_triangles, load_mesh_arrays
    from .bench import mesh_names

    if not paths:
        raise ParameterError("meshes", "no mesh given")
    paths = [os.fspath(p) for p in paths]
    specs, by_digest = [], {}
    for name, path in zip(mesh_names(paths), paths):
        verts, faces = load_mesh_arrays(path)
        tris = as_triangles(verts[faces], source=path)
        digest = content_digest(path)
        if digest in by_digest:                 # cells are keyed by contents: one set of rows
            raise InputError(path, f"has the same contents as {by_digest[digest]}: give one "
                                   f"of them")
        by_digest[digest] = path
        specs.append({"name": name, "path": os.path.abspath(path), "digest": digest,
                      "triangles": int(len(tris))})
    return specs


def model_fingerprint():
    """Hash of the hwbvh package's source: a changed model or builder invalidates saved cells."""
    h = hashlib.sha256()
    for f in sorted(Path(config.__file__).parent.glob("*.py")):
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def cell_key(mesh, cfg, fingerprint):
    return json.dumps([mesh["digest"], [cfg[k] for k in KNOBS], fingerprint])


# --------------------------------------------------------------------------------------
# worker side
# --------------------------------------------------------------------------------------
_TREES = OrderedDict()


def _tree(mesh, bins, leaf_size):
    """(tree, SAH cost) of ``mesh`` built with ``bins`` and ``leaf_size``; the last
    ``TREE_CACHE`` trees stay in this process."""
    from hwbvh.builder import build_canonical
    from hwbvh.format import tree_stats
    from hwbvh.layout import lay_out
    from hwbvh.primitives import as_triangles, load_mesh_arrays, primitive_boxes

    key = (mesh["digest"], bins, leaf_size)
    if key in _TREES:
        _TREES.move_to_end(key)
        return _TREES[key]
    if content_digest(mesh["path"]) != mesh["digest"]:
        raise InputError(mesh["path"], "is not the file the exploration was planned on (it changed, "
                                       "or a worker sees another file at this path)")
    verts, faces = load_mesh_arrays(mesh["path"])
    tree = build_canonical(primitive_boxes(as_triangles(verts[faces], source=mesh["path"])),
                           leaf_size=leaf_size, bins=bins)
    nodes, _, _ = lay_out(tree, config.DEFAULT_CAPACITY, 1)
    _TREES[key] = (tree, float(tree_stats(nodes)["sah_cost"]))
    while len(_TREES) > TREE_CACHE:
        _TREES.popitem(last=False)
    return _TREES[key]


def simulate_batch(mesh, configs):
    """Rows of ``configs`` (config dicts sharing bins and leaf size) on ``mesh``."""
    from hwbvh.cycle_model import simulate

    tree, sah = _tree(mesh, configs[0]["bins"], configs[0]["leaf_size"])
    rows = []
    for cfg in configs:
        r = simulate(tree, replace(BASE, **cfg))
        rows.append({"mesh": mesh["name"], "triangles": mesh["triangles"], "config": dict(cfg),
                     "cycles": r["cycles"], "seconds": r["seconds"],
                     "energy_joules": r["energy_joules"], "area_mm2": r["area_mm2"],
                     "active_power_w": r["active_power_w"], "traffic_bytes": r["traffic_bytes"],
                     "traffic_total_bytes": r["traffic_total_bytes"],
                     "footprint_bytes": r["footprint_bytes"], "sah_cost": sah,
                     "utilisation": r["utilisation"],
                     "upper_builder_used": r["upper_builder"]["used"],
                     "handoffs": r["subtree_builders"]["handoffs"]})
    return rows


def warm_up():
    """Load (or compile) every kernel a cell calls, once per worker process: a sequential and a
    parallel build, the layout, the statistics and the simulation."""
    from hwbvh.builder import build_canonical
    from hwbvh.cycle_model import simulate
    from hwbvh.format import tree_stats
    from hwbvh.layout import lay_out
    from hwbvh.primitives import primitive_boxes
    from scenes.meshes import random_soup

    for n in (2000, config.SEQUENTIAL_MAX_PRIMS + 2000):
        tree = build_canonical(primitive_boxes(random_soup(n, seed=1)))
        tree_stats(lay_out(tree, config.DEFAULT_CAPACITY, 1)[0])
        simulate(tree, replace(BASE, psize=512))


# --------------------------------------------------------------------------------------
# fronts and summaries
# --------------------------------------------------------------------------------------
def pareto_front(points):
    """Indices of the points ``(x, y)`` no other point beats in both (lower is better), in
    increasing x. Equal points are all kept."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1], i))
    front, best, last = [], math.inf, None
    for i in order:
        x, y = points[i]
        if y < best:
            front.append(i)
            best, last = y, (x, y)
        elif (x, y) == last:
            front.append(i)
    return front


def gaps(point, front_points):
    """How far ``point`` (area, y) is from a front: ``y_ratio`` = its y over the best y of any
    front point with no more area; ``area_ratio`` = its area over the least area of any front
    point with no more y. 1.0 = on the front."""
    a, y = point
    ys = [fy for fa, fy in front_points if fa <= a]
    areas = [fa for fa, fy in front_points if fy <= y]
    return {"y_ratio": y / min(ys) if ys else None, "area_ratio": a / min(areas) if areas else None}


def _geomean(xs):
    return math.exp(sum(math.log(x) for x in xs) / len(xs))


def summarise(rows, meshes, configs):
    """Pareto fronts, best configurations per mesh and per size class, and the presets' distance
    from the fronts, per tree setting."""
    cfg_ids = {tuple(c.values()): i for i, (c, _) in enumerate(configs)}
    presets = {name: cfg for cfg, name in configs if name}
    by = {(r["mesh"], cfg_ids[tuple(r["config"].values())]): r for r in rows}
    groups = sorted({tuple(c[k] for k in TREE_KNOBS) for c, _ in configs})
    pareto, best, preset_gaps = [], [], []
    for tree_key in groups:
        ids = [i for i, (c, _) in enumerate(configs) if tuple(c[k] for k in TREE_KNOBS) == tree_key]
        setting = dict(zip(TREE_KNOBS, tree_key))
        scopes = [(m["name"], {i: by[(m["name"], i)] for i in ids}) for m in meshes]
        overall = {}
        for i in ids:
            rs = [by[(m["name"], i)] for m in meshes]
            overall[i] = {"seconds": _geomean([r["seconds"] for r in rs]),
                          "energy_joules": _geomean([r["energy_joules"] for r in rs]),
                          "area_mm2": rs[0]["area_mm2"]}
        scopes.append(("overall", overall))
        fronts = {}
        for metric in ("seconds", "energy_joules"):
            name = "time_area" if metric == "seconds" else "energy_area"
            fronts[name] = {}
            for scope, vals in scopes:
                pts = [(vals[i]["area_mm2"], vals[i][metric]) for i in ids]
                fr = [ids[j] for j in pareto_front(pts)]
                fronts[name][scope] = [{"config": configs[i][0], "area_mm2": vals[i]["area_mm2"],
                                        metric: vals[i][metric]} for i in fr]
                for pname, pcfg in presets.items():
                    i = cfg_ids[tuple(pcfg.values())]
                    if i in vals:
                        g = gaps((vals[i]["area_mm2"], vals[i][metric]),
                                 [(vals[j]["area_mm2"], vals[j][metric]) for j in fr])
                        preset_gaps.append(dict(setting, preset=pname, front=name, scope=scope,
                                                on_front=i in fr, **{
                                                    ("time_ratio" if metric == "seconds" else "energy_ratio"):
                                                        g["y_ratio"], "area_ratio": g["area_ratio"]}))
        pareto.append(dict(setting, **fronts))
        # the best configuration per mesh and per size class
        tri = {m["name"]: m["triangles"] for m in meshes}
        scopes_best = [(n, [n]) for n in tri]
        lo = 0
        for hi, lab in SIZE_CLASSES:
            names = [n for n in tri if lo <= tri[n] < hi]
            if names:
                scopes_best.append((lab, names))
            lo = hi
        for scope, names in scopes_best:
            t = {i: _geomean([by[(n, i)]["seconds"] for n in names]) for i in ids}
            ea = {i: _geomean([by[(n, i)]["energy_joules"] * by[(n, i)]["area_mm2"] for n in names])
                  for i in ids}
            bt = min(ids, key=lambda i: (t[i], by[(names[0], i)]["area_mm2"], i))
            be = min(ids, key=lambda i: (ea[i], i))
            best.append(dict(setting, scope=scope, meshes=names,
                             triangles=[tri[n] for n in names],
                             fastest={"config": configs[bt][0], "seconds": t[bt],
                                      "area_mm2": by[(names[0], bt)]["area_mm2"]},
                             energy_area={"config": configs[be][0], "energy_area_mm2_j": ea[be],
                                          "area_mm2": by[(names[0], be)]["area_mm2"]}))
    return {"pareto": pareto, "best": best, "preset_gaps": preset_gaps}


# --------------------------------------------------------------------------------------
# files
# --------------------------------------------------------------------------------------


def _csv(rows):
    flat = []
    for r in rows:
        f = {k: v for k, v in r.items() if k not in ("config", "traffic_bytes", "utilisation", "key")}
        f.update(r["config"])
        f.update({f"traffic_{k}_bytes": v for k, v in r["traffic_bytes"].items()})
        f.update({f"utilisation_{k}": v for k, v in r["utilisation"].items()})
        flat.append(f)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(flat[0]))
    w.writeheader()
    w.writerows(flat)
    return buf.getvalue()


def plots(rows, summary, meshes, configs, grid):
    """Pareto plots (time and energy against area: every configuration in grey, the fronts in
    colour, the presets marked). The thesis' Figs. 4.2-4.3 study the subtree builder alone
    at a fixed capacity (``hwrt bench model`` draws them); this grid's builds are whole scenes."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    by_cfg = {}
    for r in rows:
        by_cfg.setdefault(tuple(r["config"].values()), {})[r["mesh"]] = r
    scopes = ["overall"] + [m["name"] for m in meshes]
    cols = min(4, len(scopes))
    nrows = -(-len(scopes) // cols)
    files = []
    for metric, name, ylabel in (("seconds", "pareto_time_area.png", "build time (s)"),
                                 ("energy_joules", "pareto_energy_area.png", "energy per build (J)")):
        front_key = "time_area" if metric == "seconds" else "energy_area"
        fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.4 * nrows), squeeze=False)
        for ax, scope in zip(axes.ravel(), scopes):
            grey, marked = [], {}
            for cfg, pname in configs:
                rs = by_cfg[tuple(cfg.values())]
                y = (_geomean([rs[m["name"]][metric] for m in meshes]) if scope == "overall"
                     else rs[scope][metric])
                point = (next(iter(rs.values()))["area_mm2"], y)
                if pname:
                    marked[pname] = point
                grey.append(point)
            ax.scatter(*zip(*grey), s=3, color="0.7", zorder=1, label="configurations")
            for k, group in enumerate(summary["pareto"]):
                fr = group[front_key][scope]
                ax.plot([p["area_mm2"] for p in fr], [p[metric] for p in fr], "-o", ms=3, lw=1.2,
                        color=f"C{k}", zorder=3, label=f"front: leaf {group['leaf_size']}, {group['bins']} bins")
            for pname, marker, colour in (("HWBVH-C", "*", "gold"), ("HWBVH-HP", "^", "tomato")):
                if pname in marked:
                    ax.plot(*[[v] for v in marked[pname]], marker, ms=11, color="k", mfc=colour,
                            zorder=5, label=pname)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_title("geometric mean over meshes" if scope == "overall" else scope, fontsize=9)
            ax.set_xlabel("area (mm$^2$, 90 nm)", fontsize=8)
            ax.set_ylabel(ylabel, fontsize=8)
            ax.grid(alpha=0.3, which="both")
        for ax in axes.ravel()[len(scopes):]:
            ax.axis("off")
        axes.ravel()[0].legend(fontsize=6, loc="upper right")
        files.append((name, figure_png(fig)))
    return files


def _count(n, one, many):
    return f"{n} {one if n == 1 else many}"


def markdown(result, command=None):
    """A summary page: the run, the cost model, the best configurations and the presets' gaps."""
    from .report import made_by_lines
    lab = labeller(result)
    f = result["cost_model"]
    lines = ["# Design-space exploration\n"] + made_by_lines(command) + [
             f"{result['cells']} cells: {len(result['configs'])} configurations x "
             f"{_count(len(result['meshes']), 'mesh', 'meshes')}; {result['computed']} computed" + (
                 f" in {result['compute_seconds']:.1f} s ({result['cells_per_second']:.0f} cells/s) on "
                 f"{result['cluster']}, {result['resumed']} resumed.\n" if result["computed"]
                 else f", {result['resumed']} resumed.\n"),
             "Grid: " + ", ".join(f"{k} = {'/'.join(str(v) for v in vals)}"
                                  for k, vals in result["grid"].items()) + "; other knobs at HWBVH-C.\n",
             f"Area and active power: {f['gates_per_fp_core']:.0f} gates per floating-point core "
             f"(comparators {config.COMPARATOR_GATES}), {f['gates_per_storage_bit']:.3f} per register "
             f"or SRAM bit, {config.MISC_LOGIC_SHARE:.0%} miscellaneous logic; "
             f"{f['area_mm2_per_gate'] * 1e6:.3f} um^2 per gate and "
             f"{f['active_w_per_gate_hz'] * 1e15:.3f} fW per gate and Hz at "
             f"{config.POWER_REFERENCE_MHZ:.0f} MHz, times (clock / {config.POWER_REFERENCE_MHZ:.0f} "
             f"MHz)^{f['power_clock_exponent']:.3f} (90 nm), fitted on HWBVH-C and HWBVH-HP (area "
             f"within {max(abs(v - 1) for v in f['area_ratio'].values()):.1%} of thesis Table 4.10, "
             f"power as it gives it, which two constants on two presets can match).\n"]
    for group in result["pareto"]:
        tk = {k: group[k] for k in TREE_KNOBS}
        lines += [f"## Leaf size {tk['leaf_size']}, {tk['bins']} bins\n",
                  "| scope | triangles | fastest | s | mm^2 | least energy x area | mJ x mm^2 | mm^2 |",
                  "|---|---:|---|---:|---:|---|---:|---:|"]
        for b in result["best"]:
            if all(b[k] == v for k, v in tk.items()):
                tri = (f"{b['triangles'][0]:,}" if len(b["triangles"]) == 1
                       else f"{len(b['triangles'])} meshes")
                lines.append(f"| {b['scope']} | {tri} | {lab(b['fastest']['config'])} | "
                             f"{b['fastest']['seconds']:.3g} | {b['fastest']['area_mm2']:.1f} | "
                             f"{lab(b['energy_area']['config'])} | {b['energy_area']['energy_area_mm2_j'] * 1e3:.3g} | "
                             f"{b['energy_area']['area_mm2']:.1f} |")
        gap = [g for g in result["preset_gaps"] if all(g[k] == v for k, v in tk.items())
               and g["scope"] == "overall"]
        if gap:
            lines += ["", "Distance of the presets from the overall fronts (1.00 = on the front): "
                          "time or energy against the best front point of no more area, and area "
                          "against the least front area at no more time or energy.\n",
                      "| preset | front | on front | time or energy ratio | area ratio |",
                      "|---|---|---|---:|---:|"]
            for g in gap:
                y = g.get("time_ratio", g.get("energy_ratio"))
                fm = lambda v: "-" if v is None else f"{v:.2f}"
                lines.append(f"| {g['preset']} | {g['front'].replace('_', ' vs ')} | "
                             f"{'yes' if g['on_front'] else 'no'} | {fm(y)} | {fm(g['area_ratio'])} |")
        lines.append("")
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------
# the exploration
# --------------------------------------------------------------------------------------
def explore(meshes, grid=None, out_dir=None, *, scheduler=None, workers=None, use_dask=True,
            fresh=False, progress=True, command=None, commit=write_files):
    """Simulate every configuration of ``grid`` (``{knob: [values]}``, default ``DEFAULT_GRID``;
    unset knobs at HWBVH-C's value) on every mesh file, on Dask (``hwrt.cluster.dask_client``:
    ``scheduler`` or a local cluster of ``workers`` processes) or, with ``use_dask=False``, in
    this process. With ``out_dir``, finished cells are saved as they come (a rerun resumes) and
    the CSV, JSON, summary and plots are written there (the summary names ``command``, the
    command line that made it, when given), in one set through ``commit(files)`` (the command
    line's also marks the run done). Everything is checked before any work."""
    from hwbvh.files import check_output_dir, held_directory

    t0 = time.perf_counter()
    grid = DEFAULT_GRID if grid is None else grid
    if not grid:
        raise ParameterError("grid", "is empty: give at least one KNOB=V1,V2,...")
    configs = [(config_of(p), name) for p, name in configurations(grid)]
    specs = mesh_specs(meshes)
    if out_dir is None:
        return _explored(t0, grid, configs, specs, out_dir, scheduler, workers, use_dask, fresh,
                         progress, command, commit)
    check_output_dir(out_dir, OUTPUT_NAMES + (CELLS_NAME,), inputs=[s["path"] for s in specs])
    # held from before its saved cells are read until its last file is written: a second
    # exploration into it meanwhile would share (or, with fresh, remove) this one's cells
    with held_directory(os.path.realpath(out_dir), "explore"):
        return _explored(t0, grid, configs, specs, out_dir, scheduler, workers, use_dask, fresh,
                         progress, command, commit)


def _explored(t0, grid, configs, specs, out_dir, scheduler, workers, use_dask, fresh, progress,
              command, commit):
    """``explore`` once its arguments are checked (and its output directory held)."""
    from hwbvh.calibration import fit_cost_model
    from hwbvh.files import json_text
    from .cluster import dask_client, describe, run_cells

    fingerprint = model_fingerprint()
    cells = _CellStore(Path(out_dir) / CELLS_NAME, fresh) if out_dir is not None else None
    done, todo = {}, []
    for mesh in specs:
        by_tree = OrderedDict()
        for cfg, _ in configs:
            key = cell_key(mesh, cfg, fingerprint)
            if cells is not None and key in cells.done:
                done[key] = cells.done[key]
            else:
                by_tree.setdefault(tuple(cfg[k] for k in TREE_KNOBS), []).append(cfg)
        for batch in by_tree.values():
            todo += [(mesh, batch[i:i + BATCH_CONFIGS]) for i in range(0, len(batch), BATCH_CONFIGS)]
    run = uuid.uuid4().hex[:8]
    tasks = {f"explore-{run}-{k}": item for k, item in enumerate(todo)}

    def finished(key, rows):
        for r in rows:
            r["key"] = cell_key(tasks[key][0], r["config"], fingerprint)
            done[r["key"]] = r
        if cells is not None:
            cells.add_many(rows)

    cells_run = [(k, simulate_batch, item) for k, item in tasks.items()]
    weight = lambda k: len(tasks[k][1])
    where, compute_s = "no computation (every cell resumed)", 0.0
    if tasks and use_dask:
        with dask_client(scheduler, workers=workers, warm_up=warm_up) as client:
            where = describe(client)
            t_cells = time.perf_counter()
            run_cells(cells_run, finished, client, desc="explore", weight=weight, progress=progress)
            compute_s = time.perf_counter() - t_cells
    elif tasks:
        where = "one process"
        t_cells = time.perf_counter()
        run_cells(cells_run, finished, None, desc="explore", weight=weight, progress=progress)
        compute_s = time.perf_counter() - t_cells
    computed = sum(len(c) for _, c in todo)
    rows = []
    for cfg, _ in configs:
        for m in specs:
            row = dict(done[cell_key(m, cfg, fingerprint)])
            row.pop("key", None)
            rows.append(row)
    summary = summarise(rows, specs, configs)
    result = {"rows": rows, **summary,
              "grid": {k: grid[k] for k in KNOBS if k in grid},
              "configs": [dict(c, preset=name) for c, name in configs],
              "meshes": [{k: m[k] for k in ("name", "triangles", "path")} for m in specs],
              "cells": len(rows), "computed": computed, "resumed": len(rows) - computed,
              "compute_seconds": compute_s,
              "cells_per_second": computed / compute_s if computed else None,
              "cluster": where, "cost_model": fit_cost_model(),
              "control_latency": BASE.control_latency, "files": []}
    result["wall_seconds"] = time.perf_counter() - t0
    if out_dir is not None:
        files = [("explore.csv", _csv(rows)), ("explore.json", json_text(result, indent=0) + "\n"),
                 ("explore.md", markdown(result, command))] + plots(rows, summary, specs, configs, grid)
        files = with_figures([(os.path.join(out_dir, n), d) for n, d in files])
        commit(files)
        # the cells a rerun resumes from are the run's too
        result["files"] = [p for p, _ in files] + [os.path.join(out_dir, CELLS_NAME)]
    return result


def human(result):
    """The command line's summary: where the files went, and the best per size class."""
    lab = labeller(result)
    lines = [f"{result['cells']} cells ({result['computed']} computed, {result['resumed']} resumed)"
             + (f", {result['cells_per_second']:.0f} cells/s on {result['cluster']}"
                if result["computed"] else "")]
    for b in result["best"]:
        if b["scope"] in {m["name"] for m in result["meshes"]}:
            continue
        lines.append(f"leaf {b['leaf_size']}, {b['bins']} bins, {b['scope']}: fastest "
                     f"{lab(b['fastest']['config'])}; least energy x area "
                     f"{lab(b['energy_area']['config'])}")
    if result["files"]:
        lines.append("wrote " + ", ".join(result["files"]))
    return "\n".join(lines)


class _CellStore:
    """Saved cells: read with ``hwrt.study.Cells`` (which also repairs a line cut by an
    interruption); appended a batch at a time (one write, one fsync). Nothing is created or
    removed on disk before the first batch arrives."""

    def __init__(self, path, fresh):
        from .study import Cells, RowSchema
        self.path = Path(path)
        self.truncate = fresh
        self.done = {} if fresh or not self.path.exists() else \
            Cells(self.path, schema=RowSchema(ROW_NUMBERS, ROW_OTHERS)).done

    def add_many(self, rows):
        from hwbvh.files import appending, json_text
        with appending(self.path, self.truncate) as f:
            f.write("".join(json_text(r) + "\n" for r in rows).encode())
        self.truncate = False
        for r in rows:
            self.done[r["key"]] = r
