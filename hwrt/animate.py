"""Dynamic scenes, frame by frame: a tree for every frame, then the image (``hwrt animate``,
``hwrt bench animation``).

Tree update strategies (thesis 2.4, "BVH Updating"):

* ``rebuild``: the hardware's build every frame (the functional builder, timed in software),
  with the simulated HWBVH-C and HWBVH-HP build time and energy from the cycle model;
* ``refit``: the first frame's topology kept, boxes refitted bottom-up every frame
  (:mod:`hwbvh.refit`), with the refit's own streaming-pass hardware time
  (:func:`hwbvh.refit.refit_cost`; no energy is charged to it);
* ``adaptive``: refit, and rebuild when the refitted tree's SAH cost has grown past
  ``threshold`` times the cost right after the last rebuild (after Lauterbach et al.'s
  degradation heuristic). Its SAH evaluation is part of its build time;
* ``embree``: Embree builds every frame (embreex) and traverses its own tree, the software peer.

The strategies update a BVH. Another acceleration structure (``accel``, e.g. the uniform grid)
has no refit: it is rebuilt every frame, so ``rebuild`` is its only strategy.

A frame whose triangle count differs from the previous one's forces a rebuild under refit and
adaptive (a refit keeps the topology); the frame's ``rebuild_reason`` says so.

Per frame: ``time_to_image_seconds`` = ``build_seconds`` (software build or refit, up to a
tracer ready to trace: our BVH's ``tracer_setup_seconds`` included, as every structure's set-up
is) + ``render_seconds`` (the Whitted render); ``time_to_image_simulated_seconds`` puts the
simulated hardware time in place of the software build or refit, our tracer's set-up still in
software. Producing a frame's geometry
(physics, mesh files) and writing it are timed apart (``scene_seconds``, ``write_seconds``).
"""
import csv
import hashlib
import io
import json
import math
import os
import time

import numpy as np

from hwbvh.files import figure_png
from hwbvh.errors import InputError, ParameterError
from hwbvh.files import (check_output_dir, held_directory, json_text, jsonable, named_after,
                         write_files)
from hwbvh.cycle_model import PRESETS
from .config import ADAPTIVE_THRESHOLD, BENCH_FRAMES, BENCH_QUICK_FRAMES, BENCH_QUICK_TRIANGLES
from .progress import note_first_compile
from .report import with_figures

STRATEGIES = ("rebuild", "refit", "adaptive", "embree")
PRESET_NAMES = tuple(PRESETS)
FRAME_NAME = "frame_{:04d}.exr"
STATE_NAME = "animation.json"
CSV_NAME = "frames.csv"
PREVIEW_NAME = "preview.gif"
BENCH_FILES = {"per_frame": "animation_tti_per_frame.png", "totals": "animation_totals.png",
               "drift": "animation_sah_drift.png", "csv": "animation.csv", "json": "animation.json",
               "md": "animation.md", "structures": "animation_structures.png"}


def _not_simulated():
    """A frame's simulated figure where the model gives none (no hardware build or refit runs:
    Embree's tree, a grid or k-d tree; or a refit's energy): each preset's entry null, so that
    the figures keep one shape on every frame."""
    return dict.fromkeys(PRESET_NAMES)


# --------------------------------------------------------------------------------------
# Tree update strategies
# --------------------------------------------------------------------------------------
class TreeUpdater:
    """Keeps one strategy's tree across frames. ``update(scene)`` -> (tracer, row dict)."""

    def __init__(self, strategy="rebuild", threshold=ADAPTIVE_THRESHOLD, accel="bvh"):
        from raytracer.render import ACCELS
        if strategy not in STRATEGIES:
            raise ParameterError("strategy", f"unknown strategy {strategy!r} (choose from {', '.join(STRATEGIES)})")
        if accel not in ACCELS:
            raise ParameterError("accel", f"unknown acceleration structure {accel!r} "
                                          f"(choose from {', '.join(ACCELS)})")
        if accel != "bvh" and strategy != "rebuild":
            raise ParameterError("strategy", f"{strategy!r} updates a BVH; the {accel} is rebuilt "
                                             "every frame (strategy 'rebuild')")
        if isinstance(threshold, bool) or not isinstance(threshold, (int, float)) or \
                not math.isfinite(threshold) or threshold < 1.0:
            raise ParameterError("threshold", f"must be a number >= 1 (SAH growth factor), got {threshold!r}")
        self.strategy = strategy
        self.accel = accel
        self.threshold = float(threshold)
        self.refitter = None
        self.sah_at_rebuild = None
        self.n_prims = None

    # -- the hardware build ---------------------------------------------------------
    def _rebuild(self, tris, reason):
        import hwbvh
        from hwbvh.cycle_model import simulate
        from hwbvh.refit import Refitter

        t = time.perf_counter()
        bvh = hwbvh.build(tris)
        build_s = time.perf_counter() - t
        t = time.perf_counter()
        sims = {name: simulate(bvh.tree, PRESETS[name]) for name in PRESET_NAMES}
        sim_s = time.perf_counter() - t
        if self.strategy in ("refit", "adaptive"):
            self.refitter = Refitter(bvh)
        self.sah_at_rebuild = bvh.meta["sah_cost"]
        self.n_prims = len(tris)
        row = {"rebuilt": True, "rebuild_reason": reason, "build_seconds": build_s,
               "simulated_build_seconds": {k: s["seconds"] for k, s in sims.items()},
               "simulated_energy_joules": {k: s["energy_joules"] for k, s in sims.items()},
               "simulation_seconds": sim_s, "sah_cost": bvh.meta["sah_cost"], "sah_growth": 1.0,
               "nodes": bvh.meta["nodes"]}
        return bvh, row

    def _refit(self, tris):
        from hwbvh.format import tree_stats
        from hwbvh.refit import refit_cost

        r = self.refitter
        t = time.perf_counter()
        nodes = r.refit_nodes(tris)
        refit_s = time.perf_counter() - t
        t = time.perf_counter()
        sah = tree_stats(nodes)["sah_cost"]
        sah_s = time.perf_counter() - t
        costs = {k: refit_cost(r.n_prims, r.node_count, r.max_depth, PRESETS[k]) for k in PRESET_NAMES}
        bvh = r.tree(nodes, tris, sah)
        row = {"rebuilt": False, "rebuild_reason": None,
               "build_seconds": refit_s + (sah_s if self.strategy == "adaptive" else 0.0),
               "refit_seconds": refit_s,
               "simulated_build_seconds": {k: c["seconds"] for k, c in costs.items()},
               "simulated_energy_joules": _not_simulated(), "simulation_seconds": 0.0,
               "sah_cost": sah, "sah_growth": sah / self.sah_at_rebuild if self.sah_at_rebuild else None,
               "nodes": r.node_count}
        return bvh, row

    def restore(self, tris):
        """Resume: the tree a rebuild at these triangles made (refit and adaptive continue
        from it; a refit depends only on the topology and the current positions)."""
        if self.strategy in ("refit", "adaptive"):
            self._rebuild(tris, "resume")

    def update(self, scene):
        """A tracer for ``scene`` (a CompiledScene) and the frame's tree figures."""
        from traversal import Tracer

        tris = scene.triangles
        if self.accel != "bvh":
            from raytracer.render import make_tracer
            from .bench import structure_figures
            tracer, build_s, _ = make_tracer(scene, accel=self.accel)
            return tracer, {"rebuilt": True, "rebuild_reason": f"the {self.accel} is rebuilt every frame",
                            "build_seconds": build_s,
                            "simulated_build_seconds": _not_simulated(),
                            "simulated_energy_joules": _not_simulated(), "simulation_seconds": 0.0,
                            "sah_cost": None, "sah_growth": None, "nodes": None,
                            **structure_figures(tracer, len(tris))}
        if self.strategy == "embree":
            from raytracer.render import make_tracer
            tracer, build_s, _ = make_tracer(scene, builder="embree", traversal="embree")
            return tracer, {"rebuilt": True, "rebuild_reason": "Embree builds every frame",
                            "build_seconds": build_s,
                            "simulated_build_seconds": _not_simulated(),
                            "simulated_energy_joules": _not_simulated(), "simulation_seconds": 0.0,
                            "sah_cost": None, "sah_growth": None, "nodes": None}
        if self.strategy == "rebuild":
            bvh, row = self._rebuild(tris, "rebuild every frame")
        elif self.refitter is None:
            bvh, row = self._rebuild(tris, "first frame")
        elif len(tris) != self.n_prims:
            bvh, row = self._rebuild(tris, f"triangle count changed ({self.n_prims} -> {len(tris)})")
        else:
            bvh, row = self._refit(tris)
            if self.strategy == "adaptive" and row["sah_growth"] > self.threshold:
                spent = row["build_seconds"]
                growth = row["sah_growth"]
                bvh, row = self._rebuild(tris, f"SAH grew {growth:.2f}x > {self.threshold:g}x")
                row["build_seconds"] += spent          # the refit that decided it was paid for
                row["refit_sah_growth"] = growth
        t = time.perf_counter()
        tracer = Tracer(bvh)
        row["tracer_setup_seconds"] = time.perf_counter() - t
        row["build_seconds"] += row["tracer_setup_seconds"]
        row["bvh"] = bvh
        return tracer, row


