"""The command line's contract on every input: bad input exits 2 with one line naming the file,
key or option, before any work and without touching an output; --json is strict JSON; signals
clean up; every option says what it does and its default."""
import argparse
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from hwbvh.errors import InputError, ParameterError
from hwrt.cli import main, make_parser
from hwrt.progress import PROGRESS_ENV

ROOT = Path(__file__).resolve().parents[1]
TETRA_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


def strict_json(text):
    """json.loads that refuses NaN and Infinity, as a browser's JSON.parse does."""
    def refuse(name):
        raise ValueError(f"not strict JSON: {name}")
    return json.loads(text, parse_constant=refuse)


def call(capsys, *argv):
    """Run the CLI in this process: (exit status, stdout, stderr)."""
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as e:                     # argparse's own exits (usage errors, --version)
        rc = e.code
    out, err = capsys.readouterr()
    return rc, out, err


def run(*argv, env=None, **kw):
    return subprocess.run([sys.executable, "-m", "hwrt.cli", *map(str, argv)], capture_output=True,
                          text=True, timeout=600, env=env, **kw)


def one_line_error(err):
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


@pytest.fixture
def tetra(tmp_path):
    p = tmp_path / "tetra.obj"
    p.write_text(TETRA_OBJ)
    return p


def write_ply(path, tris):
    import trimesh
    V = np.asarray(tris, np.float64).reshape(-1, 3)
    trimesh.Trimesh(V, np.arange(len(V)).reshape(-1, 3), process=False).export(path)
    return path


@pytest.fixture
def sphere_ply(tmp_path):
    from scenes.meshes import uv_sphere
    import trimesh
    V, F = uv_sphere(10, 16)
    p = tmp_path / "sphere.ply"
    trimesh.Trimesh(V, F, process=False).export(p)
    return p


def scene_dict(**extra):
    d = {"camera": {"eye": [0, 0, 4], "target": [0, 0, 0]}, "film": {"width": 32, "height": 24},
         "materials": {"m": {"type": "diffuse"}},
         "lights": [{"type": "point", "position": [2, 2, 2], "intensity": [10, 10, 10]}],
         "shapes": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m",
                     "subdiv": [6, 8]}]}
    d.update(extra)
    return d


# ---------------------------------------------------------------------------------------
# 1. smooth normals need no optional package
# ---------------------------------------------------------------------------------------
def test_smooth_normals_are_area_weighted_unit_vectors():
    from scenes.loader import smooth_normals
    # an octahedron: at each vertex the faces around it sum to the vertex's own direction
    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4],
                  [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    N = smooth_normals(V, F)
    assert N.shape == (8, 3, 3)
    np.testing.assert_allclose(N, V[F], atol=1e-12)
    # area weighting: a large and a small face meeting at a vertex (an open fan)
    V2 = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 1]], float)
    F2 = np.array([[0, 1, 2], [0, 2, 3]])                    # normals +z (area 50) and +x (area 5)
    n0 = smooth_normals(V2, F2)[0, 0]
    np.testing.assert_allclose(n0, np.array([5, 0, 50]) / np.hypot(5, 50), atol=1e-12)
    # a degenerate face keeps a unit normal from its neighbours or none at all, never NaN
    V3 = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    assert np.isfinite(smooth_normals(V3, np.array([[0, 1, 2]]))).all()


def test_smooth_mesh_scene_renders_without_scipy(tmp_path, sphere_ply):
    """The README's own example (a mesh with "smooth": true) on a machine without SciPy."""
    d = scene_dict()
    d["shapes"] = [{"type": "mesh", "filename": sphere_ply.name, "material": "m", "smooth": True,
                    "transform": {"scale": 1.2}}]
    scene = tmp_path / "smooth.json"
    scene.write_text(json.dumps(d))
    from scenes import compile_scene, load_scene
    c = compile_scene(load_scene(scene))
    np.testing.assert_allclose(np.linalg.norm(c.normals, axis=2), 1.0, atol=1e-6)
    out = tmp_path / "smooth.exr"
    code = ("import sys; sys.modules['scipy'] = None\n"       # SciPy is not a dependency
            "from hwrt.cli import main\n"
            f"sys.exit(main(['render', {str(scene)!r}, '-o', {str(out)!r}, '--json']))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    for word in ("scipy", "sparse", "Traceback", "falling back"):
        assert word not in r.stderr, r.stderr
    assert strict_json(r.stdout)["rays"]["primary"] == 32 * 24 and out.exists()


# ---------------------------------------------------------------------------------------
# 2-3. outputs checked before any work; no output overwrites an input
# ---------------------------------------------------------------------------------------
def _unwritable_dir(tmp_path):
    if os.geteuid() == 0:                    # root writes through permission bits
        return Path("/proc")                 # no regular files can be created in procfs
    d = tmp_path / "readonly"
    d.mkdir()
    d.chmod(0o555)
    return d


@pytest.mark.parametrize("case", ["existing-dir", "under-a-file", "read-only-dir"])
def test_render_output_checked_before_any_work(tmp_path, capsys, case):
    if case == "existing-dir":
        out = tmp_path / "x.exr"
        out.mkdir()
    elif case == "under-a-file":
        (tmp_path / "plain").write_text("")
        out = tmp_path / "plain" / "x.exr"
    else:
        out = _unwritable_dir(tmp_path) / "sub" / "x.exr"
    t = time.perf_counter()
    # a render this size takes minutes: the check must come first
    rc, out_text, err = call(capsys, "render", "cornell", "-o", out, "--width", 4000,
                             "--height", 3000, "--spp", 64, "--json")
    assert time.perf_counter() - t < 30
    line = one_line_error(err)
    assert rc == 2 and out_text == "" and str(out) in line and "internal error" not in line
    assert ".tmp-" not in line
    assert not list(tmp_path.rglob(".tmp-*"))


def test_png_preview_path_is_checked_too(tmp_path, capsys):
    (tmp_path / "x.png").mkdir()
    rc, _, err = call(capsys, "render", "cornell", "-o", tmp_path / "x.exr", "--png",
                      "--width", 4000, "--height", 3000)
    line = one_line_error(err)
    assert rc == 2 and line.startswith(f"hwrt: error: --png: {tmp_path / 'x.png'}"), line
    assert not (tmp_path / "x.exr").exists()


@pytest.mark.parametrize("flag", ["--out", "--dump-aabbs", "--dump-handoff"])
def test_build_outputs_checked_before_any_work(tmp_path, capsys, tetra, flag):
    (tmp_path / "plain").write_text("")
    bad = tmp_path / "plain" / "x"
    rc, out, err = call(capsys, "build", tetra, flag, bad, "--json")
    assert rc == 2 and out == "" and str(bad) in one_line_error(err)
    d = tmp_path / "adir"
    d.mkdir()
    if flag != "--out":
        rc, _, err = call(capsys, "build", tetra, flag, d)
        assert rc == 2 and "is a directory" in one_line_error(err) and str(d) in err


def test_verify_and_bench_outputs_checked_before_any_work(tmp_path, capsys, tetra):
    d = tmp_path / "adir.npz"
    d.mkdir()
    rc, _, err = call(capsys, "verify", tetra, "--rays", 10, "--mismatches", d)
    assert rc == 2 and str(d) in one_line_error(err)
    plain = tmp_path / "plain"
    plain.write_text("")
    for what in ("tti", "accuracy"):
        rc, _, err = call(capsys, "bench", what, tetra, "--out-dir", plain)
        assert rc == 2 and str(plain) in one_line_error(err) and "not a directory" in err
    assert not list(tmp_path.rglob(".tmp-*"))


def test_no_output_overwrites_an_input(tmp_path, capsys, tetra):
    before = tetra.read_bytes()
    for argv in (["build", tetra, "--dump-aabbs", tetra],
                 ["build", tetra, "--dump-handoff", tetra],
                 ["build", tetra, "--dump-aabbs", tmp_path / "." / "tetra.obj"],   # another spelling
                 ["build", tetra, "--out", tmp_path / "tetra", "--dump-aabbs", tmp_path / "tetra.json"]):
        rc, out, err = call(capsys, *argv)
        assert rc == 2 and out == "", err
        assert str(argv[-1]) in one_line_error(err)
    link = tmp_path / "link.obj"
    link.symlink_to(tetra)
    rc, _, err = call(capsys, "build", tetra, "--dump-aabbs", link)
    assert rc == 2 and "input" in one_line_error(err)
    assert tetra.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.obj", "tetra.obj"]


def test_an_output_the_disk_refuses_is_one_line_exit_1_and_no_file(tmp_path, capsys, tetra,
                                                                   monkeypatch):
    """Checked writable before the work, then refused by the disk (full): not bad input, not
    an internal error, but the file and the reason."""
    import errno
    import hwbvh.files as files
    real = files.tempfile.mkstemp

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(files.tempfile, "mkstemp", full)
    out = tmp_path / "boxes.bin"
    rc, stdout, err = call(capsys, "build", tetra, "--dump-aabbs", out, "--json")
    assert rc == 1 and stdout == ""
    assert one_line_error(err) == f"hwrt: cannot write {out}: No space left on device"
    monkeypatch.setattr(files.tempfile, "mkstemp", real)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tetra.obj"]


def test_write_files_is_all_or_nothing(tmp_path):
    from hwbvh.files import write_files

    def fails(tmp):
        Path(tmp).write_bytes(b"half")
        raise OSError("disk full")
    with pytest.raises(OSError):
        write_files([(tmp_path / "a.bin", b"a"), (tmp_path / "b.exr", fails)])
    assert list(tmp_path.iterdir()) == []
    write_files([(tmp_path / "a.bin", b"a"), (tmp_path / "b.txt", "b"),
                 (tmp_path / "c.dat", lambda tmp: Path(tmp).write_bytes(b"c"))])
    assert sorted(p.read_bytes() for p in tmp_path.iterdir()) == [b"a", b"b", b"c"]


def test_directories_made_for_files_that_do_not_appear_are_removed(tmp_path):
    """A failed or interrupted write removes the directories it created for its files, and
    only those; a write that succeeds keeps them."""
    import errno
    from hwbvh import files
    write_files = files.write_files

    def fails(tmp):
        raise KeyboardInterrupt
    (tmp_path / "kept").mkdir()
    with pytest.raises(KeyboardInterrupt):
        write_files([(tmp_path / "kept" / "new" / "a.bin", b"a"),
                     (tmp_path / "made" / "deeper" / "b.exr", fails)])
    assert [p.name for p in tmp_path.iterdir()] == ["kept"]
    assert list((tmp_path / "kept").iterdir()) == []
    write_files([(tmp_path / "made" / "deeper" / "b.txt", "b")])
    assert (tmp_path / "made" / "deeper" / "b.txt").read_text() == "b"
    # a file where a directory should be: the error says so, for the path asked for
    (tmp_path / "f").write_text("")
    with pytest.raises(files.OutputError) as e:
        write_files([(tmp_path / "new" / "a.bin", b"a"), (tmp_path / "f" / "sub" / "b.bin", b"b")])
    assert (e.value.errno, e.value.filename) == (errno.ENOTDIR, str(tmp_path / "f" / "sub" / "b.bin"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f", "kept", "made"]


def test_a_directory_another_writer_removes_is_made_again(tmp_path, monkeypatch):
    """Another writer that made the same new directory and failed removes it again, between
    this writer finding it and creating its temporary file there: this one makes it again."""
    from hwbvh import files
    real = files.tempfile.mkstemp
    removed = []

    def after_the_other_writer_failed(*args, dir, **kw):
        if not removed:
            os.rmdir(dir)
            removed.append(dir)
        return real(*args, dir=dir, **kw)
    monkeypatch.setattr(files.tempfile, "mkstemp", after_the_other_writer_failed)
    files.write_files([(tmp_path / "new" / "a.bin", b"a")])
    assert removed == [str(tmp_path / "new")]
    assert (tmp_path / "new" / "a.bin").read_bytes() == b"a"


def test_an_interrupt_before_the_renames_leaves_nothing(tmp_path, monkeypatch):
    """An interrupt after every file is written but before they are renamed into place
    removes the temporary files."""
    import hwbvh.files as files
    held = files.signals_held
    entered = []

    def interrupted_at_the_renames():
        entered.append(1)
        if len(entered) == 3:                 # two files made; the third hold is the renames
            raise KeyboardInterrupt
        return held()
    monkeypatch.setattr(files, "signals_held", interrupted_at_the_renames)
    with pytest.raises(KeyboardInterrupt):
        files.write_files([(tmp_path / "a.bin", b"a"), (tmp_path / "b.txt", "b")])
    assert len(entered) == 4 and list(tmp_path.iterdir()) == []      # the fourth: the clean-up


def test_a_signal_during_a_hold_is_acted_on_after_it_by_the_handler_in_place():
    from hwbvh.files import signals_held
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    steps = []
    with pytest.raises(KeyboardInterrupt):
        with signals_held():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.2)                   # Python acts on the signal here: it is held
            steps.append("held")
    assert steps == ["held"]
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


def test_a_handler_that_raises_as_a_hold_begins_leaves_the_handlers_as_they_were(monkeypatch):
    """A pending signal's handler may run (and raise) just as a hold swaps in its recorder;
    the hold still puts every handler back."""
    import hwbvh.files as files
    real = signal.signal
    calls = []

    def swap_then_raise(sig, handler):
        old = real(sig, handler)
        calls.append(sig)
        if len(calls) == 1:                   # as if SIGTERM's handler ran right after the swap
            raise KeyboardInterrupt
        return old
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(files.signal, "signal", swap_then_raise)
    with pytest.raises(KeyboardInterrupt):
        with files.signals_held():
            pass
    monkeypatch.undo()
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


# ---------------------------------------------------------------------------------------
# 4. strict JSON
# ---------------------------------------------------------------------------------------
def test_json_text_maps_non_finite_numbers_to_null():
    from hwbvh.files import json_text
    obj = {"a": float("inf"), "b": [np.float32("nan"), -np.inf, np.int64(3)], "c": np.array([1.5, np.inf]),
           "d": (np.bool_(True), None, "x")}
    assert strict_json(json_text(obj)) == {"a": None, "b": [None, None, 3], "c": [1.5, None],
                                          "d": [True, None, "x"]}


def test_verify_replay_json_is_strict(tmp_path, capsys, tetra):
    rays = tmp_path / "rays.npz"
    np.savez(rays, origins=np.array([[0.2, 0.2, -1.0], [5.0, 5.0, 5.0]]),
             dirs=np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]), tmax=np.array([np.inf, np.inf]))
    rc, out, err = call(capsys, "verify", tetra, "--replay", rays, "--json")
    assert rc == 0, err
    r = strict_json(out)
    hit, miss = r["replayed"]
    assert hit["ours"][0] >= 0 and hit["ours"][1] == pytest.approx(1.0)
    assert miss["ours"] == [-1, None] and miss["embree"] == [-1, None]


