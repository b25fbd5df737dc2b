"""Smoke tests of the study benchmarks (--quick), their outputs, resuming, and their cells
on Dask."""
import json
import subprocess
import sys
import time
from argparse import Namespace

import numpy as np
import pytest

TIMINGS = {"build_seconds", "build_spread", "render_seconds", "render_spread", "total_seconds",
           "tracer_setup_seconds"}


def run(*args):
    return subprocess.run([sys.executable, "-m", "hwrt.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=900)


@pytest.fixture(scope="module")
def mesh_dir(tmp_path_factory):
    import trimesh
    from scenes.meshes import sphere
    d = tmp_path_factory.mktemp("meshes")
    tris = sphere(24, 48)
    trimesh.Trimesh(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3), process=False).export(d / "ball.ply")
    return d


@pytest.fixture(scope="module")
def tti_quick(tmp_path_factory, mesh_dir):
    """``bench tti --quick`` on the command line: its cells on the embedded local cluster."""
    out = tmp_path_factory.mktemp("tti") / "b"
    r = run("bench", "tti", "--quick", "--mesh-dir", mesh_dir, "--out-dir", out, "--json")
    assert r.returncode == 0, r.stderr
    return out, json.loads(r.stdout)


def test_tti_quick_outputs_and_resume(tti_quick, mesh_dir):
    out, res = tti_quick
    paths = {(x["scene"], x["path"]) for x in res["rows"]}
    assert {("cornell", p) for p in ("hwbvh-C", "hwbvh-HP", "hwbvh-sw", "sweep", "embree")} <= paths
    assert ("ball", "embree") in paths
    for x in res["rows"]:
        assert x["total_seconds"] == pytest.approx((x["build_seconds"] or 0) + x["render_seconds"])
        if x["traversal"] == "numba":
            assert x["verify_clean"] is True
    assert {"cpu", "cores", "python", "numba", "embreex"} <= set(res["machine"])
    for name in ("tti.csv", "tti.json", "tti.md", "tti.png"):
        assert (out / name).exists()
    assert res["cells_file"] == str(out / "tti.jsonl") and (out / "tti.jsonl").exists()
    assert res["break_even"] and all("break_even_rays" in b for b in res["break_even"])
    # resume: a second run measures nothing new
    lines = (out / "tti.jsonl").read_text().count("\n")
    r2 = run("bench", "tti", "--quick", "--mesh-dir", mesh_dir, "--out-dir", out, "--json")
    assert r2.returncode == 0
    assert (out / "tti.jsonl").read_text().count("\n") == lines
    again = json.loads(r2.stdout)
    assert again["rows"] == res["rows"]
    # and each says where its cells came from
    assert res["cells"] == {"timed": lines, "resumed": 0, "file": "tti.jsonl",
                            "ran_on": "an embedded local Dask cluster"}
    assert again["cells"] == {"timed": 0, "resumed": lines, "file": "tti.jsonl", "ran_on": None}
    assert f"Cells: all {lines} kept from an earlier run (tti.jsonl; --fresh times them all " \
           "again)." in (out / "tti.md").read_text()


def test_tti_times_a_scenes_trees_in_rounds_whose_order_rotates(monkeypatch):
    """Each round builds and renders every tree of the scene once, the first tree of a round
    moving on by one each round, so that drift in the machine's speed falls on all alike."""
    import raytracer.render as R
    from hwrt import study
    built = []
    real = R.make_tracer

    def spy(scene, builder="hwbvh", traversal="numba", **kw):
        built.append(kw.get("accel", "bvh") if kw.get("accel", "bvh") != "bvh" else builder)
        return real(scene, builder, traversal, **kw)

    monkeypatch.setattr(R, "make_tracer", spy)
    trees = [("hwbvh", "numba", "bvh", "hwbvh"), ("sweep", "numba", "bvh", "sweep"),
             ("hwbvh", "numba", "grid", "grid")]
    records = study.tti_scene_cell(("cornell", "builtin", "cornell"), trees, 32, 24, 1, 2, 3)
    assert built[:9] == ["hwbvh", "sweep", "grid", "sweep", "grid", "hwbvh",
                         "grid", "hwbvh", "sweep"]
    assert built[9:] == ["hwbvh", "sweep", "grid"]        # then each checked against Embree
    assert set(records) == {"hwbvh", "sweep", "grid"}
    for name, r in records.items():
        assert r["verify_clean"] is True and r["scene"] == "cornell"
        assert r["render_spread"][0] <= r["render_seconds"] <= r["render_spread"][1]
    assert records["grid"]["accel"] == "grid" and "accel" not in records["sweep"]
    # each record is its own tree's
    assert records["hwbvh"]["sah_cost"] > records["sweep"]["sah_cost"] > 0
    assert records["grid"]["sah_cost"] is None
    assert records["grid"]["references_per_triangle"] > 1 == records["hwbvh"]["references_per_triangle"]


def test_tti_times_only_the_missing_cells_of_a_scene(tmp_path, mesh_dir):
    """A cells file missing some of a scene's trees: the next run times those, all of them in
    one scene's job, and keeps the others."""
    from hwrt import study
    args = Namespace(quick=True, width=32, height=24, spp=1, max_depth=2, repeat=1, fresh=False,
                     meshes=[], mesh_dir=str(mesh_dir), out_dir=str(tmp_path), accel=["bvh"])
    first = study.bench_tti(args, use_dask=False, progress=False)
    cells = tmp_path / "tti.jsonl"
    lines = cells.read_text().splitlines()
    kept = [x for x in lines if '"sweep"' not in json.loads(x)["key"]]
    assert len(kept) < len(lines)
    cells.write_text("\n".join(kept) + "\n")
    again = study.bench_tti(args, use_dask=False, progress=False)
    assert again["cells"]["timed"] == len(lines) - len(kept)
    assert again["cells"]["resumed"] == len(kept)
    assert [untimed(r) for r in again["rows"]] == [untimed(r) for r in first["rows"]]


def _page_body(md):
    """A study page without its title, the line naming the command that made it and the
    figures it shows at its end (the command line prints the tables)."""
    body, figures = md.split("`.\n\n", 1)[1].split("\n## Figures\n\n")
    return body


def test_tti_prints_the_tables_of_its_page(tti_quick, mesh_dir):
    out, _ = tti_quick
    r = run("bench", "tti", "--quick", "--mesh-dir", mesh_dir, "--out-dir", out)   # resumed
    assert r.returncode == 0, r.stderr
    body = _page_body((out / "tti.md").read_text())
    assert "| cornell | hwbvh-C |" in body and "Break-even ray budget" in body
    assert (out / "tti.md").read_text().endswith("\n## Figures\n\n![tti](tti.png)\n\n")
    assert r.stdout == body + "\nwrote " + ", ".join(str(out / f) for f in (
        "tti.csv", "tti.json", "tti.md", "tti.png")) + "\n"


def test_accuracy_quick(tmp_path, mesh_dir):
    out = tmp_path / "a"
    r = run("bench", "accuracy", "--quick", mesh_dir / "ball.ply", "--out-dir", out, "--json")
    assert r.returncode == 0, r.stderr
    first = json.loads(r.stdout)
    rows = first["rows"]
    # the study's first scene, and the mesh named beside it
    assert [x["scene"] for x in rows][::len(rows) // 2] == ["cornell", "ball"]
    knobs = {x["knob"] for x in rows}
    assert knobs == {"bins", "leaf_size", "builder", "precision", "triangle_test", "offset",
                     "offset_at_scale", "max_depth", "spp"}
    get = {(x["knob"], str(x["value"])): x for x in rows if x["scene"] == "cornell"}
    # starting secondary rays on the surface causes acne; the robust offset does not
    assert get[("offset", "none")]["rmse"] > 10 * get[("offset", "relative")]["rmse"]
    # a fixed epsilon breaks when the scene is scaled; the relative offset does not
    for sc in ("0.001", "10000"):
        assert get[("offset_at_scale", f"fixed@{sc}")]["rmse"] > 5 * get[("offset_at_scale", f"relative@{sc}")]["rmse"]
    # more samples converge toward the 16-spp reference
    assert get[("spp", "8")]["rmse"] < get[("spp", "1")]["rmse"]
    assert all(x["holes"] == 0 for x in rows)
    assert (out / "accuracy.png").exists() and (out / "accuracy.md").exists()
    # without --json (every cell resumed, none measured again): the table of its page
    lines = (out / "accuracy.jsonl").read_text().count("\n")
    r = run("bench", "accuracy", "--quick", mesh_dir / "ball.ply", "--out-dir", out)
    assert r.returncode == 0, r.stderr
    assert (out / "accuracy.jsonl").read_text().count("\n") == lines
    # the page says where its cells came from: all timed by the first run, kept by this one
    assert first["cells"]["timed"] == lines and first["cells"]["resumed"] == 0
    assert f"Cells: all {lines} kept from an earlier run (accuracy.jsonl; --fresh times them " \
           "all again)." in (out / "accuracy.md").read_text()
    body = _page_body((out / "accuracy.md").read_text())
    assert "| bins | 16 |" in body
    assert r.stdout == body + "\nwrote " + ", ".join(str(out / f) for f in (
        "accuracy.csv", "accuracy.json", "accuracy.md", "accuracy.png")) + "\n"


def untimed(record):
    return {k: v for k, v in record.items() if k not in TIMINGS}


def test_tti_on_a_one_worker_cluster_equals_the_in_process_run(tti_quick, mesh_dir, tmp_path):
    """The command line's run (cells on a local cluster of one worker) against the same cells
    run in this process: equal in everything but the timings."""
    from hwrt import study
    out, on_cluster = tti_quick
    args = Namespace(quick=True, width=160, height=120, spp=1, max_depth=5, repeat=1, fresh=False,
                     meshes=[], mesh_dir=str(mesh_dir), out_dir=str(tmp_path / "here"))
    here = study.bench_tti(args, use_dask=False, progress=False)
    assert on_cluster["setting"] == here["setting"]
    assert [untimed(r) for r in on_cluster["rows"]] == [untimed(r) for r in here["rows"]]
    assert on_cluster["machine"] == here["machine"]      # every core, as in this process
    records = lambda d: {json.loads(x)["key"]: untimed(json.loads(x))
                         for x in (d / "tti.jsonl").read_text().splitlines()}
    assert records(out) == records(tmp_path / "here")


def test_timed_cells_run_one_at_a_time_on_one_host_of_a_larger_cluster():
    """On a scheduler with two single-thread workers, cells given a host never overlap."""
    from distributed import Client, LocalCluster
    from hwrt.cluster import run_cells, timing_host

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=50) as cluster, Client(cluster) as client:
        host = timing_host(client)
        spans = {}
        cells = [(f"span-{k}", _span, (0.2,)) for k in range(6)]
        run_cells(cells, spans.__setitem__, client, progress=False, host=host)
    assert list(spans) == [k for k, _, _ in cells]                 # in order
    ordered = sorted(spans.values())
    assert all(a[1] <= b[0] for a, b in zip(ordered, ordered[1:])), ordered


def test_a_scheduler_without_workers_is_blamed_on_where_its_address_came_from(monkeypatch):
    """The timed cells of a study need a worker: a scheduler without any is blamed on the
    option, or on $HWRT_SCHEDULER when the address came from there."""
    from distributed import LocalCluster
    from hwbvh.errors import ParameterError
    from hwrt import cluster as hwrt_cluster
    from hwrt.study import _timing

    monkeypatch.setattr(hwrt_cluster, "CONNECT_TIMEOUT_S", 1)    # the wait for a worker

    with LocalCluster(n_workers=0, processes=False, dashboard_address=None,
                      silence_logs=50) as cluster:
        monkeypatch.setenv("HWRT_SCHEDULER", cluster.scheduler_address)
        for scheduler, named in ((cluster.scheduler_address, "scheduler"),
                                 (None, "$HWRT_SCHEDULER")):
            with pytest.raises(ParameterError, match="has no workers") as e:
                with _timing(scheduler, True, None):
                    pass
            assert e.value.parameter == named


def _span(seconds):
    t0 = time.time()
    time.sleep(seconds)
    return t0, time.time()


def test_unreachable_scheduler_fails_fast_and_keeps_the_cells(tmp_path, mesh_dir):
    def refused(what, out, *more):
        t0 = time.perf_counter()
        r = run("bench", what, "--quick", "--out-dir", out, "--scheduler", "tcp://127.0.0.1:9",
                *more)
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
        assert r.stderr.startswith("hwrt: error: --scheduler: no Dask scheduler answers")
        from hwrt.cluster import CONNECT_TIMEOUT_S
        assert time.perf_counter() - t0 < CONNECT_TIMEOUT_S + 30

    refused("accuracy", tmp_path / "a")
    assert not (tmp_path / "a").exists()
    # --fresh replaces the saved cells only once a new one is saved
    out = tmp_path / "t"
    out.mkdir()
    (out / "tti.jsonl").write_text('{"key": "kept"}\n')
    refused("tti", out, "--fresh")
    assert [p.name for p in out.iterdir()] == ["tti.jsonl"]
    assert (out / "tti.jsonl").read_text() == '{"key": "kept"}\n'


def test_study_meshes_that_share_a_stem_are_told_apart_by_their_paths(tmp_path):
    """Named as the other benchmarks name them (a/s.ply and b/s.ply, bunny.ply and bunny.obj
    in one directory): two scenes called 's' would share their cells."""
    import trimesh
    from hwrt.study import _scene_specs
    tetra = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
                            [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], process=False)
    for d, f in (("a", "s.ply"), ("b", "s.ply"), ("a", "other.ply"), ("dir", "bunny.ply"),
                 ("dir", "bunny.obj"), ("dir", "ball.ply")):
        (tmp_path / d).mkdir(exist_ok=True)
        tetra.export(tmp_path / d / f)     # read: the study checks each mesh before its cells
    given = [tmp_path / "a" / "s.ply", tmp_path / "b" / "s.ply", tmp_path / "a" / "other.ply"]
    meshes = _scene_specs(Namespace(meshes=[str(p) for p in given], mesh_dir=None), False)[-3:]
    assert meshes == [(str(given[0]), "mesh", str(given[0])), (str(given[1]), "mesh", str(given[1])),
                      ("other", "mesh", str(given[2]))]
    in_dir = _scene_specs(Namespace(meshes=[], mesh_dir=str(tmp_path / "dir")), False)[-3:]
    assert [name for name, _, _ in in_dir] == ["ball", "bunny.obj", "bunny.ply"]


