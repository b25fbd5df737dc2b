"""The ``hwrt`` command line: build, simulate, render, verify, bench.

Every subcommand takes ``--json`` and then prints exactly one JSON object on stdout; progress
and logs go to stderr. Outputs are checked before any work and written whole or not at all.
Library errors name a function's parameter; ``main`` reports the option that sets it.

This module imports only the standard library at its top, and ``main`` sets its signal handling
before importing the rest (NumPy, Numba, the commands), so that a Ctrl-C at any moment once
``main`` has started is the one line "hwrt: interrupted" and exit status 130 (before that, in
the few tens of milliseconds of Python's start-up, Python's own handling applies).
"""
import argparse
import contextlib
import errno
import os
import re
import select
import signal
import sys
from functools import partial

from .config import VERIFY_KIND, VERIFY_RAYS, env_flag
from .progress import PROGRESS_ENV, note_first_compile, progress_bar

DESCRIPTION = ("hwrt simulates the hardware BVH builder of M. J. Doyle's thesis (HWBVH) bit for "
               "bit and renders scenes with a Whitted ray tracer on exactly the trees it builds, "
               "checking hits against Intel Embree.")
EPILOG = ("With --json a command prints exactly one JSON object on stdout, in strict JSON: null "
          "stands for a number that is infinite or undefined (the distance of a ray that hits "
          "nothing, a break-even point never reached). Progress and logs go to stderr. Outputs "
          "are checked before any work starts and are written whole or not at all; no output "
          "may overwrite an input. Exit status: 0 success; 2 bad input, with one line on stderr "
          "naming the file, key or option and the problem; 130 interrupted (SIGINT); 143 "
          "terminated (SIGTERM); 141 when stdout's reader has gone (a closed pipe); 1 anything "
          "else.")
EXIT_BAD_INPUT = 2
EXIT_SIGINT = 128 + signal.SIGINT
EXIT_SIGTERM = 128 + signal.SIGTERM
EXIT_SIGPIPE = 128 + signal.SIGPIPE     # the reader of stdout went away (`hwrt ... | head`)
DEBUG_ENV = "HWRT_DEBUG"           # on: an internal error is re-raised with its traceback


# The exception of a SIGINT or SIGTERM that a library may have swallowed: llvmlite calls into
# Python from the compiler (Numba's object cache) and from destructors and drops what those
# raise, so a Ctrl-C while kernels compile would be lost (the run going on to exit 0) or leave
# the compiler half done (an internal error). The run answers it at its next safe point
# (``_answer_swallowed_signal``).
_signal_raised = [None]


def _quiet_swallowed_signal(unraisable):
    """``sys.unraisablehook`` while a run owns the signals: the interrupt a library swallowed
    is answered by the run (``_answer_swallowed_signal``), with the one line of any interrupt,
    not with the traceback Python prints of an exception it could not raise."""
    if not isinstance(unraisable.exc_value, KeyboardInterrupt):     # Terminated is one too
        sys.__unraisablehook__(unraisable)


def _answer_swallowed_signal():
    """Stop the run as the last SIGINT or SIGTERM should have, if its exception was swallowed."""
    raised = _signal_raised[0]
    if raised is not None:
        raise raised()


def _succeeded(args):
    """The run has succeeded: its outputs are in place and only its report is left to print.
    From here until ``main`` returns, SIGINT and SIGTERM are ignored, so that a signal arriving
    this late cannot turn the success into exit status 130 or 143."""
    if getattr(args, "signals_owned", False):
        _set_handlers(signal.SIG_IGN, signal.SIG_IGN)


def _commit(args, files):
    """Write ``files`` (``hwbvh.files.write_files`` pairs), the run's last outputs, then
    :func:`_succeeded`. ``write_files`` holds a signal that arrives while it renames, and acts
    on it as the renames end: if every path is then a new file (each renamed temporary file
    is one, made while the old file was still there), the outputs are in place and the signal
    came too late to undo them, so it is dropped. The commands whose last files are written
    in a library function (explore, animate, the benchmarks in BENCH_COMMITS) pass this down
    as its ``commit``; the --out-dir reports of the others go through :func:`_write_report`,
    which writes them with it too."""
    from hwbvh.files import file_identity, write_files
    files = [(os.fspath(p), data) for p, data in files]
    before = {p: file_identity(p) for p, _ in files}
    _answer_swallowed_signal()
    try:
        write_files(files)
        _succeeded(args)         # a signal up to the moment it ignores them is judged below
    except KeyboardInterrupt:    # SIGTERM's Terminated too
        if not files or any(file_identity(p) in (None, before[p]) for p in before):
            raise
        _signal_raised[0] = None     # came too late: the outputs are in place
        _succeeded(args)


def _emit(args, result, human):
    from hwbvh.files import json_text
    _answer_swallowed_signal()
    _succeeded(args)
    _write_stdout((json_text(result) if args.json else human(result)) + "\n")
    _warn_beyond_float32(result)


def _write_stdout(text):
    """``text`` to stdout, all of it or BrokenPipeError. Through the file descriptor where
    there is one: Python's buffered writer, whose write to a pipe is cut short when the reader
    goes away (``hwrt ... | head``), can return as if it had written everything, and the run
    would end with 0 instead of 141."""
    if sys.stdout is None:                  # closed by the caller (``>&-``): nowhere to write
        from hwbvh.files import OutputError
        raise OutputError(errno.EBADF, "it is closed", "<standard output>")
    sys.stdout.flush()
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):     # not a file (captured in-process)
        sys.stdout.write(text)
        sys.stdout.flush()
        return
    data = memoryview(text.encode(sys.stdout.encoding or "utf-8", "replace"))
    while data:
        try:
            data = data[os.write(fd, data):]
        except BlockingIOError:             # a descriptor left non-blocking by our parent
            select.select([], [fd], [])
        except BrokenPipeError:
            raise
        except OSError as e:                # a full disk or a device error: not ours
            from hwbvh.files import OutputError
            raise OutputError(e.errno, e.strerror, "<standard output>") from None


def _warn_beyond_float32(result):
    """A line on stderr when a render or animation wrote pixels too bright for float32 (its
    result's ``pixels_beyond_float32``, per image or in total): they are +inf in the EXR."""
    n = result.get("pixels_beyond_float32", result.get("pixels_beyond_float32_total"))
    if n:
        sys.stderr.write(f"hwrt: warning: {n} pixel{'s' if n != 1 else ''} brighter than float32 "
                         f"holds (3.4e38) {'are' if n != 1 else 'is'} +inf in "
                         f"{result.get('output')}; lower the scene's light values\n")


def _shown(v):
    """A value as the human-readable output shows it (``--json`` has it exact): six
    significant digits, "n/a" for what does not apply (JSON null), yes or no for a truth value,
    lists and tables inline."""
    if v is None:
        return "n/a"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, dict):
        return ", ".join(f"{k} ({_shown(x)})" if isinstance(x, dict) else f"{k} {_shown(x)}"
                         for k, x in v.items())
    if isinstance(v, (list, tuple)):
        return ", ".join(_shown(x) for x in v)
    return str(v)


def _kv(result, keys):
    width = max((len(k) for k in keys if k in result), default=0)
    return "\n".join(f"{k:>{width}}: {_shown(result[k])}" for k in keys if k in result)


# --------------------------------------------------------------------------------------
# The build options only some builders read (hwbvh.api.build): the binned SAH's leaf size and
# bins are the hardware builder's (the sweep is full SAH, with its own leaves); placement is our
# layout's, which Embree's internal tree has not.
BUILD_OPTION_READERS = {"leaf_size": ("hwbvh",), "bins": ("hwbvh",),
                        "capacity": ("hwbvh", "sweep"), "subtree_builders": ("hwbvh", "sweep"),
                        "block_nodes": ("hwbvh", "sweep")}


def _check_mesh_file(path, command):
    """A built-in scene's name (where no such file is there) or a scene file given where a mesh
    file goes is said to be one."""
    from hwbvh.errors import InputError
    from scenes.builtin import BUILTIN
    from scenes.loader import SCENE_EXTENSIONS
    if path in BUILTIN and not os.path.exists(path):
        raise InputError(path, f"no such file; {path} is a built-in scene: {command} takes a "
                               f"mesh file; render and verify take scenes")
    if str(path).lower().endswith(SCENE_EXTENSIONS):
        raise InputError(path, f"a scene file: {command} takes a mesh file; render and verify "
                               f"take scenes")


# What build --dump-handoff F writes beside F, in F.json
HANDOFF_DESCRIPTION_KEYS = ("record_bytes", "handoff_sizes")


def _holds_handoff_description(path):
    """Whether the file ``path`` holds what ``build --dump-handoff`` writes beside the dump: a
    JSON object of the record size and the handoff sizes."""
    from hwbvh.files import json_object_in
    from .config import HANDOFF_DESCRIPTION_MAX_CHARS
    d = json_object_in(path, HANDOFF_DESCRIPTION_MAX_CHARS)
    return d is not None and set(d) == set(HANDOFF_DESCRIPTION_KEYS)