def test_bench_tti_honours_size_and_writes_strict_json(tmp_path, sphere_ply):
    out_dir = tmp_path / "out"
    r = run("bench", "tti", sphere_ply, "--quick", "--width", 32, "--height", 24,
            "--out-dir", out_dir, "--json")
    assert r.returncode == 0, r.stderr
    res = strict_json(r.stdout)
    assert res["setting"]["width"] == 32 and res["setting"]["height"] == 24
    strict_json((out_dir / "tti.json").read_text())
    for line in (out_dir / "tti.jsonl").read_text().splitlines():
        strict_json(line)
    # break-even budgets are rays or null ("never behind": infinite), never Infinity
    for s in res["break_even"]:
        for key in ("break_even_rays", "break_even_rays_vs_sweep"):
            assert s[key] is None or s[key] >= 0



def test_bench_study_into_a_directory_in_use_is_refused_and_touches_nothing(tmp_path, sphere_ply):
    """A study resumes from the cells in its output directory: a second run into it while the
    first holds it (here the test holds it, as a run does) is refused before any cell."""
    from hwbvh.files import held_directory
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    (out_dir / "tti.jsonl").write_text("")
    with held_directory(str(out_dir), "bench tti"):
        r = run("bench", "tti", sphere_ply, "--quick", "--width", 8, "--height", 8,
                "--out-dir", out_dir)
    assert r.returncode == 2
    assert "another hwrt bench tti is writing into it" in one_line_error(r.stderr)
    assert sorted(p.name for p in out_dir.iterdir()) == ["tti.jsonl"]
    assert (out_dir / "tti.jsonl").read_text() == ""

# ---------------------------------------------------------------------------------------
# 5 and 10. scene files: negative light, unknown keys
# ---------------------------------------------------------------------------------------
BAD_SCENE_EDITS = {
    "negative-intensity": (lambda d: d["lights"][0].update(intensity=[-1, 1, 1]), "lights\\[0\\].intensity"),
    "negative-irradiance": (lambda d: d.update(lights=[{"type": "directional", "direction": [0, -1, 0],
                                                        "irradiance": [1, -2, 1]}]), "irradiance"),
    "negative-ambient": (lambda d: d.update(integrator={"ambient": [-0.1, 0, 0]}), "integrator.ambient"),
    "top-level-typo": (lambda d: d.update(light=d.pop("lights")), "'light'.*did you mean 'lights'"),
    "unknown-top-level": (lambda d: d.update(colour=1), "'colour': unknown key"),
    "shape-key": (lambda d: d["shapes"][0].update(radius_=2), "shapes\\[0\\].radius_.*'radius'"),
    "shape-key-of-another-type": (lambda d: d["shapes"][0].update(corners=[]), "shapes\\[0\\].corners"),
    "material-key": (lambda d: d["materials"]["m"].update(reflectanse=[1, 1, 1]), "materials.m.reflectanse"),
    "light-key": (lambda d: d["lights"][0].update(power=3), "lights\\[0\\].power"),
    "camera-key": (lambda d: d["camera"].update(fovy=30), "camera.fovy.*'fov'"),
    "film-key": (lambda d: d["film"].update(samples=4), "film.samples"),
    "integrator-key": (lambda d: d.update(integrator={"maxdepth": 3}), "integrator.maxdepth.*'max_depth'"),
    "film-jitter-not-bool": (lambda d: d["film"].update(jitter="no"), "film.jitter"),
    "negative-radius": (lambda d: d["shapes"][0].update(radius=-1),
                        "shapes\\[0\\].radius': -1 is out of range \\(must be at least 1e-30\\)"),
    "infinite-radius": (lambda d: d["shapes"][0].update(radius=float("inf")),
                        "shapes\\[0\\].radius': expected a finite number, got inf"),
    "nan-fov": (lambda d: d["camera"].update(fov=float("nan")),
                "camera.fov': expected a finite number, got nan"),
    "nan-width": (lambda d: d["film"].update(width=float("nan")),
                  "film.width': expected a finite number, got nan"),
    "infinite-width": (lambda d: d["film"].update(width=float("inf")),
                       "film.width': expected a finite number, got inf"),
    "fractional-width": (lambda d: d["film"].update(width=32.5),
                         "film.width': expected an integer, got 32.5"),
    "huge-int": (lambda d: d["camera"].update(fov=10 ** 30), "camera.fov': 1000000000000000000000000000000 is out of range"),
    "material-not-a-name": (lambda d: d["shapes"][0].update(material=[1, 2]), "shapes\\[0\\].material': unknown material"),
    "internal-key": (lambda d: d["shapes"][0].update(_world=1), "shapes\\[0\\]._world': unknown key"),
    "film-not-an-object": (lambda d: d.update(film="abc"), "key 'film': expected an object"),
    "too-many-triangles": (lambda d: d["shapes"][0].update(subdiv=[100000, 100000]), "subdiv'.*2\\^24 triangles"),
    "huge-coordinate": (lambda d: d["camera"].update(eye=[0, 0, 1e308]), "camera.eye': expected 3 finite numbers of magnitude at most 1e\\+15"),
    "huge-intensity": (lambda d: d["lights"][0].update(intensity=[1e308, 1, 1]), "lights\\[0\\].intensity': expected 3 finite numbers of magnitude at most 3.40282e\\+38"),
    "booleans-as-numbers": (lambda d: d["camera"].update(up=[False, True, False]), "camera.up': expected 3"),
    "film-too-large": (lambda d: d.update(film={"width": 32768, "height": 32768}), "film.width'.*pixels a film may hold"),
}


@pytest.mark.parametrize("name", list(BAD_SCENE_EDITS))
def test_bad_scene_keys_and_values(tmp_path, capsys, name):
    from scenes import compile_scene, load_scene
    edit, match = BAD_SCENE_EDITS[name]
    d = scene_dict()
    edit(d)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match=match):
        compile_scene(load_scene(p))
    rc, out, err = call(capsys, "render", p, "-o", tmp_path / "o.exr")
    assert rc == 2 and out == "" and str(p) in one_line_error(err)
    assert not (tmp_path / "o.exr").exists()


def test_unknown_mesh_transform_key(tmp_path, tetra):
    from scenes import compile_scene, load_scene
    d = scene_dict(shapes=[{"type": "mesh", "filename": str(tetra), "material": "m",
                            "transform": {"rotate_x": 30}}])
    p = tmp_path / "t.json"
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match="shapes\\[0\\].transform.rotate_x.*'rotate_y'"):
        compile_scene(load_scene(p))


def test_zero_mesh_scale_is_refused(tmp_path, tetra):
    from scenes import compile_scene, load_scene
    d = scene_dict(shapes=[{"type": "mesh", "filename": str(tetra), "material": "m",
                            "transform": {"scale": [1, 0, 1]}}])
    p = tmp_path / "t.json"
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match="shapes\\[0\\].transform.scale': a scale of 0"):
        compile_scene(load_scene(p))


def test_builtin_and_mesh_scenes_use_known_keys_only(tetra):
    from scenes import BUILTIN, compile_scene, load_scene, transform_scene
    for name in BUILTIN:
        compile_scene(transform_scene(load_scene(name, width=8, height=6), 2.0))
    compile_scene(load_scene(tetra))


def test_obj_face_index_zero_is_an_error(tmp_path, capsys):
    p = tmp_path / "zero.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 0 2 4\n")
    from hwbvh.primitives import load_mesh_arrays
    with pytest.raises(InputError, match="line 6: face index 0"):
        load_mesh_arrays(p)
    rc, _, err = call(capsys, "build", p)
    assert rc == 2 and str(p) in one_line_error(err) and "index 0" in err
    q = tmp_path / "slashes.obj"
    q.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/0 3/1\n")
    with pytest.raises(InputError, match="index 0"):
        load_mesh_arrays(q)
    ok = tmp_path / "ok.obj"                           # 10, 20, comments: not index 0
    ok.write_text("v 0 0 0\n" * 10 + "v 1 0 0\nv 0 1 0\n# f 0 1 2\nf 10 11 12\nf -3 -2 -1\n")
    V, F = load_mesh_arrays(ok)
    assert V[F].tolist() == [[[0, 0, 0], [1, 0, 0], [0, 1, 0]]] * 2


# ---------------------------------------------------------------------------------------
# 6. build --json: kernel loading apart from building
# ---------------------------------------------------------------------------------------
def test_build_json_reports_startup_apart_from_build(tetra):
    r = run("build", tetra, "--json")                  # a fresh process: kernels still to load
    assert r.returncode == 0, r.stderr
    res = strict_json(r.stdout)
    assert res["triangles"] == 4
    # loading the kernels is startup, not build: the four-triangle build itself is far shorter
    assert 0 <= res["build_seconds"] < res["startup_seconds"]


# ---------------------------------------------------------------------------------------
# 7. option values: exit 2, one line naming the option
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv,flag", [
    (["render", "cornell", "--seed", "-1"], "--seed"),
    (["render", "cornell", "--width", "0"], "--width"),
    (["bench", "build", "--repeat", "0"], "--repeat"),
    (["bench", "tti", "--quick", "--width", "0"], "--width"),
    (["verify", "cornell", "--rays", "0"], "--rays"),
    (["build", "m.obj", "--leaf-size", "four"], "--leaf-size"),
    (["simulate", "m.obj", "--clock-mhz", "-5"], "--clock-mhz"),
    (["simulate", "m.obj", "--control-latency", "-1"], "--control-latency"),
])
def test_bad_option_values_exit_2_in_one_line(capsys, argv, flag):
    rc, out, err = call(capsys, *argv)
    line = one_line_error(err)
    assert rc == 2 and out == "" and flag in line and "internal error" not in line


@pytest.mark.parametrize("option,values,words", [
    ("--clock-mhz", ["0", "0.5", "2000", "nan"], "must lie in 1..1000, got"),
    ("--w", ["0"], "must be at least 1, got"),
    ("--w", ["99"], "must be at most 64, got"),
])
def test_a_hardware_knob_off_its_range_says_the_range_on_either_side(capsys, option, values, words):
    """The simulator's knobs read their hardware ranges where they are parsed, so a value below
    the range is told as one above it is (0 and 0.5 MHz alike)."""
    for v in values:
        rc, out, err = call(capsys, "simulate", "m.obj", option, v)
        assert rc == 2 and out == "" and one_line_error(err) == f"hwrt: error: {option}: {words} {v}"


