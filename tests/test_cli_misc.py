"""Smoke tests of the narrated example and the benchmarks' plumbing; slow scale runs; a mesh
file's input errors at the command line."""
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hwbvh.errors import InputError
from hwbvh.parallel import usable_cores

ROOT = Path(__file__).resolve().parents[1]


def test_narrated_example_writes_an_exr(tmp_path):
    r = subprocess.run([sys.executable, str(ROOT / "examples" / "narrated.py")], cwd=tmp_path,
                       capture_output=True, text=True, timeout=600,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 0, r.stderr
    from raytracer.output import read_exr
    px, names, _ = read_exr(tmp_path / "renders" / "narrated.exr")
    assert px.shape == (240, 320, 8) and px[..., 0].max() > 0.05


def test_bench_build_on_generated_meshes_prints_ratios(tmp_path):
    import trimesh
    from scenes.meshes import sphere
    tris = sphere(20, 40)
    p = tmp_path / "s.ply"
    trimesh.Trimesh(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3), process=False).export(p)
    r = subprocess.run([sys.executable, "-m", "hwrt.cli", "bench", "build", str(p), "--repeat", "1", "--json"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    row = json.loads(r.stdout)["meshes"][0]
    assert row["triangles"] == len(tris)
    assert row["ratio"] == pytest.approx(row["hwbvh_seconds"] / row["embree_seconds"])


def test_bench_trace_prints_throughput_and_ratios(tmp_path):
    import trimesh
    from scenes.meshes import bumpy_sphere
    tris = bumpy_sphere(4000)
    p = tmp_path / "b.ply"
    trimesh.Trimesh(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3), process=False).export(p)
    r = subprocess.run([sys.executable, "-m", "hwrt.cli", "bench", "trace", str(p), "--rays", "3000",
                        "--repeat", "1", "--json"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    sets = json.loads(r.stdout)["meshes"][0]["sets"]
    assert set(sets) == {"primary", "incoherent", "shadow"}
    for row in sets.values():
        assert row["rays"] > 0 and row["ours_mrays"] > 0 and row["embreex_mrays"] > 0
        assert row["ratio_vs_embreex"] == pytest.approx(row["ours_mrays"] / row["embreex_mrays"])


@pytest.mark.slow
def test_two_million_triangles_build_and_validate():
    import hwbvh
    from hwbvh.primitives import primitive_boxes
    from scenes.meshes import bumpy_sphere
    tris = bumpy_sphere(2_000_000)
    bvh = hwbvh.build(tris)
    hwbvh.validate(bvh.nodes, bvh.indices, len(tris), 4, primitive_boxes(tris))
    assert bvh.meta["sah_cost"] > 0 and bvh.meta["triangles"] >= 1_990_000


@pytest.mark.skipif(usable_cores() < 2, reason="the child compiles on a second core")
def test_a_first_run_compiles_the_traversal_in_a_child_and_renders_the_warm_image(tmp_path):
    """On an empty Numba cache, a child process compiles the traversal into the cache (so the
    render compiles only the rest); a later process finds it there and starts no child; the
    first render's image is the one a warm run renders."""
    cache = tmp_path / "numba-cache"
    cache.mkdir()
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    code = ("from raytracer.render import traversal_cached, _compile_traversal_beside\n"
            "print(traversal_cached())\n"
            "child = _compile_traversal_beside()\n"
            "print(child is not None, child.wait(timeout=600))\n"
            "print(traversal_cached(), _compile_traversal_beside() is None)\n")
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                       timeout=900)
    assert r.stdout.split() == ["False", "True", "0", "True", "True"], r.stdout + r.stderr
    cold, warm = tmp_path / "cold.exr", tmp_path / "warm.exr"
    args = [sys.executable, "-m", "hwrt.cli", "render", "cornell", "--width", "40", "--height", "30",
            "--spp", "2"]
    subprocess.run(args + ["-o", str(cold)], check=True, capture_output=True, env=env)
    subprocess.run(args + ["-o", str(warm)], check=True, capture_output=True)
    from raytracer.output import read_exr
    assert np.array_equal(read_exr(cold)[0], read_exr(warm)[0])


@pytest.mark.parametrize("asked", [False, True])
def test_progress_bars_show_off_a_terminal_only_when_asked(asked, capsys, monkeypatch):
    from hwrt.progress import PROGRESS_ENV, progress_bar, progress_over
    if asked:
        monkeypatch.setenv(PROGRESS_ENV, "1")
    assert list(progress_over([1, 2, 3], "items", "item")) == [1, 2, 3]
    with progress_bar(3, "bar", "step") as bar:
        bar.update(3)
    with progress_bar(3, "never", "step", show=False) as bar:
        bar.update(3)
    err = capsys.readouterr().err
    assert ("items" in err and "bar" in err) == asked and (err == "") != asked
    assert "never" not in err


@pytest.mark.parametrize("asked, cached", [(True, False), (True, True), (False, False)])
def test_a_run_that_compiles_says_so_where_progress_shows(asked, cached, capsys, monkeypatch):
    import raytracer.render
    from hwrt.progress import PROGRESS_ENV, note_first_compile
    monkeypatch.setattr(raytracer.render, "traversal_cached", lambda: cached)
    if asked:
        monkeypatch.setenv(PROGRESS_ENV, "1")
    else:
        monkeypatch.delenv(PROGRESS_ENV, raising=False)
    note_first_compile()
    err = capsys.readouterr().err
    assert ("compiling the kernels" in err) == (asked and not cached)
    assert err.count("\n") == (1 if asked and not cached else 0)


def test_every_progress_bar_goes_through_hwrt_progress():
    """So that HWRT_PROGRESS governs them all (the README's promise)."""
    users = [p.relative_to(ROOT) for d in ("hwbvh", "traversal", "raytracer", "scenes", "hwrt")
             for p in (ROOT / d).glob("*.py") if "tqdm" in p.read_text()]
    assert users == [Path("hwrt/progress.py")]


# --------------------------------------------------------------------------------------
# a mesh file's input errors at the command line: one line naming the file, exit status 2,
# no output (in a child process, so that a warning printed on the way shows on stderr)
# --------------------------------------------------------------------------------------
def _hwrt(*argv):
    return subprocess.run([sys.executable, "-m", "hwrt.cli", *map(str, argv)], capture_output=True,
                          text=True, timeout=600, env={**os.environ, "PYTHONPATH": str(ROOT)})


def _refused(r, output, message):
    assert r.returncode == 2 and r.stdout == "" and r.stderr.splitlines() == [f"hwrt: error: {message}"]
    assert not Path(output).exists()


@pytest.mark.parametrize("vertex", ["v 0.5 2 -1", "v 0 0 0"])
def test_a_mesh_whose_vertices_all_coincide_is_refused_naming_the_file(tmp_path, vertex):
    p = tmp_path / "point.obj"
    p.write_text(f"{vertex}\n" * 3 + "f 1 2 3\n")
    out = tmp_path / "o.exr"
    _refused(_hwrt("render", p, "-o", out, "--width", 8, "--height", 6), out,
             f"{p}: its triangles' vertices all coincide; nothing to frame")


def test_bench_trace_refuses_a_mesh_whose_vertices_all_coincide_naming_it(tmp_path):
    p = tmp_path / "point.obj"
    p.write_text("v 0.5 2 -1\n" * 3 + "f 1 2 3\n")
    out = tmp_path / "o"
    _refused(_hwrt("bench", "trace", p, "--rays", 100, "--out-dir", out), out,
             f"{p}: its triangles' vertices all coincide; nothing to frame")


@pytest.mark.parametrize("kind", ["primary", "shadow"])
def test_verify_refuses_a_scene_whose_vertices_all_coincide_naming_it(tmp_path, kind):
    """The primary set frames the triangles' box, and verify refuses any kind for such a
    scene as render does: without extent the box has no view (NaN directions, which would
    verify as agreeing misses)."""
    scene = tmp_path / "point.json"
    scene.write_text(json.dumps({
        "camera": {"eye": [0, 1.6, 4.2], "target": [0, 0.4, 0]},
        "materials": {"red": {"type": "plastic"}},
        "shapes": [{"type": "triangles", "material": "red", "data": [[[1, 1, 1]] * 3] * 2}]}))
    out = tmp_path / "m.npz"
    _refused(_hwrt("verify", scene, "--rays", 100, "--kind", kind, "--mismatches", out), out,
             f"{scene}: its triangles' vertices all coincide; nothing to frame")
    from traversal.raysets import primary
    with pytest.raises(InputError, match="^tris: its triangles' vertices all coincide"):
        primary(np.ones((1, 3, 3), np.float32), 10)


@pytest.mark.parametrize("face, problem", [
    ("f 1 2 7", "line 5: a face refers to vertex 7, but the file has 3 vertices"),
    ("f 1/1 2/1 4/1", "line 5: a face refers to vertex 4, but the file has 3 vertices"),
    ("f -1 -2 -4", "line 5: a face refers to vertex -4, counting back from that line, but only "
                   "3 vertices come before it"),
    # read as the vertex after it before negative indices counted back from the face's line
    ("f -4 -2 -1\nv 0 0 1", "line 5: a face refers to vertex -4, counting back from that line, "
                            "but only 3 vertices come before it"),
    ("f 1/-2 2/-1 3/-1", "line 5: a face refers to texture coordinate -2, counting back from "
                         "that line, but only 1 texture coordinate comes before it"),
    ("f 1 2 \\\n7", "line 5: a face refers to vertex 7, but the file has 3 vertices"),
    ("f 1 2 \\\r\n  \\\n 3 # c", "line 5: a face holds '#', which is not an index (a comment "
                                 "must be on a line of its own)"),
    ("f 1 2 3 #\nf 1 2 9", "line 5: a face holds '#', which is not an index (a comment must be "
                           "on a line of its own)"),
])
def test_an_obj_face_past_the_vertices_is_named_by_its_line_and_index(tmp_path, face, problem):
    p = tmp_path / "bad.obj"
    p.write_bytes(f"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\n{face}\n".encode())
    out = tmp_path / "o.exr"
    _refused(_hwrt("render", p, "-o", out, "--width", 8, "--height", 6), out, f"{p}: {problem}")


# the triangle each group of vertices below makes
A, B, C = ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[5, 5, 5], [6, 5, 5], [5, 6, 5]],
           [[0, 0, 9], [1, 0, 9], [0, 1, 9]])
