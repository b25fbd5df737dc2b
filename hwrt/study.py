"""The figures the project exists to show: time to image, and what accuracy costs.

``bench_tti``: time to image (thesis Eq. 4.1: construction + rendering) per scene and
acceleration path. ``bench_accuracy``: what each accuracy knob costs in time and buys in
correctness and image quality.

Both take a mesh directory (default ../shared/meshes when present, else generated meshes),
show a progress bar, print the machine into their results, and resume after an interruption:
every finished cell is appended to ``OUT/<name>.jsonl`` at once, and a rerun skips the cells
already there (``--fresh`` starts over).

Cells run on Dask (``hwrt.cluster``): by default an embedded local cluster of one worker with
every core, else the workers of a scheduler. Either way the cells are timed one at a time, all
on one machine (``cluster.timing_host``), so that no cell shares the machine with another and
every figure compares with the others; the machine in the results is that one. A cell is a
module-level function of picklable arguments (a scene is described, not loaded, so that a
worker loads it itself); ``use_dask=False`` runs the same cells in this process.
"""
import csv
import io
import json
import os
import statistics
import threading
import time
import uuid
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from hwbvh.errors import InputError
from hwbvh.files import appending, content_digest, json_text, write_files
from .config import MISMATCH_RAYS, MISMATCH_RAYS_QUICK, REFERENCE_DEPTH, REFERENCE_SPP_OF_SPP_KNOB
from .report import command_of, made_by_block, with_figures
from .bench import machine, mesh_inputs, round_order, traceable

TTI_PATHS = ("hwbvh-C", "hwbvh-HP", "hwbvh-sw", "sweep", "embree")
TTI_TREES = (("hwbvh", "numba"), ("sweep", "numba"), ("embree", "embree"))   # (builder, traversal)


def tti_structures(chosen=None):
    """The acceleration structures other than the BVH that time to image times, each a path
    of its own named after it: ``chosen`` (names from ``raytracer.render.ACCELS``), default
    every one. Their cells are keyed by the structure's name where a BVH cell has its builder."""
    from raytracer.render import ACCELS
    return tuple(a for a in (chosen or ACCELS) if a != "bvh")


def output_names(name):
    """The files a study called ``name`` writes in its output directory."""
    return [f"{name}{ext}" for ext in (".jsonl", ".csv", ".json", ".md", ".png")]


def _not_ours(token):
    raise ValueError(f"{token} is not a number our cells hold")


class RowSchema:
    """The fields of a saved cell, so that a row edited or left by another version runs again
    instead of reaching the tables: ``numbers`` hold a number or null, ``others`` any value;
    every one of them is present, besides ``key``, and at most the ``optional`` numbers and
    ``optional_others`` too."""

    def __init__(self, numbers, others=(), optional=(), optional_others=()):
        self.numbers = frozenset(numbers) | frozenset(optional)
        self.required = frozenset(numbers) | frozenset(others) | {"key"}
        self.allowed = self.required | frozenset(optional) | frozenset(optional_others)

    def fits(self, row):
        keys = set(row)
        return self.required <= keys <= self.allowed and all(
            row[k] is None or (isinstance(row[k], (int, float)) and not isinstance(row[k], bool))
            for k in self.numbers & keys)


TTI_ROW = RowSchema(
    numbers=("triangles", "build_seconds", "render_seconds", "rays", "sah_cost",
             "tracer_setup_seconds"),
    others=("scene", "builder", "traversal", "build_spread", "render_spread", "ray_kinds",
            "verify_clean", "simulated_build_seconds"),
    optional=("memory_bytes", "references_per_triangle"),     # ``bench.structure_figures``
    optional_others=("accel",))
ACCURACY_ROW = RowSchema(
    numbers=("build_seconds", "render_seconds", "total_seconds", "sah_cost", "nodes_per_ray",
             "tris_per_ray", "mismatch_rate", "tie_rate", "holes", "hole_probes", "rmse",
             "max_error"),
    others=("scene", "knob", "value", "render_spread"))