def test_library_errors_name_parameters_and_the_cli_names_options(capsys, tetra):
    import hwbvh
    from scenes.meshes import sphere
    for kw, param in (({"leaf_size": 0}, "leaf_size"), ({"bins": 1}, "bins"),
                      ({"builder": "fast"}, "builder"), ({"capacity": 0}, "capacity")):
        with pytest.raises(ParameterError) as e:
            hwbvh.build(sphere(4, 6), **kw)
        assert e.value.parameter == param and "--" not in str(e.value)
    rc, _, err = call(capsys, "build", tetra, "--bins", 100)
    assert rc == 2 and one_line_error(err) == ("hwrt: error: --bins: must be an integer in 2..64 "
                                               "(the hardware has at most 16), got 100")


# ---------------------------------------------------------------------------------------
# 8. signals: temporary files removed, 130 / 143
# ---------------------------------------------------------------------------------------
SIGNAL_DURING_WRITE = textwrap.dedent("""
    import os, signal, sys, time
    from pathlib import Path
    import hwrt.cli as cli
    from hwbvh.files import write_files

    def slow_write(tmp):
        Path(tmp).write_bytes(b"half an image")
        os.kill(os.getpid(), signal.{sig})
        time.sleep(30)                      # the handler interrupts this
        Path(tmp).write_bytes(b"a whole image")

    def fake_build(args):                   # an output being written when the signal comes
        write_files([(args.out + ".exr", slow_write)])

    cli.cmd_build = fake_build
    sys.exit(cli.main(["build", "mesh.obj", "--out", sys.argv[1]]))
""")