_OBJ_VERTICES = {"A": "v 0 0 0\nv 1 0 0\nv 0 1 0\n", "B": "v 5 5 5\nv 6 5 5\nv 5 6 5\n",
                 "C": "v 0 0 9\nv 1 0 9\nv 0 1 9\n"}


@pytest.mark.parametrize("text, triangles", [
    ("o a\n{A}f -3 -2 -1\no b\n{B}f -3 -2 -1\n", [A, B]),           # each object's own vertices
    ("{A}vt 0 0\nvn 0 0 1\nf -3/-1/-1 -2/-1/-1 -1/-1/-1\n{B}vt 1 1\nf -3/-1 -2/-1 -1/-2\n", [A, B]),
    ("{A}f -3 2 -1\n{B}f -6 -2 \\\n -1\n{C}f 1 -5 \\\r\n3\r\n",
     [A, [A[0]] + B[1:], [A[0], B[1], A[2]]]),
    ("{A}{B}{C}f 4 5 6\nf -9 -8 -7\nf 7 8 9\n", [B, A, C]),
    ("\n  {A}f -3 -2 -1\n{B}f -3 -2 -1\n", [A, B]),    # trimesh strips the file's first indent
])
def test_negative_obj_indices_count_back_from_their_line(tmp_path, text, triangles):
    from hwbvh.primitives import load_mesh_arrays
    p = tmp_path / "relative.obj"
    p.write_bytes(text.format(**_OBJ_VERTICES).encode())
    V, F = load_mesh_arrays(p)
    assert V[F].tolist() == triangles