def test_a_missing_mesh_is_refused_before_any_cell_or_cluster(tmp_path):
    out = tmp_path / "out"
    for quick in (["--quick"], []):
        t0 = time.perf_counter()
        r = run("bench", "tti", tmp_path / "none.ply", *quick, "--out-dir", out)
        assert r.returncode == 2 and r.stderr.splitlines() == [f"hwrt: error: {tmp_path / 'none.ply'}: no such file"]
        assert time.perf_counter() - t0 < 60 and not out.exists()


def test_a_bad_mesh_directory_is_refused_before_the_cells_file_is_touched(tmp_path):
    """Opening the cells file repairs a last line cut short by an interruption; a run that
    fails on its input leaves the file as it was."""
    from hwbvh.errors import ParameterError
    from hwrt.study import _scene_specs
    with pytest.raises(ParameterError, match="/nonexistent: no such directory"):
        _scene_specs(Namespace(meshes=[], mesh_dir="/nonexistent"), False)
    out = tmp_path / "out"
    out.mkdir()
    saved = '{"key": "kept"}\n{"key": "cut sh'
    # (accuracy reads no mesh directory: a mesh file named that is not there)
    for what, given, error in (
            ("tti", ["--mesh-dir", tmp_path / "none"], f"--mesh-dir: {tmp_path / 'none'}: no such directory"),
            ("accuracy", [tmp_path / "none.ply"], f"{tmp_path / 'none.ply'}: no such file")):
        (out / f"{what}.jsonl").write_text(saved)
        r = run("bench", what, "--quick", *given, "--out-dir", out)
        assert r.returncode == 2 and r.stderr.splitlines() == [f"hwrt: error: {error}"]
        assert (out / f"{what}.jsonl").read_text() == saved


