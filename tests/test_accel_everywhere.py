"""Every acceleration structure where the BVH is: ``bench trace --accel``, ``bench tti``'s
structure rows and ``animate --accel``, end to end at tiny sizes, and their bad input."""
import json
from argparse import Namespace

import numpy as np
import pytest
import trimesh

from hwrt.cli import main
from hwrt.progress import PROGRESS_ENV
from raytracer.render import ACCELS

OTHERS = [a for a in ACCELS if a != "bvh"]


def _cli(capsys, *argv):
    """(exit status, stdout, stderr) of ``hwrt argv``; argparse's own errors included."""
    try:
        rc = main(list(map(str, argv)))
    except SystemExit as e:
        rc = e.code
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    from scenes.meshes import sphere
    d = tmp_path_factory.mktemp("accel-meshes")
    tris = sphere(8, 16)
    trimesh.Trimesh(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3),
                    process=False).export(d / "ball.ply")
    return d


def test_bench_trace_traces_the_same_rays_with_each_structure(ball, capsys):
    mesh = ball / "ball.ply"
    rc, out, err = _cli(capsys, "bench", "trace", mesh, "--rays", 300, "--repeat", 1,
                        *[x for a in ACCELS for x in ("--accel", a)], "--json")
    assert rc == 0, err
    r = json.loads(out)
    assert r["accels"] == list(ACCELS)
    (m,) = r["meshes"]
    assert set(m["sets"]) == {"primary", "incoherent", "shadow"}
    assert set(m["accels"]) == set(ACCELS)
    for name, st in m["accels"].items():
        assert st["build_seconds"] > 0 and st["memory_bytes"] > 0
        assert st["build_vs_sweep_bvh"] == pytest.approx(st["build_seconds"] /
                                                         m["sweep_bvh_build_seconds"])
        assert st["references_per_triangle"] >= 1.0, name
        assert set(st["sets"]) == set(m["sets"])
        for kind, s in st["sets"].items():
            assert s["mrays"] > 0 and s["ratio_vs_bvh"] > 0
    # the BVH's index list holds each triangle once
    assert m["accels"]["bvh"]["references_per_triangle"] == 1.0
    # without --accel the rows are the BVH's against its peers only
    rc, out, err = _cli(capsys, "bench", "trace", mesh, "--rays", 300, "--repeat", 1, "--json")
    assert rc == 0, err
    r = json.loads(out)
    assert "accels" not in r and "accels" not in r["meshes"][0]
    rc, out, err = _cli(capsys, "bench", "trace", mesh, "--rays", 300, "--repeat", 1,
                        "--accel", OTHERS[0])
    assert rc == 0, err
    assert "vs bvh" in out and OTHERS[0] in out


@pytest.mark.parametrize("argv", [
    ("bench", "trace", "--accel", "octree"),
    ("bench", "tti", "--accel", "octree"),
    ("render", "cornell", "--accel", "octree"),
    ("verify", "cornell", "--accel", "octree"),
    ("animate", "cloth", "--accel", "octree"),
])
def test_an_unknown_structure_is_one_line_exit_2(argv, capsys):
    rc, out, err = _cli(capsys, *argv)
    assert rc == 2 and out == ""
    assert len(err.strip().splitlines()) == 1
    assert "--accel" in err and "octree" in err


def test_bench_options_that_do_not_read_accel_refuse_it(capsys):
    rc, _, err = _cli(capsys, "bench", "build", "--accel", "grid")
    assert rc == 2 and "--accel" in err and len(err.strip().splitlines()) == 1