def test_an_obj_without_negative_indices_is_handed_to_trimesh_unread(tmp_path, monkeypatch):
    """Minus signs in coordinates, names and comments do not send a file through the pass
    that makes negative indices positive; trimesh reads it from its path as before."""
    from hwbvh import primitives

    def rewritten(*args):
        raise AssertionError("rewritten")
    monkeypatch.setattr(primitives, "_obj_resolved_text", rewritten)
    p = tmp_path / "plain.obj"
    p.write_text("# a mesh-1 -2\nv -1 -0 -1e-3\nv 1 0 0\nv 0 1 -0\ng part-2\nusemtl m-1\n"
                 "f 1 2 3\nf 3/1  10/2 1\nv 0 0 1\nv 0 0 2\nv 0 0 3\nv 0 0 4\nv 0 0 5\nv 0 0 6\n"
                 "v 0 0 7\n")
    V, F = primitives.load_mesh_arrays(p)
    assert V[F].tolist() == [[[-1, 0, -1e-3], [1, 0, 0], [0, 1, 0]],
                             [[0, 1, 0], [0, 0, 7], [-1, 0, -1e-3]]]


@pytest.mark.parametrize("block_size", [1, 2, 3, 4, 5, 7, 64])
def test_obj_vertices_are_counted_across_blocks_as_lines_are_read(block_size):
    """The error path counts a file's vertices at C speed a block at a time; every block
    boundary gives the count of its line-by-line reading (continued lines are not vertices)."""
    import io
    from hwbvh.primitives import _count_obj_vertices, _obj_lines
    data = (b"v 0 0 0\nvt 0 0\nv 1 0 0\\\nv 2 0 0\r\nvn 0 0 1\\\r\nv 3\r\nv 4 0 0\nv\t5\n"
            b"f 1 2 3 \\\n\\\nv 6\n  v 7\nv 8 0 0")
    lines = sum(line.startswith(b"v ") for _, line in _obj_lines(io.BytesIO(data)))
    assert lines == 4 and _count_obj_vertices(io.BytesIO(data), block_size) == lines