def cmd_build(args):
    import time
    import numpy as np
    from hwbvh import config
    from hwbvh.api import (build, prefix_example, prefix_problem, tree_files, tree_paths,
                           warm_up)
    from hwbvh.builder import builds_in_parallel
    from hwbvh.errors import InputError
    from hwbvh.files import check_outputs, directory_problem, json_text, made_as_written
    from hwbvh.primitives import as_triangles, load_mesh_arrays, pack_records, primitive_boxes

    _check_mesh_file(args.mesh, "build")
    # options only some builders read: refused with the others, not ignored
    for dest, readers in BUILD_OPTION_READERS.items():
        if getattr(args, dest) is not None and args.builder not in readers:
            raise InputError(f"--{dest.replace('_', '-')}",
                             f"--builder {args.builder} does not read this option (read by "
                             f"--builder {' and '.join(readers)})")
    planned = []
    if args.out:
        problem = prefix_problem(args.out)
        if problem:
            raise InputError("--out", f"{args.out} {problem}; give a prefix of file names such as "
                                      f"{prefix_example(args.out)} (writes PREFIX.nodes, "
                                      f"PREFIX.indices and PREFIX.json)")
        problem = directory_problem(args.out)     # one for all three files: name the prefix
        if problem:
            raise InputError(f"--out {args.out}", problem)
        planned += tree_paths(args.out)
    if args.dump_aabbs:
        planned.append(args.dump_aabbs)
    if args.dump_handoff:
        planned += [args.dump_handoff, args.dump_handoff + ".json"]
    if args.builder == "embree" and planned:
        given = next(o for o, v in (("--out", args.out), ("--dump-aabbs", args.dump_aabbs),
                                    ("--dump-handoff", args.dump_handoff)) if v)
        raise InputError(given, "needs a tree of ours (--builder hwbvh or sweep): Embree's "
                                "tree stays inside Embree")
    if args.dump_handoff:
        beside = args.dump_handoff + ".json"
        # named by the option, not given: a file there that is not such a description (a
        # scene file, when F was given as "scene") is not ours to replace
        if os.path.isfile(beside) and not _holds_handoff_description(beside):
            raise InputError("--dump-handoff", f"{args.dump_handoff}: {beside}, written beside "
                                               f"it, is there and is not a handoff dump's "
                                               f"description, which the dump would replace; "
                                               f"choose another name")
    check_outputs(planned, inputs=[args.mesh])
    verts, faces = load_mesh_arrays(args.mesh)
    tris = as_triangles(verts[faces], source=args.mesh)
    if args.builder == "embree":
        from traversal.embree_ref import embree_build_seconds
        t = time.perf_counter()
        embree_build_seconds(np.eye(3, dtype=np.float32), np.array([[0, 1, 2]], np.int32))
        startup = time.perf_counter() - t
        secs = embree_build_seconds(verts, faces)
        result = {"builder": "embree", "triangles": int(len(faces)), "nodes": None,
                  "leaves": None, "max_depth": None, "sah_cost": None, "fallback_splits": None,
                  "build_seconds": secs, "startup_seconds": startup}
        return _emit(args, result, lambda r: _kv(r, r.keys()))
    startup = warm_up(args.builder, parallel=builds_in_parallel(len(tris)))
    given = {dest: getattr(args, dest) for dest in BUILD_OPTION_READERS
             if getattr(args, dest) is not None}           # the others: the library's defaults
    bvh = build(tris, builder=args.builder, validate_tree=True, source_name=args.mesh, **given)
    result = dict(bvh.meta, startup_seconds=startup)
    # the tree and the dumps are one set: all of them appear, or none; each file's bytes are
    # made as it is written, so that only one payload is in memory at a time
    files = tree_files(bvh, args.out) if args.out else []
    if args.dump_aabbs or args.dump_handoff:
        boxes = primitive_boxes(bvh.triangles)
        if args.dump_aabbs:
            files.append((args.dump_aabbs, made_as_written(lambda: pack_records(boxes))))
        if args.dump_handoff:
            order, sizes = bvh.handoff_order()
            files.append((args.dump_handoff, made_as_written(lambda: pack_records(boxes, order))))
            files.append((args.dump_handoff + ".json",
                          json_text(dict(zip(HANDOFF_DESCRIPTION_KEYS,
                                             (config.PRIMITIVE_RECORD_BYTES, sizes)))) + "\n"))
            result["handoff_sizes"] = [int(x) for x in sizes]
    _commit(args, files)
    # _commit returns only with every planned file in place: it drops a signal at the renames
    # only when every file was then renamed
    result["outputs"] = planned
    keys = ["builder", "triangles", "nodes", "leaves", "max_depth", "sah_cost", "fallback_splits",
            "build_seconds", "startup_seconds", "handoffs"] + (["outputs"] if planned else [])
    _emit(args, result, lambda r: _kv(r, keys))


def _scene_geometry(name):
    """(label, triangles f32, vertices f32, faces i32) of a scene name/file or mesh file."""
    from hwbvh.primitives import as_triangles, load_mesh_arrays
    import numpy as np
    from scenes import is_scene, load_scene_geometry
    from scenes.loader import name_of_file
    if is_scene(name) or not os.path.exists(name):     # the scene loader names a missing one
        return load_scene_geometry(name)
    verts, faces = load_mesh_arrays(name)
    tris = as_triangles(verts[faces], source=name)
    return name_of_file(name), tris, verts.astype(np.float32), faces.astype(np.int32)


# The arrays of a mismatch file (hwrt verify writes them) that --replay reads: key -> the
# shape of one ray's entry
REPLAY_ARRAYS = {"origins": (3,), "dirs": (3,), "tmax": ()}
# What the file says of the run that wrote it: key -> what --replay assumes of a file without
# it (one written by hand): closest-hit rays on the hardware's tree, on any triangles
REPLAY_RUN = {"kind": "random", "accel": "bvh", "scene": None, "triangles_sha256": None}


def _triangles_digest(tris):
    """SHA-256 of the triangles as the float32 units read them: a mismatch file names the
    geometry its rays were verified on."""
    import hashlib
    import numpy as np
    return hashlib.sha256(np.ascontiguousarray(tris, np.float32).tobytes()).hexdigest()


def _check_float32_values(path, key, a):
    """The rays are traced in float32: a value that is not finite or that float32 cannot hold
    is named, not cast to infinity."""
    import numpy as np
    from hwbvh.errors import InputError

    if not np.isfinite(a).all():
        raise InputError(path, f"key '{key}': not every value is finite")
    big = np.abs(a.astype(np.float64)).max(initial=0.0)
    if big > np.finfo(np.float32).max:
        raise InputError(path, f"key '{key}': value {big:g} exceeds the float32 range "
                               f"(+-{np.finfo(np.float32).max:.4g})")


def _replay_array(path, data, key, want):
    """``data[key]`` of a mismatch file, or an InputError naming what it is instead."""
    from hwbvh.errors import InputError
    try:
        return data[key]
    except ValueError as e:
        got = "an object array" if "allow_pickle" in str(e) else f"an unreadable array ({e})"
        raise InputError(path, f"key '{key}': expected {want}, got {got}") from None


def _replay_rays(path):
    """(origins, dirs, tmax) of mismatch file ``path``, checked: InputError naming the file and
    the key for anything but finite float arrays of one length (tmax may be infinite) and
    non-zero directions; and the run that wrote it (``REPLAY_RUN``'s keys, defaults where
    the file has none), as a fourth item."""
    import zipfile
    import numpy as np
    from hwbvh.errors import InputError
    from traversal.api import ACCELS
    from traversal.verify import RAY_KINDS
    try:
        data = np.load(path, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):   # a .npy file: one bare array
            raise ValueError("not an archive")
        with data:
            arrays = {}
            for key, shape in REPLAY_ARRAYS.items():
                if key not in data.files:
                    raise InputError(path, f"not a mismatch file from hwrt verify (no key '{key}')")
                want = f"a {'(n, 3)' if shape else '(n,)'} array of numbers"
                a = _replay_array(path, data, key, want)
                if a.dtype.kind not in "fiu" or a.ndim != 1 + len(shape) or a.shape[1:] != shape:
                    raise InputError(path, f"key '{key}': expected {want}, got {a.dtype} of shape "
                                           f"{a.shape}")
                if key != "tmax":
                    _check_float32_values(path, key, a)
                arrays[key] = a.astype(np.float64 if key == "tmax" else np.float32)
            run = {}
            for key in REPLAY_RUN:
                if key in data.files:
                    a = _replay_array(path, data, key, "a string")
                    if a.dtype.kind != "U" or a.shape != ():
                        raise InputError(path, f"key '{key}': expected a string, got {a.dtype} "
                                               f"of shape {a.shape}")
                    run[key] = str(a)
    except InputError:                                # (a ValueError)
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):
        raise InputError(path, "not a mismatch file from hwrt verify (not an .npz archive)") from None
    O, D, tmax = arrays["origins"], arrays["dirs"], arrays["tmax"]
    run = dict(REPLAY_RUN, **run)
    for key, names, what in (("kind", RAY_KINDS, "ray set"), ("accel", ACCELS, "structure")):
        if run[key] not in names:
            raise InputError(path, f"key '{key}': {run[key]!r} is not a {what} hwrt verify "
                                   f"checks ({', '.join(names)})")
    if not len(O) == len(D) == len(tmax):
        raise InputError(path, f"keys 'origins', 'dirs' and 'tmax' hold {len(O)}, {len(D)} and "
                               f"{len(tmax)} rays; expected one length")
    if np.isnan(tmax).any() or (tmax <= 0).any():
        raise InputError(path, "key 'tmax': expected positive numbers (inf for no bound)")
    if (~D.any(axis=1)).any():
        raise InputError(path, f"key 'dirs': ray {int(np.flatnonzero(~D.any(axis=1))[0])} has "
                               f"a zero direction")
    return O, D, tmax, run


def _verify_tracer(accel, tris):
    """The tracer ``hwrt verify`` checks: the hardware's tree, a grid or a kd-tree over
    ``tris``, compiled before its build so that a build time measures the build."""
    if accel == "grid":
        from traversal.grid import GridTracer, warm_up_grid
        warm_up_grid()
        return GridTracer(tris)
    if accel == "kdtree":
        from traversal.kdtree import KdTreeTracer, warm_up_kdtree
        warm_up_kdtree()
        return KdTreeTracer(tris)
    import hwbvh
    from traversal import Tracer
    return Tracer(hwbvh.build(tris))


def _replay(path, scene, tris, verts, faces):
    """Re-trace the rays of a mismatch file with the structure and query its run checked,
    with Embree and the float64 reference, on the triangles it was made on."""
    import numpy as np
    from hwbvh.errors import InputError, ParameterError
    from traversal.embree_ref import embree_intersect, embree_occluded, embree_scene
    from traversal.verify import diagnose, diagnose_occluded, query_of

    O, D, tmax, run = _replay_rays(path)
    if run["triangles_sha256"] not in (None, _triangles_digest(tris)):
        made_on = f" ({run['scene']!r})" if run["scene"] else ""
        raise InputError(path, f"its rays were verified on other triangles{made_on} than the "
                               f"{len(tris)} of {scene}: replay it on the scene it was made on")
    tracer = _verify_tracer(run["accel"], tris)
    reference = embree_scene(verts, faces)
    rays = [{"origin": O[i].tolist(), "dir": D[i].tolist(), "tmax": float(tmax[i])}
            for i in range(len(O))]
    occluded = query_of(run["kind"]) == "occluded"
    try:
        ours = tracer.occluded(O, D, 0.0, tmax) if occluded else tracer.intersect(O, D, 0.0, tmax)
    except ParameterError as e:                 # rays no run of the float32 units traced
        raise InputError(path, f"its rays are beyond the float32 units ({e.parameter}: "
                               f"{e.finding}): no hwrt verify run wrote them") from None
    if occluded:
        blocked = ours
        ref = embree_occluded(reference, O, D, tmax)
        found = diagnose_occluded(tris, O, D, 0.0, tmax, blocked, ref)
        answers = [{"ours": bool(blocked[i]), "embree": bool(ref[i])} for i in range(len(O))]
    else:
        h = ours
        te, pe, *_ = embree_intersect(reference, O, D, None if np.isinf(tmax).all() else tmax)
        found = diagnose(tris, O, D, 0.0, tmax, h.prim.astype(np.int64), h.t, pe, te)
        answers = [{"ours": [int(h.prim[i]), float(h.t[i])],
                    "embree": [int(pe[i]), float(te[i])]} for i in range(len(O))]
    rows = [dict(rays[i], **answers[i], **found[i]) for i in range(len(O))]
    counts = {k: sum(r["class"] == k for r in rows) for k in ("agree", "tie", "mismatch")}
    return dict(rays=len(rows), **counts, **_wrong_counts(found), kind=run["kind"],
                accel=run["accel"], query=query_of(run["kind"]),
                replayed=rows, file=str(path))


def _replay_answer(answer):
    """An answer of a replayed ray in words: blocked or not (occluded), else the triangle
    hit and where, or a miss."""
    if isinstance(answer, bool):
        return "blocked" if answer else "not blocked"
    prim, t = answer
    return "a miss" if prim < 0 else f"triangle {prim} at t = {t:.9g}"