class Cells:
    """Finished cells on disk, one JSON object per line, keyed by ``key``.

    An interruption can cut the last line short. Such a line is dropped when the file is
    opened (its cell runs again), so that the next record starts on a line of its own. A line
    that is not a row of ``schema`` (a ``RowSchema``), or holds a NaN or Infinity token, is
    passed over: its cell runs again.
    ``fresh`` ignores the cells on disk; they are replaced when the first new cell is saved,
    so that a run that fails before any cell (a scheduler that does not answer) changes
    nothing on disk."""

    def __init__(self, path, fresh=False, schema=None):
        self.path = Path(path)
        self.schema = schema
        self.done = {}
        self.truncate = fresh
        if not fresh and self.path.exists():
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
                # our lines hold null for a number that is not finite: a NaN or Infinity
                # token is a line edited since, not a result
                row = json.loads(line, parse_constant=_not_ours)
            except ValueError:                          # damaged: that cell runs again
                continue
            if isinstance(row, dict) and "key" in row and \
                    (self.schema is None or self.schema.fits(row)):
                self.done[row["key"]] = row

    def get(self, key):
        return self.done.get(key)

    def add(self, row):
        self.done[row["key"]] = row
        with appending(self.path, self.truncate) as f:
            f.write((json_text(row) + "\n").encode())
        self.truncate = False


def _scene_specs(args, quick):
    """[(name, kind, source)]: built-in scenes, then meshes, each described for
    :func:`load_scene_spec` (kind ``builtin``, ``mesh`` with an absolute path, or
    ``generated`` with the name of a generated mesh). Meshes are found and named as the other
    benchmarks find and name them (``bench.mesh_inputs``)."""
    from scenes.builtin import BUILTIN

    specs = [(n, "builtin", n) for n in (["cornell"] if quick else list(BUILTIN))]
    meshes = mesh_inputs(args)
    generated = [m for m in meshes if m.path is None]
    if generated:
        return specs + [(m.name, "generated", m.stem) for m in generated[:1 if quick else None]]
    if quick:
        meshes = sorted(meshes, key=lambda m: m.path.stat().st_size)[:1]
    return _named_apart(specs + _checked_meshes(meshes))


def _checked_meshes(meshes):
    """The specs of mesh files ``meshes`` (``MeshInput``), each read and checked as its cells
    will read it before any cell runs or any file is opened: a file that is no mesh, or a
    mesh the float32 units cannot trace, is refused naming the file as the user gave it."""
    from scenes import compile_scene, mesh_scene

    for m in meshes:
        traceable(str(m.path), compile_scene(mesh_scene(str(m.path))))
    return [(m.name, "mesh", os.path.abspath(m.path)) for m in meshes]


# The accuracy study's scenes: a diffuse box with a mirror and a glass block, glass and mirror
# spheres, a cloth sheet (offsets and precision matter on curved, reflective and thin surfaces)
ACCURACY_SCENES = ("cornell", "marbles", "cloth")


def _accuracy_specs(args, quick):
    """``ACCURACY_SCENES`` (--quick: the first), then the mesh files named, each as
    :func:`_scene_specs` describes it."""
    specs = [(n, "builtin", n) for n in ACCURACY_SCENES[:1 if quick else None]]
    if args.meshes:
        specs += _checked_meshes(mesh_inputs(args))
    return _named_apart(specs)


def _named_apart(specs):
    """``specs``, refused where a mesh takes the name of a built-in scene the study also runs:
    a study keeps its cells by scene name, so the two would share (and resume from) one
    scene's results."""
    builtin = {name for name, kind, _ in specs if kind == "builtin"}
    for name, kind, source in specs:
        if kind == "mesh" and name in builtin:
            raise InputError(source, f"named {name!r}, as a built-in scene the study also "
                                     f"runs, whose results are kept by name: rename the file")
    return specs


_generated = {"dir": None, "lock": threading.Lock()}


def _generated_mesh(name):
    """The file of a generated mesh, written once per process into a directory that goes
    with the process (scenes read their meshes from files)."""
    import tempfile
    from hwbvh.primitives import trimesh_module
    from scenes.meshes import GENERATED
    trimesh = trimesh_module()

    with _generated["lock"]:
        if _generated["dir"] is None:
            _generated["dir"] = tempfile.TemporaryDirectory(prefix="hwrt-gen-")
        f = Path(_generated["dir"].name) / f"{name}.ply"
        if not f.exists():
            tris = GENERATED[name]()
            trimesh.Trimesh(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3),
                            process=False).export(f)
    return f


def load_scene_spec(spec):
    """The scene dict of one of :func:`_scene_specs`' descriptions."""
    from scenes import load_scene, mesh_scene

    name, kind, source = spec
    if kind == "builtin":
        return load_scene(source)
    if kind == "generated":
        return mesh_scene(str(_generated_mesh(source)))
    return mesh_scene(source)


def _median(xs):
    return statistics.median(xs), [min(xs), max(xs)]