@pytest.mark.parametrize("how", ["mesh", "nan mesh", "mesh in a scene", "scene triangles"])
def test_an_infinite_or_nan_vertex_is_one_line_on_stderr(tmp_path, how):
    mesh = tmp_path / "bad.obj"
    mesh.write_text(f"v 0 0 0\nv 1 0 0\nv {'nan' if 'nan' in how else 'inf'} 1 0\nf 1 2 3\n")
    message = f"{mesh}: triangle 0 has a NaN or infinite coordinate"
    if "scene" in how:
        shape = {"type": "mesh", "filename": mesh.name} if how == "mesh in a scene" else \
            {"type": "triangles", "data": [[[0, 0, 0], [1, 0, 0], [float("inf"), 1, 0]]]}
        scene = {"camera": {"eye": [0, 1, 4], "target": [0, 0, 0]},
                 "materials": {"m": {"type": "diffuse"}}, "shapes": [dict(shape, material="m")]}
        spec = tmp_path / "s.json"
        spec.write_text(json.dumps(scene))          # inf as JSON's Infinity, which Python reads
        if how == "scene triangles":
            message = f"{spec}: key 'shapes[0].data': expected finite coordinates of magnitude at most 1e+15"
        else:
            message = f"{spec}: key 'shapes[0].filename': {message}"
    else:
        spec = mesh
    out = tmp_path / "o.exr"
    _refused(_hwrt("render", spec, "-o", out, "--width", 8, "--height", 6), out, message)


@pytest.mark.parametrize("how", ["mesh", "mesh in a scene"])
def test_a_too_large_vertex_is_named_as_such_in_one_line(tmp_path, how):
    """1e200 is finite in the file's float64 but not in float32: it is refused as too large
    before the cast, which would print numpy's overflow warning and report it as infinite."""
    mesh = tmp_path / "big.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 1e200 1 0\nf 1 2 3\n")
    spec = mesh
    if how == "mesh in a scene":
        spec = tmp_path / "s.json"
        spec.write_text(json.dumps({
            "camera": {"eye": [0, 1, 4], "target": [0, 0, 0]},
            "materials": {"m": {"type": "diffuse"}},
            "shapes": [{"type": "mesh", "filename": mesh.name, "material": "m"}]}))
    out = tmp_path / "o.exr"
    key = f"{spec}: key 'shapes[0].filename': " if how == "mesh in a scene" else ""
    _refused(_hwrt("render", spec, "-o", out, "--width", 8, "--height", 6), out,
             f"{key}{mesh}: triangle 0 has a coordinate too large: magnitude 1e+200 exceeds 1e+15 "
             "(float32 SAH costs would overflow)")


def test_bench_trace_tells_meshes_of_one_stem_apart_and_errors_name_the_file(tmp_path):
    import trimesh
    from scenes.meshes import sphere
    paths = []
    for d, n in (("a", 6), ("b", 8), ("a", 5)):
        tris = sphere(n, 2 * n)
        p = tmp_path / d / ("other.ply" if n == 5 else "s.ply")
        p.parent.mkdir(exist_ok=True)
        trimesh.Trimesh(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3),
                        process=False).export(p)
        paths.append(p)
    r = _hwrt("bench", "trace", *paths, "--rays", 200, "--repeat", 1, "--json")
    assert r.returncode == 0, r.stderr
    result = json.loads(r.stdout)
    assert [m["mesh"] for m in result["meshes"]] == [str(paths[0]), str(paths[1]), "other"]
    from hwrt.bench import human
    rows = 1 + sum(len(m["sets"]) for m in result["meshes"])
    table = human("trace")(result).splitlines()[:rows]
    assert len({len(line) for line in table}) == 1, table      # a path as name keeps the columns
    bad = tmp_path / "nan.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    r = _hwrt("bench", "trace", bad, "--rays", 200, "--repeat", 1)
    assert r.returncode == 2 and r.stderr.splitlines() == [
        f"hwrt: error: {bad}: triangle 0 has a NaN or infinite coordinate"]


def test_long_mesh_and_scene_names_keep_the_tables_aligned():
    from pathlib import Path
    from hwrt import trees
    from hwrt.bench import human
    long = "meshes/of/one/stem/bunny.ply"
    row = {"mesh": long, "triangles": 10, "hwbvh_seconds": 0.001, "embree_seconds": 0.002,
           "ratio": 0.5, "sah_cost": 12.0}
    build = human("build")({"meshes": [row, dict(row, mesh="bunny")], "repeat": 1}).splitlines()
    assert len({len(line) for line in build[:3]}) == 1, build
    result = json.loads((Path(__file__).parents[1] / "docs" / "trees.json").read_text())
    result["rows"][0]["scene"] = long
    lines = trees.human(result).splitlines()
    first = lines[:2 + 2 * len(result["rows"])]
    assert len({len(line) for line in first}) == 1, first
    classes = sum(len(x["by_path"]) for x in result["rows"])
    where = lines.index(next(line for line in lines if line.startswith("where the trace time")))
    split = lines[where + 1:where + 3 + classes]
    assert len({len(line) for line in split}) == 1, split


def test_bench_refuses_a_missing_mesh_or_a_directory_before_any_work(tmp_path):
    import os
    (tmp_path / "d").mkdir()
    os.mkfifo(tmp_path / "pipe.ply")
    for given, problem in ((tmp_path / "none.ply", "no such file"),
                           (tmp_path / "d", "is a directory, not a mesh file"),
                           (tmp_path / "pipe.ply", "not a regular file (a pipe or a device?): "
                                                   "give a mesh file")):
        r = _hwrt("bench", "trace", given, "--rays", 200, "--repeat", 1, "--out-dir", tmp_path / "out")
        _refused(r, tmp_path / "out", f"{given}: {problem}")