@pytest.mark.parametrize("sig,code,word", [("SIGTERM", 143, "terminated"), ("SIGINT", 130, "interrupted")])
def test_signal_during_a_write_removes_the_temporary_file(tmp_path, sig, code, word):
    r = subprocess.run([sys.executable, "-c", SIGNAL_DURING_WRITE.format(sig=sig), str(tmp_path / "x")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == code, r.stderr
    assert one_line_error(r.stderr) == f"hwrt: {word}"
    assert list(tmp_path.iterdir()) == []


SIGNAL_AS_THE_TEMPORARY_FILE_IS_MADE = textwrap.dedent("""
    import os, signal, sys, tempfile, threading, time
    import hwrt.cli as cli
    from hwbvh.files import write_files

    real_mkstemp = tempfile.mkstemp
    bystander = threading.Thread(target=threading.Event().wait, daemon=True)
    bystander.start()

    def mkstemp(*args, **kwargs):           # the signal comes once the file exists
        made = real_mkstemp(*args, **kwargs)
        if sys.argv[2] == "process":
            os.kill(os.getpid(), signal.SIGTERM)
        else:                               # the kernel's choice when another thread takes it
            signal.pthread_kill(bystander.ident, signal.SIGTERM)
            time.sleep(0.5)                 # Python acts on it in this thread, in the sleep
        return made

    tempfile.mkstemp = mkstemp

    def fake_build(args):
        write_files([(args.out + ".exr", lambda tmp: None)])

    cli.cmd_build = fake_build
    sys.exit(cli.main(["build", "mesh.obj", "--out", sys.argv[1]]))
""")


@pytest.mark.parametrize("receiver", ["process", "another thread"])
def test_signal_as_the_temporary_file_is_made_leaves_nothing(tmp_path, receiver):
    """A signal between creating a temporary file and recording it for clean-up is held
    until the file is recorded, so the clean-up removes it, whichever thread receives it."""
    r = subprocess.run([sys.executable, "-c", SIGNAL_AS_THE_TEMPORARY_FILE_IS_MADE,
                        str(tmp_path / "x"), receiver.split()[0]],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 143, r.stderr
    assert list(tmp_path.iterdir()) == []


LATE_SIGNAL = textwrap.dedent("""
    import os, signal, sys, time
    import hwrt.cli as cli

    out, when = sys.argv[1], sys.argv[2]
    if when == "renames":                   # held while write_files renames, acted on after
        real_replace = os.replace

        def replace(src, dst):
            real_replace(src, dst)
            if dst == out:
                os.kill(os.getpid(), signal.SIGINT)

        os.replace = replace
    else:                                   # once the report is out
        real_emit = cli._emit

        def emit(*args):
            real_emit(*args)
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1)                   # Python acts on the signal here

        cli._emit = emit
    sys.exit(cli.main(["render", "cornell", "--width", "8", "--height", "8", "--spp", "1",
                       "-o", out]))
""")


@pytest.mark.parametrize("when", ["renames", "report"])
def test_a_signal_once_the_outputs_are_in_place_does_not_fail_the_run(tmp_path, when):
    out = tmp_path / "x.exr"
    r = subprocess.run([sys.executable, "-c", LATE_SIGNAL, str(out), when], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert f"output: {out}" in r.stdout
    assert [p.name for p in tmp_path.iterdir()] == ["x.exr"]


def test_sigterm_during_a_render_leaves_nothing(tmp_path):
    out = tmp_path / "x.exr"
    env = dict(os.environ, **{PROGRESS_ENV: "1"})
    p = subprocess.Popen([sys.executable, "-m", "hwrt.cli", "render", "cornell", "-o", str(out),
                          "--width", "64", "--height", "48", "--spp", "4096", "--png"],
                         stderr=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
    try:
        seen = b""
        while b"render cornell" not in seen:       # the progress bar: rendering has started
            chunk = p.stderr.read1(4096)
            assert chunk, "the render ended before it could be signalled"
            seen += chunk
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 143, (seen + err).decode()
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------
# 9. resume file with a cut last line
# ---------------------------------------------------------------------------------------
def test_resume_file_with_a_cut_last_line_keeps_the_next_record(tmp_path):
    from hwrt.study import Cells
    p = tmp_path / "tti.jsonl"
    p.write_text(json.dumps({"key": "a", "v": 1}) + "\n" + '{"key": "b", "v": 2, "render_sec')
    cells = Cells(p)
    assert cells.get("a") and not cells.get("b")
    cells.add({"key": "b", "v": 3})
    again = Cells(p)
    assert again.get("a")["v"] == 1 and again.get("b")["v"] == 3
    assert [json.loads(line)["key"] for line in p.read_text().splitlines()] == ["a", "b"]
    # a whole record that only lacks its newline is kept
    q = tmp_path / "acc.jsonl"
    q.write_text(json.dumps({"key": "c", "v": 4}))
    Cells(q).add({"key": "d", "v": 5})
    assert set(Cells(q).done) == {"c", "d"}


@pytest.mark.parametrize("store", ["tti", "explore"])
def test_a_cells_file_the_disk_refuses_is_an_output_error_naming_it(tmp_path, monkeypatch, store):
    """A benchmark's or explore's cells file that cannot be appended to (a full disk, told at
    the flush to the disk) says so by name, as every other output does."""
    import errno
    import hwrt.explore as explore
    import hwrt.study as study
    from hwbvh.files import OutputError

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(study.os, "fsync", full)
    p = tmp_path / "cells.jsonl"
    with pytest.raises(OutputError, match="No space left on device") as e:
        if store == "tti":
            study.Cells(p).add({"key": "a", "v": 1})
        else:
            explore._CellStore(p, fresh=True).add_many([{"key": "a", "v": 1}])
    assert e.value.filename == str(p)
    assert list(tmp_path.iterdir()) == []          # no empty cells file left behind
    # a fresh run's first cell replaces the saved cells only once it is on the disk
    p.write_text('{"key": "kept"}\n')
    with pytest.raises(OutputError):
        if store == "tti":
            study.Cells(p, fresh=True).add({"key": "a", "v": 1})
        else:
            explore._CellStore(p, fresh=True).add_many([{"key": "a", "v": 1}])
    assert list(tmp_path.iterdir()) == [p] and p.read_text() == '{"key": "kept"}\n'


# ---------------------------------------------------------------------------------------
# 10. options honoured or rejected; verify --rays N traces N rays
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv,flag", [
    (["bench", "build", "--width", "64"], "--width"),
    (["bench", "animation", "--rays", "10"], "--rays"),
    (["bench", "accuracy", "--spp", "2"], "--spp"),
    (["bench", "model", "--repeat", "2"], "--repeat"),
    (["bench", "tti", "--rays", "10"], "--rays"),
])
def test_bench_options_a_benchmark_does_not_read_are_errors(capsys, argv, flag):
    rc, out, err = call(capsys, *argv)
    assert rc == 2 and out == "" and flag in one_line_error(err) and "does not read" in err


def test_bench_accel_named_twice_is_an_error(capsys):
    rc, out, err = call(capsys, "bench", "trace", "--accel", "grid", "--accel", "kdtree",
                        "--accel", "grid")
    assert rc == 2 and out == "" and one_line_error(err) == "hwrt: error: --accel: grid given twice"


@pytest.mark.parametrize("argv,line", [
    (["bench", "tti", "--quick", ""], "hwrt: error: MESH: expected a value, got an empty one"),
    (["bench", "trees", "--repeat", "1", "a.ply", "--bogus"], "hwrt: error: unrecognized arguments: --bogus"),
    (["bench", "trees", "--repeat", "1", "--", "no/such.ply"],
     "hwrt: error: no/such.ply: no such scene or file (built-in scenes: cornell, marbles, cloth, room)"),
])
def test_bench_meshes_after_options_are_checked_as_meshes(capsys, argv, line):
    rc, out, err = call(capsys, *argv)
    assert rc == 2 and out == "" and one_line_error(err) == line


def test_bench_contention_takes_one_scene(capsys):
    rc, out, err = call(capsys, "bench", "contention", "cornell", "marbles")
    assert rc == 2 and out == "" and one_line_error(err) == (
        "hwrt: error: marbles: bench contention takes one scene or mesh file")


def test_bench_scale_takes_no_meshes(capsys, tetra):
    rc, _, err = call(capsys, "bench", "scale", tetra)
    assert rc == 2 and str(tetra) in one_line_error(err)


def test_bench_quick_sizes_give_way_to_explicit_ones():
    from hwrt.cli import _bench_options
    p = make_parser()
    a = p.parse_args(["bench", "tti", "--quick", "--width", "40"])
    _bench_options(a)
    assert (a.width, a.height, a.repeat, a.spp) == (40, 120, 1, 1)
    a = p.parse_args(["bench", "accuracy", "--height", "30", "--repeat", "2"])
    _bench_options(a)
    assert (a.width, a.height, a.repeat, a.out_dir) == (160, 30, 2, "renders/bench")


@pytest.mark.parametrize("kind", ["primary", "random", "bounces", "shadow"])
def test_verify_traces_exactly_the_rays_asked_for(capsys, tmp_path, sphere_ply, kind):
    rc, out, err = call(capsys, "verify", sphere_ply, "--rays", 1001, "--kind", kind,
                        "--mismatches", tmp_path / "m.npz", "--json")
    assert rc == 0, err
    r = strict_json(out)
    assert r["rays"] == r["rays_requested"] == 1001
    assert r["agree"] + r["tie"] + r["mismatch"] == 1001


def test_verify_says_so_when_it_traces_fewer_and_refuses_none(capsys, tmp_path):
    # a sliver seen edge-on by the framing camera: few first rays hit it
    p = write_ply(tmp_path / "sliver.ply", [[[0, 0, 0], [1, 0, 0], [0.5, 1e-2, 0]]])
    rc, out, err = call(capsys, "verify", p, "--rays", 50, "--kind", "shadow", "--json",
                        "--mismatches", tmp_path / "m.npz")
    assert rc == 0, err
    r = strict_json(out)
    assert r["rays_requested"] == 50 and 0 < r["rays"] < 50
    assert f"{r['rays']} of the 50 requested" in err
    # a triangle of no area: no first ray hits it, so there is nothing to verify
    p = write_ply(tmp_path / "line.ply", [[[0, 0, 0], [1, 0, 0], [2, 0, 0]]])
    rc, out, err = call(capsys, "verify", p, "--rays", 50, "--kind", "shadow")
    assert rc == 2 and out == "" and one_line_error(err) == (
        f"hwrt: error: {p}: makes no shadow rays: none of the first rays that make them hits "
        f"the mesh")


def test_verify_reports_how_many_rays_hit(capsys, tmp_path, sphere_ply):
    """"All agree" is read with the hits: shadow rays are checked as occluded queries, the
    others as closest-hit ones, and each says how many of its rays hit (or are blocked)."""
    for kind, query in (("primary", "intersect"), ("shadow", "occluded")):
        rc, out, err = call(capsys, "verify", sphere_ply, "--rays", 500, "--kind", kind,
                            "--json", "--mismatches", tmp_path / "m.npz")
        assert rc == 0, err
        r = strict_json(out)
        assert r["query"] == query and r["hit_fraction"] == r["hit"] / r["rays"]
        # the framing camera's rays miss around the sphere; shadow rays from its far side
        # are blocked by the sphere itself
        assert 0 < r["hit"] < r["rays"] == 500


def test_verify_without_mismatches_says_an_earlier_file_was_left(capsys, tmp_path, sphere_ply):
    """No mismatches: no file is written, and one already at the path (an earlier run's) is
    left as it was, with a note, so that it is not taken for this run's."""
    old = tmp_path / "m.npz"
    old.write_bytes(b"an earlier run's")
    rc, out, err = call(capsys, "verify", sphere_ply, "--rays", 300, "--kind", "primary",
                        "--mismatches", old, "--json")
    assert rc == 0 and strict_json(out)["mismatch"] == 0, err
    assert err == f"hwrt: note: no mismatches, so {old} was not written: the file there is " \
                  "an earlier run's\n"
    assert old.read_bytes() == b"an earlier run's"
    rc, out, err = call(capsys, "verify", sphere_ply, "--rays", 300, "--kind", "primary",
                        "--mismatches", tmp_path / "new.npz", "--json")
    assert rc == 0 and err == "" and not (tmp_path / "new.npz").exists()


def _mismatch_file(path, tris, **run):
    """A mismatch file as hwrt verify writes it, for two rays from inside the tetrahedron."""
    from hwrt.cli import _triangles_digest
    centre = np.asarray(tris, np.float64).reshape(-1, 3).mean(axis=0)
    run.setdefault("triangles_sha256", _triangles_digest(tris))
    np.savez(path, origins=np.array([centre, centre], np.float32),
             dirs=np.array([[0, 0, 1], [1, 1, 1]], np.float32), tmax=np.array([np.inf, 1e-3]),
             **{k: np.str_(v) for k, v in run.items()})
    return path


def test_replay_traces_as_the_run_that_wrote_the_file(capsys, tmp_path, tetra):
    """A mismatch file records its ray set, structure and triangles: --replay re-traces with
    that query and structure, and refuses another scene's triangles."""
    from hwrt.cli import _scene_geometry
    tris = _scene_geometry(str(tetra))[1]
    f = _mismatch_file(tmp_path / "m.npz", tris, kind="shadow", accel="kdtree", scene="tetra")
    rc, out, err = call(capsys, "verify", tetra, "--replay", f, "--json")
    assert rc == 0, err
    r = strict_json(out)
    assert (r["kind"], r["accel"], r["query"], r["rays"], r["agree"]) == \
        ("shadow", "kdtree", "occluded", 2, 2)
    # from inside, the first ray is blocked; the second stops before any face
    assert [(x["ours"], x["embree"]) for x in r["replayed"]] == [(True, True), (False, False)]
    rc, out, err = call(capsys, "verify", tetra, "--replay", f)
    assert rc == 0 and out.splitlines()[0] == (
        f"replayed 2 shadow rays of {f} (occluded queries, accel kdtree): 2 agree, 0 tie, "
        f"0 mismatch (our answer wrong in 0, Embree's in 0)")
    centre = "(" + ", ".join(f"{x:.9g}" for x in r["replayed"][0]["origin"]) + ")"
    assert out.splitlines()[1:] == [
        f"  ray 0: agree; ours blocked, Embree blocked; origin {centre}, direction (0, 0, 1), "
        f"t_max inf",
        f"  ray 1: agree; ours not blocked, Embree not blocked; origin {centre}, direction "
        f"(1, 1, 1), t_max 0.001"]
    other = _mismatch_file(tmp_path / "o.npz", tris + 1, kind="random", scene="elsewhere")
    rc, out, err = call(capsys, "verify", tetra, "--replay", other)
    assert rc == 2 and out == "" and one_line_error(err) == (
        f"hwrt: error: --replay {other}: its rays were verified on other triangles ('elsewhere') "
        f"than the {len(tris)} of tetra: replay it on the scene it was made on")
    bad = _mismatch_file(tmp_path / "b.npz", tris, kind="sideways")
    rc, out, err = call(capsys, "verify", tetra, "--replay", bad)
    assert rc == 2 and one_line_error(err) == (
        f"hwrt: error: --replay {bad}: key 'kind': 'sideways' is not a ray set hwrt verify "
        f"checks (primary, random, bounces, shadow)")
    bad = _mismatch_file(tmp_path / "a.npz", tris, accel="octree")
    rc, out, err = call(capsys, "verify", tetra, "--replay", bad)
    assert rc == 2 and out == "" and one_line_error(err) == (
        f"hwrt: error: --replay {bad}: key 'accel': 'octree' is not a structure hwrt verify "
        f"checks (bvh, grid, kdtree)")


@pytest.mark.parametrize("kind, accel, query", [("random", "bvh", "intersect"),
                                                ("shadow", "grid", "occluded")])
def test_a_file_written_by_verify_replays_as_its_run(capsys, tmp_path, monkeypatch, tetra,
                                                     kind, accel, query):
    """What hwrt verify writes, --replay reads: two of a real run's rays reported as
    mismatches go to the file, and replaying it re-traces them with the run's query and
    structure, where they agree."""
    import traversal.verify as tv
    real = tv.verify_mesh

    def two_reported(*a, **k):
        counts, labels, rays, ours, ref = real(*a, **k)
        labels = labels.copy()
        labels[:2] = 2
        return counts, labels, rays, ours, ref

    monkeypatch.setattr(tv, "verify_mesh", two_reported)
    f = tmp_path / "m.npz"
    rc, out, err = call(capsys, "verify", tetra, "--rays", 50, "--kind", kind, "--accel", accel,
                        "--mismatches", f, "--json")
    assert rc == 0 and strict_json(out)["mismatch_file"] == str(f), err
    monkeypatch.undo()
    rc, out, err = call(capsys, "verify", tetra, "--replay", f, "--json")
    assert rc == 0, err
    r = strict_json(out)
    assert (r["kind"], r["accel"], r["query"], r["rays"], r["agree"] + r["tie"]) == \
        (kind, accel, query, 2, 2)


def test_replay_of_a_run_key_stored_as_an_object_array_names_the_key(capsys, tmp_path, tetra):
    """A run key NumPy can read only through pickle is named, not taken for a broken
    archive."""
    from hwrt.cli import _scene_geometry
    tris = _scene_geometry(str(tetra))[1]
    f = tmp_path / "m.npz"
    _mismatch_file(f, tris)
    arrays = dict(np.load(f))
    arrays["scene"] = np.array(["tetra", None], dtype=object)
    np.savez(f, **arrays)
    rc, out, err = call(capsys, "verify", tetra, "--replay", f)
    assert rc == 2 and out == "" and one_line_error(err) == (
        f"hwrt: error: --replay {f}: key 'scene': expected a string, got an object array")


def test_replay_rejects_options_of_a_verification_run(capsys, tmp_path, tetra):
    rc, _, err = call(capsys, "verify", tetra, "--replay", tmp_path / "x.npz", "--rays", 10)
    assert rc == 2 and "--rays" in one_line_error(err)
    # the file records its structure: any --accel is refused, the default's name too
    for accel in ("bvh", "grid"):
        rc, _, err = call(capsys, "verify", tetra, "--replay", tmp_path / "x.npz", "--accel", accel)
        assert rc == 2 and one_line_error(err) == (
            "hwrt: error: --accel: is for a verification run; --replay re-traces the file's rays")


def test_the_mismatch_file_must_be_named_as_an_npz_archive(capsys, tmp_path, tetra):
    rc, out, err = call(capsys, "verify", tetra, "--rays", 10, "--mismatches", tmp_path / "m.txt")
    assert rc == 2 and out == "" and one_line_error(err) == (
        f"hwrt: error: --mismatches: {tmp_path / 'm.txt'} does not end in .npz (the mismatch file "
        "is a NumPy archive, which --replay reads)")


def test_replay_of_a_missing_or_foreign_file(capsys, tmp_path, tetra):
    missing = tmp_path / "x.npz"
    rc, _, err = call(capsys, "verify", tetra, "--replay", missing)
    assert rc == 2 and one_line_error(err).endswith(f"{missing}: no such file")
    foreign = tmp_path / "y.npz"
    np.savez(foreign, something=np.zeros(3))
    rc, _, err = call(capsys, "verify", tetra, "--replay", foreign)
    assert rc == 2 and "not a mismatch file" in one_line_error(err)


# ---------------------------------------------------------------------------------------
# 12. --help and --version
# ---------------------------------------------------------------------------------------
def _subparsers(parser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices
    return {}


def test_every_option_has_help_and_shows_its_default():
    parser = make_parser()
    for name, sub in _subparsers(parser).items():
        text = sub.format_help()
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action.help, f"hwrt {name} {action.option_strings or action.dest}: no help text"
            if action.option_strings and action.default is not None and action.default is not False:
                assert "default" in sub._get_formatter()._get_help_string(action), (name, action.dest)
        assert "SPEC" not in text and "``" not in text
    assert "(default: 4)" in _subparsers(parser)["build"].format_help()       # --leaf-size
    assert "jitter, 0-2147483647 (default: 0)" in _subparsers(parser)["render"].format_help()   # --seed


def test_top_level_help_is_plain_text_and_version_comes_from_the_package(capsys):
    from importlib.metadata import version
    rc, out, _ = call(capsys, "--help")
    assert rc == 0 and "SPEC" not in out and "``" not in out and ":class:" not in out
    assert "null" in out and "143" in out            # the JSON and exit-status conventions
    rc, out, _ = call(capsys, "--version")
    assert rc == 0 and out.strip() == f"hwrt {version('hwrt')}"


def test_bench_render_page_names_the_command_that_made_it(tmp_path):
    from hwrt.cli import main
    out = tmp_path / "docs"
    assert main(["bench", "render", "--repeat", "1", "--width", "16", "--height", "12",
                 "--spp", "1", "--out-dir", str(out), "--json"]) == 0
    md = (out / "render.md").read_text()
    assert md.startswith("# hwrt bench render\n\nMade by `hwrt bench render --repeat 1 --width 16")


def test_bench_report_written_to_out_dir(tmp_path, capsys):
    from hwrt.cli import main
    out = tmp_path / "docs"
    assert main(["bench", "trees", "cornell", "--repeat", "1", "--width", "16", "--height", "12",
                 "--spp", "1", "--out-dir", str(out), "--json"]) == 0
    files = [str(out / "trees.md"), str(out / "trees.json")]
    assert strict_json(capsys.readouterr().out)["files"] == files
    assert main(["bench", "scale", "--repeat", "1", "--out-dir", str(out)]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == \
        f"wrote {out / 'scale.md'}, {out / 'scale.json'}"
    md = (out / "trees.md").read_text()
    assert "hwrt bench trees cornell --repeat 1" in md and "single-ray" in md
    assert "where the trace time goes" in md
    page = json.loads((out / "trees.json").read_text())
    assert page["machine"]["cores"] >= 1             # where it was measured, as every page
    row = page["rows"][0]
    assert row["scene"] == "cornell"
    # every ray of the packet render falls in exactly one class of the time split
    assert {(c["kind"], c["path"]) for c in row["by_path"]} <= {
        (k, p) for k in ("closest", "shadow") for p in ("packets", "one by one")}
    assert sum(c["rays"] for c in row["by_path"]) == row["packets"]["work"]["hwbvh"]["rays"]
    assert abs(sum(c["time_share"] for c in row["by_path"]) - 1) < 1e-9
    assert "what a unit costs" in md
    assert all("cost_fit" in c and "nodes_ratio" in c for c in row["by_path"])
    # the render's time split into its closest-hit queries, shadow queries and other stages
    assert "where the render's time goes" in md
    for mode in ("packets", "single_ray"):
        stages = row[mode]["stages"]
        assert abs(sum(stages[p]["share"] for p in ("closest", "shadow", "other")) - 1) < 1e-9
        assert stages["closest"]["work_ratio"] > 0 and stages["other"]["work_ratio"] is None
        assert stages["floor_vs_work"] is not None


def test_a_page_made_from_the_mesh_directory_of_the_environment_names_it(tmp_path, capsys,
                                                                         monkeypatch):
    """A benchmark whose meshes come from $HWRT_MESHES records it before its command, so that
    the page's line makes the page again; one given its meshes does not."""
    import trimesh
    from hwrt.cli import THREADING_ENVS, main
    from scenes.meshes import sphere
    for name in THREADING_ENVS:
        monkeypatch.delenv(name, raising=False)
    d = tmp_path / "my meshes"
    d.mkdir()
    tris = sphere(6, 8)
    trimesh.Trimesh(tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3),
                    process=False).export(d / "ball.ply")
    monkeypatch.setenv("HWRT_MESHES", str(d))
    assert main(["bench", "build", "--repeat", "1", "--out-dir", str(tmp_path / "a")]) == 0
    assert f"Made by `HWRT_MESHES='{d}' hwrt bench build --repeat 1 --out-dir " in \
        (tmp_path / "a" / "build.md").read_text()
    assert main(["bench", "build", str(d / "ball.ply"), "--repeat", "1", "--out-dir",
                 str(tmp_path / "b")]) == 0
    assert "Made by `hwrt bench build " in (tmp_path / "b" / "build.md").read_text()
    capsys.readouterr()
    from hwrt.cli import _environment_read, make_parser
    read = lambda *argv: _environment_read(make_parser().parse_args(list(argv)))
    assert read("bench", "animation") == {"HWRT_MESHES": str(d)}      # its exploding bunny
    assert read("bench", "animation", "--quick") == {}       # a generated sphere instead
    assert read("bench", "build", "--mesh-dir", str(d)) == {}
    assert read("bench", "trees") == {} and read("render") == {}
    # how the kernels use the machine, where set: a page's figures depend on it
    monkeypatch.setenv("HWRT_THREADING", "workqueue")
    monkeypatch.setenv("NUMBA_NUM_THREADS", "1")
    assert read("bench", "trees") == {"HWRT_THREADING": "workqueue", "NUMBA_NUM_THREADS": "1"}
    assert read("render") == {}


def test_bench_rows_of_one_name_are_told_apart_by_their_source(tmp_path, capsys):
    """A scene file named as a built-in scene, beside it: the two rows take the names given on
    the command line, not "cornell" twice."""
    from hwrt.bench import told_apart
    from hwrt.cli import main
    scene = tmp_path / "mine.json"
    scene.write_text(json.dumps({
        "name": "cornell", "camera": {"eye": [0, 0, 3], "target": [0, 0, 0]},
        "film": {"width": 8, "height": 6, "spp": 1},
        "lights": [{"type": "point", "position": [2, 3, 2], "intensity": [15, 15, 15]}],
        "materials": {"m": {"type": "diffuse"}},
        "shapes": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m"}]}))
    assert main(["bench", "trees", "--repeat", "1", "--width", "8", "--height", "6", "--spp",
                 "1", "--json", str(scene), "cornell"]) == 0
    rows = json.loads(capsys.readouterr().out)["rows"]
    assert [r["scene"] for r in rows] == [str(scene), "cornell"]
    assert [r["scene"] for r in told_apart([{"scene": "a", "source": "x"},
                                            {"scene": "b", "source": "y"}])] == ["a", "b"]
    # a row renamed to its source may meet another row's name: renamed again until apart
    rows = told_apart([{"scene": "cornell", "source": "a.json"},
                       {"scene": "cornell", "source": "cornell"},
                       {"scene": "a.json", "source": "b.json"}])
    assert [r["scene"] for r in rows] == ["a.json", "cornell", "b.json"]


def test_bench_trees_on_a_scene_whose_rays_do_no_work_gives_null_ratios(tmp_path, capsys):
    """A scene every ray misses (the one triangle behind the camera) visits no node with either
    tree: the work ratios have nothing to divide, so they are null in strict JSON and "-" on
    the page, not a crash."""
    from hwrt.cli import main
    scene = tmp_path / "behind.json"
    scene.write_text(json.dumps({
        "camera": {"eye": [0, 0, 0], "target": [0, 0, -1]},
        "film": {"width": 8, "height": 6, "spp": 1},
        "lights": [{"type": "point", "position": [2, 3, 2], "intensity": [15, 15, 15]}],
        "materials": {"floor": {"type": "diffuse"}},
        "shapes": [{"type": "triangles", "material": "floor",
                    "data": [[[0, 0, 10], [1, 0, 10], [0, 1, 10]]]}]}))
    out = tmp_path / "docs"
    # (the scene after the options: a benchmark's meshes may come anywhere after its name)
    assert main(["bench", "trees", "--repeat", "1", "--out-dir", str(out), "--json",
                 str(scene)]) == 0
    printed = capsys.readouterr().out
    row = json.loads(printed, parse_constant=lambda c: pytest.fail(f"{c} in --json"))["rows"][0]
    for mode in ("packets", "single_ray"):
        assert row[mode]["work"]["hwbvh"]["work_per_ray"] == 0
        assert row[mode]["work_ratio"] is None and row[mode]["render_vs_work"] is None
        assert row[mode]["render_ratio"] > 0
        assert row[mode]["stages"]["floor_vs_work"] is None
    assert " - " in (out / "trees.md").read_text()


def test_unknown_threading_setup_is_a_one_line_input_error(tmp_path):
    """HWRT_THREADING is read when the packages load; a name it does not know is reported like
    any bad input: one line naming it, exit 2, no output."""
    env = dict(os.environ, HWRT_THREADING="bogus")
    out = tmp_path / "x.exr"
    r = run("render", "cornell", "--width", 8, "--height", 8, "--spp", 1, "-o", out, env=env)
    assert r.returncode == 2, r.stderr
    assert "HWRT_THREADING" in one_line_error(r.stderr) and "'bogus'" in r.stderr
    assert not out.exists()


@pytest.mark.parametrize("value", ["0", "two"])
def test_numbas_thread_count_that_numba_cannot_take_is_a_one_line_input_error(tmp_path, value):
    """Numba reads $NUMBA_NUM_THREADS as it is imported: 0 ends in its traceback, a word in a
    page of warnings; the command names it in one line before either."""
    env = dict(os.environ, NUMBA_NUM_THREADS=value)
    out = tmp_path / "x.exr"
    r = run("render", "cornell", "--width", 8, "--height", 8, "--spp", 1, "-o", out, env=env)
    assert r.returncode == 2 and not out.exists()
    assert one_line_error(r.stderr) == f"hwrt: error: $NUMBA_NUM_THREADS: '{value}' is not a " \
                                       f"positive whole number of threads"


def test_every_parallel_entry_of_the_library_reports_an_unknown_threading_setup(monkeypatch):
    import hwbvh
    from hwbvh import parallel
    from hwbvh.cycle_model import simulate_mesh
    from hwbvh.refit import refit
    tris = np.random.default_rng(0).random((64, 3, 3))
    bvh = hwbvh.build(tris)
    monkeypatch.setattr(parallel, "_THREADING_PROBLEM", ("HWRT_THREADING", "unknown set-up 'x'"))
    entries = [lambda: hwbvh.build(tris), lambda: simulate_mesh(tris), lambda: refit(bvh, tris),
               lambda: parallel.run_ranges(lambda lo, hi: None, 10)]
    raised = []
    for entry in entries:
        with pytest.raises(InputError, match="HWRT_THREADING: unknown set-up 'x'") as e:
            entry()
        raised.append(e.value)
    assert len({id(e) for e in raised}) == len(raised)     # a new error each time


def test_human_output_shows_what_does_not_apply_as_n_a(capsys, tetra):
    rc, out, err = call(capsys, "build", tetra, "--builder", "embree")
    assert rc == 0, err
    assert "None" not in out and "nodes: n/a" in out
    rc, out, err = call(capsys, "simulate", tetra)
    assert rc == 0, err
    assert "{" not in out and "'" not in out            # tables inline, not Python reprs
    assert "changed" not in out                         # the preset as it is
    # knobs given beside a preset: said in the text, not only in the JSON's parameters
    rc, out, err = call(capsys, "simulate", tetra, "--preset", "HWBVH-HP", "--w", "2")
    assert rc == 0, err
    assert "changed: w 2 (preset: 4), capacity 4096 (preset: 8192)" in out
    rc, out, err = call(capsys, "simulate", tetra, "--clock-mhz", "250.0000001")
    assert rc == 0 and "changed: clock_mhz 250.0000001 (preset: 250.0)" in out, out
    from hwrt.cli import _shown
    assert _shown({"rays": 3, "closest": {"agree": 2, "t": 0.1234567}, "none": None}) == \
        "rays 3, closest (agree 2, t 0.123457), none n/a"


@pytest.mark.parametrize("content,problem", [(b"\xff\xfe{}", "not UTF-8 text"),
                                             (b"[" * 100000 + b"]" * 100000, "nested too deeply")])
def test_unreadable_scene_files(tmp_path, capsys, content, problem):
    p = tmp_path / "s.json"
    p.write_bytes(content)
    rc, out, err = call(capsys, "render", p, "-o", tmp_path / "o.exr")
    assert rc == 2 and f"{p}: cannot read the scene ({problem}" in one_line_error(err)
    assert not (tmp_path / "o.exr").exists()


def test_overrides_of_a_film_that_is_not_an_object(tmp_path, capsys):
    p = tmp_path / "s.json"
    p.write_text(json.dumps(scene_dict(film="abc")))
    rc, out, err = call(capsys, "render", p, "--width", 8, "-o", tmp_path / "o.exr")
    assert rc == 2 and "key 'film': expected an object" in one_line_error(err)


@pytest.mark.parametrize("argv,option", [
    (["verify", "cornell", "--rays", 10 ** 9], "--rays"),
    (["build", "x.ply", "--capacity", 10 ** 30], "--capacity"),
    (["animate", "exploding", "--fps", "1e-300"], "--fps"),
    (["bench", "build", "--repeat", 10 ** 6], "--repeat")])
def test_options_beyond_what_the_machine_can_hold_are_refused(capsys, argv, option):
    rc, out, err = call(capsys, *argv)
    assert rc == 2 and one_line_error(err).startswith(f"hwrt: error: {option}: must")


def test_rendering_a_moving_scene_points_to_animate(tmp_path, capsys):
    p = tmp_path / "a.json"
    p.write_text(json.dumps(scene_dict(animation={"frames": 2})))
    for argv in (["render", p, "-o", tmp_path / "o.exr"], ["verify", p]):
        rc, out, err = call(capsys, *argv)
        assert rc == 2 and one_line_error(err).endswith(
            "the scene moves: render it with hwrt animate (--verify checks its frames)")


def test_a_shape_without_a_material_and_a_toml_date_are_named_as_such(tmp_path, capsys):
    p = tmp_path / "s.json"
    p.write_text(json.dumps(scene_dict(shapes=[{"type": "box", "min": [0, 0, 0], "max": [1, 1, 1]}])))
    rc, _, err = call(capsys, "render", p, "-o", tmp_path / "o.exr")
    assert rc == 2 and one_line_error(err).startswith(
        f"hwrt: error: {p}: key 'shapes[0].material': missing (defined: ")
    t = tmp_path / "s.toml"
    t.write_text("name = 1979-05-27\n")
    rc, _, err = call(capsys, "render", t, "-o", tmp_path / "o.exr")
    assert rc == 2 and one_line_error(err) == (
        f"hwrt: error: {t}: key 'name': expected a non-empty string, got the date 1979-05-27")


@pytest.mark.parametrize("option,value", [("--width", 99999), ("--spp", 5000), ("--max-depth", 65)])
def test_frame_overrides_are_checked_as_options(capsys, tmp_path, option, value):
    rc, out, err = call(capsys, "render", "cornell", option, value, "-o", tmp_path / "o.exr")
    assert rc == 2 and one_line_error(err).startswith(f"hwrt: error: {option}: must be at most")


# ---------------------------------------------------------------------------------------
# bench: its usage and one help page per benchmark
# ---------------------------------------------------------------------------------------
def test_bench_without_a_benchmark_names_the_benchmark_only(capsys):
    rc, out, err = call(capsys, "bench")
    line = one_line_error(err)
    assert rc == 2 and "required: BENCHMARK" in line and "what" not in line and "MESH" not in line
    usage = _subparsers(make_parser())["bench"].format_usage()
    assert "BENCHMARK [MESH ...]" in usage and "{build" not in usage


def test_each_benchmark_has_a_page_of_its_own(capsys):
    from hwrt.cli import BENCH_OPTIONS, BENCHMARKS
    pages = {}
    for what in BENCH_OPTIONS:
        rc, out, _ = call(capsys, "bench", what, "--help")
        assert rc == 0 and out.startswith(f"usage: hwrt bench {what} ")
        text, duration = BENCHMARKS[what]
        flat = " ".join(out.split())
        assert text[1:] in flat and duration in flat, what
        # the options it reads, and no other
        for option in ("--mesh-dir", "--rays", "--quick", "--scheduler", "--frames", "--accel"):
            reads = option[2:].replace("-", "_") in BENCH_OPTIONS[what]
            assert (f"  {option} " in out) == reads, (what, option)
        pages[what] = out
    assert len(set(pages.values())) == len(pages)
    assert "no peer" in pages["scale"] and "Embree" in pages["build"]
    assert "(default: 5)" in pages["build"] and "(default: 3)" in pages["scale"]   # --repeat
    # a page speaks of its own benchmark only: no "read by", no other benchmark's defaults
    for what, page in pages.items():
        flat = " ".join(page.split())
        assert "read by" not in flat, what
        others = [w for w in ("tti", "accuracy", "model") if w != what]
        if "--scheduler" in page:
            assert not any(f"for {w}" in flat or f"{w} and" in flat for w in others), what
        assert ("[SCENE ...]" in page) == (what in ("render", "trees", "contention")), what
    rc, generic, _ = call(capsys, "bench", "--help")
    flat = " ".join(generic.split())
    assert rc == 0 and all(f"{what} {BENCHMARKS[what][0]}" in flat for what in BENCHMARKS)


def test_bench_quick_is_described_as_seconds_not_minutes(capsys):
    rc, out, _ = call(capsys, "bench", "tti", "--help")
    quick = " ".join(out.split("--quick ", 1)[1].split("--fresh")[0].split())
    assert "seconds" in quick and "minutes" not in quick


# ---------------------------------------------------------------------------------------
# errors name what the user typed
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("prefix,problem", [("d/", "names a directory"), ("d", "names a directory"),
                                            ("new/", "ends in a path separator"),
                                            ("d/.t", "a file name starting with a dot")])
def test_build_refuses_an_out_prefix_that_is_a_directory(tmp_path, capsys, tetra, prefix, problem):
    (tmp_path / "d").mkdir()
    rc, out, err = call(capsys, "build", tetra, "--out", str(tmp_path) + os.sep + prefix)
    assert rc == 2 and one_line_error(err).startswith("hwrt: error: --out: ") and problem in err
    assert list((tmp_path / "d").iterdir()) == [] and not (tmp_path / "new").exists()


def test_build_takes_o_for_out_as_render_and_animate_do(tmp_path, capsys, tetra):
    rc, out, err = call(capsys, "build", tetra, "-o", tmp_path / "t")
    assert rc == 0 and sorted(p.name for p in tmp_path.glob("t.*")) == ["t.indices", "t.json",
                                                                         "t.nodes"]


def test_build_does_not_replace_a_json_file_that_is_not_a_tree(tmp_path, capsys, tetra):
    scene = tmp_path / "scene.json"
    scene.write_text('{"camera": {"eye": [0, 0, 1]}}')
    rc, out, err = call(capsys, "build", tetra, "--out", scene)
    assert rc == 2 and one_line_error(err).startswith("hwrt: error: --out: ")
    assert "is there and is not a tree's description, which the tree would replace" in err
    assert not any(p.suffix in (".nodes", ".indices") for p in tmp_path.iterdir())
    assert scene.read_text() == '{"camera": {"eye": [0, 0, 1]}}'


@pytest.mark.parametrize("argv,flag,problem", [
    (["--builder", "embree", "--bins", "8"], "--bins", "--builder embree does not read"),
    (["--builder", "embree", "--leaf-size", "2"], "--leaf-size", "--builder embree does not read"),
    (["--builder", "embree", "--capacity", "64"], "--capacity", "--builder embree does not read"),
    (["--builder", "sweep", "--bins", "8"], "--bins", "--builder sweep does not read"),
    (["--builder", "sweep", "--leaf-size", "2"], "--leaf-size", "--builder sweep does not read")])
def test_build_refuses_options_its_builder_does_not_read(capsys, tetra, argv, flag, problem):
    rc, out, err = call(capsys, "build", tetra, *argv)
    assert rc == 2 and out == "" and one_line_error(err).startswith(f"hwrt: error: {flag}: {problem}")


def test_build_passes_the_options_given_and_the_library_defaults_otherwise(capsys, tetra):
    rc, out, _ = call(capsys, "build", tetra, "--bins", 8, "--json")
    p = json.loads(out)["parameters"]
    assert rc == 0 and p["bins"] == 8 and p["leaf_size"] == 4
    rc, out, _ = call(capsys, "build", tetra, "--builder", "sweep", "--capacity", 64, "--json")
    p = json.loads(out)["parameters"]
    assert rc == 0 and p["capacity"] == 64 and p["bins"] is None


def test_a_film_too_large_names_the_options_that_set_it(capsys, tmp_path):
    rc, _, err = call(capsys, "render", "cornell", "--width", 32768, "--height", 2048,
                      "-o", tmp_path / "o.exr")
    assert rc == 2 and one_line_error(err) == (
        "hwrt: error: --width 32768 --height 2048: 32768 x 2048 is more than the 33554432 "
        "pixels a film may hold")


@pytest.mark.parametrize("film, integrator, argv, key, problem", [
    ({"width": "wide"}, {}, ["--width", 16], "film.width", "expected an integer, got 'wide'"),
    ({"width": 64.5}, {}, ["--width", 16], "film.width", "expected an integer, got 64.5"),
    ({"height": True}, {}, ["--height", 12], "film.height", "expected an integer, got true"),
    ({"spp": 0}, {}, ["--spp", 1], "film.spp", "0 is out of range"),
    ({}, {"max_depth": 999}, ["--max-depth", 2], "integrator.max_depth", "999 is out of range"),
])
def test_a_bad_film_value_is_refused_though_an_option_replaces_it(capsys, tmp_path, film,
                                                                  integrator, argv, key, problem):
    """The scene file is checked as written: an option that sets the same value does not
    hide the file's error."""
    d = {"camera": {"eye": [0, 0, 3], "target": [0, 0, 0]}, "film": film,
         "integrator": integrator, "materials": {"white": {"type": "diffuse"}},
         "shapes": [{"type": "triangles", "material": "white",
                     "data": [[[-1, -1, 0], [1, -1, 0], [0, 1, 0]]]}]}
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))
    out = tmp_path / "o.exr"
    rc, _, err = call(capsys, "render", p, *argv, "-o", out)
    assert rc == 2 and one_line_error(err).startswith(f"hwrt: error: {p}: key '{key}': {problem}")
    assert not out.exists()


def test_an_output_directory_that_is_a_file_is_named_by_its_option(capsys, tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    for argv, option in ((["bench", "tti"], "--out-dir"), (["bench", "build"], "--out-dir"),
                         (["animate", "cloth", "-o"], "--output")):
        argv = argv + [f] if option == "--output" else argv + ["--out-dir", f]
        rc, _, err = call(capsys, *argv)
        assert rc == 2 and one_line_error(err) == f"hwrt: error: {option} {f}: exists and is not a directory"


def test_an_unreadable_ply_says_so(capsys, tmp_path):
    p = tmp_path / "g.ply"
    p.write_text("ply\n")
    rc, _, err = call(capsys, "build", p)
    assert rc == 2 and one_line_error(err).startswith(f"hwrt: error: {p}: not a readable PLY file (")
    # a vertex element without the y its reader looks up: the reader's bare key, explained
    p.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n")
    rc, _, err = call(capsys, "build", p)
    assert rc == 2 and one_line_error(err) == \
        f"hwrt: error: {p}: not a readable PLY file (it has no 'y')"


def test_a_scene_named_to_a_mesh_benchmark_is_said_to_be_one(capsys, tmp_path):
    for bench in ("build", "tti", "accuracy"):
        rc, out, err = call(capsys, "bench", bench, "cornell", "--out-dir", tmp_path / bench)
        assert rc == 2 and out == "" and one_line_error(err) == (
            "hwrt: error: cornell: no such file; cornell is a built-in scene: this benchmark "
            "takes mesh files (those that render pick their built-in scenes themselves)")
        assert not (tmp_path / bench).exists()


def test_a_scene_given_to_build_or_simulate_is_said_to_be_one(capsys, tmp_path):
    scene = tmp_path / "still.toml"
    scene.write_text("[camera]\n")
    for command in ("build", "simulate"):
        rc, _, err = call(capsys, command, "cornell")
        assert rc == 2 and one_line_error(err) == (
            f"hwrt: error: cornell: no such file; cornell is a built-in scene: {command} takes a "
            f"mesh file; render and verify take scenes")
        rc, _, err = call(capsys, command, scene)
        assert rc == 2 and one_line_error(err) == (
            f"hwrt: error: {scene}: a scene file: {command} takes a mesh file; render and verify "
            f"take scenes")


def test_every_command_opens_its_help_with_a_description():
    for name, sub in _subparsers(make_parser()).items():
        assert sub.description, name


def test_verify_names_its_default_mismatch_file_after_the_scene_name(capsys, tmp_path,
                                                                     monkeypatch):
    """As render names its image: the scene's 'name', not the file's."""
    scene = tmp_path / "file.json"
    scene.write_text(json.dumps(scene_dict(name="ball")))
    monkeypatch.chdir(tmp_path)
    taken = tmp_path / "renders" / "verify-ball-random-mismatches.npz"
    taken.mkdir(parents=True)                   # where the file would go: refused up front
    rc, _, err = call(capsys, "verify", scene, "--rays", 10)
    assert rc == 2 and "verify-ball-random-mismatches.npz" in one_line_error(err)
    # another structure's run names its own file, so that runs do not replace each other's
    for accel in ("grid", "kdtree"):
        (tmp_path / "renders" / f"verify-ball-random-{accel}-mismatches.npz").mkdir()
        rc, _, err = call(capsys, "verify", scene, "--rays", 10, "--accel", accel)
        assert rc == 2 and f"verify-ball-random-{accel}-mismatches.npz" in one_line_error(err)
    rc, _, err = call(capsys, "render", scene, "--width", 8, "--height", 6)
    assert rc == 0 and (tmp_path / "renders" / "ball.exr").exists(), err


def test_verify_refuses_mismatches_over_a_mesh_its_scene_reads(capsys, tmp_path, tetra):
    scene = tmp_path / "s.json"
    scene.write_text(json.dumps(scene_dict(shapes=[{"type": "mesh", "filename": tetra.name, "material": "m"}])))
    before = tetra.read_bytes()
    rc, _, err = call(capsys, "verify", scene, "--rays", 10, "--mismatches", tetra)
    assert rc == 2 and "does not end in .npz" in one_line_error(err)
    assert tetra.read_bytes() == before
    # a mesh the scene reads, were it named as an archive, is an input all the same
    npz_mesh = tmp_path / "tetra.npz.obj"
    npz_mesh.write_bytes(before)
    scene.write_text(json.dumps(scene_dict(shapes=[{"type": "mesh", "filename": npz_mesh.name,
                                                    "material": "m"}])))
    link = tmp_path / "m.npz"
    link.symlink_to(npz_mesh)
    rc, _, err = call(capsys, "verify", scene, "--rays", 10, "--mismatches", link)
    assert rc == 2 and "is an input of this run" in one_line_error(err)
    assert npz_mesh.read_bytes() == before


@pytest.mark.parametrize("arrays,problem", [
    ({"origins": np.zeros((2, 2)), "dirs": np.ones((2, 3)), "tmax": np.ones(2)}, "key 'origins'"),
    ({"origins": np.array(["a", "b"]), "dirs": np.ones((2, 3)), "tmax": np.ones(2)},
     "key 'origins'"),
    ({"origins": np.zeros((2, 3)), "dirs": np.ones((3, 3)), "tmax": np.ones(2)}, "one length"),
    ({"origins": np.zeros((2, 3)), "dirs": np.ones((2, 3))}, "no key 'tmax'"),
    ({"origins": np.full((2, 3), np.nan), "dirs": np.ones((2, 3)), "tmax": np.ones(2)},
     "key 'origins': not every value is finite"),
    ({"origins": np.full((2, 3), 1e300), "dirs": np.ones((2, 3)), "tmax": np.ones(2)},
     "key 'origins': value 1e+300 exceeds the float32 range"),
    ({"origins": np.zeros((2, 3)), "dirs": np.zeros((2, 3)), "tmax": np.ones(2)},
     "key 'dirs': ray 0 has a zero direction"),
    (None, "not an .npz archive")])
@pytest.mark.filterwarnings("error")            # a warning would print before the one line
def test_replay_of_a_malformed_file_is_one_line_naming_the_file(capsys, tmp_path, tetra,
                                                                arrays, problem):
    f = tmp_path / "m.npz"
    if arrays is None:
        f.write_text("origins dirs tmax\n")
    else:
        np.savez(f, **arrays)
    rc, out, err = call(capsys, "verify", tetra, "--replay", f)
    line = one_line_error(err)
    assert rc == 2 and out == "" and line.startswith(f"hwrt: error: --replay {f}: ") and problem in line
    assert "pickle" not in line


@pytest.mark.filterwarnings("error")            # a warning would print before the one line
@pytest.mark.parametrize("command", ["build", "render"])
def test_a_mesh_coordinate_beyond_reach_is_one_line_without_warnings(capsys, tmp_path, command):
    stl = tmp_path / "huge.stl"
    stl.write_text("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1e300 0 0\n"
                   "vertex 0 1 0\nendloop\nendfacet\nendsolid t\n")
    out = tmp_path / ("o" if command == "build" else "o.exr")
    rc, _, err = call(capsys, command, stl, "--out" if command == "build" else "-o", out)
    assert rc == 2 and "coordinate too large" in one_line_error(err) and str(stl) in err
    assert not out.exists()


@pytest.mark.parametrize("argv", [["render", "--wid", "10"], ["build", "x.obj", "--leaf", "2"],
                                  ["bench", "build", "--rep", "1"]])
def test_an_abbreviated_option_is_not_taken_for_the_whole(capsys, argv):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    assert f"unrecognized arguments: {argv[-2]}" in capsys.readouterr().err


@pytest.mark.parametrize("argv, option", [
    (["build", "x.obj", "--out", ""], "-o/--out"),
    (["build", "x.obj", "--dump-aabbs", ""], "--dump-aabbs"),
    (["render", "cornell", "-o", ""], "-o/--output"),
    (["explore", "x.obj", "--out-dir", ""], "--out-dir"),
    (["verify", "cornell", "--mismatches", ""], "--mismatches"),
    (["animate", "exploding", "-o", ""], "-o/--output"),
    (["bench", "build", "--out-dir", ""], "--out-dir"),
    (["build", ""], "mesh"),
    (["render", ""], "scene"),
    (["bench", "build", ""], "MESH"),
    (["explore", "x.obj", "--scheduler", ""], "--scheduler")])
def test_an_empty_path_or_address_is_refused_naming_its_argument(capsys, tmp_path, monkeypatch, argv, option):
    """An empty path would mean the current directory, or no file at all, without a word."""
    monkeypatch.chdir(tmp_path)
    rc, out, err = call(capsys, *argv)
    line = one_line_error(err)
    assert rc == 2 and out == "" and line == f"hwrt: error: {option}: expected a value, got an empty one"
    assert list(tmp_path.iterdir()) == []


def test_verify_of_a_misspelt_scene_lists_the_built_in_scenes(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rc, out, err = call(capsys, "verify", "cornel")
    assert rc == 2 and one_line_error(err) == \
        "hwrt: error: cornel: no such scene or file (built-in scenes: cornell, marbles, cloth, room)"


@pytest.mark.parametrize("strategy", ["rebuild", "refit", "embree"])
def test_animate_refuses_a_threshold_its_strategy_does_not_read(capsys, tmp_path, strategy):
    rc, out, err = call(capsys, "animate", "exploding", "--strategy", strategy, "--threshold", "2",
                        "-o", tmp_path / "a")
    assert rc == 2 and one_line_error(err) == \
        f"hwrt: error: --threshold: is read by --strategy adaptive only, not {strategy}"
    assert not (tmp_path / "a").exists()


@pytest.mark.parametrize("from_env", [False, True])
def test_explore_refuses_workers_beside_a_running_scheduler(capsys, tmp_path, monkeypatch, from_env):
    """--workers sizes the local cluster, which a scheduler address replaces."""
    argv = ["explore", tmp_path / "x.obj", "--workers", "2", "--out-dir", tmp_path / "e"]
    (tmp_path / "x.obj").write_text(TETRA_OBJ)
    monkeypatch.delenv("HWRT_SCHEDULER", raising=False)
    if from_env:
        monkeypatch.setenv("HWRT_SCHEDULER", "tcp://127.0.0.1:1")
    else:
        argv += ["--scheduler", "tcp://127.0.0.1:1"]
    rc, out, err = call(capsys, *argv)
    given = "$HWRT_SCHEDULER" if from_env else "--scheduler"
    assert rc == 2 and one_line_error(err) == (
        f"hwrt: error: --workers: sizes the local cluster, which is not made when {given} "
        "names a running scheduler")
    assert not (tmp_path / "e").exists()


def test_a_local_cluster_takes_at_most_a_worker_per_core(capsys, tmp_path, monkeypatch):
    """A cell keeps a core busy: more local workers than cores would only share them (and a
    hundred worker processes on two cores did not start within Dask's timeouts). Refused
    before any work, from the command line and from Python."""
    from hwbvh.errors import ParameterError
    from hwbvh.parallel import usable_cores
    from hwrt.cluster import dask_client
    monkeypatch.delenv("HWRT_SCHEDULER", raising=False)
    (tmp_path / "x.obj").write_text(TETRA_OBJ)
    cores = usable_cores()
    rc, out, err = call(capsys, "explore", tmp_path / "x.obj", "--workers", cores + 1,
                        "--out-dir", tmp_path / "e")
    assert rc == 2 and one_line_error(err).startswith(
        f"hwrt: error: --workers: at most {cores}, the cores this process may use")
    assert not (tmp_path / "e").exists()
    for workers in (cores + 1, 0, 1.5, True):
        with pytest.raises(ParameterError) as e:
            with dask_client(workers=workers):
                pass
        assert e.value.parameter == "workers" and f"from 1 to {cores}" in str(e.value)


def test_a_bad_scheduler_from_the_environment_is_named_as_such(capsys, tmp_path, monkeypatch):
    (tmp_path / "x.obj").write_text(TETRA_OBJ)
    monkeypatch.setenv("HWRT_SCHEDULER", "tcp://127.0.0.1:1")
    rc, out, err = call(capsys, "explore", tmp_path / "x.obj", "--out-dir", tmp_path / "e")
    assert rc == 2 and one_line_error(err).startswith(
        "hwrt: error: $HWRT_SCHEDULER: no Dask scheduler answers at 'tcp://127.0.0.1:1'")


def test_replay_of_a_bare_npy_array_is_refused_in_one_line(capsys, tmp_path):
    f = tmp_path / "rays.npy"
    np.save(f, np.zeros((3, 3)))
    rc, out, err = call(capsys, "verify", "cornell", "--replay", f)
    assert rc == 2 and one_line_error(err) == (f"hwrt: error: --replay {f}: not a mismatch file "
                                              "from hwrt verify (not an .npz archive)")


@pytest.mark.parametrize("argv,line", [
    (["render", "cornell", "-o", ".exr"],
     "hwrt: error: -o/--output: .exr: expected a file name with the extension .exr, such as "
     "image.exr (--png adds a PNG preview beside the EXR)"),
    (["animate", "exploding", "--mesh", "bunny.ply", "--triangles", "500"],
     "hwrt: error: --triangles: makes a generated mesh: a mesh given brings its own triangles")])
def test_options_that_cannot_apply_are_named(tmp_path, capsys, monkeypatch, argv, line):
    monkeypatch.chdir(tmp_path)
    rc, out, err = call(capsys, *argv)
    assert rc == 2 and one_line_error(err) == line and not any(tmp_path.iterdir())


@pytest.mark.parametrize("value,line", [
    ("4_0", "hwrt: error: --leaf-size: expected an integer, got '4_0'"),
    (" 4", "hwrt: error: --leaf-size: expected an integer, got ' 4'"),
    ("4.0", "hwrt: error: --leaf-size: expected an integer, got '4.0'"),
    ("1" + "0" * 2000, "hwrt: error: --leaf-size: must be an integer in 1..255, got a number "
                       "of 2001 digits"),
    ("0", "hwrt: error: --leaf-size: must be an integer in 1..255, got 0")])
def test_integer_options_take_digits_only(tmp_path, capsys, value, line):
    p = tmp_path / "m.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    rc, out, err = call(capsys, "build", p, "--leaf-size", value)
    assert rc == 2 and out == "" and one_line_error(err) == line



@pytest.mark.parametrize("option, knob", [("--block-nodes", "block_nodes"),
                                          ("--subtree-builders", "subtree_builders")])
def test_a_placement_option_states_the_range_the_library_takes(capsys, tmp_path, option, knob):
    """One range, the library's, in the parser's refusal and its help: a value the parser took
    would otherwise meet the library's other bound after it."""
    from hwbvh.config import LAYOUT_KNOB_RANGES
    lo, hi = LAYOUT_KNOB_RANGES[knob]
    p = tmp_path / "m.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    for value in (hi + 1, 2**31 - 1, 10**11):
        rc, out, err = call(capsys, "build", p, option, value)
        assert rc == 2 and one_line_error(err) == (
            f"hwrt: error: {option}: must be an integer in {lo}..{hi}, got {value}")
    rc, out, err = call(capsys, "build", p, option, hi)
    assert rc == 0, err


def test_explore_knobs_after_one_grid_option_are_refused_with_the_way_to_give_them(capsys,
                                                                                 tmp_path):
    rc, out, err = call(capsys, "explore", "m.ply", "--grid", "w=2", "tsize=4", "psize=1024",
                        "--out-dir", tmp_path / "o")
    assert (rc, out) == (2, "") and one_line_error(err).endswith(
        "unrecognized arguments: tsize=4 psize=1024 (one knob per --grid: --grid tsize=4 "
        "--grid psize=1024)")
    assert not (tmp_path / "o").exists()

def test_a_mesh_of_an_unknown_type_is_refused_by_its_name(capsys, tmp_path):
    p = tmp_path / "points.xyz"
    p.write_text("0 0 0\n1 0 0\n0 1 0\n")
    for command in ("build", "simulate"):
        rc, out, err = call(capsys, command, p)
        assert rc == 2 and out == "" and one_line_error(err) == (
            f"hwrt: error: {p}: unknown mesh file type (expected "
            ".ply/.obj/.stl/.off/.glb/.gltf)")


def test_replay_text_says_which_answer_is_wrong_and_why():
    from hwrt.cli import _replay_human
    r = dict(rays=2, kind="random", file="m.npz", query="intersect", accel="bvh", agree=1, tie=0,
             mismatch=1, mismatch_ours_wrong=1, mismatch_embree_wrong=0, replayed=[
                 {"origin": [0.0, 0.5, -1.0], "dir": [0.0, 0.0, 1.0], "tmax": float("inf"),
                  "ours": [-1, None], "embree": [-1, None], "class": "agree", "wrong": [],
                  "why": {}},
                 {"origin": [1e-8, 2.0, 3.0], "dir": [0.0, 1.0, 0.0], "tmax": 5.0,
                  "ours": [7, 1.25], "embree": [3, 0.5], "class": "mismatch", "wrong": ["ours"],
                  "why": {"ours": "it misses triangle 3, which the ray enters at t = 0.5"}}])
    assert _replay_human(r).splitlines()[1:] == [
        "  ray 0: agree; ours a miss, Embree a miss; origin (0, 0.5, -1), direction (0, 0, 1), "
        "t_max inf",
        "  ray 1: mismatch; ours triangle 7 at t = 1.25, Embree triangle 3 at t = 0.5; origin "
        "(1e-08, 2, 3), direction (0, 1, 0), t_max 5",
        "    our answer is wrong: it misses triangle 3, which the ray enters at t = 0.5"]


def test_a_signal_ignored_at_start_stays_ignored():
    """A shell's background job starts with SIGINT ignored (a ^C is for the foreground): the
    command's handlers leave it so, and still take SIGTERM."""
    code = ("import os, signal\n"
            "from hwrt import cli\n"
            "def run(argv, signals_owned):\n"
            "    os.kill(os.getpid(), signal.SIGINT)\n"
            "    print(signal.getsignal(signal.SIGINT) is signal.SIG_IGN,"
            " signal.getsignal(signal.SIGTERM) is cli._raise_terminated)\n"
            "    return 0\n"
            "cli._run = run\n"
            "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"     # ignored after the import
            "raise SystemExit(cli.main([]))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.split() == ["True", "True"], out.stderr


@pytest.mark.parametrize("argv,line", [
    (["render", "exploding"], "hwrt: error: exploding: a built-in animation: render it with hwrt animate"),
    (["render", "{dir}"], "hwrt: error: {dir}: is a directory, not a scene or mesh file"),
    (["animate", "{dir}"], "hwrt: error: {dir}: is a directory, not a scene or mesh file"),
    (["animate", "{dir}/scene.json", "--physics", "bullet"],
     "hwrt: error: --physics: only the built-in animation marbles takes it"),
])
def test_a_scene_that_is_not_one_says_what_it_is(capsys, tmp_path, argv, line):
    d = tmp_path / "looks.json"                # a directory named like a scene file
    d.mkdir()
    rc, out, err = call(capsys, *[a.format(dir=d) for a in argv])
    assert rc == 2 and out == "" and one_line_error(err) == line.format(dir=d)


def test_simulate_help_gives_each_knobs_range_as_checked(capsys):
    from hwbvh import config
    rc, out, _ = call(capsys, "simulate", "--help")
    flat = " ".join(out.split())
    for knob, (lo, hi) in config.KNOB_RANGES.items():
        option = "--" + knob.replace("_", "-")
        text = flat.split(f"{option} ", 2)[2].split(" --")[0]     # after the usage line
        shown = f"{lo:g}..{hi:g}" if isinstance(lo, float) else f"{lo}..{hi}"
        assert shown in text, (option, text)
    # and the check refuses just past the range it gives
    rc, _, err = call(capsys, "simulate", "no.ply", "--ram-pairs",
                      str(config.KNOB_RANGES["ram_pairs"][1] + 1))
    assert rc == 2 and "--ram-pairs" in one_line_error(err)


@pytest.mark.parametrize("option", ["--out", "--dump-aabbs", "--dump-handoff"])
def test_an_output_embree_cannot_give_names_its_option(capsys, tmp_path, tetra, option):
    rc, out, err = call(capsys, "build", tetra, "--builder", "embree", option, str(tmp_path / "t"))
    assert rc == 2 and out == "" and one_line_error(err) == (
        f"hwrt: error: {option}: needs a tree of ours (--builder hwbvh or sweep): Embree's tree "
        "stays inside Embree")
    assert [f.name for f in tmp_path.iterdir()] == ["tetra.obj"]      # the mesh alone



def test_a_handoff_dump_does_not_replace_a_foreign_file_beside_it(capsys, tmp_path, tetra):
    """F.json is written beside the dump F without being named: a file there that is not a
    dump's description is refused, not replaced; a dump's own is replaced by the next."""
    dump = tmp_path / "hd.bin"
    beside = tmp_path / "hd.bin.json"
    beside.write_text('{"precious": 1}')
    rc, out, err = call(capsys, "build", tetra, "--dump-handoff", dump)
    assert (rc, out) == (2, "") and one_line_error(err) == (
        f"hwrt: error: --dump-handoff: {dump}: {beside}, written beside it, is there and is not a "
        f"handoff dump's description, which the dump would replace; choose another name")
    assert beside.read_text() == '{"precious": 1}' and not dump.exists()
    beside.unlink()
    for _ in range(2):
        rc, out, err = call(capsys, "build", tetra, "--dump-handoff", dump)
        assert rc == 0, err
    assert set(json.loads(beside.read_text())) == {"record_bytes", "handoff_sizes"}

@pytest.mark.parametrize("argv", [["bench", "render", "cornell", "cornell"],
                                  ["bench", "trees", "cornell", "cornell"]])
def test_a_scene_given_twice_to_a_benchmark_is_refused(argv, capsys):
    rc, out, err = call(capsys, *argv)
    assert (rc, out) == (2, "") and one_line_error(err) == "hwrt: error: cornell: given twice"


def test_control_latency_takes_the_range_its_help_gives(capsys):
    rc, out, err = call(capsys, "simulate", "m.ply", "--control-latency", 10**6 + 1)
    assert rc == 2 and one_line_error(err) == \
        "hwrt: error: --control-latency: must be at most 1000000, got 1000001"


@pytest.mark.parametrize("name", ["HWRT_PROGRESS", "HWRT_DEBUG"])
def test_environment_switches_take_words_for_off_and_refuse_others(name, tmp_path):
    import os
    env = dict(os.environ)
    for word in ("0", "false", "No", "off", ""):        # taken: the run goes on to the scene
        env[name] = word
        r = run("render", tmp_path / "none.json", env=env)
        assert r.returncode == 2 and one_line_error(r.stderr).startswith(
            f"hwrt: error: {tmp_path / 'none.json'}"), (word, r.stderr)
    env[name] = "junk"
    r = run("render", "cornell", "--width", 8, "--height", 8, "-o", tmp_path / "x.exr", env=env)
    assert r.returncode == 2 and one_line_error(r.stderr) == (
        f"hwrt: error: ${name}: unknown value 'junk' (choose 1 or 0; true/false, yes/no and "
        f"on/off are taken too)")
    assert not (tmp_path / "x.exr").exists()
    from hwrt.config import env_flag
    for word, on in (("1", True), ("TRUE", True), ("yes", True), ("0", False), ("off", False)):
        os.environ[name] = word
        try:
            assert env_flag(name) is on
        finally:
            del os.environ[name]


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
@pytest.mark.parametrize("argv", [["--help"], ["--version"], ["simulate", "TETRA", "--json"]])
def test_a_full_standard_output_is_a_one_line_error_not_a_silent_success(argv, tetra):
    argv = [str(tetra) if a == "TETRA" else a for a in argv]
    with open("/dev/full", "w") as full:
        p = subprocess.run([sys.executable, "-m", "hwrt.cli", *argv], stdout=full,
                           stderr=subprocess.PIPE, text=True, timeout=600)
    assert p.returncode == 1 and one_line_error(p.stderr) == \
        "hwrt: cannot write <standard output>: No space left on device"


def test_a_closed_standard_output_is_refused_before_the_work(tetra, tmp_path):
    """``hwrt ... >&-``: Python has no sys.stdout, and the summary would be lost after the
    work; ``--help`` has no work before it and fails as a full standard output does."""
    for argv, status, line in (
            (["build", tetra, "-o", tmp_path / "tree"], 2,
             "hwrt: error: <standard output>: is closed: give the command somewhere to print "
             "(>/dev/null drops what it prints)"),
            (["--help"], 1, "hwrt: cannot write <standard output>: it is closed")):
        p = subprocess.run([sys.executable, "-m", "hwrt.cli", *map(str, argv)],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                           timeout=600, preexec_fn=lambda: os.close(1))
        assert p.returncode == status and one_line_error(p.stderr) == line
    assert not list(tmp_path.glob("tree*"))


@pytest.mark.parametrize("command", [["render", "SCENE", "-o", "OUT/x.exr"],
                                     ["verify", "SCENE", "--rays", "5"],
                                     ["animate", "SCENE", "-o", "OUT/a", "--frames", "1"]])
def test_a_scene_file_that_is_a_pipe_or_a_device_is_refused_before_it_is_read(tmp_path, capsys,
                                                                            command):
    """A read from a pipe would wait for a writer for ever, one from /dev/zero fill the memory."""
    fifo = tmp_path / "f.json"
    os.mkfifo(fifo)
    zero = tmp_path / "z.toml"
    zero.symlink_to("/dev/zero")
    for scene in (fifo, zero):
        argv = [str(scene) if a == "SCENE" else a.replace("OUT", str(tmp_path / "o"))
                for a in command]
        rc, out, err = call(capsys, *argv)
        assert (rc, out) == (2, "") and one_line_error(err) == (
            f"hwrt: error: {scene}: not a regular file (a pipe or a device?): give a scene or "
            f"mesh file")
    assert not (tmp_path / "o").exists()


def test_an_output_name_longer_than_the_file_system_takes_is_refused_before_the_work(
        tmp_path, capsys, tetra):
    """Found when the finished render was renamed into place, it exited 1 after the work."""
    long = "a" * 300
    for argv, said in (
            (["render", "cornell", "--width", "8", "--height", "8", "-o", tmp_path / f"{long}.exr"],
             "is too long (304 bytes)"),
            (["build", tetra, "-o", tmp_path / long / "tree"], "is too long (300 bytes)"),
            (["build", tetra, "-o", tmp_path / "new" / long / "tree"], "is too long (300 bytes); "
                                                                        "its file system takes at most")):
        rc, out, err = call(capsys, *argv)
        assert (rc, out) == (2, "") and said in one_line_error(err)
    assert os.listdir(tmp_path) == ["tetra.obj"]



@pytest.mark.parametrize("command, output", [("render", "renders/{name}.exr"),
                                             ("animate", "renders/animate-{name}-rebuild"),
                                             ("verify", "renders/verify-{name}-random-")])
def test_a_scene_name_too_long_for_the_default_output_points_to_o(tmp_path, capsys,
                                                                  monkeypatch, command, output):
    """The default output is named after the scene: a name too long for the file system is
    refused before the work, as made from the scene's name, with -o as the way out."""
    monkeypatch.chdir(tmp_path)
    name = "n" * 300
    scene = tmp_path / "long.json"
    scene.write_text(json.dumps({
        "name": name, "camera": {"eye": [0, 1, 4], "target": [0, 0, 0]},
        "materials": {"w": {"type": "diffuse"}},
        "shapes": [{"type": "box", "min": [0, 0, 0], "max": [1, 1, 1], "material": "w"}],
        **({"animation": {"frames": 1}} if command == "animate" else {})}))
    size = ["--rays", "100"] if command == "verify" else ["--width", "8", "--height", "8"]
    rc, out, err = call(capsys, command, scene, *size)
    line = one_line_error(err)
    assert (rc, out) == (2, "") and line.startswith(f"hwrt: error: {output.format(name=name)}")
    way = {"render": "-o to name the image", "animate": "-o to name the directory",
           "verify": "--mismatches to name the file"}[command]
    assert line.endswith(f"its file system takes at most {os.pathconf(tmp_path, 'PC_NAME_MAX')}: "
                         f"the name is made from the scene's name; give {way}")
    assert os.listdir(tmp_path) == ["long.json"]

def test_replay_of_rays_beyond_the_float32_units_names_the_file(tmp_path, capsys, tetra):
    """Rays no run of the float32 units traced (origins past float32's reach) are the file's
    problem, said of the file, with no Python remedy; a t_max past float32 is infinity there,
    without a warning."""
    far = tmp_path / "far.npz"
    np.savez(far, origins=np.array([[1e38, 0.2, -1.0]]), dirs=np.array([[0.0, 0.0, 1.0]]),
             tmax=np.array([np.inf]))
    rc, out, err = call(capsys, "verify", tetra, "--replay", far)
    line = one_line_error(err)
    assert (rc, out) == (2, "") and line.startswith(f"hwrt: error: --replay {far}: its rays are "
                                                     f"beyond the float32 units (origins: ")
    assert "Tracer" not in line and line.endswith("no hwrt verify run wrote them")
    long = tmp_path / "long.npz"
    np.savez(long, origins=np.array([[0.2, 0.2, -1.0]]), dirs=np.array([[0.0, 0.0, 1.0]]),
             tmax=np.array([1e300]))
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rc, out, err = call(capsys, "verify", tetra, "--replay", long, "--json")
    assert rc == 0 and err == "" and strict_json(out)["replayed"][0]["ours"][0] >= 0


def test_a_hard_link_to_a_mesh_given_beside_it_is_given_twice(capsys, tmp_path, tetra):
    link = tmp_path / "link.obj"
    os.link(tetra, link)
    for argv in (["bench", "build", tetra, link], ["bench", "render", tetra, link]):
        rc, out, err = call(capsys, *argv)
        assert (rc, out) == (2, "") and one_line_error(err) == f"hwrt: error: {link}: given twice"


@pytest.mark.parametrize("scale,problem", [(1e14, "too large for the float32 units"),
                                           (1e-11, "too small for the float32 units")])
@pytest.mark.parametrize("argv", [["bench", "trace", "--repeat", 1, "--rays", 10],
                                  ["bench", "trees"], ["bench", "contention"],
                                  ["bench", "tti", "--quick"], ["bench", "accuracy", "--quick"]])
def test_a_mesh_beyond_the_float32_units_is_refused_by_every_benchmark_naming_it(
        capsys, tmp_path, monkeypatch, argv, scale, problem):
    """Before any work or any file: ``tti`` and ``accuracy`` must not run the built-in
    scenes' cells first (their cells file would be left behind), and ``trace`` names the mesh
    file, not the rays."""
    monkeypatch.chdir(tmp_path)
    mesh = tmp_path / "far.obj"
    mesh.write_text("".join(f"v {x * scale} {y * scale} {z * scale}\n" for x, y, z in
                            ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1))) +
                    "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    out = tmp_path / "out"
    rc, stdout, err = call(capsys, *argv, mesh, "--out-dir", out)
    assert (rc, stdout) == (2, "") and one_line_error(err).startswith(
        f"hwrt: error: {mesh}: {problem}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["far.obj"]      # nothing written


def test_a_bad_film_for_contention_names_the_options_before_any_child_starts(capsys):
    rc, out, err = call(capsys, "bench", "contention", "--width", 32768, "--height", 32768)
    assert (rc, out) == (2, "") and one_line_error(err) == (
        "hwrt: error: --width 32768 --height 32768: 32768 x 32768 is more than the 33554432 "
        "pixels a film may hold")