def warm_up(strategy, accel="bvh"):
    """Load the kernels a strategy (or another structure ``accel``) uses (build, refit,
    traversal) on a tiny input, so that the first frame's timings measure work, not JIT loading."""
    from raytracer.render import warm_up as render_warm_up
    t = time.perf_counter()
    if accel != "bvh":
        from .bench import warm_up_accel
        render_warm_up("hwbvh", "numba")          # the render's own kernels
        warm_up_accel(accel)
    elif strategy == "embree":
        render_warm_up("embree", "embree")
    else:
        render_warm_up("hwbvh", "numba", parallel_build=True)
        import hwbvh
        from hwbvh.refit import Refitter
        from scenes.meshes import sphere
        tris = sphere(4, 6)
        Refitter(hwbvh.build(tris)).refit(tris)
    return time.perf_counter() - t


# --------------------------------------------------------------------------------------
# One animation run
# --------------------------------------------------------------------------------------
def default_mesh():
    """Exploding's default mesh: the bunny of the mesh directory the benchmarks use
    (:func:`hwrt.bench.mesh_directory`: $HWRT_MESHES, else the default one when it is there),
    else None, for a generated sphere. A directory asked for that is missing or holds no mesh
    files is an error, and so is one without a bunny, rather than a sphere in its place."""
    from .bench import mesh_directory
    found = mesh_directory(None)
    if found is None:
        return None
    _, files, named = found
    bunny = next((p for p in files if p.stem == "bunny"), None)
    if bunny is None:
        raise InputError(named, "has no bunny (bunny.ply, .obj, ...) for exploding to break: "
                                "name a mesh with --mesh, or give --triangles for a sphere")
    return str(bunny)


def open_animation(spec, width=None, height=None, spp=None, max_depth=None, fps=None,
                   mesh=None, triangles=None, physics=None):
    from scenes.animation import load_animation
    if spec == "exploding" and mesh is None and triangles is None:
        mesh = default_mesh()
    if fps is not None and not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise ParameterError("fps", f"must be a positive number, got {fps!r}")
    return load_animation(spec, width=width, height=height, spp=spp, max_depth=max_depth, fps=fps,
                          mesh=mesh, triangles=triangles, physics=physics)


def _inputs_digest(paths):
    """SHA-256 over the files a run reads (their paths and bytes, a .gltf's buffers with it):
    a scene file or mesh edited since the frames on disk were rendered makes another run."""
    from hwbvh.files import with_companions
    h = hashlib.sha256()
    for path in with_companions(paths):
        h.update(os.fsencode(path) + b"\0")
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


# What a run's parameters mean by a key they leave out
PARAMS_ABSENT = {"accel": "bvh"}


def _source_path(source):
    """A run's source as its state records it: a scene file, mesh file or frame pattern as its
    absolute path with links resolved, so that a rerun naming the same file another way
    (``scene.json``, ``./scene.json``, its absolute path) is the same run; a built-in's name
    as it is."""
    from scenes.animation import ANIMATIONS
    from scenes.loader import BUILTIN, is_pattern

    source = str(source)
    if source in ANIMATIONS or source in BUILTIN:      # a name the loaders take before any file
        return source
    return os.path.realpath(source) if os.path.exists(source) or is_pattern(source) else source


def _same_source(old, new):
    """Whether a state's recorded source ``old`` names the source ``new`` (``_source_path``);
    a state that recorded a relative path names the same file from this directory."""
    return old == new or (isinstance(old, str) and _source_path(old) == new)