def _write_outputs(cells, out_dir, name, rows, md, plot_files, extra, where=None,
                   commit=write_files):
    """The CSV, JSON, summary and plots, in one set through ``commit(files)``; ``where``: the
    machine the cells were timed on (default: this one). The result names the files and
    ``cells``' file, what a rerun resumes from."""
    buf = io.StringIO()
    flat = [{k: (json_text(v) if isinstance(v, (dict, list)) else v) for k, v in r.items()} for r in rows]
    keys = sorted({k for r in flat for k in r})
    w = csv.DictWriter(buf, fieldnames=keys)
    w.writeheader()
    w.writerows(flat)
    result = {"rows": rows, "machine": where or machine()}
    result.update(extra)
    files = [(os.path.join(out_dir, f"{name}.csv"), buf.getvalue()),
             (os.path.join(out_dir, f"{name}.json"), json_text(result, indent=1) + "\n"),
             (os.path.join(out_dir, f"{name}.md"), md)] + plot_files
    files = with_figures(files)
    commit(files)
    result["files"] = [f for f, _ in files]
    result["cells_file"] = str(cells.path)
    return result


class _Timing:
    """Runs timed cells one at a time on one machine: this process, or one host of a
    Dask cluster."""

    def __init__(self, client, named="scheduler"):
        from .cluster import timing_host
        self.client = client
        self.host = timing_host(client, named) if client is not None else None

    def run(self, jobs, on_result, desc, progress):
        """``jobs``: [(key, fn, args)]; ``on_result(key, result)`` in this process."""
        from .cluster import run_cells
        run_cells(jobs, on_result, self.client, desc=desc, progress=progress, host=self.host)

    def machine(self):
        """The machine the cells were timed on."""
        if self.client is None:
            return machine()
        got = {}
        self.run([(f"machine-{_run_id()}", machine, ())], got.__setitem__,
                 "machine", False)
        return next(iter(got.values()))


@contextmanager
def _timing(scheduler, use_dask, warm_up):
    """A :class:`_Timing` whose workers ran ``warm_up`` once each (this process, without
    Dask). The embedded cluster is one worker with as many kernel threads as this process
    would use, so a cell there runs as it would here."""
    if not use_dask:
        warm_up()
        yield _Timing(None)
        return
    import numba
    from .cluster import address_source, dask_client
    with dask_client(scheduler, workers=1, threads_per_cell=numba.config.NUMBA_NUM_THREADS,
                     warm_up=warm_up) as client:
        yield _Timing(client, address_source(scheduler))


def _provenance(args, use_dask, timed, used, cells):
    """Where a benchmark's cells came from, for its JSON (``_provenance_line`` words it): how
    many were timed in this run and how many kept from an earlier one (``cells``' file), and
    what ran them."""
    from .cluster import SCHEDULER_ENV
    address = getattr(args, "scheduler", None) or os.environ.get(SCHEDULER_ENV)
    ran_on = ("this process" if not use_dask else
              f"the Dask scheduler at {address}" if address else "an embedded local Dask cluster")
    return {"timed": timed, "resumed": used - timed, "file": os.path.basename(str(cells.path)),
            "ran_on": ran_on if timed else None}


def _provenance_line(cells):
    """A ``_provenance`` as the first line of a benchmark's page."""
    kept = (f"kept from an earlier run ({cells['file']}; --fresh times them all again)")
    if not cells["timed"]:
        return f"Cells: all {cells['resumed']} {kept}.\n\n"
    return (f"Cells: {cells['timed']} timed in this run, on {cells['ran_on']}; "
            f"{cells['resumed']} {kept}.\n\n")


def _run_id():
    """A prefix that keeps one run's Dask keys apart from another's on a shared scheduler."""
    return uuid.uuid4().hex[:8]


# --------------------------------------------------------------------------------------
# time to image
# --------------------------------------------------------------------------------------
def warm_up_tti():
    """Load the kernels of every tree and structure a time-to-image cell builds and traverses."""
    from raytracer.render import warm_up
    from .bench import warm_up_accel
    for builder, traversal in TTI_TREES:
        warm_up(builder, traversal, parallel_build=True)
    for accel in tti_structures():
        warm_up_accel(accel)


def scene_identity(spec):
    """What a study keys one scene's cells by: the name of a built-in scene or a generated
    mesh; a mesh file's name with its contents' digest, so that a file given other contents
    under the same name is timed again rather than answered from the old file's cells."""
    name, kind, source = spec
    return [name, content_digest(source)] if kind == "mesh" else name