def _mesh_args(mesh_dir=None, meshes=()):
    from argparse import Namespace
    return Namespace(meshes=[str(m) for m in meshes], mesh_dir=None if mesh_dir is None else str(mesh_dir))


def test_a_mesh_directory_asked_for_must_exist_and_hold_meshes(tmp_path, monkeypatch):
    """Asked for by the parameter (the command line's --mesh-dir) or by $HWRT_MESHES: a
    directory that is missing, a file, or empty of meshes is an error naming what asked for
    it, never a silent run on generated meshes."""
    from hwbvh.errors import InputError, ParameterError
    from hwrt.bench import mesh_inputs
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("")
    (tmp_path / "file").write_text("")
    cases = [(tmp_path / "none", "no such directory"), (tmp_path / "file", "not a directory"),
             (tmp_path / "empty", "has no mesh files (.ply, .obj, .stl, .off, .glb, .gltf)")]
    monkeypatch.delenv("HWRT_MESHES", raising=False)
    for d, problem in cases:
        with pytest.raises(ParameterError) as e:
            mesh_inputs(_mesh_args(d))
        assert e.value.parameter == "mesh_dir" and e.value.problem == f"{d}: {problem}"
        r = _hwrt("bench", "build", "--mesh-dir", d, "--repeat", 1)
        assert r.returncode == 2 and r.stderr.splitlines() == [f"hwrt: error: --mesh-dir: {d}: {problem}"]
    for d, problem in cases:
        monkeypatch.setenv("HWRT_MESHES", str(d))
        with pytest.raises(InputError) as e:
            mesh_inputs(_mesh_args())
        assert (e.value.source, e.value.problem) == (f"$HWRT_MESHES {d}", problem)


def test_a_mesh_directory_beside_mesh_files_is_refused_not_ignored(tmp_path):
    from hwbvh.errors import ParameterError
    from hwrt.bench import mesh_inputs
    (tmp_path / "d").mkdir()
    with pytest.raises(ParameterError) as e:
        mesh_inputs(_mesh_args(tmp_path / "d", [tmp_path / "m.ply"]))
    assert e.value.parameter == "mesh_dir" and "mesh files are given" in e.value.problem
    r = _hwrt("bench", "build", tmp_path / "m.ply", "--mesh-dir", tmp_path / "d", "--repeat", 1)
    assert r.returncode == 2 and r.stderr.splitlines() == [
        "hwrt: error: --mesh-dir: not read when mesh files are given: give the files or the "
        "directory"]


def test_generated_meshes_only_when_no_directory_is_asked_for_or_there(tmp_path, monkeypatch):
    import hwrt.bench as bench
    from hwbvh.errors import InputError
    from scenes.meshes import GENERATED
    monkeypatch.delenv("HWRT_MESHES", raising=False)
    monkeypatch.setattr(bench, "default_mesh_dir", lambda: None)          # ../shared/meshes absent
    got = bench.mesh_inputs(_mesh_args())
    assert [(m.name, m.path, m.stem) for m in got] == [(n, None, n) for n in GENERATED]
    assert got[0].source == got[0].name
    (tmp_path / "default").mkdir()
    monkeypatch.setattr(bench, "default_mesh_dir", lambda: tmp_path / "default")  # there, but empty
    with pytest.raises(InputError) as e:
        bench.mesh_inputs(_mesh_args())
    assert e.value.source == str(tmp_path / "default") and e.value.problem.startswith("has no mesh files")


def test_mesh_inputs_are_records_naming_files_by_stem_unless_shared(tmp_path):
    from hwbvh.errors import InputError
    from hwrt.bench import mesh_inputs
    for rel in ("a/s.ply", "b/s.ply", "a/t.obj"):
        (tmp_path / rel).parent.mkdir(exist_ok=True)
        (tmp_path / rel).write_text("")
    a, b, t = tmp_path / "a/s.ply", tmp_path / "b/s.ply", tmp_path / "a/t.obj"
    got = mesh_inputs(_mesh_args(meshes=[a, b, t]))
    assert [(m.name, m.path, m.stem, m.source) for m in got] == [
        (str(a), a, "s", str(a)), (str(b), b, "s", str(b)), ("t", t, "t", str(t))]
    in_dir = mesh_inputs(_mesh_args(tmp_path / "a"))
    assert [(m.name, m.path, m.stem) for m in in_dir] == [("s", a, "s"), ("t", t, "t")]
    with pytest.raises(InputError, match=f"^{a}: given twice$"):
        mesh_inputs(_mesh_args(meshes=[a, t, a]))
    other_spelling = tmp_path / "b" / ".." / "a" / "s.ply"
    with pytest.raises(InputError, match="given twice$"):
        mesh_inputs(_mesh_args(meshes=[a, other_spelling]))