def _run_params(anim, strategy, threshold, scene, accel="bvh", seed=0, written=False):
    """What makes a run's frames what they are: a rerun resumes only frames made with all of
    it the same; for a ``written`` run (one that can be resumed), the inputs' content too."""
    p = {"scene": anim.name, "source": _source_path(anim.source), "strategy": strategy,
         "width": scene.width, "height": scene.height, "spp": scene.spp,
         "max_depth": scene.max_depth, "fps": anim.fps, "animation": anim.info, "seed": seed}
    if written:                       # read only where a rerun is to be told apart
        p["inputs_sha256"] = _inputs_digest(anim.inputs)
    if strategy == "adaptive":
        p["threshold"] = threshold
    if accel != "bvh":                # a BVH run's state names no structure
        p["accel"] = accel
    return jsonable(p)


def _written_beside_state(frames):
    """The files a run of ``frames`` frames writes beside its state: each frame, then the
    CSV and the preview."""
    return [FRAME_NAME.format(i) for i in range(frames)] + [CSV_NAME, PREVIEW_NAME]


def _check_output_dir(out_dir, anim, frames):
    """Fail before any work unless every output can be written and none is an input."""
    check_output_dir(out_dir, _written_beside_state(frames) + [STATE_NAME], anim.inputs)


def _load_state(out_dir, params, frames, fresh=False):
    """The rows of the earlier run in ``out_dir`` to resume from ({} for none). ``fresh``: that
    run, whatever its settings, is not resumed; its files are removed by ``_discard_run``."""
    path = os.path.join(out_dir, STATE_NAME)
    if not os.path.exists(path):
        # a run writes each frame with its state, and its CSV and preview after: without a
        # state they are someone else's files, which a run would replace
        theirs = [n for n in _written_beside_state(frames)
                  if os.path.exists(os.path.join(out_dir, n))]
        if theirs:
            raise InputError(out_dir, f"holds {theirs[0]} but no {STATE_NAME} of an hwrt animate "
                                      f"run: a run would replace it; choose another output "
                                      f"directory")
        return {}
    try:
        with open(path) as f:
            state = json.load(f)
        old = state["parameters"]
        rows = {int(r["frame"]): r for r in state["frames"]}
    except (OSError, ValueError, KeyError, TypeError):
        raise InputError(path, "is not the state of an hwrt animate run; "
                                   "choose another output directory") from None
    if fresh:
        return {}
    for r in rows.values():             # a frame without simulation may be stored as null
        for key in ("simulated_build_seconds", "simulated_energy_joules",
                    "time_to_image_simulated_seconds"):
            if r.get(key) is None:
                r[key] = _not_simulated()
    # every key of either run: a key only one names (accel, threshold) differs too
    value = lambda p, k: p.get(k, PARAMS_ABSENT.get(k))
    diff = [k for k in list(params) + [k for k in old if k not in params]
            if not (_same_source(old.get(k), params.get(k)) if k == "source" else
                    value(old, k) == value(params, k))]
    if diff:
        k = diff[0]
        what = ("made from other contents of the input files" if k == "inputs_sha256" else
                f"{k}: {value(old, k)!r}, now {value(params, k)!r}")
        raise InputError(out_dir, f"holds frames of another run ({what}); start it over with "
                                   f"--fresh or choose another output directory")
    return rows


def _discard_run(out_dir):
    """Remove the earlier run in ``out_dir`` (``run``'s ``fresh``): the files its state names
    (its frames, CSV, preview) and the state itself, last, so that an interruption leaves a
    state that names no missing frame as whole. Nothing else in the directory is touched."""
    path = os.path.join(out_dir, STATE_NAME)
    if not os.path.exists(path):
        return
    with open(path) as f:
        state = json.load(f)
    names = [FRAME_NAME.format(int(r["frame"])) for r in state["frames"]]
    for name in names + [CSV_NAME, PREVIEW_NAME, STATE_NAME]:
        try:
            os.remove(os.path.join(out_dir, name))
        except FileNotFoundError:
            pass


def _frame_intact(out_dir, i, width, height):
    """Whether frame i of a run being resumed is on disk and reads back as a whole image of the
    run's size that says it is frame i: a frame cut short or replaced since (another frame
    copied over it) is rendered again, not carried into the preview."""
    from raytracer.output import read_exr

    path = os.path.join(out_dir, FRAME_NAME.format(i))
    if not os.path.exists(path):
        return False
    try:
        px, _, meta = read_exr(path)
    except (OSError, RuntimeError, ValueError):     # not a readable EXR
        return False
    return px is not None and px.shape[:2] == (height, width) and meta.get("frame") == i


def _state_file(out_dir, params, rows):
    """The run's state as a ``write_files`` pair."""
    state = {"parameters": params, "frames": [rows[k] for k in sorted(rows)]}
    return os.path.join(out_dir, STATE_NAME), json_text(state, indent=1) + "\n"


def _write_state(out_dir, params, rows, with_files=()):
    """The run's state, and ``with_files`` (``write_files`` pairs) in the same set."""
    write_files(list(with_files) + [_state_file(out_dir, params, rows)])


def _csv_text(rows):
    flat = []
    for r in rows:
        d = {}
        for k, v in r.items():
            if isinstance(v, dict):
                for kk, vv in v.items():
                    d[f"{k}.{kk}"] = vv
            else:
                d[k] = v
        flat.append(d)
    keys = []
    for d in flat:
        keys += [k for k in d if k not in keys]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=keys)
    w.writeheader()
    w.writerows(flat)
    return buf.getvalue()


def _preview(out_dir, frames, fps):
    """An animated GIF (imageio) of the tone-mapped frames: its bytes."""
    import imageio.v3 as iio
    from raytracer.output import read_exr, tonemap

    images = []
    for i in range(frames):
        px, _, _ = read_exr(os.path.join(out_dir, FRAME_NAME.format(i)))
        images.append(tonemap(px[..., :3]))
    return iio.imwrite("<bytes>", np.stack(images), extension=".gif",
                       duration=max(20, int(round(1000 / fps))), loop=0)


def _check_frame_reach(anim, i, scene):
    """``raytracer.render.check_float32_reach`` for frame ``i``, naming the file and the
    frame."""
    from raytracer.render import check_float32_reach
    try:
        check_float32_reach(scene)
    except ParameterError as e:
        raise InputError(anim.source, f"frame {i} (time {anim.time(i):g}) is {e.problem}") from None