def test_tti_rows_include_each_structure_and_old_cells_stay_valid(ball, tmp_path):
    """Cells of a run with the BVH paths only are reused by a run with every structure: only
    the structures' cells run, and the BVH rows are the same."""
    from hwrt import study
    base = dict(quick=True, width=32, height=24, spp=1, max_depth=2, repeat=1, fresh=False,
                meshes=[], mesh_dir=str(ball), out_dir=str(tmp_path / "tti"))
    bvh_only = study.bench_tti(Namespace(**base, accel=["bvh"]), use_dask=False, progress=False)
    assert {r["path"] for r in bvh_only["rows"]} == set(study.TTI_PATHS)
    jsonl = tmp_path / "tti" / "tti.jsonl"
    before = jsonl.read_text().splitlines()
    res = study.bench_tti(Namespace(**base, accel=None), use_dask=False, progress=False)
    after = jsonl.read_text().splitlines()
    scenes = {r["scene"] for r in bvh_only["rows"]}
    assert after[:len(before)] == before
    assert len(after) - len(before) == len(scenes) * len(OTHERS)
    paths = {(r["scene"], r["path"]) for r in res["rows"]}
    assert {(s, a) for s in scenes for a in OTHERS} <= paths
    assert [r for r in res["rows"] if r["accel"] == "bvh"] == bvh_only["rows"]
    for r in res["rows"]:
        if r["accel"] != "bvh":
            assert r["verify_clean"] is True and r["memory_bytes"] > 0
            assert r["total_seconds"] == pytest.approx(r["build_seconds"] + r["render_seconds"])
            bvh = next(x for x in res["rows"] if x["scene"] == r["scene"] and x["path"] == "hwbvh-sw")
            assert r["rays"] == bvh["rays"]          # the same compiled render, the same rays
    md = (tmp_path / "tti" / "tti.md").read_text()
    csv = (tmp_path / "tti" / "tti.csv").read_text()
    for a in OTHERS:
        assert f"| {a} |" in md and f",{a}," in csv
    assert (tmp_path / "tti" / "tti.png").stat().st_size > 0


def _animate(capsys, out, *extra):
    rc, stdout, err = _cli(capsys, "animate", "exploding", "--triangles", 200, "--frames", 2,
                           "--width", 32, "--height", 24, "-o", out, "--json", *extra)
    assert rc == 0, err
    return json.loads(stdout)


@pytest.mark.parametrize("accel", OTHERS)
def test_animate_rebuilds_the_structure_every_frame(accel, tmp_path, capsys):
    from raytracer.output import read_exr
    r = _animate(capsys, tmp_path / accel, "--accel", accel, "--verify")
    assert r["accel"] == accel and r["rebuilds"] == 2 and len(r["frames"]) == 2
    assert r["verify"]["mismatch"] == 0 and r["verify"]["rays"] > 0
    for f in r["frames"]:
        assert f["rebuilt"] and f["memory_bytes"] > 0 and f["sah_cost"] is None
        assert f["time_to_image_seconds"] == pytest.approx(f["build_seconds"] + f["render_seconds"])
    _animate(capsys, tmp_path / "bvh")                  # the BVH frames to compare with
    for i in range(2):
        a, chans, meta = read_exr(tmp_path / accel / f"frame_{i:04d}.exr")
        b, _, _ = read_exr(tmp_path / "bvh" / f"frame_{i:04d}.exr")
        assert meta["accel"] == accel and a.shape == b.shape
        # the same triangle unit and tie rule: the same image, but for rays on shared edges
        assert np.mean(np.abs(a[..., :3] - b[..., :3]) > 1e-4) < 0.01
    # a rerun resumes: the state names the structure
    again = _animate(capsys, tmp_path / accel, "--accel", accel)
    assert again["resumed_from"] == 2


@pytest.mark.parametrize("progress", ["", "1"])
@pytest.mark.parametrize("strategy", ["refit", "adaptive", "embree"])
def test_animate_strategies_other_than_rebuild_are_for_the_bvh(strategy, progress, tmp_path,
                                                                capsys, monkeypatch):
    # with the progress bar asked for, no bar comes before the error: it starts with the work
    monkeypatch.setenv(PROGRESS_ENV, progress)
    rc, out, err = _cli(capsys, "animate", "cloth", "--accel", OTHERS[0], "--strategy", strategy,
                        "-o", tmp_path / "o")
    assert rc == 2 and out == "" and len(err.strip().splitlines()) == 1
    assert "--strategy" in err and strategy in err
    assert not (tmp_path / "o").exists()