def test_a_mesh_named_as_a_built_in_scene_the_study_runs_is_refused(tmp_path, mesh_dir):
    """A study keeps its cells by scene name: a mesh file called cornell.ply would share the
    built-in cornell's cells. Refused in one line naming the file, the cells file untouched."""
    import shutil
    from hwbvh.errors import InputError
    from hwrt.study import _accuracy_specs, _scene_specs
    same = tmp_path / "meshes" / "cornell.ply"
    same.parent.mkdir()
    shutil.copy(mesh_dir / "ball.ply", same)
    for specs, args in ((_accuracy_specs, Namespace(meshes=[str(same)], mesh_dir=None)),
                        (_scene_specs, Namespace(meshes=[], mesh_dir=str(same.parent)))):
        with pytest.raises(InputError, match="named 'cornell', as a built-in scene"):
            specs(args, False)
    # a mesh of another name is taken
    assert _accuracy_specs(Namespace(meshes=[str(mesh_dir / "ball.ply")], mesh_dir=None),
                           True)[-1][:2] == ("ball", "mesh")
    out = tmp_path / "out"
    out.mkdir()
    (out / "accuracy.jsonl").write_text('{"key": "kept"}\n')
    r = run("bench", "accuracy", "--quick", same, "--out-dir", out)
    assert r.returncode == 2 and r.stderr.splitlines() == [
        f"hwrt: error: {same}: named 'cornell', as a built-in scene the study also runs, whose "
        f"results are kept by name: rename the file"]
    assert (out / "accuracy.jsonl").read_text() == '{"key": "kept"}\n'