def _check_float32_reach(anim, frames, tri_mag, eye_mag):
    """The float32 units' reach (``raytracer.render.check_float32_reach``, which every
    frame's render applies) checked for every frame before the first is made, as far as the
    shapes a scene file places go (the bounds of ``Animation.check``): the bound from the
    frame's coordinate magnitudes, and the frame's own triangles where that bound is not
    small enough. (A scene too small for the units is found frame by frame, before each
    frame's render: magnitudes do not bound a scene's span from below.)"""
    from raytracer.render import point_light_positions
    from traversal.config import F32_UNIT_MAX_PRODUCT
    from traversal.triangle_unit import f32_reach_bound
    lights = float(np.abs(point_light_positions(anim.base.lights)).max(initial=0))
    bound = f32_reach_bound(tri_mag, np.maximum(eye_mag, lights))
    for i in np.flatnonzero(~(bound <= F32_UNIT_MAX_PRODUCT)):
        _check_frame_reach(anim, int(i), anim.scene(int(i)))


def run(anim, strategy="rebuild", frames=None, out_dir=None, threshold=ADAPTIVE_THRESHOLD,
        verify=False, progress=None, seed=0, inspect=None, accel="bvh", on_start=None,
        commit=write_files, fresh=False):
    """Render ``frames`` frames of ``anim`` (see ``_run``), the output directory held by this
    run alone from before its state is read until its last file is written: a second run into
    it meanwhile is refused (InputError), as each would replace the other's frames."""
    frames = anim.frames if frames is None else frames
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ParameterError("frames", f"must be a positive integer, got {frames!r}")
    if verify and strategy == "embree":
        raise ParameterError("verify", "checks our traversal against Embree; choose a strategy "
                                   "that uses the hardware's tree")
    updater = TreeUpdater(strategy, threshold, accel)   # its checks, before any directory
    args = (anim, strategy, frames, out_dir, updater, verify, progress, seed, inspect, accel,
            on_start, commit, fresh)
    if out_dir is None:
        return _run(*args)
    if not os.fspath(out_dir):
        raise ParameterError("out_dir", "is empty: give a directory (\".\" for this one)")
    _check_output_dir(out_dir, anim, frames)    # a path that can be made, before it is
    # one spelling for the lock and the files: the directory the system resolves the path to
    # (abspath would cancel a ``..`` after a symbolic link against the link's name)
    resolved = os.path.realpath(out_dir)
    with held_directory(resolved, "animate"):
        return _run(*args[:3], resolved, *args[4:])


def _run(anim, strategy, frames, out_dir, updater, verify, progress, seed, inspect, accel,
         on_start, commit, fresh):
    """Render ``frames`` frames of ``anim`` (scenes.animation.Animation) under a tree update
    ``strategy`` (``accel`` other than "bvh": that structure, rebuilt every frame). With ``out_dir``: one EXR per frame (written atomically), the run state
    (animation.json, also what a rerun resumes from, at the first frame missing or damaged), then a CSV
    and a GIF preview, the last set, through ``commit(files)`` (the command line's also marks
    the run done). Without it nothing is written (benchmarks). ``inspect(i, scene, bvh)`` sees
    every frame's tree (None under embree). ``on_start(first)``: called once every input and
    the output directory have been checked, with the first frame to render (later than 0 when
    a rerun resumes); ``progress(i)`` after each frame. ``fresh``: an earlier run in ``out_dir``
    is removed (``_discard_run``) once every check has passed, not resumed, whatever its
    settings. ``updater``: the run's TreeUpdater; ``out_dir``: checked, resolved and held by
    ``run``. Returns the result dict."""
    t_start = time.perf_counter()
    _check_float32_reach(anim, frames, *anim.check(frames))
    t = time.perf_counter()
    first = anim.scene(0)
    first_scene_s = time.perf_counter() - t
    _check_frame_reach(anim, 0, first)          # before any output
    params = _run_params(anim, strategy, updater.threshold, first, accel, seed,
                         written=out_dir is not None)
    rows, beyond = {}, {}
    if out_dir is not None:
        rows = _load_state(out_dir, params, frames, fresh)
        # frames of this run past the last asked for stay in its state (not orphaned on disk):
        # a longer rerun resumes them
        beyond = {k: v for k, v in rows.items() if k >= frames}
        rows = {k: v for k, v in rows.items() if k < frames}
    # resumed: the frames on disk and whole, verified if this run verifies
    start = 0
    while start < frames and start in rows and (not verify or "verify_seconds" in rows[start]) and \
            (out_dir is None or _frame_intact(out_dir, start, first.width, first.height)):
        start += 1
    rows = {k: v for k, v in rows.items() if k < start}
    if fresh and out_dir is not None:
        _discard_run(out_dir)
    note_first_compile()                        # before the progress bar takes the line
    if on_start is not None:
        on_start(start)
    startup_s = warm_up(strategy, accel)
    if 0 < start < frames:
        last = max(k for k, r in rows.items() if r["rebuilt"])
        updater.restore(anim.scene(last).triangles)
        updater.sah_at_rebuild = rows[last]["sah_cost"]
    from raytracer.render import render, simulated_ready_seconds, verified_render
    for i in range(start, frames):
        t = time.perf_counter()
        scene = first if i == 0 else anim.scene(i)
        scene_s = first_scene_s if i == 0 else time.perf_counter() - t
        _check_frame_reach(anim, i, scene)
        tracer, row = updater.update(scene)
        bvh = row.pop("bvh", None)
        t = time.perf_counter()
        res = render(scene, tracer, seed=seed + i)
        render_s = time.perf_counter() - t
        ready = simulated_ready_seconds(row)
        out = {"frame": i, "time": anim.time(i), "triangles": int(len(scene.triangles)), **row,
               "render_seconds": render_s,
               "time_to_image_seconds": row["build_seconds"] + render_s,
               "time_to_image_simulated_seconds":
                   _not_simulated() if ready is None else
                   {k: v + render_s for k, v in ready.items()},
               "scene_seconds": scene_s, "rays": res.stats["rays"],
               "pixels_beyond_float32": res.stats["pixels_beyond_float32"]}
        if verify:
            summary, out["verify_seconds"] = verified_render(scene, tracer, seed + i, res.image)
            out["verify"] = {k: summary[k] for k in ("rays", "agree", "tie", "mismatch",
                                                     "same_image")}
            out["verify"]["by_query"] = {k: summary[k] for k in ("closest", "shadow")}
        if out_dir is not None:
            from raytracer.output import exr_writer
            t = time.perf_counter()
            path = os.path.join(out_dir, FRAME_NAME.format(i))
            meta = {"scene": anim.name, "accel": accel,
                    "builder": "embree" if strategy == "embree" else "hwbvh",
                    "traversal": "embree" if strategy == "embree" else "numba",
                    "build_seconds": out["build_seconds"], "render_seconds": render_s,
                    "spp": scene.spp, "max_depth": scene.max_depth, "frame": i,
                    "time": out["time"], "strategy": strategy, "rebuilt": int(out["rebuilt"])}
            meta.update({f"rays_{k}": v for k, v in res.stats["rays"].items()})
            if out["sah_cost"] is not None:
                meta["sah_cost"] = out["sah_cost"]
            out["output"] = path
            rows[i] = jsonable(out)
            # the frame and the state that lists it appear together: a frame on disk is
            # always in a state, so one without a state is someone else's
            _write_state(out_dir, params, rows | beyond, [(path, exr_writer(path, res, meta))])
            rows[i]["write_seconds"] = out["write_seconds"] = time.perf_counter() - t
        else:
            rows[i] = jsonable(out)
        if inspect is not None:
            inspect(i, scene, bvh)
        if progress:
            progress(i)
    result = {"strategy": strategy, "scene": anim.name, "accel": accel,
              **{k: v for k, v in params.items() if k not in ("scene", "strategy", "accel")},
              "frames": [rows[k] for k in range(frames)], "resumed_from": start,
              "startup_seconds": startup_s}
    ordered = result["frames"]
    result["rebuilds"] = sum(1 for r in ordered if r["rebuilt"])
    result["adaptive_rebuild_frames"] = [r["frame"] for r in ordered if r["rebuilt"] and r["frame"] > 0] \
        if strategy == "adaptive" else None
    for key in ("build_seconds", "render_seconds", "time_to_image_seconds", "simulation_seconds"):
        result[f"{key}_total"] = sum(r[key] or 0.0 for r in ordered)
    result["pixels_beyond_float32_total"] = sum(r.get("pixels_beyond_float32", 0) for r in ordered)
    if strategy != "embree" and accel == "bvh":
        result["time_to_image_simulated_seconds_total"] = {
            k: sum(r["time_to_image_simulated_seconds"][k] for r in ordered) for k in PRESET_NAMES}
    if verify:
        result["verify"] = {k: sum(r["verify"][k] for r in ordered)
                            for k in ("rays", "agree", "tie", "mismatch")}
        result["verify"]["same_image"] = all(r["verify"]["same_image"] for r in ordered)
        result["verify_seconds_total"] = sum(r["verify_seconds"] for r in ordered)
    if out_dir is not None:
        csv_path = os.path.join(out_dir, CSV_NAME)
        preview_path = os.path.join(out_dir, PREVIEW_NAME)
        csv_text = _csv_text([{k: v for k, v in r.items() if k != "rays"} |
                              {f"rays.{k}": v for k, v in r["rays"].items()} for r in ordered])
        # the state again, now with the last frame's write time
        commit([_state_file(out_dir, params, rows | beyond), (csv_path, csv_text),
                (preview_path, _preview(out_dir, frames, anim.fps))])
        result["files"] = {"frames": os.path.join(out_dir, "frame_%04d.exr"),
                           "preview": preview_path, "csv": csv_path,
                           "state": os.path.join(out_dir, STATE_NAME)}
    result["output"] = out_dir
    result["total_seconds"] = time.perf_counter() - t_start
    return result