def _replay_human(r):
    """A summary line, then a line per ray (its class, both answers, the ray), and under a
    mismatch a line for each answer the re-test rejects, saying why."""
    triple = lambda v: "(" + ", ".join(f"{x:.9g}" for x in v) + ")"
    whose = {"ours": "our answer", "embree": "Embree's answer"}
    lines = [f"replayed {r['rays']} {r['kind']} rays of {r['file']} ({r['query']} queries, "
             f"accel {r['accel']}): {r['agree']} agree, {r['tie']} tie, {r['mismatch']} "
             f"mismatch (our answer wrong in {r['mismatch_ours_wrong']}, Embree's in "
             f"{r['mismatch_embree_wrong']})"]
    for i, x in enumerate(r["replayed"]):
        lines.append(f"  ray {i}: {x['class']}; ours {_replay_answer(x['ours'])}, Embree "
                     f"{_replay_answer(x['embree'])}; origin {triple(x['origin'])}, direction "
                     f"{triple(x['dir'])}, t_max {x['tmax']:.9g}")
        lines += [f"    {whose[name]} is wrong: {x['why'][name]}" for name in x["wrong"]]
    return "\n".join(lines)


def _wrong_counts(found):
    """Of ``diagnose``'s rows, the mismatches whose answer of ours and of Embree's is wrong
    (a mismatch may count in both)."""
    return {f"mismatch_{name}_wrong": sum(name in r["wrong"] for r in found)
            for name in ("ours", "embree")}


def _verifiable_geometry(name):
    """``_scene_geometry``, refused (naming the scene) where the float32 units cannot trace it
    whole: too large or too small, as ``render`` refuses it, for the rays the sets make."""
    from raytracer.render import check_float32_reach_from
    from traversal.raysets import check_extent, points_beyond

    geometry = _scene_geometry(name)
    tris = geometry[1]
    if len(tris):
        check_extent(tris, name)
        check_float32_reach_from(tris, points_beyond(tris))
    return geometry


def cmd_verify(args):
    import io
    import numpy as np
    from hwbvh.errors import InputError
    from hwbvh.files import absent, check_outputs, json_text, named_after
    from scenes.loader import scene_inputs
    from traversal.verify import diagnose, diagnose_occluded, query_of, verify_mesh

    if args.replay:
        for flag, value in (("--rays", args.rays), ("--kind", args.kind),
                            ("--mismatches", args.mismatches),
                            ("--accel", args.accel)):
            if value is not None:
                raise InputError(flag, "is for a verification run; --replay re-traces the file's rays")
        if not os.path.isfile(args.replay):
            raise InputError(args.replay, "not a file" if os.path.exists(args.replay)
                             else absent(args.replay, "no such file"))
        label, tris, verts, faces = _verifiable_geometry(args.scene)
        return _emit(args, _replay(args.replay, label, tris, verts, faces), _replay_human)
    if args.mismatches and not args.mismatches.lower().endswith(".npz"):
        raise InputError("--mismatches", f"{args.mismatches} does not end in .npz (the mismatch "
                                         f"file is a NumPy archive, which --replay reads)")
    rays = VERIFY_RAYS if args.rays is None else args.rays
    accel = args.accel or "bvh"               # None in args: --replay refuses any given
    kind = args.kind or VERIFY_KIND
    label, tris, verts, faces = _verifiable_geometry(args.scene)
    # named by the scene's name, as render's image is, and by the structure but the default's
    where = "" if accel == "bvh" else f"-{accel}"
    out = args.mismatches or os.path.join("renders",
                                          f"verify-{label}-{kind}{where}-mismatches.npz")
    with named_after("the scene's name", args.mismatches, "give --mismatches to name the file"):
        check_outputs([out], inputs=scene_inputs(args.scene))
    tracer = _verify_tracer(accel, tris)
    counts, labels, (O, D, tmax), ours, ref = verify_mesh(tris, verts, faces, kind, rays,
                                                          tracer=tracer)
    if counts["rays"] == 0:
        raise InputError(args.scene, f"makes no {kind} rays: none of the first rays that "
                                     f"make them hits the mesh")
    result = dict(counts)
    result.update({"kind": kind, "scene": label, "rays_requested": rays, "accel": accel,
                   "query": query_of(kind),
                   "hit_fraction": counts["hit"] / counts["rays"]})
    if accel != "bvh":
        result.update({k: v for k, v in tracer.stats().items()
                       if k in ("build_seconds", "memory_bytes", "references_per_triangle")})
    if counts["rays"] != rays:
        print(f"hwrt: note: {counts['rays']} of the {rays} requested {kind} rays: too few of the "
              f"first rays hit the mesh", file=sys.stderr)
    bad = np.flatnonzero(labels == 2)
    bounds = np.full(len(bad), np.inf) if tmax is None else np.asarray(tmax)[bad]
    if query_of(kind) == "occluded":
        answers = {"ours_blocked": ours[bad], "embree_blocked": ref[bad]}
        found = diagnose_occluded(tris, O[bad], D[bad], 0.0, bounds, ours[bad], ref[bad])
    else:
        te, pe = ref
        answers = {"ours_prim": ours.prim[bad], "ours_t": ours.t[bad], "embree_prim": pe[bad],
                   "embree_t": te[bad]}
        found = diagnose(tris, O[bad], D[bad], 0.0, bounds, ours.prim[bad].astype(np.int64),
                         ours.t[bad], pe[bad], te[bad])
    result.update(_wrong_counts(found))
    if len(bad):
        buf = io.BytesIO()
        np.savez(buf, origins=O[bad], dirs=D[bad], tmax=bounds, **answers, kind=np.str_(kind),
                 accel=np.str_(accel), scene=np.str_(label),
                 triangles_sha256=np.str_(_triangles_digest(tris)))
        _commit(args, [(out, buf.getvalue())])
        result["mismatch_file"] = out
    elif os.path.exists(out):
        print(one_line(f"hwrt: note: no mismatches, so {out} was not written: the file there "
                       f"is an earlier run's"), file=sys.stderr)
    _emit(args, result, lambda r: _kv(r, ["scene", "accel", "kind", "query", "rays",
                                          "rays_requested", "hit", "agree", "tie", "mismatch",
                                          "mismatch_ours_wrong", "mismatch_embree_wrong",
                                          "mismatch_file"]))


def cmd_simulate(args):
    from hwbvh.cycle_model import simulate_mesh

    _check_mesh_file(args.mesh, "simulate")
    result = simulate_mesh(args.mesh, args.preset, w=args.w, tsize=args.tsize, psize=args.psize,
                           subtree_builders=args.subtree_builders, ram_pairs=args.ram_pairs,
                           clock_mhz=args.clock_mhz, leaf_size=args.leaf_size, bins=args.bins,
                           control_latency=args.control_latency)
    changed = _knobs_changed(result["changed"], args.preset)
    _emit(args, result, lambda r: _kv(dict(r, preset=r["base_preset"], changed=changed)
                                      if changed else
                                      {k: v for k, v in r.items() if k != "changed"},
                                      ["preset", "changed", "triangles", "cycles", "seconds",
                                       "energy_joules", "area_mm2", "active_power_w",
                                       "traffic_bytes", "footprint_bytes", "utilisation",
                                       "sah_cost"]))


def _knobs_changed(changed, preset):
    """``simulate_mesh``'s ``changed`` knobs beside ``preset``'s values, as a line:
    "w 2 (preset: 4), capacity 4096 (preset: 8192)"; "" for the preset itself."""
    from dataclasses import asdict
    from hwbvh.cycle_model import PRESETS

    base = asdict(PRESETS[preset]) | {"capacity": PRESETS[preset].capacity}

    def shown_apart(v, w):          # as many digits as tell the two apart
        return (_shown(v), _shown(w)) if _shown(v) != _shown(w) else (repr(v), repr(w))

    return ", ".join("{} {} (preset: {})".format(k, *shown_apart(v, base[k]))
                     for k, v in changed.items())


def cmd_explore(args):
    from hwbvh.errors import InputError, ParameterError
    from hwbvh.parallel import usable_cores
    from .cluster import SCHEDULER_ENV
    from .explore import KNOBS, explore, human, parse_grid

    if args.workers is not None and (args.scheduler or os.environ.get(SCHEDULER_ENV)):
        given = "--scheduler" if args.scheduler else f"${SCHEDULER_ENV}"
        raise InputError("--workers", f"sizes the local cluster, which is not made when "
                                      f"{given} names a running scheduler")
    if args.workers is not None and args.workers > usable_cores():
        raise InputError("--workers", f"at most {usable_cores()}, the cores this process may use "
                                      f"(a cell keeps a core busy: more worker processes would "
                                      f"only share them; --scheduler runs cells on a larger "
                                      f"cluster), got {args.workers}")
    try:
        grid = parse_grid(args.grid) if args.grid else None
        from .report import command_of
        result = explore(args.meshes, grid, args.out_dir, command=command_of(args),
                         scheduler=args.scheduler,
                         workers=args.workers, fresh=args.fresh,
                         commit=partial(_commit, args))
    except ParameterError as e:      # a knob's value was given in --grid
        if e.parameter in KNOBS:
            raise ParameterError("grid", f"{e.parameter}: {e.problem}") from None
        raise
    _emit(args, result, human)