def test_a_mesh_file_given_new_contents_is_timed_again_not_resumed(tmp_path):
    """The studies keep their cells by scene: a mesh file's by its name and its contents, so
    a file rewritten under the same name is a new scene to them."""
    import trimesh
    from hwrt import study
    from scenes.meshes import sphere
    d = tmp_path / "meshes"
    d.mkdir()

    def write(rings):
        tris = sphere(rings, 2 * rings)
        trimesh.Trimesh(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3),
                        process=False).export(d / "ball.ply")
        return len(tris)

    args = Namespace(quick=True, width=16, height=12, spp=1, max_depth=1, repeat=1, fresh=False,
                     meshes=[str(d / "ball.ply")], mesh_dir=None, out_dir=str(tmp_path / "tti"),
                     accel=["bvh"])
    first_n = write(8)
    first = study.bench_tti(args, use_dask=False, progress=False)
    again = study.bench_tti(args, use_dask=False, progress=False)
    assert again["cells"]["timed"] == 0
    second_n = write(12)
    third = study.bench_tti(args, use_dask=False, progress=False)
    ball = lambda res: {r["triangles"] for r in res["rows"] if r["scene"] == "ball"}
    assert ball(first) == {first_n} and ball(third) == {second_n} != {first_n}
    # cornell's cells stay; the ball's are timed again
    assert third["cells"]["timed"] == len(study.TTI_TREES) and third["cells"]["resumed"] > 0
    spec = ("ball", "mesh", str(d / "ball.ply"))
    assert study.scene_identity(spec)[0] == "ball" and study.scene_identity(("cornell", "builtin", "cornell")) == "cornell"