# --------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------
def cmd_animate(args, commit=write_files):
    """``hwrt animate`` (library errors name parameters; the command line reports options);
    ``commit`` writes the run's last set of files (see :func:`run`)."""
    from .progress import progress_bar

    for key in ("width", "height", "spp", "max_depth", "frames", "triangles"):
        v = getattr(args, key, None)
        if v is not None and v < 1:
            raise InputError(f"--{key.replace('_', '-')}", f"must be at least 1, got {v}")
    if args.threshold is not None and args.strategy in STRATEGIES and args.strategy != "adaptive":
        raise InputError("--threshold", f"is read by --strategy adaptive only, not "
                                        f"{args.strategy}")
    anim = open_animation(args.scene, width=args.width, height=args.height, spp=args.spp,
                          max_depth=args.max_depth, fps=args.fps, mesh=args.mesh,
                          triangles=args.triangles, physics=args.physics)
    frames = args.frames or anim.frames
    accel = getattr(args, "accel", "bvh")
    how = args.strategy if accel == "bvh" else accel
    out = args.output or os.path.join("renders", f"animate-{anim.name}-{how}")
    bars = []

    def start(first):                          # every check passed: the work begins
        bars.append(progress_bar(frames, f"animate {anim.name} ({how})", "frame", initial=first))

    threshold = ADAPTIVE_THRESHOLD if args.threshold is None else args.threshold
    try:
        with named_after("the scene's name", args.output, "give -o to name the directory"):
            result = run(anim, args.strategy, frames, out, threshold=threshold,
                         verify=args.verify, progress=lambda i: bars[0].update(1),
                         seed=args.seed, accel=accel, on_start=start, commit=commit,
                         fresh=args.fresh)
    finally:
        for bar in bars:
            bar.close()
    return jsonable(result)


def human(r):
    lines = [f"{'frame':>5}{'tris':>9}{'rebuilt':>8}{'build ms':>10}{'HWBVH-C ms':>11}"
             f"{'render ms':>10}{'tti ms':>9}{'SAH':>9}"]
    for f in r["frames"]:
        sim = f["simulated_build_seconds"]["HWBVH-C"]
        c = f"{sim * 1e3:>11.2f}" if sim is not None else f"{'-':>11}"
        sah = f"{f['sah_cost']:>9.1f}" if f["sah_cost"] is not None else f"{'-':>9}"
        lines.append(f"{f['frame']:>5}{f['triangles']:>9}{'yes' if f['rebuilt'] else 'no':>8}"
                     f"{f['build_seconds'] * 1e3:>10.2f}{c}{f['render_seconds'] * 1e3:>10.1f}"
                     f"{f['time_to_image_seconds'] * 1e3:>9.1f}{sah}")
    start = r.get("resumed_from") or 0
    # resumed frames' rows (and their time to image) are the earlier run's; the wall time is
    # this run's alone
    wall = "this run" if start else "total"
    rebuilds = f"{r['rebuilds']} rebuild{'' if r['rebuilds'] == 1 else 's'}"
    lines.append(f"{rebuilds}; time to image {r['time_to_image_seconds_total']:.2f} s; "
                 f"{wall} {r['total_seconds']:.2f} s; wrote {r['output']}")
    if start:
        which = f"frame 0 of {len(r['frames'])} was" if start == 1 else \
            f"frames 0-{start - 1} of {len(r['frames'])} were"
        lines.append(f"resumed: {which} on disk from an earlier run of the same settings "
                     f"({'its row is' if start == 1 else 'their rows are'} that run's)")
    if r.get("verify"):
        v = r["verify"]
        lines.append(f"verify: {v['rays']} rays, {v['agree']} agree, {v['tie']} tie, "
                     f"{v['mismatch']} mismatch; the checked renders made "
                     f"{'the same images' if v['same_image'] else 'OTHER IMAGES than the timed ones'}"
                     f" ({r['verify_seconds_total']:.2f} s, not in the times above)")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------
