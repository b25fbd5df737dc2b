"""Smoke tests of the study benchmarks (--quick), their outputs, and resuming."""
import json
import subprocess
import sys

import numpy as np
import pytest


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


def test_tti_quick_outputs_and_resume(tmp_path, mesh_dir):
    out = tmp_path / "b"
    r = run("bench", "tti", "--quick", "--mesh-dir", mesh_dir, "--out-dir", out, "--json")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
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
    assert res["break_even"] and all("break_even_rays" in b for b in res["break_even"])
    # resume: a second run measures nothing new
    lines = (out / "tti.jsonl").read_text().count("\n")
    r2 = run("bench", "tti", "--quick", "--mesh-dir", mesh_dir, "--out-dir", out, "--json")
    assert r2.returncode == 0
    assert (out / "tti.jsonl").read_text().count("\n") == lines
    assert json.loads(r2.stdout)["rows"] == res["rows"]


def test_accuracy_quick(tmp_path, mesh_dir):
    out = tmp_path / "a"
    r = run("bench", "accuracy", "--quick", "--mesh-dir", mesh_dir, "--out-dir", out, "--json")
    assert r.returncode == 0, r.stderr
    rows = json.loads(r.stdout)["rows"]
    knobs = {x["knob"] for x in rows}
    assert knobs == {"bins", "leaf_size", "builder", "precision", "triangle_test", "offset",
                     "offset_at_scale", "max_depth", "spp"}
    get = {(x["knob"], str(x["value"])): x for x in rows}
    # starting secondary rays on the surface causes acne; the robust offset does not
    assert get[("offset", "none")]["rmse"] > 10 * get[("offset", "relative")]["rmse"]
    # a fixed epsilon breaks when the scene is scaled; the relative offset does not
    for sc in ("0.001", "1000"):
        assert get[("offset_at_scale", f"fixed@{sc}")]["rmse"] > 5 * get[("offset_at_scale", f"relative@{sc}")]["rmse"]
    # more samples converge toward the 16-spp reference
    assert get[("spp", "8")]["rmse"] < get[("spp", "1")]["rmse"]
    assert all(x["holes"] == 0 for x in rows)
    assert (out / "accuracy.png").exists() and (out / "accuracy.md").exists()