def _tti_key(scene, builder, W, H, spp, depth, repeat):
    return json.dumps([scene, builder, W, H, spp, depth, repeat])


def tti_scene_cell(spec, trees, W, H, spp, depth, repeat):
    """One scene's time-to-image cells, one per tree of ``trees`` ((builder, traversal, accel,
    name): a BVH by ``builder`` for ``accel`` "bvh", else that structure with its own build),
    timed together: ``repeat`` rounds, each building and rendering every tree once, in an
    order that rotates round by round, so that drift in the machine's speed falls on all
    alike (timed one tree after another, renders of 10-20 ms differed by 20-30% between
    trees that trace alike). Then, for our traversal, every ray of a small render checked
    against Embree. Returns {name: the record of its cell, without its key}."""
    from raytracer.render import make_tracer, render
    from scenes import compile_scene, with_frame
    from traversal.tracers import VerifyingTracer
    from .bench import structure_figures

    scene_name = spec[0]
    scene = compile_scene(with_frame(load_scene_spec(spec), W, H, spp, depth))
    runs = {t[3]: {"build": [], "render": [], "setup": []} for t in trees}
    last = {}
    for i in range(repeat):
        for builder, traversal, accel, name in round_order(trees, i):
            tracer, b, info = make_tracer(scene, builder, traversal, accel=accel)
            t0 = time.perf_counter()
            res = render(scene, tracer)
            r = runs[name]
            r["render"].append(time.perf_counter() - t0)
            r["build"].append(b)
            r["setup"].append(info.get("tracer_setup_seconds"))
            if i == repeat - 1:         # the figures of the structure, once: they do not vary
                figures = structure_figures(tracer, len(scene.triangles)) \
                    if traversal == "numba" else {}
                last[name] = (res.stats["rays"], info, figures)
            del tracer, res
    records = {}
    small = None
    for builder, traversal, accel, name in trees:
        rays, info, figures = last[name]
        clean = None
        if traversal == "numba":        # --verify at a small size: every ray vs Embree
            if small is None:
                small = compile_scene(with_frame(load_scene_spec(spec), 64, 48, 1, depth))
            tr, _, _ = make_tracer(small, builder, traversal, accel=accel)
            checked = VerifyingTracer(tr, small.triangles, small.vertices, small.faces)
            render(small, checked)
            clean = checked.summary()["mismatch"] == 0
        r = runs[name]
        b_med, b_spread = _median(r["build"])
        r_med, r_spread = _median(r["render"])
        record = {"scene": scene_name, "builder": builder, "traversal": traversal,
                  "triangles": int(len(scene.triangles)), "build_seconds": b_med,
                  "build_spread": b_spread, "render_seconds": r_med, "render_spread": r_spread,
                  "rays": int(sum(rays.values())), "ray_kinds": rays,
                  "sah_cost": info.get("sah_cost"), "verify_clean": clean,
                  "simulated_build_seconds": info.get("simulated_build_seconds"),
                  # our BVH's set-up (inside build_seconds); None for the other structures,
                  # whose set-up their build includes
                  "tracer_setup_seconds": None if None in r["setup"] else _median(r["setup"])[0],
                  **figures}
        if accel != "bvh":
            record["accel"] = accel
        records[name] = record
    return records