# Benchmark: every built-in animation under every strategy
# --------------------------------------------------------------------------------------
def bench_animation(args, commit=write_files):
    """Every built-in animation under every strategy, and with every other acceleration
    structure (``args.accel``: names from ``raytracer.render.ACCELS``; None: all) rebuilt
    every frame, in one process after warm-up: time to image per frame (build + render),
    totals, SAH drift of refit against rebuild, the frames at which adaptive rebuilds, and when
    the hardware's full rebuild beats software refitting. Writes animation.csv/.json/.md and
    plots to ``--out-dir``, in one set through ``commit(files)`` (the command line's also marks
    the run done)."""
    from scenes.animation import ANIMATIONS
    from raytracer.render import ACCELS
    from .bench import machine
    from .progress import progress_over

    frames = args.frames or (BENCH_QUICK_FRAMES if args.quick else BENCH_FRAMES)
    tris = BENCH_QUICK_TRIANGLES if args.quick else None
    check_output_dir(args.out_dir, BENCH_FILES.values())
    structures = [a for a in dict.fromkeys(getattr(args, "accel", None) or ACCELS) if a != "bvh"]
    runs = {}
    # a run is named by its strategy (the BVH's) or by the structure it rebuilds every frame
    cells = [(a, s, "bvh") for a in ANIMATIONS for s in STRATEGIES] + \
            [(a, st, st) for a in ANIMATIONS for st in structures]
    for name, label, accel in progress_over(cells, "bench animation", "run"):
        anim = open_animation(name, width=args.width, height=args.height, spp=args.spp,
                              max_depth=args.max_depth,
                              triangles=tris if name in ("exploding", "cloth") else None)
        strategy = "rebuild" if accel != "bvh" else label
        runs[(name, label)] = run(anim, strategy, min(frames, anim.frames), accel=accel)
    rows = []
    for (name, label), r in runs.items():
        for f in r["frames"]:
            sim = f["simulated_build_seconds"]
            en = f["simulated_energy_joules"]
            rows.append({"animation": name, "structure": r["accel"], "strategy": r["strategy"],
                         "frame": f["frame"],
                         "triangles": f["triangles"], "rebuilt": f["rebuilt"],
                         "build_seconds": f["build_seconds"], "render_seconds": f["render_seconds"],
                         "time_to_image_seconds": f["time_to_image_seconds"],
                         "simulated_build_seconds_C": sim.get("HWBVH-C"),
                         "simulated_build_seconds_HP": sim.get("HWBVH-HP"),
                         "simulated_energy_joules_C": en.get("HWBVH-C"),
                         "simulated_energy_joules_HP": en.get("HWBVH-HP"),
                         "simulation_seconds": f["simulation_seconds"],
                         "sah_cost": f["sah_cost"], "rays": sum(f["rays"].values())})
    summary = _bench_summary(runs, structures)
    out_dir = args.out_dir
    # what the run was, in the JSON file as on stdout, so that the file says how it was made
    result = jsonable({"setting": {"width": args.width, "height": args.height, "spp": args.spp,
                                   "max_depth": args.max_depth, "triangles": tris},
                       "frames": frames, "structures": structures,
                       "physics": runs[("marbles", "rebuild")]["animation"].get("physics"),
                       "summary": summary, "rows": rows, "machine": machine()})
    files = _bench_files(out_dir, result, runs, frames, args, structures)
    result["files"] = [f for f, _ in files]
    commit(files)
    return result


def _per_frame(frames):
    """Mean build, render and time to image per frame (seconds) of one run's frames."""
    return {k: float(np.mean([f[f"{k}_seconds"] for f in frames]))
            for k in ("build", "render", "time_to_image")}


def _bench_summary(runs, structures):
    from raytracer.render import simulated_ready_seconds
    out = []
    for name in dict.fromkeys(a for a, _ in runs):
        per = {s: runs[(name, s)] for s in STRATEGIES}
        reb, ref = per["rebuild"]["frames"], per["refit"]["frames"]
        n = len(reb)
        row = {"animation": name, "frames": n, "triangles": reb[0]["triangles"],
               "animation_info": per["rebuild"]["animation"]}
        for s, r in per.items():
            row[f"{s}_tti_total"] = r["time_to_image_seconds_total"]
            row[f"{s}_build_total"] = r["build_seconds_total"]
            row[f"{s}_render_total"] = r["render_seconds_total"]
        for k in PRESET_NAMES:
            # the hardware's full rebuild: simulated build + render of the rebuilt tree
            hw = [f["time_to_image_simulated_seconds"][k] for f in reb]
            sw = [f["time_to_image_seconds"] for f in ref]
            row[f"hw_rebuild_{k}_tti_total"] = sum(hw)
            row[f"hw_rebuild_{k}_vs_refit"] = sum(hw) / sum(sw)
            row[f"hw_rebuild_{k}_wins_frames"] = sum(1 for a, b in zip(hw, sw) if a < b)
            wins = [f["frame"] for f, a, b in zip(reb, hw, sw) if a < b]
            row[f"hw_rebuild_{k}_first_win_frame"] = wins[0] if wins else None
            row[f"energy_per_frame_{k}_joules"] = float(np.mean([f["simulated_energy_joules"][k] for f in reb]))
            row[f"simulated_build_per_frame_{k}_seconds"] = float(np.mean([f["simulated_build_seconds"][k] for f in reb]))
            # the hardware's build and our tracer's set-up after it, up to a tracer ready to trace
            row[f"simulated_ready_per_frame_{k}_seconds"] = float(np.mean(
                [simulated_ready_seconds(f)[k] for f in reb]))
        row["refit_seconds_per_frame"] = float(np.mean([f.get("refit_seconds") or f["build_seconds"] for f in ref]))
        row["rebuild_seconds_per_frame"] = float(np.mean([f["build_seconds"] for f in reb]))
        row["simulation_seconds_per_frame"] = float(np.mean([f["simulation_seconds"] for f in reb]))
        drift = [b["sah_cost"] / a["sah_cost"] for a, b in zip(reb, ref)]
        row["refit_sah_ratio_final"] = drift[-1]
        row["refit_sah_ratio_max"] = max(drift)
        row["adaptive_rebuild_frames"] = per["adaptive"]["adaptive_rebuild_frames"]
        row["mean_render_seconds"] = {s: r["render_seconds_total"] / n for s, r in per.items()}
        # every structure rebuilt every frame: the BVH by hwbvh's software build, the others
        row["structures"] = {"bvh": _per_frame(per["rebuild"]["frames"])}
        for st in structures:
            row["structures"][st] = _per_frame(runs[(name, st)]["frames"])
        out.append(row)
    return out


