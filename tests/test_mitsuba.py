"""Mitsuba 3 as a peer: the matching scene, image agreement, and ``hwrt bench render``.

The agreement tests need the optional ``mitsuba`` package and are skipped without it; the
refusals and the benchmark's own checks run everywhere."""
import argparse
import dataclasses
import json
import statistics

import numpy as np
import pytest

from hwbvh.errors import InputError
from hwrt import mitsuba_peer as mp
from scenes import compile_scene, load_scene

from .conftest import MESH_DIR

# The comparison's bar (a figure of the benchmark, checked here at a small size): our image may
# differ from Mitsuba's by at most 1.25x as much as two Mitsuba renders with different seeds do.
AGREEMENT_LIMIT = 1.25


def _mesh_file(tmp_path):
    """The bunny when the shared meshes are there, else a generated indexed mesh: a sphere left
    of centre standing on a floor, so the image is lopsided and holds a cast shadow."""
    bunny = MESH_DIR / "bunny.ply"
    if bunny.exists():
        return bunny
    import trimesh
    from scenes.meshes import uv_sphere
    V, F = uv_sphere(24, 48, radius=0.5, center=(-0.5, 0.5, 0.0))
    floor = np.array([[-2, 0, -2], [2, 0, -2], [2, 0, 2], [-2, 0, 2]], np.float64)
    verts = np.concatenate([V, floor])
    faces = np.concatenate([F, len(V) + np.array([[0, 2, 1], [0, 3, 2]])])
    path = tmp_path / "sphere-on-floor.ply"
    trimesh.Trimesh(verts, faces, process=False).export(path)
    return path


def _small(spec, width=64, height=48, spp=4):
    d = load_scene(str(spec))
    d["film"] = {"width": width, "height": height, "spp": spp}
    return compile_scene(d)


def _ours(scene, seed=0):
    from raytracer.render import make_tracer, render
    tracer, _, _ = make_tracer(scene, "hwbvh", "numba")
    return render(scene, tracer, seed=seed).image


# ---------------------------------------------------------------------------------------------
# what the comparison accepts
# ---------------------------------------------------------------------------------------------
def test_refuses_materials_it_cannot_match():
    scene = compile_scene(load_scene("cornell", width=8, height=6, spp=1))
    with pytest.raises(InputError, match=r"^cornell: Mitsuba comparison: material '\w+' .*"
                                         r"only diffuse materials are supported"):
        mp.check_supported(scene)


def test_refuses_directional_lights():
    scene = compile_scene(load_scene("marbles", width=8, height=6, spp=1))
    scene = dataclasses.replace(scene, kr=np.zeros_like(scene.kr), ior=np.zeros_like(scene.ior),
                                ks=np.zeros_like(scene.ks))             # diffuse, so the light decides
    with pytest.raises(InputError, match=r"lights\[0\] is a directional light \(only point lights"):
        mp.check_supported(scene)


def test_refuses_smooth_normals(tmp_path):
    d = load_scene(str(_mesh_file(tmp_path)))
    assert mp.unsupported(compile_scene(d)) is None
    d["shapes"][0]["smooth"] = True
    assert "smooth" in mp.unsupported(compile_scene(d))


def test_indexed_mesh_keeps_every_triangle():
    from scenes.meshes import sphere
    tris = sphere(6, 8)
    verts, faces = mp._indexed(tris)
    assert len(verts) == 2 + 5 * 8                   # the UV sphere's shared vertices
    np.testing.assert_array_equal(verts[faces], tris)


def test_relative_rmse():
    ref = np.ones((2, 2, 3))
    assert mp.relative_rmse(ref, ref) == 0
    assert mp.relative_rmse(ref * 1.1, ref) == pytest.approx(0.1)


# ---------------------------------------------------------------------------------------------
# image agreement against Mitsuba 3
# ---------------------------------------------------------------------------------------------
def test_image_agrees_with_mitsuba(tmp_path):
    pytest.importorskip("mitsuba")
    scene = mp.neutral_scene(_small(_mesh_file(tmp_path)))
    ours = _ours(scene)
    peer = mp.MitsubaPeer(scene, "scalar_rgb")
    a = mp.image_agreement(ours, peer)
    assert a["mitsuba_vs_mitsuba"] > 0
    assert a["ratio"] <= AGREEMENT_LIMIT, a
    # the measure has the power to tell: the same image mirrored left-right is far outside it
    mirrored = mp.image_agreement(ours[:, ::-1], peer)
    assert mirrored["ratio"] > 2 * AGREEMENT_LIMIT, mirrored
    # and a light 10% too bright is outside it too
    assert mp.image_agreement(ours * 1.1, peer)["ratio"] > AGREEMENT_LIMIT
    # the light's scale is the same in both renderers (the means agree to a few percent)
    ms, _ = peer.load()
    theirs, _ = peer.render(ms, seed=3)
    assert ours.mean() == pytest.approx(theirs.mean(), rel=0.03)