def bench_tti(args, *, use_dask=True, progress=True, commit=write_files):
    """Time to image per scene and path; cells on Dask (``args.scheduler``, else the embedded
    local cluster) or, with ``use_dask=False``, in this process. ``commit(files)`` writes the
    last set of files (the command line's also marks the run done)."""
    W, H = args.width, args.height
    spp, depth = args.spp, args.max_depth
    repeat = args.repeat
    out_dir = args.out_dir
    specs = _scene_specs(args, args.quick)      # bad meshes refused before the cells file is opened
    cells = Cells(os.path.join(out_dir, "tti.jsonl"), fresh=args.fresh, schema=TTI_ROW)
    run = _run_id()
    jobs, keys = [], {}
    structures = tti_structures(getattr(args, "accel", None))
    trees = [(b, t, "bvh", b) for b, t in TTI_TREES] + [("hwbvh", "numba", a, a) for a in structures]
    scenes = {spec[0]: scene_identity(spec) for spec in specs}
    cell_keys = {spec[0]: {t[3]: _tti_key(scenes[spec[0]], t[3], W, H, spp, depth, repeat)
                           for t in trees}
                 for spec in specs}
    for spec in specs:                  # a job per scene: the trees whose cells are missing
        missing = {name: key for name, key in cell_keys[spec[0]].items() if not cells.get(key)}
        if missing:
            job = f"tti-{run}-{len(jobs)}"
            keys[job] = missing
            todo = [t for t in trees if t[3] in missing]
            jobs.append((job, tti_scene_cell, (spec, todo, W, H, spp, depth, repeat)))

    def save(job, records):
        for name, record in records.items():
            cells.add({"key": keys[job][name], **record})

    where = None
    if jobs:
        with _timing(getattr(args, "scheduler", None), use_dask, warm_up_tti) as timing:
            timing.run(jobs, save, "bench tti", progress)
            where = timing.machine()
    rows, summary = _tti_rows(cells, specs, scenes, W, H, spp, depth, repeat, structures)
    used = sum(1 for by_tree in cell_keys.values() for key in by_tree.values() if cells.get(key))
    timed = sum(len(k) for k in keys.values())        # cells, not scenes
    provenance = _provenance(args, use_dask, timed, used, cells)
    md = "# hwrt bench tti\n\n" + made_by_block(command_of(args)) + \
        _provenance_line(provenance) + _tti_markdown(rows, summary, W, H, spp, depth)
    plots = _tti_plot(rows, out_dir, TTI_PATHS + structures)
    return _write_outputs(cells, out_dir, "tti", rows, md, plots,
                          {"setting": {"width": W, "height": H, "spp": spp, "max_depth": depth,
                                       "repeat": repeat}, "break_even": summary,
                           "cells": provenance}, where, commit)


def _tti_rows(cells, specs, scenes, W, H, spp, depth, repeat, structures=()):
    """``scenes``: each spec's name to its ``scene_identity``."""
    from raytracer.render import simulated_ready_seconds
    rows, summary = [], []
    for name, _, _ in specs:
        got = {b: cells.get(_tti_key(scenes[name], b, W, H, spp, depth, repeat))
               for b, _ in TTI_TREES}
        if not all(got.values()):
            continue
        others = {a: cells.get(_tti_key(scenes[name], a, W, H, spp, depth, repeat))
                  for a in structures}
        hw = got["hwbvh"]
        # a simulated hardware build still leaves our tracer's set-up to software
        sim = simulated_ready_seconds(hw) or {}
        for path, build, src in (("hwbvh-C", sim.get("HWBVH-C"), hw), ("hwbvh-HP", sim.get("HWBVH-HP"), hw),
                                 ("hwbvh-sw", hw["build_seconds"], hw), ("sweep", got["sweep"]["build_seconds"], got["sweep"]),
                                 ("embree", got["embree"]["build_seconds"], got["embree"])):
            rows.append({"scene": name, "path": path, "triangles": src["triangles"],
                         "build_seconds": build, "render_seconds": src["render_seconds"],
                         "total_seconds": (build or 0) + src["render_seconds"],
                         "render_spread": src["render_spread"], "rays": src["rays"],
                         "sah_cost": src["sah_cost"], "verify_clean": src["verify_clean"],
                         "traversal": src["traversal"], "accel": "bvh",
                         "memory_bytes": src.get("memory_bytes"),
                         "references_per_triangle": src.get("references_per_triangle")})
        for accel, src in others.items():
            if src:
                rows.append({"scene": name, "path": accel, "triangles": src["triangles"],
                             "build_seconds": src["build_seconds"],
                             "render_seconds": src["render_seconds"],
                             "total_seconds": src["build_seconds"] + src["render_seconds"],
                             "render_spread": src["render_spread"], "rays": src["rays"],
                             "sah_cost": None, "verify_clean": src["verify_clean"],
                             "traversal": src["traversal"], "accel": accel,
                             "memory_bytes": src.get("memory_bytes"),
                             "references_per_triangle": src.get("references_per_triangle")})
        # At what ray budget does each hardware build stop paying for itself? Against Embree's
        # build and traversal, and against the full-SAH sweep tree through the same traversal
        # (a better tree costs fewer seconds per ray but a longer build).
        e, sw = got["embree"], got["sweep"]
        per_ray = lambda cell: cell["render_seconds"] / max(cell["rays"], 1)
        c_hw, c_e, c_sw = per_ray(hw), per_ray(e), per_ray(sw)

        def break_even(saved, c_ours, c_peer):
            if saved <= 0:
                return 0.0
            return float("inf") if c_ours <= c_peer else saved / (c_ours - c_peer)
        for preset in ("HWBVH-C", "HWBVH-HP"):
            if preset not in sim:
                continue
            saved_e = e["build_seconds"] - sim[preset]
            saved_sw = sw["build_seconds"] - sim[preset]
            summary.append({"scene": name, "preset": preset, "build_saved_seconds": saved_e,
                            "seconds_per_ray_ours": c_hw, "seconds_per_ray_embree": c_e,
                            "break_even_rays": break_even(saved_e, c_hw, c_e),
                            "build_saved_vs_sweep_seconds": saved_sw,
                            "seconds_per_ray_sweep_tree": c_sw,
                            "break_even_rays_vs_sweep": break_even(saved_sw, c_hw, c_sw)})
    return rows, summary


