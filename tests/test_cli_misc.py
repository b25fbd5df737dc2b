"""Smoke tests of the narrated example and the benchmarks' plumbing; slow scale runs."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

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


def test_first_render_on_an_empty_cache_fills_it_and_matches_a_warm_render(tmp_path):
    """A first run (empty Numba cache) compiles the traversal in a child process while the
    render compiles the rest; the child fills the cache, and the image is the one a warm run
    renders."""
    cache = tmp_path / "numba-cache"
    cache.mkdir()
    cold, warm = tmp_path / "cold.exr", tmp_path / "warm.exr"
    args = [sys.executable, "-m", "hwrt.cli", "render", "cornell", "--width", "40", "--height", "30",
            "--spp", "2"]
    subprocess.run(args + ["-o", str(cold)], check=True, capture_output=True,
                   env=dict(os.environ, NUMBA_CACHE_DIR=str(cache)))
    assert any(p.name.startswith("traverse.trace_chunks") and p.suffix == ".nbi"
               for p in cache.rglob("*")), "the traversal kernel was not cached"
    subprocess.run(args + ["-o", str(warm)], check=True, capture_output=True)
    from raytracer.output import read_exr
    assert np.array_equal(read_exr(cold)[0], read_exr(warm)[0])


def test_a_warm_process_starts_no_compiling_child():
    from raytracer.render import _compile_traversal_beside
    from traversal.api import compile_kernels
    compile_kernels()
    assert _compile_traversal_beside() is None