def cmd_render(args):
    import time
    from hwbvh.errors import InputError, ParameterError
    from hwbvh.files import OutputPathError, check_outputs, named_after
    from raytracer.render import (builder_and_traversal, check_float32_reach, make_tracer,
                                   render, simulated_ready_seconds, verified_render, warm_up)
    from raytracer.output import exr_writer, png_writer
    from scenes import compile_scene, load_scene, with_frame
    from scenes.loader import scene_inputs

    t_start = time.perf_counter()
    # a grid or kd-tree is built by its own builder (a --builder, even the default's name, would
    # be ignored) and walked by our units (--traversal numba says just that)
    if args.accel != "bvh" and (args.builder is not None or args.traversal not in (None, "numba")):
        raise InputError("--accel", f"--accel {args.accel} builds and traverses its own structure: "
                         "it takes no --builder and no --traversal embree")
    # Embree's tree is traversed by Embree only, and Embree traverses only its own tree: one
    # of the pair given as embree picks the other
    if args.builder == "embree" and args.traversal == "numba":
        raise InputError("--builder embree", "needs --traversal embree, not numba (Embree's "
                                             "tree is traversed by Embree only)")
    if args.traversal == "embree" and args.builder not in (None, "embree"):
        raise InputError("--traversal embree", f"needs --builder embree, not {args.builder} "
                                               f"(Embree traverses only its own tree)")
    args.builder, args.traversal = builder_and_traversal(args.builder, args.traversal)
    embree = args.builder == "embree"
    if args.verify and embree:
        raise InputError("--verify", "checks our traversal against Embree; it takes no --builder "
                                     "embree or --traversal embree")
    if args.precision != "float32" and (embree or args.accel != "bvh"):
        raise InputError("--precision", f"{args.precision} is a precision of our BVH traversal's "
                                        f"units; {'Embree' if embree else f'the {args.accel}'} "
                                        f"traces in float32")
    d = with_frame(load_scene(args.scene), args.width, args.height, args.spp, args.max_depth)
    out = args.output or os.path.join("renders", f"{d.get('name', 'scene')}.exr")
    if os.path.splitext(out)[1].lower() != ".exr":
        raise InputError("-o/--output", f"{out}: expected a file name with the extension .exr, "
                                        f"such as image.exr (--png adds a PNG preview beside "
                                        f"the EXR)")
    png = os.path.splitext(out)[0] + ".png" if args.png else None
    try:
        with named_after("the scene's name", args.output, "give -o to name the image"):
            check_outputs([out, png], inputs=scene_inputs(args.scene))
    except OutputPathError as e:
        if png is None or e.source != png:
            raise
        raise InputError("--png", f"{png}, the preview beside the EXR: {e.problem}") from None
    scene = compile_scene(d)
    if args.verify and args.precision != "float32":
        try:                            # the reference must reach the scene too
            check_float32_reach(scene)
        except ParameterError as e:
            raise InputError("--verify", f"checks against Embree, which traces in float32, and "
                                         f"the scene is {e.problem}") from None
    if args.precision == "float32":     # with the remedy this command takes
        wider = args.accel == "bvh" and not embree and not args.verify
        check_float32_reach(scene, float64="add --precision float64" if wider else None)
    from hwbvh.builder import builds_in_parallel
    # a large mesh builds with the data-parallel kernels: loaded now, so that the build time
    # is the build's, not the compiler's
    large = args.accel == "bvh" and args.builder == "hwbvh" and \
        builds_in_parallel(len(scene.triangles))
    note_first_compile()
    startup_s = warm_up(args.builder, args.traversal, parallel_build=large,
                        precision=args.precision)
    if args.accel == "grid":
        from traversal.grid import warm_up_grid
        startup_s += warm_up_grid()
    elif args.accel == "kdtree":
        from traversal.kdtree import warm_up_kdtree
        startup_s += warm_up_kdtree()
    tracer, build_s, info = make_tracer(scene, args.builder, args.traversal,
                                        precision=args.precision, accel=args.accel)
    with progress_bar(scene.height, f"render {scene.name}", "row") as bar:
        t0 = time.perf_counter()
        res = render(scene, tracer, seed=args.seed, progress=bar.update)
        render_s = time.perf_counter() - t0
    checked = None
    if args.verify:
        with progress_bar(scene.height, f"verify {scene.name}", "row") as bar:
            checked = verified_render(scene, tracer, args.seed, res.image, progress=bar.update)
        if not checked[0]["same_image"]:
            _warn_other_image("the checked render")
    bvh = args.accel == "bvh"              # another structure has its own build and traversal
    result = {"output": out, "scene": scene.name, "accel": args.accel,
              "builder": args.builder if bvh else None, "traversal": args.traversal if bvh else None,
              "precision": args.precision,
              "triangles": int(len(scene.triangles)), "width": scene.width, "height": scene.height,
              "spp": scene.spp, "max_depth": scene.max_depth,
              "seed": args.seed, "jitter": bool(scene.jitter),
              "build_seconds": build_s, "render_seconds": render_s,
              "time_to_image_seconds": build_s + render_s,
              "simulated_build_seconds": info.get("simulated_build_seconds"),
              "startup_seconds": startup_s,
              "rays": res.stats["rays"],
              "passes": res.stats["passes"],
              "pixels_beyond_float32": res.stats["pixels_beyond_float32"]}
    result.update({k: v for k, v in info.items() if k in ("nodes", "sah_cost", "memory_bytes",
                                                           "references_per_triangle")})
    ready = simulated_ready_seconds(info)
    if ready:
        result["time_to_image_simulated_seconds"] = {k: v + render_s for k, v in ready.items()}
    if checked is not None:
        result["verify"], result["verify_seconds"] = checked
    meta = {"scene": scene.name, "accel": args.accel, "precision": args.precision,
            "build_seconds": build_s,
            "render_seconds": render_s, "spp": scene.spp, "max_depth": scene.max_depth,
            "seed": args.seed, "jitter": int(bool(scene.jitter))}
    if bvh:
        meta.update(builder=args.builder, traversal=args.traversal)
    meta.update({f"rays_{k}": v for k, v in res.stats["rays"].items()})
    files = [(out, exr_writer(out, res, meta, layers=not args.no_layers))]
    if png:
        files.append((png, png_writer(png, res.image)))
        result["png"] = png
    _commit(args, files)
    result["wall_seconds"] = time.perf_counter() - t_start
    _emit(args, result, lambda r: _kv(r, ["output", "png", "scene", "triangles", "build_seconds",
                                          "render_seconds", "time_to_image_seconds",
                                          "simulated_build_seconds", "rays", "verify",
                                          "verify_seconds"]))


def _warn_other_image(which):
    """One line on stderr: a render is deterministic, so a check that rendered another image
    than the timed render's did not check that render's queries."""
    print(f"hwrt: warning: {which} made another image than the timed render: its answers "
          f"were checked, the timed render's were not (the renderer is not deterministic here)",
          file=sys.stderr)


def cmd_animate(args):
    from . import animate
    result = animate.cmd_animate(args, commit=partial(_commit, args))
    if result.get("verify") and not result["verify"]["same_image"]:
        other = [str(r["frame"]) for r in result["frames"] if not r["verify"]["same_image"]]
        _warn_other_image(f"the checked render of frame{'s' if len(other) > 1 else ''} "
                          f"{', '.join(other)}")
    _emit(args, result, animate.human)


# What each benchmark measures, against which peer, and roughly how long it runs with its
# defaults (mesh benchmarks: on the shared meshes). The bench help lists them;
# `hwrt bench NAME --help` opens with one.
BENCHMARKS = {
    "build": ("build time of the hardware's binned SAH builder (run in software) against "
              "Embree's build, per mesh", "a minute or so"),
    "scale": ("build time of the hardware's builder from 10k to 2M generated triangles and the "
              "exponent of its growth, beside N log N's over the same range; no peer", "minutes"),
    "trace": ("rays per second of our traversal against embreex (and Open3D when installed) on "
              "the same primary, incoherent and shadow rays, per mesh", "minutes"),
    "render": ("time to image (build + render) of the hardware's tree and our traversal "
               "against Embree's build and traversal through the same renderer, and against "
               "Mitsuba 3 on mesh scenes; the render against tracing its rays alone, and its "
               "seconds per stage", "minutes"),
    "tti": ("time to image per scene of every path (simulated HWBVH-C and HWBVH-HP builds, the "
            "builder in software, the full-SAH sweep tree, grid, kd-tree) against Embree's, "
            "with the ray budgets up to which a hardware build stays ahead",
            "minutes; --quick: seconds"),
    "accuracy": ("what each accuracy knob (bins, leaf size, builder, precision, triangle test, "
                 "ray offset, depth, spp) costs in time and buys in image error against a "
                 "float64 reference, in hits that disagree with Embree's and in holes",
                 "minutes; --quick: under a minute"),
    "model": ("the cycle model's build times for HWBVH-C and HWBVH-HP against the thesis' "
              "published times, and the fit of its one calibrated constant", "minutes"),
    "contention": ("how much a busy competitor on every core slows our build + render, against "
                   "how much it slows Embree's, for each threading set-up", "minutes"),
    "trees": ("whether render time shows the tree: the full-SAH sweep tree against the "
              "hardware's, render and trace time against the work per ray, and where the "
              "render's time goes (queries by kind, other stages)", "minutes"),
    "animation": ("time to image per frame of every built-in animation: the hardware's rebuild, "
                  "refit and adaptive update against Embree's rebuild every frame (and the grid "
                  "and kd-tree rebuilt every frame)", "minutes"),
}

# The options each benchmark reads, with their defaults (None: see BENCH_NONE). Any other
# option given to a benchmark is an error, so that no option is silently ignored.
BENCH_OPTIONS = {
    "build": {"meshes": [], "mesh_dir": None, "repeat": 5, "out_dir": None},
    "scale": {"repeat": 3, "out_dir": None},
    "trace": {"meshes": [], "mesh_dir": None, "repeat": 5, "rays": 500_000, "out_dir": None,
              "accel": None},
    "render": {"meshes": [], "repeat": 5, "out_dir": None, "width": None, "height": None,
               "spp": None, "max_depth": None},
    "tti": {"meshes": [], "mesh_dir": None, "repeat": 5, "quick": False, "fresh": False,
            "out_dir": "renders/bench", "width": 320, "height": 240, "spp": 1, "max_depth": 5,
            "scheduler": None, "accel": None},
    "accuracy": {"meshes": [], "repeat": 3, "quick": False, "fresh": False,
                 "out_dir": "renders/bench", "width": 160, "height": 120, "scheduler": None},
    "model": {"meshes": [], "mesh_dir": None, "out_dir": None, "scheduler": None},
    "contention": {"meshes": [], "repeat": 5, "width": 320, "height": 240, "spp": 1, "out_dir": None},
    "trees": {"meshes": [], "repeat": 5, "width": None, "height": None, "spp": None, "out_dir": None},
    "animation": {"quick": False, "out_dir": "renders/bench", "width": 320, "height": 240, "spp": 1,
                  "max_depth": None, "frames": None, "accel": None},
}
BENCH_QUICK = {"tti": {"repeat": 1, "width": 160, "height": 120},     # --quick: small cells
               "accuracy": {"repeat": 1, "width": 64, "height": 48}}
BENCH_NONE = {"mesh_dir": "$HWRT_MESHES, else shared/meshes beside the project or the working "
                          "directory, if there, else generated meshes",
              "out_dir": "no files", "width": "the scene's", "height": "the scene's",
              "spp": "the scene's", "max_depth": "the scene's",
              "scheduler": None}        # filled in below, from BENCH_LOCAL_CLUSTER
BENCH_WRITES_OUT_DIR = ("tti", "accuracy")
BENCH_REPORTS = ("build", "scale", "trace", "contention", "trees")  # --out-dir: OUT/<what>.md, .json   # checked here; bench render checks its own files
# The benchmarks that write their own files (with --out-dir), the last set through ``commit``
BENCH_COMMITS = ("render", "tti", "accuracy", "animation", "model")


# The cell benchmarks' Dask cluster when no scheduler is given, and those that time their
# cells one at a time on one host
BENCH_LOCAL_CLUSTER = {"tti": "one worker with every core",
                       "accuracy": "one worker with every core", "model": "one worker per core"}
BENCH_TIMES_ONE_AT_A_TIME = ("tti", "accuracy")
DASK_HELP = "a running Dask scheduler, tcp://HOST:PORT, whose workers run the cells"


def _local_clusters():
    """--scheduler's default on bench's page: the local cluster of each cell benchmark."""
    clusters = {}
    for what, cluster in BENCH_LOCAL_CLUSTER.items():
        clusters.setdefault(cluster, []).append(what)
    return "$HWRT_SCHEDULER, else a local cluster: " + ", ".join(
        f"for {' and '.join(ws)} {c}" for c, ws in clusters.items())


BENCH_NONE["scheduler"] = _local_clusters()


def _scheduler_help(what):
    """--scheduler's help on the page of cell benchmark ``what``."""
    timed = ", timed one at a time on one host" if what in BENCH_TIMES_ONE_AT_A_TIME else ""
    return (f"{DASK_HELP}{timed} (default: $HWRT_SCHEDULER, else a local cluster of "
            f"{BENCH_LOCAL_CLUSTER[what]})")