# --------------------------------------------------------------------------------------
# the process's signals: one line and 130 at any moment before success, 0 after it
# --------------------------------------------------------------------------------------
TETRA_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"

# the console script's path (hwrt.cli.run) with ``{setup}`` run first: argv after the script
CONSOLE_RUN = """
import os, signal, sys, time
{setup}
import hwrt.cli
sys.argv = ["hwrt", *sys.argv[1:]]
hwrt.cli.run()
"""


def _console(setup, *argv):
    return subprocess.run([sys.executable, "-c", CONSOLE_RUN.format(setup=setup), *map(str, argv)],
                          capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})


def test_the_console_script_is_run():
    from importlib.metadata import entry_points
    (script,) = [e for e in entry_points(group="console_scripts") if e.name == "hwrt"]
    assert script.value == "hwrt.cli:run"


def test_importing_the_command_line_loads_no_numerical_library():
    """A Ctrl-C while the libraries load is handled by main, not shown as a traceback."""
    r = subprocess.run([sys.executable, "-c", "import sys, hwrt.cli; print(sorted(m for m in "
                        "('numpy', 'numba', 'hwbvh', 'scenes', 'raytracer') if m in sys.modules))"],
                       capture_output=True, text=True, timeout=600,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.stdout == "[]\n", r.stderr


@pytest.mark.parametrize("sig,code,word", [("SIGINT", 130, "interrupted"),
                                           ("SIGTERM", 143, "terminated")])
def test_a_signal_while_the_parser_is_made_is_one_line(tmp_path, sig, code, word):
    setup = f"""
import hwrt.cli as cli
real = cli.make_parser
def make_parser():
    os.kill(os.getpid(), signal.{sig})
    time.sleep(1)                           # Python acts on the signal here
    return real()
cli.make_parser = make_parser
"""
    r = _console(setup, "build", "x.obj", "--out", tmp_path / "t")
    assert r.returncode == code and r.stderr == f"hwrt: {word}\n" and r.stdout == ""


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_a_signal_as_the_interpreter_exits_after_a_success_is_ignored(tmp_path, sig):
    """The report is printed: a signal while Python shuts down (here from an exit handler)
    leaves exit status 0."""
    setup = f"""
import atexit
def late():
    os.kill(os.getpid(), signal.{sig})
    time.sleep(0.5)                         # Python acts on the signal here unless ignored
atexit.register(late)
"""
    mesh = tmp_path / "tetra.obj"
    mesh.write_text(TETRA_OBJ)
    r = _console(setup, "build", mesh, "--out", tmp_path / "tree", "--json")
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert json.loads(r.stdout)["triangles"] == 4


def test_main_in_process_puts_the_handlers_back_after_a_success(tmp_path, capsys):
    import signal
    from hwrt.cli import main
    mesh = tmp_path / "tetra.obj"
    mesh.write_text(TETRA_OBJ)
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    assert main(["build", str(mesh)]) == 0
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


@pytest.mark.parametrize("first, second, code, word", [
    ("SIGINT", "SIGINT", 130, "interrupted"), ("SIGTERM", "SIGINT", 143, "terminated")])
def test_a_second_signal_during_the_clean_up_is_dropped(tmp_path, first, second, code, word):
    """Ctrl-C pressed twice (or a supervisor's SIGTERM, then Ctrl-C): the first stops the run
    as its output is written, the second lands while the temporary file is removed, and is
    dropped: one line, 130 or 143, no file left (breaking into the clean-up, it would leave
    the temporary file and a traceback)."""
    setup = f"""
_chmod, _unlink = os.chmod, os.unlink
def chmod(path, mode, **kw):
    if os.path.basename(str(path)).startswith(".tmp-"):     # a written temporary file
        os.chmod = _chmod
        os.kill(os.getpid(), signal.{first})
        time.sleep(0.5)
    return _chmod(path, mode, **kw)
def unlink(path, **kw):
    if os.path.basename(str(path)).startswith(".tmp-"):     # its removal, unwinding
        print("again", file=sys.stderr)
        os.kill(os.getpid(), signal.{second})
        time.sleep(0.5)
    return _unlink(path, **kw)
os.chmod, os.unlink = chmod, unlink
"""
    mesh = tmp_path / "tetra.obj"
    mesh.write_text(TETRA_OBJ)
    r = _console(setup, "build", mesh, "--out", tmp_path / "tree")
    assert r.stderr == f"again\nhwrt: {word}\n" and r.returncode == code, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tetra.obj"]


def test_a_third_signal_stops_a_run_that_swallowed_the_first(tmp_path):
    """A library that catches BaseException swallows the first Ctrl-C; the second is dropped
    (as during a clean-up); the third stops the run."""
    setup = """
import hwrt.cli as cli
real = cli.make_parser
def make_parser():
    try:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.5)
    except BaseException:
        pass                                # swallowed, as some libraries do
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(0.5)
    print("still running", file=sys.stderr)
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(0.5)
    return real()
cli.make_parser = make_parser
"""
    r = _console(setup, "build", "x.obj", "--out", tmp_path / "t")
    assert r.stderr == "still running\nhwrt: interrupted\n" and r.returncode == 130, r.stderr


@pytest.mark.parametrize("sig, code", [("SIGINT", 130), ("SIGTERM", 143)])
def test_main_in_process_puts_the_handlers_back_after_an_interrupt(tmp_path, capsys,
                                                                   monkeypatch, sig, code):
    import signal
    import hwrt.cli as cli
    real = cli.make_parser

    def make_parser():
        os.kill(os.getpid(), getattr(signal, sig))
        time.sleep(1)                           # Python acts on the signal here
        return real()
    monkeypatch.setattr(cli, "make_parser", make_parser)
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    assert cli.main(["build", str(tmp_path / "x.obj")]) == code
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


def test_a_signal_while_trimesh_is_imported_is_acted_on(tmp_path):
    """trimesh catches BaseException around some of its imports: a Ctrl-C landing in one of
    them still interrupts the run, with no output written."""
    setup = """
import importlib.abc
class Interrupting(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        # scipy's first module trimesh imports, inside its `except BaseException` (whether
        # or not scipy is installed: the finders are asked before the lookup fails)
        if name.split(".")[0] == "scipy" and "trimesh" in sys.modules:
            sys.meta_path.remove(self)
            print("signalled", file=sys.stderr)
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.5)                 # Python acts on the signal here unless held
        return None
sys.meta_path.insert(0, Interrupting())
"""
    mesh = tmp_path / "tetra.obj"
    mesh.write_text(TETRA_OBJ)
    r = _console(setup, "build", mesh, "--out", tmp_path / "tree")
    assert r.stderr == "signalled\nhwrt: interrupted\n" and r.returncode == 130
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tetra.obj"]


def test_a_reader_that_goes_away_ends_the_command_quietly(tmp_path):
    """`hwrt build m.obj | true`: stdout's reader gone, the command ends as one killed by
    SIGPIPE would, with nothing on stderr (not an internal error)."""
    p = tmp_path / "m.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    r, w = os.pipe()
    os.close(r)                                   # no reader at all
    try:
        proc = subprocess.run([sys.executable, "-m", "hwrt.cli", "build", str(p), "--json"],
                              stdout=w, stderr=subprocess.PIPE, text=True, timeout=300)
    finally:
        os.close(w)
    assert (proc.returncode, proc.stderr) == (141, "")


@pytest.mark.parametrize("sig, word, code", [("SIGINT", "interrupted", 130),
                                             ("SIGTERM", "terminated", 143)])
@pytest.mark.parametrize("then", ["finishes", "fails", "in a destructor"])
def test_a_signal_a_library_swallowed_still_stops_the_run(tmp_path, sig, word, code, then):
    """llvmlite drops what Python raises in its callbacks (Numba's compiler calls back into
    Python) and destructors: a Ctrl-C there is swallowed. The run still stops as the signal
    asked, with its one line and before it writes anything, whether the library then goes on
    or fails for having been cut short."""
    setup = f"""
import hwbvh.parallel as parallel
real = parallel.check_threading
class Signalled:
    def __del__(self):                      # what it raises, Python reports and drops
        os.kill(os.getpid(), signal.{sig})
        time.sleep(0.5)
def check_threading():                      # the first step of every command
    if "{then}" == "in a destructor":
        Signalled()
        return real()
    try:
        os.kill(os.getpid(), signal.{sig})
        time.sleep(0.5)
    except BaseException:
        pass                                # swallowed, as llvmlite's callbacks do
    if "{then}" == "fails":
        raise RuntimeError("no compiled object yet")
    return real()
parallel.check_threading = check_threading
"""
    mesh = tmp_path / "tetra.obj"
    mesh.write_text(TETRA_OBJ)
    r = _console(setup, "build", mesh, "--out", tmp_path / "tree")
    assert (r.stderr, r.returncode) == (f"hwrt: {word}\n", code)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tetra.obj"]


def test_a_reader_that_goes_away_mid_output_ends_the_command_quietly(tmp_path):
    """`hwrt ... | head` with more output than a pipe holds: the write is cut short when the
    reader goes; the command still ends as one killed by SIGPIPE would (Python's buffered
    writer would return as if it had written everything, and the run exit 0)."""
    setup = """
import hwbvh.files as files
real_json = files.json_text
files.json_text = lambda obj, *a, **k: real_json(obj, *a, **k) + " " * 4_000_000
"""
    p = tmp_path / "m.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    proc = subprocess.Popen([sys.executable, "-c", CONSOLE_RUN.format(setup=setup), "build",
                             str(p), "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.stdout.read(10).startswith(b"{")
    proc.stdout.close()                           # the reader goes, as head does
    err = proc.stderr.read()
    assert (proc.wait(timeout=300), err) == (141, b"")


def test_output_to_a_non_blocking_pipe_is_written_whole(tmp_path):
    """A parent may hand the command a stdout it set non-blocking: a write the pipe cannot
    take yet waits for the reader instead of failing."""
    setup = """
import hwbvh.files as files
real_json = files.json_text
files.json_text = lambda obj, *a, **k: real_json(obj, *a, **k) + " " * 4_000_000
"""
    p = tmp_path / "m.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    r, w = os.pipe()
    os.set_blocking(w, False)
    proc = subprocess.Popen([sys.executable, "-c", CONSOLE_RUN.format(setup=setup), "build",
                             str(p), "--json"], stdout=w, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    os.close(w)
    with os.fdopen(r, "rb") as reader:
        got = reader.read()
    assert proc.wait(timeout=300) == 0, proc.stderr.read()
    assert len(got) > 4_000_000 and got.startswith(b"{") and got.endswith(b"\n")


def test_a_page_shows_the_figures_written_with_it():
    from hwrt.report import with_figures
    files = [("d/a.csv", "x\n"), ("d/a.md", "# A\n\ntable\n"), ("d/a_b.png", b"png"),
             ("d/c.png", b"png")]
    got = dict(with_figures(files))
    assert got["d/a.md"] == "# A\n\ntable\n\n## Figures\n\n![a b](a_b.png)\n\n![c](c.png)\n\n"
    assert got["d/a.csv"] == "x\n" and got["d/c.png"] == b"png"
    assert with_figures(files[:2]) == files[:2]          # no figure: the page as it was


@pytest.mark.parametrize("subdiv, builder, parallel", [([64, 96], "hwbvh", True),
                                                       ([16, 32], "hwbvh", False),
                                                       ([64, 96], "sweep", False)])
def test_render_compiles_the_builder_a_large_scene_takes_before_its_build_is_timed(
        tmp_path, monkeypatch, capsys, subdiv, builder, parallel):
    """A scene past SEQUENTIAL_MAX_PRIMS builds with the data-parallel kernels: render warms
    them up first, so that build_seconds is the build's, not the compiler's."""
    import raytracer.render as render_module
    from hwbvh.config import SEQUENTIAL_MAX_PRIMS
    from hwrt.cli import main
    seen = []
    real = render_module.warm_up

    def recording(*args, **kwargs):
        seen.append(kwargs.get("parallel_build", False))
        return real(*args, **kwargs)

    monkeypatch.setattr(render_module, "warm_up", recording)
    scene = {"camera": {"eye": [0, 0, 4], "target": [0, 0, 0]},
             "film": {"width": 16, "height": 12, "spp": 1},
             "materials": {"m": {"type": "diffuse"}},
             "shapes": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m",
                         "subdiv": subdiv}]}
    p = tmp_path / "s.json"
    p.write_text(json.dumps(scene))
    assert main(["render", str(p), "--builder", builder, "-o", str(tmp_path / "o.exr"),
                 "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert (result["triangles"] > SEQUENTIAL_MAX_PRIMS) == (subdiv == [64, 96])
    assert seen == [parallel]


def test_a_render_records_its_seed_and_jitter_so_its_image_can_be_made_again(tmp_path, capsys):
    from hwrt.cli import main
    from raytracer.output import read_exr
    images = []
    for seed in (0, 7):
        out = tmp_path / f"s{seed}.exr"
        assert main(["render", "cornell", "--width", "32", "--height", "24", "--spp", "2",
                     "--seed", str(seed), "-o", str(out), "--json"]) == 0
        result = json.loads(capsys.readouterr().out)
        pixels, _, meta = read_exr(out)
        assert (result["seed"], result["jitter"]) == (seed, True)
        assert (meta["seed"], meta["jitter"]) == (seed, 1)
        images.append(pixels)
    assert not np.array_equal(images[0], images[1])        # the seed is what made the image


def test_a_figure_of_one_run_says_so():
    from hwrt.bench import medians_of
    assert medians_of(1) == "one run" and medians_of(1, "warm runs") == "one warm run"
    assert medians_of(7) == "medians of 7 runs"


@pytest.mark.parametrize("command", ["render", "build"])
def test_a_symbolic_link_that_leads_nowhere_is_named_as_one(tmp_path, command):
    """A loop of links, or a link to a missing file, is there as a link: not "no such file"."""
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.symlink_to(b.name)
    b.symlink_to(a.name)
    dangling = tmp_path / "gone.ply"
    dangling.symlink_to("missing.ply")
    out = tmp_path / "o.exr"
    for link, target in ((a, b.name), (dangling, "missing.ply")):
        if command == "build" and link == a:
            continue
        argv = [command, link] + (["-o", out, "--width", 8, "--height", 6] if command == "render"
                                  else [])
        _refused(_hwrt(*argv), out, f"{link}: a symbolic link to {target}, which leads to no "
                                    f"file (its target is missing, or the links loop)")