def _frame_axis(ax, label):
    """An x axis of frame numbers: whole frames on its ticks (a short run would be ticked 0.0,
    0.2, ...), and ``label`` under it unless None."""
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    if label:
        ax.set_xlabel(label)


def _bench_files(out_dir, result, runs, frames, args, structures):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    summary, rows = result["summary"], result["rows"]

    names = list(dict.fromkeys(a for a, _ in runs))
    files = []
    # time to image per frame, build and render stacked, one panel per (animation, strategy)
    fig, axes = plt.subplots(len(names), len(STRATEGIES), figsize=(4 * len(STRATEGIES), 2.6 * len(names)),
                             squeeze=False, sharex=True)
    for a, name in enumerate(names):
        top = max(f["time_to_image_seconds"] for s in STRATEGIES for f in runs[(name, s)]["frames"]) * 1e3
        for b, s in enumerate(STRATEGIES):
            ax = axes[a, b]
            fr = runs[(name, s)]["frames"]
            x = [f["frame"] for f in fr]
            build = np.array([f["build_seconds"] for f in fr]) * 1e3
            rend = np.array([f["render_seconds"] for f in fr]) * 1e3
            ax.stackplot(x, build, rend, labels=["build (software)", "render"], alpha=0.8)
            if s == "rebuild":
                hw = np.array([f["time_to_image_simulated_seconds"]["HWBVH-C"] for f in fr]) * 1e3
                ax.plot(x, hw, "k--", lw=1, label="HWBVH-C build + render")
            if s == "adaptive":
                for f in fr:
                    if f["rebuilt"] and f["frame"] > 0:
                        ax.axvline(f["frame"], color="r", lw=0.8, alpha=0.6)
            ax.set_ylim(0, top * 1.05)
            ax.set_title(f"{name} / {s}", fontsize=9)
            if b == 0:
                ax.set_ylabel("ms per frame")
            _frame_axis(ax, "frame" if a == len(names) - 1 else None)
            if a == 0 and b == 0:
                ax.legend(fontsize=7, loc="upper left")
    files.append((os.path.join(out_dir, BENCH_FILES["per_frame"]), figure_png(fig)))
    # totals over the animation
    fig, ax = plt.subplots(figsize=(9, 4))
    labels = list(STRATEGIES) + ["HWBVH-C rebuild", "HWBVH-HP rebuild"]
    w = 0.8 / len(labels)
    for k, lab in enumerate(labels):
        vals = []
        for row in summary:
            if lab in STRATEGIES:
                vals.append(row[f"{lab}_tti_total"])
            else:
                vals.append(row[f"hw_rebuild_{lab.split()[0]}_tti_total"])
        ax.bar(np.arange(len(summary)) + k * w, vals, w, label=lab)
    ax.set_xticks(np.arange(len(summary)) + 0.4 - w / 2, [r["animation"] for r in summary])
    ax.set_ylabel(f"time to image, {frames} frames (s)")
    ax.legend(fontsize=8)
    files.append((os.path.join(out_dir, BENCH_FILES["totals"]), figure_png(fig)))
    # SAH drift of refit (and adaptive) against rebuild
    fig, axes = plt.subplots(1, len(names), figsize=(4 * len(names), 3.2), squeeze=False)
    for ax, name in zip(axes[0], names):
        reb = runs[(name, "rebuild")]["frames"]
        for s in ("refit", "adaptive"):
            fr = runs[(name, s)]["frames"]
            ax.plot([f["frame"] for f in fr], [f["sah_cost"] / g["sah_cost"] for f, g in zip(fr, reb)], label=s)
        for f in runs[(name, "adaptive")]["frames"]:
            if f["rebuilt"] and f["frame"] > 0:
                ax.axvline(f["frame"], color="r", lw=0.8, alpha=0.5)
        ax.set_yscale("log")
        ax.set_title(name)
        _frame_axis(ax, "frame (red: adaptive rebuilds)")
        ax.set_ylabel("SAH cost / rebuild's")
        ax.legend(fontsize=8)
    files.append((os.path.join(out_dir, BENCH_FILES["drift"]), figure_png(fig)))
    # time to image per frame of every structure rebuilt every frame, one panel per animation
    fig, axes = plt.subplots(1, len(names), figsize=(4 * len(names), 3.2), squeeze=False)
    for ax, name in zip(axes[0], names):
        reb = runs[(name, "rebuild")]["frames"]
        x = [f["frame"] for f in reb]
        ax.plot(x, [f["time_to_image_seconds"] * 1e3 for f in reb], label="bvh (software build)")
        ax.plot(x, [f["time_to_image_simulated_seconds"]["HWBVH-C"] * 1e3 for f in reb],
                "k--", lw=1, label="bvh (HWBVH-C build)")
        for st in structures:
            fr = runs[(name, st)]["frames"]
            ax.plot([f["frame"] for f in fr], [f["time_to_image_seconds"] * 1e3 for f in fr], label=st)
        ax.set_yscale("log")
        ax.set_title(name)
        _frame_axis(ax, "frame")
        ax.set_ylabel("time to image, ms per frame")
        ax.legend(fontsize=7)
    files.append((os.path.join(out_dir, BENCH_FILES["structures"]), figure_png(fig)))
    files.append((os.path.join(out_dir, BENCH_FILES["csv"]), _csv_text(rows)))
    files.append((os.path.join(out_dir, BENCH_FILES["json"]), json_text(result, indent=1) + "\n"))
    files.append((os.path.join(out_dir, BENCH_FILES["md"]),
                  _bench_markdown(summary, frames, args, result["machine"], structures)))
    return with_figures(files)