def _frames_help(on_its_page=False):
    """--frames' help: on bench's page, or on bench animation's own."""
    from .config import BENCH_FRAMES, BENCH_QUICK_FRAMES
    reader = "" if on_its_page else "read by animation; "
    return (f"frames per animation ({reader}default: {BENCH_FRAMES}; with --quick: "
            f"{BENCH_QUICK_FRAMES})")


DEPTH_HELP = ("rays per path, the camera ray counted: 1 traces camera rays and their shadow "
              "rays, with no reflection or refraction; 2 adds one reflection or refraction")

BENCH_OPTION_HELP = {
    "mesh_dir": "directory of meshes", "repeat": "timed runs; figures are their medians",
    "rays": "rays per set",
    "quick": "a short run: tti and accuracy, a few small cells (tti seconds, accuracy under a "
             "minute); animation, fewer "
             "frames of fewer triangles",
    "fresh": "start over, ignoring finished cells", "out_dir": "where result files go",
    "scheduler": f"{DASK_HELP} ({' and '.join(BENCH_TIMES_ONE_AT_A_TIME)} time theirs one at "
                 "a time on one host)",
    "width": "image width", "height": "image height", "spp": "samples per pixel",
    "max_depth": DEPTH_HELP}


# What --quick does to each benchmark that reads it
BENCH_QUICK_HELP = {
    "tti": "a short run: the cornell scene and the smallest mesh, small cells, one run each "
           "(seconds)",
    "accuracy": "a short run: the cornell scene (and the meshes named), small cells, one run "
                "each, fewer rays checked (under a minute)",
    "animation": "a short run: fewer frames of fewer triangles"}

# The benchmarks whose MESH arguments may be scenes too (SCENE on their help pages)
BENCH_TAKES_SCENES = ("render", "trees", "contention")
# The MESH arguments of a benchmark (None: of those not listed)
BENCH_MESHES = {None: "mesh files (default: every mesh in --mesh-dir)",
                "accuracy": "mesh files studied beside the scenes cornell, marbles and cloth "
                            "(default: none)",
                "render": "scenes or mesh files (default: cornell)",
                "trees": "scenes or mesh files (default: cornell, marbles)",
                "contention": "one scene or mesh file (default: cornell)"}


# What --accel NAME adds to each benchmark that reads it
BENCH_ACCEL_HELP = {
    "trace": "also trace the ray sets with each, the BVH's own row as the others' reference "
             "(default: the BVH against its peers only)",
    "tti": "the structures timed beside the BVH paths, which are always timed (default: every "
           "one; bvh alone: none)",
    "animation": "the structures rebuilt every frame beside the BVH's strategies (default: "
                 "every one; bvh alone: none)"}


def _accel_help(what=None):
    """The help of bench's --accel: for benchmark ``what``, or for each that reads it."""
    from raytracer.render import ACCELS
    head = f"an acceleration structure ({', '.join(ACCELS)}); repeat the option for more"
    if what is not None:
        return f"{head}: {BENCH_ACCEL_HELP[what]}"
    return f"{head}. " + "; ".join(f"{w}: {t}" for w, t in BENCH_ACCEL_HELP.items())


def _bench_help(dest, what=None):
    """The help of a bench option: what it sets (BENCH_OPTION_HELP) and its default, for
    benchmark ``what`` or for each benchmark (BENCH_OPTIONS)."""
    text = BENCH_OPTION_HELP[dest]
    if what is not None and dest == "quick":
        return BENCH_QUICK_HELP[what]
    if what is not None:
        v = BENCH_OPTIONS[what][dest]
        if v is False:                                        # a flag
            return text
        shown = BENCH_NONE.get(dest, "none") if v is None else v
        quick = BENCH_QUICK.get(what, {}).get(dest)
        return f"{text} (default: {shown}{'' if quick is None else f'; with --quick: {quick}'})"
    groups = {}
    for name, opts in BENCH_OPTIONS.items():
        if dest in opts:
            v = opts[dest]
            shown = BENCH_NONE.get(dest, "none") if v is None else v
            groups.setdefault(str(shown), []).append(name)
    unused = [w for w, opts in BENCH_OPTIONS.items() if dest not in opts]
    if set(groups) == {"False"}:                              # a flag: who reads it
        return f"{text} (read by {', '.join(groups['False'])})"
    parts = ["; ".join(f"{', '.join(ws)}: {v}" for v, ws in groups.items())]
    quick = [f"{w} {q[dest]}" for w, q in BENCH_QUICK.items() if dest in q]
    if quick:
        parts.append("with --quick: " + ", ".join(quick))
    if unused:
        parts.append("not read by " + ", ".join(unused))
    return f"{text} (default: {'; '.join(parts)})"


def _bench_options(args):
    """Reject options the benchmark does not read; fill in the defaults of those it does."""
    from hwbvh.errors import InputError
    table = BENCH_OPTIONS[args.what]
    for dest in sorted(vars(args)):
        if dest in ("command", "func", "what", "json", "argv", "environment", "signals_owned") \
                or dest in table \
                or getattr(args, dest) in (None, False, []):
            continue
        if dest == "meshes":
            raise InputError(args.meshes[0], f"bench {args.what} takes no mesh files")
        raise InputError("--" + dest.replace("_", "-"), f"bench {args.what} does not read this option")
    twice = [a for k, a in enumerate(args.accel or []) if a in args.accel[:k]]
    if twice:
        raise InputError("--accel", f"{twice[0]} given twice")
    if args.what == "contention" and len(args.meshes) > 1:     # it measures one scene
        raise InputError(args.meshes[1], "bench contention takes one scene or mesh file")
    defaults = dict(table, **(BENCH_QUICK.get(args.what, {}) if args.quick else {}))
    for dest, default in defaults.items():
        if getattr(args, dest, None) is None:
            setattr(args, dest, default)


def cmd_bench(args):
    from hwbvh.files import check_output_dir, held_directory
    from . import study
    _bench_options(args)
    if args.what in BENCH_WRITES_OUT_DIR:
        check_output_dir(args.out_dir, study.output_names(args.what), inputs=args.meshes)
    if args.what in BENCH_REPORTS and args.out_dir:
        check_output_dir(args.out_dir, [f"{args.what}.md", f"{args.what}.json"], inputs=args.meshes)
    run, human = _bench_run(args.what)
    commit = partial(_commit, args)
    # a study keeps its cells in its output directory and resumes from them: a second run into
    # it meanwhile is refused, where the two would append to, or with --fresh replace, each
    # other's cells
    with held_directory(os.path.realpath(args.out_dir), f"bench {args.what}") \
            if args.what in BENCH_WRITES_OUT_DIR else contextlib.nullcontext():
        result = run(args, commit=commit)
    if args.what in BENCH_REPORTS and args.out_dir:
        result["files"] = _write_report(args, result, human, commit)
    _emit(args, result, partial(_with_files_line, human))


def _with_files_line(human, result):
    """``human(result)``, then the files the benchmark wrote, if any."""
    text = human(result)
    return text + "\nwrote " + ", ".join(result["files"]) if result.get("files") else text


def _bench_run(what):
    """(run, human) of benchmark ``what``: ``run(args, commit=)`` runs it, ``human(result)`` shows
    its result. Those in BENCH_COMMITS write their last set of files through ``commit``; the
    others write no file (their --out-dir report is written by :func:`_write_report`)."""
    from . import bench, study
    if what == "contention":
        from . import contention
        fn, human = contention.bench_contention, contention.human
    elif what == "trees":
        from . import trees
        fn, human = trees.bench_trees, trees.human
    elif what == "animation":
        from . import animate
        fn, human = animate.bench_animation, animate.human_bench
    else:
        fn = {"build": bench.bench_build, "scale": bench.bench_scale, "trace": bench.bench_trace,
              "render": bench.bench_render, "tti": study.bench_tti,
              "accuracy": study.bench_accuracy, "model": bench.bench_model}[what]
        human = bench.human(what)
    if what in BENCH_COMMITS:
        return fn, human
    return (lambda args, commit: fn(args)), human


def _write_report(args, result, human, commit):
    """OUT/<what>.md (the table and the command that made it) and OUT/<what>.json; returns
    their paths."""
    from hwbvh.files import json_text
    from .report import command_of, made_by_block
    md = (f"# hwrt bench {args.what}\n\n{made_by_block(command_of(args))}```text\n{human(result)}\n```\n")
    files = [(os.path.join(args.out_dir, f"{args.what}.md"), md),
             (os.path.join(args.out_dir, f"{args.what}.json"), json_text(result, indent=1) + "\n")]
    commit(files)
    return [path for path, _ in files]


# --------------------------------------------------------------------------------------
# The largest integer an option takes: counts and sizes reach the kernels as 32-bit or 64-bit
# integers, and none is meaningful beyond this.
MAX_OPTION_INT = (1 << 31) - 1
# Tighter limits where a larger value would only exhaust memory or the machine: rays per query
# set (traversal.config.MAX_RAYS), triangles of a generated animation (a tree holds 2^24),
# timed repeats. Local Dask workers: at most one per core (``hwrt.cluster.dask_client``). Frames
# of an animation: scenes.loader.MAX_FRAMES, which a scene file's animation.frames shares.
MAX_REPEAT = 1000


def _int_at_least(lo, hi=MAX_OPTION_INT, note=None):
    """An integer option in lo..hi. ``note`` (a str, may be empty): a value out of range is
    refused as "must be an integer in lo..hi<note>", the words the library uses for it
    (``hwbvh.builder.check_params``), else as "must be at least lo" / "at most hi"."""
    def parse(v):
        # digits only (Python's int() also takes "4_0" and " 5"); a number too long to convert
        # is beyond any limit
        if not re.fullmatch(r"[+-]?[0-9]+", v):
            from hwbvh.errors import shown
            raise argparse.ArgumentTypeError(f"expected an integer, got {shown(v)}")
        long = len(v.lstrip("+-")) >= 1000
        i = (hi + 1 if v[0] != "-" else lo - 1) if long else int(v)
        got = f"a number of {len(v.lstrip('+-'))} digits" if long else i
        if note is not None and not lo <= i <= hi:
            raise argparse.ArgumentTypeError(f"must be an integer in {lo}..{hi}{note}, got {got}")
        if i < lo:
            raise argparse.ArgumentTypeError(f"must be at least {lo}, got {got}")
        if i > hi:
            raise argparse.ArgumentTypeError(f"must be at most {hi}, got {got}")
        return i
    return parse


_positive = _int_at_least(1)
_non_negative = _int_at_least(0)


def _int_in(lo, hi, note=""):
    """An integer option in lo..hi, refused in the library's words (``_int_at_least``)."""
    return _int_at_least(lo, hi, note)


def _scene_limit(name):
    """An option that a scene limit bounds: 1 up to ``scenes.loader``'s ``name``."""
    def parse(v):
        from scenes import loader
        return _int_at_least(1, getattr(loader, name))(v)
    return parse


def _rays(v):
    """Rays of a generated query set: 1 up to ``traversal.config.MAX_RAYS``."""
    from traversal.config import MAX_RAYS
    return _int_at_least(1, MAX_RAYS)(v)