def human_tti(result):
    """A ``bench_tti`` result as the command line prints it: the tables of its tti.md."""
    s = result["setting"]
    return (_provenance_line(result["cells"]) +
            _tti_markdown(result["rows"], result["break_even"], s["width"], s["height"], s["spp"],
                          s["max_depth"]))


def _tti_markdown(rows, summary, W, H, spp, depth):
    lines = [f"Time to image (build + render), Whitted {W}x{H}, {spp} spp, depth {depth}.\n",
             "Build: up to a structure ready to trace, its tracer's set-up included (our "
             "tracer's triangle rows in index order and checks); for hwbvh-C and hwbvh-HP, the "
             "simulated hardware build time plus that set-up, in software.\n",
             "Medians of the repeated runs, in which a scene's trees and structures alternate "
             "run by run (hwbvh-C, hwbvh-HP and hwbvh-sw render one tree), in an order that "
             "rotates each round, so that drift in the machine's speed falls on all alike; the "
             "render spread is min-max over them.\n",
             "Memory: the structure's nodes or cells, its triangle references and preprocessed "
             "triangles (with the BVH's map from primitive to triangle row; our traversal "
             "only); refs/tri: references per triangle.\n",
             "| scene | path | build s | render s (spread) | total s | rays | SAH | memory MiB "
             "| refs/tri | verify |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        sah = f"{r['sah_cost']:.1f}" if r["sah_cost"] else "-"
        mem = "-" if r.get("memory_bytes") is None else f"{r['memory_bytes'] / 2**20:.2f}"
        refs = "-" if r.get("references_per_triangle") is None else f"{r['references_per_triangle']:.2f}"
        ver = {True: "clean", False: "MISMATCH", None: "n/a"}[r["verify_clean"]]
        lo, hi = r["render_spread"]
        lines.append(f"| {r['scene']} | {r['path']} | {r['build_seconds']:.4f} | {r['render_seconds']:.3f} "
                     f"({lo:.3f}-{hi:.3f}) | {r['total_seconds']:.3f} | {r['rays']} | {sah} | {mem} "
                     f"| {refs} | {ver} |")
    lines += ["", "Break-even ray budget: a hardware build (simulated) saves build time against a "
              "peer; where its tree costs more per ray, it stays ahead in time to image up to "
              "this many rays. Against Embree (its build and traversal) and against the full-SAH "
              "sweep tree through the same traversal (a better tree, a longer software build). "
              "Seconds per ray are render seconds over rays traced, at this film size.", "",
              "| scene | preset | build saved vs Embree s | break-even rays | build saved vs sweep s "
              "| us/ray hwbvh tree | us/ray sweep tree | break-even rays vs sweep |",
              "|---|---|---:|---:|---:|---:|---:|---:|"]
    fmt = lambda x: "never behind" if x == float("inf") else f"{x:.3g}"
    for s in summary:
        lines.append(f"| {s['scene']} | {s['preset']} | {s['build_saved_seconds']:.4f} | "
                     f"{fmt(s['break_even_rays'])} | {s['build_saved_vs_sweep_seconds']:.4f} | "
                     f"{1e6 * s['seconds_per_ray_ours']:.4g} | {1e6 * s['seconds_per_ray_sweep_tree']:.4g} | "
                     f"{fmt(s['break_even_rays_vs_sweep'])} |")
    return "\n".join(lines) + "\n"


def _tti_plot(rows, out_dir, paths=TTI_PATHS):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    if not scenes:
        return []
    fig, ax = plt.subplots(figsize=(max(8, len(scenes) * 1.2), 5))
    width = 0.8 / len(paths)
    x = np.arange(len(scenes))
    for k, path in enumerate(paths):
        b = [next((r["build_seconds"] for r in rows if r["scene"] == s and r["path"] == path), 0) or 0 for s in scenes]
        rd = [next((r["render_seconds"] for r in rows if r["scene"] == s and r["path"] == path), 0) for s in scenes]
        pos = x + (k - (len(paths) - 1) / 2) * width
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
    # the same scene scaled: a fixed epsilon breaks, the relative offset does not. Scaled up
    # by 1e4: from hit points on their triangles' planes a fixed 1e-4 still clears the float32
    # unit's rounding at 1e3 (cornell: RMSE 0.0003 against the relative offset's 0.0007), not
    # at 1e4 (0.35)
    "offset_at_scale": ["relative@0.001", "fixed@0.001", "relative@10000", "fixed@10000"],
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


def warm_up_accuracy():
    """Load the kernels of both trees' builds and traversals."""
    from raytracer.render import warm_up
    warm_up("hwbvh", "numba", parallel_build=True)
    warm_up("sweep", "numba")


def _accuracy_setting(knob, val):
    """(the knobs of a cell, the scene's scale): ``BASE`` with ``knob`` set to ``val``."""
    if knob != "offset_at_scale":
        return dict(BASE, **{knob: val}), 1.0
    strategy, scale = val.split("@")
    return dict(BASE, offset=strategy), float(scale)


def _reference_spp(knob, setting):
    return REFERENCE_SPP_OF_SPP_KNOB if knob == "spp" else setting["spp"]


def accuracy_reference(spec, W, H, spp):
    """The high-accuracy image the cells of a scene are compared with: the sweep tree,
    float64, long paths."""
    from raytracer.render import make_tracer, render
    from scenes import compile_scene, with_frame

    rs = compile_scene(with_frame(load_scene_spec(spec), W, H, spp, REFERENCE_DEPTH))
    tr, _, _ = make_tracer(rs, "sweep", "numba", precision="float64")
    return render(rs, tr, seed=0).image


def accuracy_cell(spec, knob, val, W, H, repeat, rays, reference):
    """One knob at one value (the others at ``BASE``): timed builds and renders, the work per
    ray, the image error against ``reference``, the disagreement with Embree on ``rays``
    random rays and the holes of a closed sphere. The record of the cell, without its key."""
    from raytracer.render import make_tracer, render
    from scenes import compile_scene, transform_scene, with_frame
    from traversal import raysets
    from traversal.embree_ref import embree_intersect, embree_scene
    from traversal.tracers import CountingTracer
    from traversal.verify import classify

    setting, scale = _accuracy_setting(knob, val)
    d = load_scene_spec(spec)
    scene = compile_scene(with_frame(transform_scene(d, scale) if scale != 1.0 else d,
                                   W, H, setting["spp"], setting["max_depth"]))
    builds, renders = [], []
    for r in range(repeat + 1):
        tracer, b, info = make_tracer(scene, setting["builder"], "numba", setting["leaf_size"],
                                      setting["bins"], setting["precision"],
                                      setting["triangle_test"] == "watertight")
        if r == 0:
            # untimed: a setting's first render may compile kernels that it alone uses (the
            # float64 units, the watertight test)
            render(scene, tracer, seed=0, offset=setting["offset"])
            continue
        t0 = time.perf_counter()
        res = render(scene, tracer, seed=0, offset=setting["offset"])
        renders.append(time.perf_counter() - t0)
        builds.append(b)
    counting = CountingTracer(tracer)          # work per ray, outside the timed renders
    render(scene, counting, seed=0, offset=setting["offset"])
    per_ray = counting.work()
    err = res.image - reference
    # disagreement with Embree on random rays through this tree and these units
    O, D = raysets.incoherent(scene.triangles, rays)
    h = tracer.intersect(O, D)
    te, pe, *_ = embree_intersect(embree_scene(scene.vertices, scene.faces), O, D)
    counts, _ = classify(scene.triangles, O, D, 0.0, np.inf, h.prim.astype(np.int64), h.t, pe, te)
    holes, probes = _holes(setting)
    b_med, b_spread = _median(builds)
    r_med, r_spread = _median(renders)
    return {"scene": spec[0], "knob": knob, "value": val, "build_seconds": b_med,
            "render_seconds": r_med, "total_seconds": b_med + r_med,
            "render_spread": r_spread, "sah_cost": info.get("sah_cost"),
            "nodes_per_ray": per_ray["nodes_per_ray"], "tris_per_ray": per_ray["tris_per_ray"],
            "mismatch_rate": counts["mismatch"] / counts["rays"],
            "tie_rate": counts["tie"] / counts["rays"], "holes": holes, "hole_probes": probes,
            "rmse": float(np.sqrt(np.mean(err ** 2))), "max_error": float(np.abs(err).max())}


def bench_accuracy(args, *, use_dask=True, progress=True, commit=write_files):
    """What each accuracy knob costs and buys; cells on Dask (``args.scheduler``, else the
    embedded local cluster) or, with ``use_dask=False``, in this process. The reference
    images the pending cells need are cells too, run first. ``commit(files)`` writes the last
    set of files (the command line's also marks the run done)."""
    quick = args.quick
    W, H = args.width, args.height
    repeat = args.repeat
    rays = MISMATCH_RAYS_QUICK if quick else MISMATCH_RAYS
    specs = _accuracy_specs(args, quick)                    # before the cells file is opened
    cells = Cells(os.path.join(args.out_dir, "accuracy.jsonl"), fresh=args.fresh,
                  schema=ACCURACY_ROW)
    work = [(spec, knob, val) for spec in specs for knob, vals in KNOBS.items() for val in vals]
    scenes = {spec[0]: scene_identity(spec) for spec in specs}
    key_of = lambda spec, knob, val: json.dumps([scenes[spec[0]], knob, val, W, H, repeat])
    pending = [(spec, knob, val) for spec, knob, val in work if not cells.get(key_of(spec, knob, val))]
    where = None
    if pending:
        run = _run_id()
        needed = list(dict.fromkeys((spec, _reference_spp(knob, _accuracy_setting(knob, val)[0]))
                                    for spec, knob, val in pending))
        ref_jobs = {f"accuracy-{run}-ref-{i}": (accuracy_reference, (spec, W, H, ref_spp))
                    for i, (spec, ref_spp) in enumerate(needed)}
        ref_of = dict(zip(ref_jobs, needed))
        refs = {}
        with _timing(getattr(args, "scheduler", None), use_dask, warm_up_accuracy) as timing:
            timing.run([(k, fn, a) for k, (fn, a) in ref_jobs.items()],
                       lambda k, image: refs.__setitem__(ref_of[k], image),
                       "bench accuracy: references", progress)
            jobs, keys = [], {}
            for spec, knob, val in pending:
                k = f"accuracy-{run}-{len(jobs)}"
                keys[k] = key_of(spec, knob, val)
                ref = refs[(spec, _reference_spp(knob, _accuracy_setting(knob, val)[0]))]
                jobs.append((k, accuracy_cell, (spec, knob, val, W, H, repeat, rays, ref)))
            timing.run(jobs, lambda k, record: cells.add({"key": keys[k], **record}),
                       "bench accuracy", progress)
            where = timing.machine()
    rows = [cells.get(key_of(spec, k, v)) for spec, k, v in work]
    rows = [r for r in rows if r]
    provenance = _provenance(args, use_dask, len(pending), len(rows), cells)
    md = "# hwrt bench accuracy\n\n" + made_by_block(command_of(args)) + \
        _provenance_line(provenance) + _accuracy_markdown(rows)
    plots = _accuracy_plots(rows, args.out_dir)
    return _write_outputs(cells, args.out_dir, "accuracy", rows, md, plots,
                          {"setting": {"width": W, "height": H, "repeat": repeat, "base": BASE},
                           "cells": provenance}, where, commit)


def human_accuracy(result):
    """A ``bench_accuracy`` result as the command line prints it: the table of its
    accuracy.md."""
    return _provenance_line(result["cells"]) + _accuracy_markdown(result["rows"])


def _accuracy_markdown(rows):
    lines = ["Each row sets one knob to one value, the others at their defaults. Medians of the "
             "repeated runs; the render spread is min-max over them. nodes/ray and tris/ray: the "
             "work per closest-hit ray of the render, as the single-ray unit does it. mismatch "
             f"and tie: the shares of {MISMATCH_RAYS:,} random rays (--quick: "
             f"{MISMATCH_RAYS_QUICK:,}) whose answer through this tree and these units is a "
             "mismatch or a tie against Embree's (the terms of hwrt verify). holes: rays from "
             "the centre of a closed sphere, built and traced with the row's settings, through "
             "its vertices and edge midpoints that escape it, out of all such rays. RMSE and max err: the image's root-mean-square and largest "
             "per-channel difference from the scene's reference image (the full-SAH tree, "
             f"float64 units, paths {REFERENCE_DEPTH} bounces long; for the spp knob "
             f"{REFERENCE_SPP_OF_SPP_KNOB} samples per pixel), in the image's linear radiance.\n",
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