def _bench_markdown(summary, frames, args, mach, structures):
    from .report import command_of, made_by_lines
    L = [f"# Animation benchmark: {frames} frames at {args.width}x{args.height}, {args.spp} spp",
         ""] + made_by_lines(command_of(args)) + [
         f"Machine: {mach['cpu']}, {mach['cores']} cores, Numba {mach['numba']}.", "",
         "Animations: " + "; ".join(
             f"{r['animation']} ({', '.join(f'{k} {v}' for k, v in r['animation_info'].items())})"
             if r["animation_info"] else r["animation"] for r in summary) + ".", "",
         "Time to image over the animation (seconds; build + render, software timings; the "
         "HWBVH columns put the simulated hardware build in place of the software build):", "",
         "| animation | triangles | rebuild | refit | adaptive | embree | HWBVH-C rebuild | HWBVH-HP rebuild |",
         "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in summary:
        L.append(f"| {r['animation']} | {r['triangles']} | {r['rebuild_tti_total']:.2f} | "
                 f"{r['refit_tti_total']:.2f} | {r['adaptive_tti_total']:.2f} | {r['embree_tti_total']:.2f} | "
                 f"{r['hw_rebuild_HWBVH-C_tti_total']:.2f} | {r['hw_rebuild_HWBVH-HP_tti_total']:.2f} |")
    L += ["", "Hardware full rebuild against software refitting, per frame (software rebuild: the "
          "build and our tracer's set-up; HWBVH builds: the simulated hardware alone, the set-up "
          "added in the time to image):", "",
          "| animation | software refit ms | software rebuild ms | HWBVH-C build ms | HWBVH-HP build ms | "
          "HWBVH-C / refit (tti) | frames HWBVH-C wins | HWBVH-C mJ/frame | HWBVH-HP mJ/frame | "
          "refit SAH (final, max) x rebuild's | adaptive rebuilds at |",
          "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---|"]
    for r in summary:
        L.append(f"| {r['animation']} | {r['refit_seconds_per_frame'] * 1e3:.2f} | "
                 f"{r['rebuild_seconds_per_frame'] * 1e3:.2f} | "
                 f"{r['simulated_build_per_frame_HWBVH-C_seconds'] * 1e3:.2f} | "
                 f"{r['simulated_build_per_frame_HWBVH-HP_seconds'] * 1e3:.2f} | "
                 f"{r['hw_rebuild_HWBVH-C_vs_refit']:.2f} | {r['hw_rebuild_HWBVH-C_wins_frames']}/{r['frames']} | "
                 f"{r['energy_per_frame_HWBVH-C_joules'] * 1e3:.2f} | {r['energy_per_frame_HWBVH-HP_joules'] * 1e3:.2f} | "
                 f"{r['refit_sah_ratio_final']:.2f}, {r['refit_sah_ratio_max']:.2f} | "
                 f"{', '.join(map(str, r['adaptive_rebuild_frames'])) or 'never'} |")
    L += ["", "A ratio below 1 means the hardware's full rebuild every frame reaches the image sooner "
          "than refitting in software. Where the refit's tree grows worse than a rebuild's (an SAH "
          "ratio above 1), its render time grows as the scene moves away from the topology it was "
          "built for.", ""]
    if structures:
        L += ["Every structure rebuilt every frame (ms per frame, means over the frames; build: up "
              "to a structure ready to trace, the HWBVH-C row's the simulated build and our "
              "tracer's set-up; the last column against the BVH's software rebuild):", "",
              "| animation | triangles | structure | build | render | time to image | x BVH |",
              "|---|---:|---|---:|---:|---:|---:|"]
        for r in summary:
            st = r["structures"]
            base = st["bvh"]["time_to_image"]
            hw_build = r["simulated_ready_per_frame_HWBVH-C_seconds"]
            cells = [("bvh (software build)", st["bvh"])]
            cells.append(("bvh (HWBVH-C build)", {"build": hw_build, "render": st["bvh"]["render"],
                                                 "time_to_image": hw_build + st["bvh"]["render"]}))
            cells += [(k, v) for k, v in st.items() if k != "bvh"]
            for label, v in cells:
                L.append(f"| {r['animation']} | {r['triangles']} | {label} | {v['build'] * 1e3:.2f} | "
                         f"{v['render'] * 1e3:.2f} | {v['time_to_image'] * 1e3:.2f} | "
                         f"{v['time_to_image'] / base:.2f} |")
        L += ["", "A structure that traces well but builds slowly pays its build on every frame of "
              "a dynamic scene.", ""]
    return "\n".join(L)


def human_bench(r):
    lines = [f"{'animation':<12}{'tris':>8}{'rebuild s':>10}{'refit s':>9}{'adapt s':>9}{'embree s':>9}"
             f"{'HW-C s':>8}{'HW-C/refit':>11}{'mJ/frame C':>11}"]
    for s in r["summary"]:
        lines.append(f"{s['animation']:<12}{s['triangles']:>8}{s['rebuild_tti_total']:>10.2f}"
                     f"{s['refit_tti_total']:>9.2f}{s['adaptive_tti_total']:>9.2f}{s['embree_tti_total']:>9.2f}"
                     f"{s['hw_rebuild_HWBVH-C_tti_total']:>8.2f}{s['hw_rebuild_HWBVH-C_vs_refit']:>11.2f}"
                     f"{s['energy_per_frame_HWBVH-C_joules'] * 1e3:>11.2f}")
    if r.get("structures"):
        lines += ["", f"{'animation':<12}{'structure':<10}{'build ms':>10}{'render ms':>10}{'tti ms':>9}"
                      "   (per frame, rebuilt every frame)"]
        for s in r["summary"]:
            for st, v in s["structures"].items():
                lines.append(f"{s['animation']:<12}{st:<10}{v['build'] * 1e3:>10.2f}"
                             f"{v['render'] * 1e3:>10.2f}{v['time_to_image'] * 1e3:>9.2f}")
    return "\n".join(lines)