_film_side = _scene_limit("MAX_FILM_SIDE")
_spp = _scene_limit("MAX_SPP")
_depth = _scene_limit("MAX_DEPTH")
_frames = _scene_limit("MAX_FRAMES")


def _fps(v):
    from scenes.config import MAX_FPS, MIN_FPS
    return _float_within(MIN_FPS, MAX_FPS)(v)


def _path(v):
    """A path (or address) argument's value: not empty (an empty one would silently mean the
    current directory, no file at all, or the default) and without NUL bytes."""
    if not v:
        raise argparse.ArgumentTypeError("expected a value, got an empty one")
    if "\0" in v:
        raise argparse.ArgumentTypeError(f"a path cannot hold a NUL byte, got {v!r}")
    return v


def _float_within(lo, hi):
    """A number in [lo, hi], with the range in the message whichever side it falls off."""
    def parse(v):
        try:
            x = float(v)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {v!r}") from None
        if not lo <= x <= hi:                       # NaN too
            raise argparse.ArgumentTypeError(f"must lie in {lo:g}..{hi:g}, got {v}")
        return x
    return parse


def _positive_float(v):
    try:
        x = float(v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {v!r}") from None
    if not (x > 0 and x < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {v}")
    return x


class _HelpFormatter(argparse.HelpFormatter):
    """Shows each option's default after its help, unless the help already gives it."""

    def _get_help_string(self, action):
        text = action.help or ""
        if (not action.option_strings or action.default is None or action.default is False
                or action.default == argparse.SUPPRESS or "default" in text):
            return text
        shown = " ".join(map(str, action.default)) if isinstance(action.default, list) else "%(default)s"
        return f"{text} (default: {shown})"


class _ListFormatter(_HelpFormatter):
    """Also keeps a description's or epilog's lines: a line that starts with two spaces is an
    item of a list, "  NAME TEXT", its TEXT filled beside NAME's column."""

    NAME_COLUMN = 14

    def _fill_text(self, text, width, indent):
        import textwrap
        lines = []
        for line in text.split("\n"):
            if line.startswith("  "):
                name, _, rest = line.strip().partition(" ")
                head = f"{indent}  {name:<{self.NAME_COLUMN - 2}}"
                lines.append(textwrap.fill(rest, width, initial_indent=head,
                                           subsequent_indent=" " * len(head)))
            else:
                lines.append(super()._fill_text(line, width, indent))
        return "\n".join(lines)


class _BenchHelp(argparse._HelpAction):
    """-h/--help of ``hwrt bench``: after a benchmark's name, that benchmark's page (what it
    measures, against which peer, about how long it runs, and only the options it reads, with
    its defaults); else the page of every benchmark."""

    def __call__(self, parser, namespace, values, option_string=None):
        what = getattr(namespace, "what", None)
        if what is None:
            parser.print_help()
        else:
            parser._print_message(_bench_page(parser, what), sys.stdout)
        parser.exit()


def _bench_page(parser, what):
    """The help page of ``hwrt bench WHAT``, from ``parser`` (bench's): its description from
    BENCHMARKS, the options it reads (BENCH_OPTIONS) with their defaults for it."""
    import copy
    text, duration = BENCHMARKS[what]
    page = _Parser(prog=f"{parser.prog} {what}", add_help=False,
                   description=f"{text[0].upper()}{text[1:]}. Runs for {duration}. An option "
                               f"not listed here is an error.")
    reads = set(BENCH_OPTIONS[what]) | {"json"}
    # where bench's own page speaks of several benchmarks, this one's words
    own = {"scheduler": lambda: _scheduler_help(what), "frames": lambda: _frames_help(True)}
    for action in parser._actions:
        if not (isinstance(action, argparse._HelpAction) or action.dest in reads):
            continue
        if action.dest in BENCH_OPTION_HELP or action.dest in ("meshes", "accel", "frames"):
            action = copy.copy(action)
            if action.dest == "meshes":
                action.help = BENCH_MESHES.get(what, BENCH_MESHES[None])
                if what in BENCH_TAKES_SCENES:
                    action.metavar = "SCENE"
            elif action.dest == "accel":
                action.help = _accel_help(what)
            elif action.dest in own:
                action.help = own[action.dest]()
            else:
                action.help = _bench_help(action.dest, what)
        page._add_action(action)
    return page.format_help()


class _Parser(argparse.ArgumentParser):
    """Usage errors in one line naming the option, exit status 2; defaults shown in --help."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _HelpFormatter)
        kwargs.setdefault("allow_abbrev", False)    # --wid is no --width: options are spelled out
        super().__init__(*args, **kwargs)

    def error(self, message):
        # as every other error is written: "hwrt: error: --w: must be ...", the option first
        if message.startswith("argument "):
            message = message[len("argument "):]
        self.exit(EXIT_BAD_INPUT, f"hwrt: error: {one_line(message)}\n")

    def _print_message(self, message, file=None):
        # --help and --version as every result is written: all of it, or 141 for a reader
        # gone and one line for a full disk (_run), never a silent 0
        if message and (file is None or file is sys.stdout):
            _write_stdout(message)
        else:
            super()._print_message(message, file)


def _version():
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("hwrt")
    except PackageNotFoundError:
        return "unknown (not installed)"


SEED_HELP = f"seed of the pixel jitter, 0-{MAX_OPTION_INT}"


def make_parser():
    from hwbvh import config
    from hwbvh.api import BUILDERS
    from hwbvh.cycle_model import PRESETS
    from raytracer.render import ACCELS, PRECISIONS, TRAVERSALS
    from scenes.loader import MAX_DEPTH, MAX_FILM_PIXELS, MAX_FILM_SIDE, MAX_SPP
    from traversal.verify import RAY_KINDS
    film = f"1-{MAX_FILM_SIDE}, width x height at most {MAX_FILM_PIXELS:,}"
    spp = f"1-{MAX_SPP}"
    depth = f"{DEPTH_HELP}; 1-{MAX_DEPTH}"
    p = _Parser(prog="hwrt", description=DESCRIPTION, epilog=EPILOG)
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    b = sub.add_parser("build", help="build a BVH over a mesh",
                       description="Build a BVH over a mesh in the hardware's node format.")
    b.add_argument("mesh", type=_path, help="mesh file (.ply, .obj, .stl, .off, .glb, .gltf)")
    b.add_argument("--builder", choices=[*BUILDERS, "embree"], default="hwbvh",
                   help="hwbvh: the hardware's binned SAH; sweep: full SAH reference; "
                        "embree: Embree's own build (timing only)")
    # defaults None: an option a builder does not read is refused only when given
    b.add_argument("--leaf-size", type=_int_in(1, config.MAX_LEAF_SIZE),
                   help=f"primitives per leaf, hwbvh only: 1..{config.MAX_LEAF_SIZE} (default: "
                        f"{config.DEFAULT_LEAF_SIZE})")
    b.add_argument("--bins", type=_int_in(config.MIN_BINS, config.MAX_SOFTWARE_BINS,
                                          f" (the hardware has at most "
                                          f"{config.MAX_HARDWARE_BINS})"),
                   help=f"SAH bins per axis, hwbvh only: {config.MIN_BINS}.."
                        f"{config.MAX_SOFTWARE_BINS} (the hardware has at most "
                        f"{config.MAX_HARDWARE_BINS}, so a tree built with more cannot be "
                        f"simulated; default: {config.DEFAULT_BINS})")
    b.add_argument("--capacity", type=_positive,
                   help=f"subtree capacity w*Psize, at least the leaf size; placement only (the "
                        f"tree never changes); hwbvh and sweep (default: {config.DEFAULT_CAPACITY})")
    b.add_argument("--subtree-builders", type=_int_in(*config.LAYOUT_KNOB_RANGES["subtree_builders"]),
                   help=f"subtree builders, placement only; hwbvh and sweep: "
                        f"1..{config.LAYOUT_KNOB_RANGES['subtree_builders'][1]} (default: 1)")
    b.add_argument("--block-nodes", type=_int_in(*config.LAYOUT_KNOB_RANGES["block_nodes"]),
                   help=f"nodes per block of the upper builder's pool, placement only; hwbvh "
                        f"and sweep: {'..'.join(map(str, config.LAYOUT_KNOB_RANGES['block_nodes']))} "
                        f"(default: {config.DEFAULT_BLOCK_NODES})")
    b.add_argument("-o", "--out", metavar="PREFIX", type=_path,
                   help="write PREFIX.nodes, PREFIX.indices and PREFIX.json; a PREFIX ending in "
                        "one of them names the same three (default: no files)")
    b.add_argument("--dump-aabbs", metavar="F", type=_path,
                   help="write the 27-byte primitive records as the hardware reads them")
    b.add_argument("--dump-handoff", metavar="F", type=_path,
                   help="write the records in upper-builder hand-off order, sizes in F.json")
    b.add_argument("--json", action="store_true", help="print one JSON object")
    b.set_defaults(func=cmd_build)

    s = sub.add_parser("simulate", help="cycles, traffic, footprint and energy of the hardware build",
                       description="Simulate the hardware build of a mesh on one of the thesis' "
                                   "instances (HWBVH-C or HWBVH-HP, or one with its knobs "
                                   "changed): cycles, seconds, DRAM traffic, memory footprint, "
                                   "energy, area and utilisation, from the cycle model.")
    s.add_argument("mesh", type=_path, help="mesh file")
    s.add_argument("--preset", default="HWBVH-C", choices=list(PRESETS),
                   help="the thesis' hardware instance")
    for name, text in (("w", "partitioning units per subtree builder"),
                       ("tsize", "threads per subtree builder"),
                       ("psize", "primitives per buffer, with w * psize (the subtree capacity) "
                                 f"at most {config.MAX_PRIMITIVES} and at least the leaf size"),
                       ("subtree-builders", "subtree builders"), ("ram-pairs", "DRAM channel pairs"),
                       ("leaf-size", "primitives per leaf"), ("bins", "SAH bins per axis")):
        lo, hi = config.KNOB_RANGES[name.replace("-", "_")]
        power = ", a power of two" if name in config.POWER_OF_TWO_KNOBS else ""
        s.add_argument(f"--{name}", type=_int_at_least(lo, hi),
                       help=f"{text}: {lo}..{hi}{power} (default: the preset's)")
    lo, hi = config.KNOB_RANGES["clock_mhz"]
    s.add_argument("--clock-mhz", type=_float_within(lo, hi),
                   help=f"clock: {lo:g}..{hi:g} MHz (default: the preset's)")
    s.add_argument("--control-latency", type=_int_at_least(0, config.MAX_CONTROL_LATENCY),
                   metavar="CYCLES",
                   help=f"control cycles per split beyond Table 3.3: 0..{config.MAX_CONTROL_LATENCY} "
                        f"(default: the calibrated value, {config.CONTROL_LATENCY}; 0 = the "
                        f"text-only model)")
    s.add_argument("--json", action="store_true", help="print one JSON object")
    s.set_defaults(func=cmd_simulate)

    x = sub.add_parser("explore", help="design-space exploration: time, energy and area of every "
                                       "configuration of a grid on every mesh, Pareto fronts",
                       description="Simulate every configuration of a grid of hardware knobs on "
                                   "every mesh (knobs not in the grid stay at HWBVH-C's value), "
                                   "with each configuration's own area and power; write the rows, "
                                   "the Pareto fronts of time and energy against area, and plots. "
                                   "Cells run on Dask and resume after an interruption.")
    x.add_argument("meshes", nargs="+", metavar="MESH", type=_path, help="mesh files")
    x.add_argument("--grid", action="append", metavar="KNOB=V1,V2,...",
                   help="values of one knob (bins, leaf_size, w, tsize, psize, subtree_builders, "
                        "ram_pairs, clock_mhz); repeat for more knobs (default: a grid over w, "
                        "tsize, psize, subtree_builders, ram_pairs, clock_mhz and leaf_size)")
    x.add_argument("--scheduler", metavar="ADDRESS", type=_path,
                   help="a running Dask scheduler, tcp://HOST:PORT (default: $HWRT_SCHEDULER, "
                        "else a local cluster of one worker per core)")
    x.add_argument("--workers", type=_int_at_least(1, MAX_OPTION_INT),
                   help="workers of the local cluster, at most one per core (default: one per "
                        "core)")
    x.add_argument("--out-dir", default="renders/explore", type=_path, help="where the files and the "
                                                                "resumable cells go")
    x.add_argument("--fresh", action="store_true", help="ignore finished cells")
    x.add_argument("--json", action="store_true", help="print one JSON object")
    x.set_defaults(func=cmd_explore)

    r = sub.add_parser("render", help="render a scene (Whitted) to EXR",
                       description="Render a scene with the Whitted ray tracer to an EXR file.")
    r.add_argument("scene", nargs="?", default="cornell", type=_path,
                   help="built-in scene (cornell, marbles, cloth, room), scene file (.json, "
                        ".toml), or mesh file (default: cornell)")
    r.add_argument("-o", "--output", metavar="FILE.exr", type=_path,
                   help="EXR path (default: renders/<scene>.exr)")
    r.add_argument("--width", type=_film_side, help=f"image width, {film} (default: the scene's)")
    r.add_argument("--height", type=_film_side, help=f"image height, {film} (default: the scene's)")
    r.add_argument("--spp", type=_spp, help=f"samples per pixel, {spp} (default: the scene's)")
    r.add_argument("--max-depth", type=_depth, help=f"{depth} (default: the scene's)")
    r.add_argument("--builder", choices=[*BUILDERS, "embree"],
                   help="the tree: hwbvh (the hardware's), sweep (full SAH) or embree (default: "
                        "hwbvh; embree with --traversal embree)")
    r.add_argument("--traversal", choices=TRAVERSALS,
                   help="numba: our units on the raw nodes; embree: Embree on its own tree "
                        "(default: numba; embree with --builder embree)")
    r.add_argument("--accel", choices=ACCELS, default="bvh",
                   help="acceleration structure: bvh (built by --builder), grid (uniform grid) "
                        "or kdtree (SAH kd-tree)")
    r.add_argument("--precision", choices=PRECISIONS, default="float32",
                   help="working precision of our traversal's units: float32 (the hardware's) "
                        "or float64 (for a scene too large or too small for float32)")
    r.add_argument("--verify", action="store_true",
                   help="render again with every ray checked against Embree (its time reported "
                        "apart, as verify_seconds; a warning if that render's image differs)")
    r.add_argument("--png", action="store_true",
                   help="also write a tone-mapped PNG preview beside the EXR")
    r.add_argument("--no-layers", action="store_true", help="RGB only (no Z, N, prim.id)")
    r.add_argument("--seed", type=_non_negative, default=0, help=SEED_HELP)
    r.add_argument("--json", action="store_true", help="print one JSON object")
    r.set_defaults(func=cmd_render)

    v = sub.add_parser("verify", help="trace rays with our units and with Embree; classify each",
                       description="Trace a set of rays through our traversal and through Intel "
                                   "Embree on the same scene or mesh and classify each ray: "
                                   "agree, tie (both answers right by a float64 re-test, as on a "
                                   "shared edge) or mismatch. Mismatching rays go to a file "
                                   "that --replay traces again.")
    v.add_argument("scene", type=_path, help="built-in scene name, scene file, or mesh file")
    v.add_argument("--rays", type=_rays,
                   help=f"rays to trace (default: {VERIFY_RAYS}); a kind made from the first "
                        f"rays' hits traces fewer where too few of them hit, and says so")
    v.add_argument("--kind", choices=RAY_KINDS,
                   help=f"the ray set; shadow rays are checked as occluded queries, the "
                        f"others as closest hits (default: {VERIFY_KIND})")
    v.add_argument("--mismatches", metavar="F.npz", type=_path,
                   help="where mismatching rays are written (default: "
                        "renders/verify-<scene>-<kind>-mismatches.npz, with -<accel> before "
                        "-mismatches for grid and kdtree; only if there are any)")
    v.add_argument("--accel", choices=ACCELS,
                   help="acceleration structure checked: bvh (hwbvh's tree), grid (uniform grid) "
                        "or kdtree (SAH kd-tree) (default: bvh)")
    v.add_argument("--replay", metavar="F.npz", type=_path,
                   help="re-trace the rays of a mismatch file instead, with the ray set's "
                        "query and the structure the file records; refused where the file "
                        "records other triangles than the scene's (default: a new run)")
    v.add_argument("--json", action="store_true", help="print one JSON object")
    v.set_defaults(func=cmd_verify)

    an = sub.add_parser("animate", help="render an animation, a tree per frame, one EXR per frame",
                        description="Render an animated scene frame by frame, updating the tree "
                                    "each frame by the chosen strategy; one EXR per frame, a GIF "
                                    "preview and a CSV in the output directory. A rerun into the "
                                    "same directory resumes at the first frame missing or damaged.")
    an.add_argument("scene", type=_path, help="built-in animation (exploding, cloth, marbles, flythrough), "
                                  "scene file, or frame pattern of mesh files ('f_%%04d.ply' or a glob)")
    an.add_argument("--frames", type=_frames,
                    help="frames to render (default: the animation's)")
    an.add_argument("--fps", type=_fps,
                    help="frames per second of animation time (default: the animation's, else 30)")
    from .animate import STRATEGIES
    an.add_argument("--strategy", default="rebuild", metavar="{" + ",".join(STRATEGIES) + "}",
                    help="tree update per frame: rebuild, refit, adaptive or embree (refit, "
                         "adaptive and embree update a BVH; other --accel structures rebuild)")
    an.add_argument("--accel", choices=ACCELS, default="bvh",
                    help="acceleration structure: bvh (updated by --strategy) or another, "
                         "rebuilt every frame")
    from scenes.config import GENERATED_TRIANGLES
    from .config import ADAPTIVE_THRESHOLD
    an.add_argument("--threshold", type=_positive_float,
                    help="adaptive: rebuild when the SAH cost grows past this factor of the last "
                         f"rebuild's (default: {ADAPTIVE_THRESHOLD})")
    an.add_argument("--width", type=_film_side,
                    help=f"image width, {film} (default: the animation's)")
    an.add_argument("--height", type=_film_side,
                    help=f"image height, {film} (default: the animation's)")
    an.add_argument("--spp", type=_spp, help=f"samples per pixel, {spp} (default: the animation's)")
    an.add_argument("--max-depth", type=_depth, help=f"{depth} (default: the animation's)")
    an.add_argument("--mesh", type=_path, help="exploding: the mesh that breaks (default: the bunny of the mesh "
                                   "directory, $HWRT_MESHES, else shared/meshes beside the project "
                                   "or the working directory; without either, a generated sphere)")
    an.add_argument("--triangles", type=_int_at_least(1, config.MAX_PRIMITIVES),
                    help="exploding (generated sphere) and cloth: about this many triangles "
                         f"(default: {GENERATED_TRIANGLES})")
    an.add_argument("--physics", help="marbles: pybullet, analytic or auto (default: auto)")
    an.add_argument("--verify", action="store_true",
                    help="render each frame again with every ray (closest hits and shadows) "
                         "checked against Embree (its time reported apart)")
    an.add_argument("--seed", type=_non_negative, default=0, help=SEED_HELP)
    an.add_argument("-o", "--output", metavar="DIR", type=_path,
                    help="output directory (default: renders/animate-<scene>-<strategy>; with "
                         "--accel grid or kdtree, renders/animate-<scene>-<accel>)")
    an.add_argument("--fresh", action="store_true",
                    help="start over: remove an earlier run's frames, CSV, preview and state from "
                         "the output directory instead of resuming it (whatever its settings)")
    an.add_argument("--json", action="store_true", help="print one JSON object")
    an.set_defaults(func=cmd_animate)

    be = sub.add_parser("bench", help="benchmarks against peers measured in the same run",
                        description="Benchmarks: each figure is a median of warm runs, beside "
                                    "a peer measured in the same run (scale: beside N log N). An "
                                    "option a benchmark does not read is an error.",
                        epilog="Benchmarks (hwrt bench BENCHMARK --help: what it reads):\n"
                               + "\n".join(f"  {name} {text} ({duration})"
                                           for name, (text, duration) in BENCHMARKS.items()),
                        formatter_class=_ListFormatter, add_help=False)
    be.add_argument("-h", "--help", action=_BenchHelp,
                    help="show this help message (after a benchmark's name: its own) and exit")
    be.add_argument("what", metavar="BENCHMARK", choices=list(BENCHMARKS),
                    help=f"the benchmark: {', '.join(BENCHMARKS)} (see below)")
    be.add_argument("meshes", nargs="*", default=[], metavar="MESH", type=_path,
                    help=f"{BENCH_MESHES[None]}; " + "; ".join(
                        f"{what}: {text}" for what, text in BENCH_MESHES.items() if what))
    be.add_argument("--mesh-dir", type=_path, help=_bench_help("mesh_dir"))
    be.add_argument("--repeat", type=_int_at_least(1, MAX_REPEAT),
                    help=_bench_help("repeat"))
    be.add_argument("--rays", type=_rays,
                    help=_bench_help("rays"))
    be.add_argument("--quick", action="store_true",
                    help=_bench_help("quick"))
    be.add_argument("--fresh", action="store_true",
                    help=_bench_help("fresh"))
    be.add_argument("--out-dir", type=_path, help=_bench_help("out_dir"))
    be.add_argument("--scheduler", metavar="ADDRESS", type=_path,
                    help=_bench_help("scheduler"))
    be.add_argument("--width", type=_film_side, help=_bench_help("width"))
    be.add_argument("--height", type=_film_side, help=_bench_help("height"))
    be.add_argument("--spp", type=_spp, help=_bench_help("spp"))
    be.add_argument("--max-depth", type=_depth,
                    help=_bench_help("max_depth"))
    be.add_argument("--accel", action="append", choices=ACCELS, metavar="NAME",
                    help=_accel_help())
    be.add_argument("--frames", type=_frames, help=_frames_help())
    be.add_argument("--json", action="store_true", help="print one JSON object")
    be.set_defaults(func=cmd_bench)
    return p


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Python runs next, so that it unwinds like Ctrl-C: writers in
    progress remove their temporary files."""


# The signals ignored when the run began (``_main``), which stay ignored: a shell's background
# job ignores SIGINT, so that a ^C meant for the foreground does not stop it, and Python itself
# leaves it so.
_ignored_on_entry = set()


def _set_handlers(interrupt, terminate):
    """SIGINT's and SIGTERM's handlers, where Python set them (a handler set outside Python
    stays, and so does a signal ignored when the run began)."""
    for sig, handler in ((signal.SIGINT, interrupt), (signal.SIGTERM, terminate)):
        if signal.getsignal(sig) is not None and sig not in _ignored_on_entry:
            signal.signal(sig, handler)


def _drop_one(signum, frame):
    """The signal after the one that stopped the run: dropped, since it lands while the run
    unwinds and removes its temporary files, where it would leave a file behind and a
    traceback. The one after it stops the process again (a clean-up that hangs, a library
    that swallowed the first)."""
    _set_handlers(_raise_interrupted, _raise_terminated)


def _raise_interrupted(signum, frame):
    """SIGINT: the run stops (KeyboardInterrupt); the next signal is dropped (``_drop_one``)."""
    _set_handlers(_drop_one, _drop_one)
    _signal_raised[0] = KeyboardInterrupt
    raise KeyboardInterrupt()


def _raise_terminated(signum, frame):
    """SIGTERM: as SIGINT (``_raise_interrupted``), raising Terminated."""
    _set_handlers(_drop_one, _drop_one)
    _signal_raised[0] = Terminated
    raise Terminated()


def _option_of(parser, args, parameter):
    """The option of the running subcommand that sets the library parameter ``parameter``."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            command = action.choices.get(getattr(args, "command", None))
            for a in (command._actions if command else ()):
                if a.dest == parameter and a.option_strings:
                    return max(a.option_strings, key=len)
    return None


# The options that name outputs: an error about an output path names the output option given
# that path, though an input option may hold the same one (animate --mesh a.ply -o a.ply)
OUTPUT_DESTS = ("output", "out", "out_dir", "dump_aabbs", "dump_handoff", "mismatches")


def _option_valued(parser, args, value, output=False):
    """The option of the running subcommand given as ``value`` (a path an error names), or None;
    an output option first when ``output`` (the error is about an output path)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            command = action.choices.get(getattr(args, "command", None))
            found = [a for a in (command._actions if command else ())
                     if a.option_strings and isinstance(getattr(args, a.dest, None), str)
                     and getattr(args, a.dest) == value]
            found.sort(key=lambda a: not (output and a.dest in OUTPUT_DESTS))
            if found:
                return max(found[0].option_strings, key=len)
    return None


def one_line(text):
    """``text`` as one line of a terminal: each character that would break the line or move
    the cursor (a newline in a file's name, a carriage return, any other control character
    or line separator) written as its escape, as Python writes it in a string."""
    return "".join(c if c.isprintable() or c == " " else repr(c)[1:-1] for c in text)


def _input_message(parser, args, e):
    """The line of InputError ``e``, naming what the user typed: the option that sets a
    library parameter, or whose value (a path) the error names; for a film too large
    (width x height), every film size option given, since together they set it."""
    from hwbvh.errors import ParameterError
    if isinstance(e, ParameterError):
        from scenes.loader import FILM_TOO_LARGE
        if e.parameter in ("width", "height") and e.problem.endswith(FILM_TOO_LARGE):
            given = [d for d in ("width", "height") if getattr(args, d, None) is not None]
            if given:
                return " ".join(f"--{d} {getattr(args, d)}" for d in given) + f": {e.problem}"
        # an option that sets the parameter, else a positional argument of its name (the
        # scene, the mesh): what the user typed
        given = getattr(args, e.parameter, None) if e.parameter in ("scene", "mesh") else None
        named = _option_of(parser, args, e.parameter) or \
            (given if isinstance(given, str) else e.parameter)
        return f"{named}: {e.problem}"
    from hwbvh.files import OutputPathError
    option = _option_valued(parser, args, e.source, output=isinstance(e, OutputPathError))
    return f"{option} {e.source}: {e.problem}" if option else str(e)


def _late_meshes(parser, extra):
    """A benchmark's mesh arguments that argparse left over (``extra``, after its options):
    checked as the MESH argument checks them; an option among them is unrecognised."""
    options = [x for x in extra if x.startswith("-") and x != "--"]
    if options:
        parser.error(f"unrecognized arguments: {' '.join(options)}")
    try:
        return [_path(x) for x in extra if x != "--"]
    except argparse.ArgumentTypeError as e:
        parser.error(f"argument MESH: {e}")


# The environment variables that set how a run's kernels use the machine: a benchmark's page
# records those given, as its figures depend on them (``bench contention`` measures how much)
THREADING_ENVS = ("HWRT_THREADING", "NUMBA_NUM_THREADS", "NUMBA_THREADING_LAYER")


def _environment_read(args):
    """The environment variables a benchmark's results depend on beyond its command line, for
    the command its page records: those of ``THREADING_ENVS`` that are set, and $HWRT_MESHES
    where it supplies the meshes (a benchmark given no meshes and no --mesh-dir, or the
    animation benchmark's exploding bunny, but for --quick's)."""
    from .paths import MESH_DIR_ENV

    if args.command != "bench":
        return {}
    read = {k: os.environ[k] for k in THREADING_ENVS if os.environ.get(k)}
    value = os.environ.get(MESH_DIR_ENV)
    reads = BENCH_OPTIONS.get(args.what, {})
    # --quick's exploding animation explodes a generated sphere, not the directory's bunny
    from_dir = (args.what == "animation" and not args.quick) or (
        "mesh_dir" in reads and getattr(args, "mesh_dir", None) is None
        and not getattr(args, "meshes", None))
    if value and from_dir:
        read[MESH_DIR_ENV] = value
    return read


def _numba_threads_problem():
    """Why Numba's own $NUMBA_NUM_THREADS cannot be taken, or None: Numba reads it as it is
    imported, which fails with a traceback on 0 and warns at length on a word. Checked before
    anything imports Numba."""
    value = os.environ.get("NUMBA_NUM_THREADS")
    if value is not None and not re.fullmatch(r"\s*0*[1-9][0-9]{0,8}\s*", value):
        text = repr(value) if len(value) <= 20 else repr(value[:17]) + "..."   # no hwbvh yet
        return f"$NUMBA_NUM_THREADS: {text} is not a positive whole number of threads"
    return None


def _run(argv, signals_owned):
    """Parse ``argv`` and run its command; the exit status. Interrupts go to the caller."""
    problem = _numba_threads_problem()
    if problem:
        print(f"hwrt: error: {one_line(problem)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    from hwbvh.errors import InputError
    from hwbvh.files import OutputError
    from hwbvh.parallel import check_threading
    parser = make_parser()
    args = None
    try:
        args, extra = parser.parse_known_args(argv)
        if args.command == "bench" and extra:
            # argparse gives a benchmark's meshes the empty list where options come between
            # its name and them ("bench tti --quick MESH"); they are meshes all the same
            args.meshes = args.meshes + _late_meshes(parser, extra)
        elif extra:
            from .explore import KNOBS
            knobs = [x for x in extra if x.split("=", 1)[0] in KNOBS and "=" in x]
            hint = (f" (one knob per --grid: --grid {' --grid '.join(knobs)})"
                    if args.command == "explore" and knobs else "")
            parser.error(f"unrecognized arguments: {' '.join(extra)}{hint}")
        args.argv = argv
        args.environment = _environment_read(args)
        args.signals_owned = signals_owned
        for name in (PROGRESS_ENV, DEBUG_ENV):
            if env_flag(name) is None:
                raise InputError(f"${name}", f"unknown value {os.environ[name]!r} (choose 1 or 0; "
                                             f"true/false, yes/no and on/off are taken too)")
        check_threading()
        if sys.stdout is None:          # closed by the caller (``>&-``): found before the work
            raise InputError("<standard output>", "is closed: give the command somewhere to "
                                                  "print (>/dev/null drops what it prints)")
        args.func(args)
        _answer_swallowed_signal()
    except InputError as e:
        _answer_swallowed_signal()
        print(f"hwrt: error: {one_line(_input_message(parser, args, e))}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:
        # as a command killed by SIGPIPE would end, silently; stdout goes nowhere from here, so
        # that the interpreter's last flush cannot fail again
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError):       # stdout is not a file (called in-process)
            pass
        return EXIT_SIGPIPE
    except OutputError as e:      # checked writable, then not writable: the disk, not us
        _answer_swallowed_signal()
        print(one_line(f"hwrt: cannot write {e.filename}: {e.strerror}"), file=sys.stderr)
        return 1
    except Exception as e:  # anything else is our fault, not the input's
        _answer_swallowed_signal()       # or a library's that swallowed an interrupt
        print(one_line(f"hwrt: internal error: {type(e).__name__}: {e}"), file=sys.stderr)
        if env_flag(DEBUG_ENV) is not False:       # on, or a word _run refused (in-process use)
            raise
        return 1
    return 0


def _main(argv, last_act):
    argv = sys.argv[1:] if argv is None else list(argv)
    _signal_raised[0] = None
    try:
        previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
        _ignored_on_entry.clear()
        _ignored_on_entry.update(sig for sig, h in previous.items() if h is signal.SIG_IGN)
        _set_handlers(_raise_interrupted, _raise_terminated)
    except ValueError:                        # not the main thread: leave signals alone
        previous = None
    status = None
    hook = sys.unraisablehook
    if previous is not None:
        sys.unraisablehook = _quiet_swallowed_signal
    try:
        status = _run(argv, signals_owned=previous is not None)
        return status
    except Terminated:
        status = EXIT_SIGTERM
        print("hwrt: terminated", file=sys.stderr)
        return status
    except KeyboardInterrupt:
        status = EXIT_SIGINT
        print("hwrt: interrupted", file=sys.stderr)
        return status
    finally:
        sys.unraisablehook = hook
        # a run that succeeded ignores the signals from _succeeded on; as the process's last
        # act, a run that ended at all ignores them through the interpreter's exit (a signal
        # then would end it with a traceback from its shutdown, or by the signal itself once
        # Python has given the default actions back)
        if last_act and status is not None and previous is not None:
            _set_handlers(signal.SIG_IGN, signal.SIG_IGN)
        else:
            for sig, handler in (previous or {}).items():
                if handler is not None:        # None: set outside Python, never changed here
                    signal.signal(sig, handler)


def main(argv=None):
    """Run the command line ``argv`` (default: this process's arguments); its exit status.
    The signal handlers it sets are put back as it returns, so it can be called in-process;
    the console script is :func:`run`."""
    return _main(argv, last_act=False)


def run():
    """The console script ``hwrt`` (and ``python -m hwrt``): :func:`main` as the process's last
    act. Once the run has succeeded, SIGINT and SIGTERM stay ignored until the interpreter has
    exited (flushing stdout and unloading the libraries takes tenths of a second), so that a
    signal then cannot turn the success into 130 or 143; a run that a signal stopped, or that
    failed, ignores them from its last line on too."""
    sys.exit(_main(None, last_act=True))


if __name__ == "__main__":
    run()