def test_llvm_variant_is_probed_not_trusted():
    pytest.importorskip("mitsuba")
    ok, why = mp.variant_status("llvm_ad_rgb")
    assert ok or why                                  # usable, or a reason to show
    assert mp.variant_status("scalar_rgb") == (True, "")


# ---------------------------------------------------------------------------------------------
# hwrt bench render
# ---------------------------------------------------------------------------------------------
def _bench_args(meshes, out_dir, **kw):
    a = dict(meshes=[str(m) for m in meshes], width=24, height=16, spp=2, max_depth=2, repeat=1,
             out_dir=str(out_dir))
    a.update(kw)
    return argparse.Namespace(**a)


def test_bench_render_honours_the_frame_flags(tmp_path):
    from hwrt.bench import bench_render, human

    r = bench_render(_bench_args([], tmp_path / "out", repeat=3))
    json.dumps(r, allow_nan=False)
    assert set(r) >= {"scenes", "repeat", "machine", "files"}
    (s,) = r["scenes"]
    assert (s["scene"], s["width"], s["height"], s["spp"], s["max_depth"]) == ("cornell", 24, 16, 2, 2)
    assert "mitsuba" not in s                        # a built-in scene: no peer
    assert [(m["builder"], m["traversal"]) for m in s["rows"]] == [("hwbvh", "numba"), ("embree", "embree")]
    for m in s["rows"]:
        assert m["rays"]["primary"] == 24 * 16 * 2
        assert m["render_seconds"] > 0 and m["trace_only_seconds"] > 0
        rounds = m["render_over_trace_only_rounds"]       # each round's render / its replay
        assert len(rounds) == 3 and min(rounds) > 0
        assert m["render_over_trace_only"] == statistics.median(rounds)
        assert m["render_over_trace_only_spread"] == [min(rounds), max(rounds)]
        st = m["stage_seconds"]                          # per stage, summed over the threads
        assert set(st) == {"generate", "queues", "intersect", "shade", "occluded", "accumulate"}
        assert all(v >= 0 for v in st.values()) and st["intersect"] > 0 and st["shade"] > 0
    assert (tmp_path / "out" / "render.md").read_text().count("| hwbvh build") == 1
    assert json.loads((tmp_path / "out" / "render.json").read_text())["scenes"][0]["width"] == 24
    assert "ratio (ours / embree)" in human("render")(r)
    assert "stages, hwbvh+numba (s over all threads): generate" in human("render")(r)
    assert (tmp_path / "out" / "render.md").read_text().count("| hwbvh + numba | ") == 1


def test_bench_render_rejects_a_bad_flag(tmp_path):
    from hwrt.bench import bench_render
    with pytest.raises(InputError, match="--spp: must be at least 1"):
        bench_render(_bench_args([], tmp_path, spp=0))


@pytest.mark.slow
def test_bench_render_compares_with_mitsuba(tmp_path):
    pytest.importorskip("mitsuba")
    from hwrt.bench import bench_render, human

    r = bench_render(_bench_args([_mesh_file(tmp_path)], tmp_path / "out", width=32, height=24, spp=4))
    json.dumps(r, allow_nan=False)
    (s,) = r["scenes"]
    peer = s["mitsuba"]
    assert peer["skipped"] is None and "ambient 0" in peer["changes"]
    assert peer["versions"]["mitsuba"].startswith("3.")
    rows = {v["variant"]: v for v in peer["variants"]}
    assert set(rows) == set(mp.VARIANTS)
    scalar = rows["scalar_rgb"]
    assert scalar["available"]
    assert scalar["rays_estimate"] >= 32 * 24 * 4
    assert scalar["ours_over_peer"]["total"] == pytest.approx(
        s["rows"][0]["total_seconds"] / scalar["total_seconds"])
    assert scalar["agreement"]["ratio"] <= 2 * AGREEMENT_LIMIT      # 32x24: a noisy estimate
    assert "mitsuba scalar_rgb" in human("render")(r)
