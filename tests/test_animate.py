"""Dynamic scenes: refit, animated scene descriptions, built-in animations, tree update
strategies and ``hwrt animate``."""
import os

import numpy as np
import pytest

import hwbvh
from hwbvh.cycle_model import PRESETS
from hwbvh.format import WORD_A, WORD_B, node_views
from hwbvh.primitives import primitive_boxes
from hwbvh.refit import Refitter, refit_cost
from scenes.meshes import random_soup, sphere


def _containment(bvh, tris):
    """Every child box inside its parent's and every triangle inside its leaf (the validator),
    and every internal box exactly the union of its children's (a refit is tight)."""
    hwbvh.validate(bvh.nodes, bvh.indices, len(tris), bvh.meta["parameters"]["max_leaf"],
                   primitive_boxes(tris))
    u, f = node_views(bvh.nodes)
    r = Refitter(bvh)
    for i in r.internal:
        lo = np.minimum(f[u[i, WORD_A], :3], f[u[i, WORD_B], :3])
        hi = np.maximum(f[u[i, WORD_A], 3:6], f[u[i, WORD_B], 3:6])
        assert np.array_equal(f[i, :3], lo) and np.array_equal(f[i, 3:6], hi)


# --------------------------------------------------------------------------------------
# refit
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("builder", ["hwbvh", "sweep"])
def test_refit_of_unchanged_geometry_reproduces_the_builders_nodes_bit_for_bit(builder):
    tris = random_soup(3000, seed=5)
    bvh = hwbvh.build(tris, builder=builder)
    again = Refitter(bvh).refit(tris)
    assert again.nodes.tobytes() == bvh.nodes.tobytes()
    assert again.meta["sah_cost"] == bvh.meta["sah_cost"]


@pytest.mark.parametrize("scale", [1e-3, 0.05, 1.0, 1e4])
def test_refit_after_random_perturbation_keeps_containment(rng, scale):
    tris = random_soup(5000, seed=1)
    bvh = hwbvh.build(tris, block_nodes=16, subtree_builders=2, capacity=512)  # children in other blocks
    moved = (tris + rng.normal(0, scale, tris.shape)).astype(np.float32)
    out = Refitter(bvh).refit(moved)
    _containment(out, moved)
    # topology and the index list untouched; only word 0 of each node changed
    assert np.array_equal(node_views(bvh.nodes)[0][:, WORD_A:], node_views(out.nodes)[0][:, WORD_A:])
    assert np.array_equal(out.indices, bvh.indices)


def test_refit_handles_huge_tiny_and_flat_coordinates(rng):
    tris = sphere(12, 24).astype(np.float64)
    for moved in (tris * 1e14, tris * 1e-30, tris * [1, 0, 1]):
        moved = moved.astype(np.float32)
        bvh = hwbvh.build(tris.astype(np.float32))
        _containment(Refitter(bvh).refit(moved), moved)


def test_refit_refuses_a_different_triangle_count_and_nan():
    tris = random_soup(200)
    r = Refitter(hwbvh.build(tris))
    with pytest.raises(hwbvh.InputError, match="needs a rebuild"):
        r.refit(tris[:100])
    bad = tris.copy()
    bad[7, 1, 2] = np.nan
    with pytest.raises(hwbvh.InputError, match="NaN"):
        r.refit(bad)


def test_refit_cost_is_one_streaming_pass_through_the_ram_pairs():
    c = refit_cost(8000, 4001, 20, PRESETS["HWBVH-C"])
    # reads: 8000 AABB words + 1000 index words + 4001 node words, one RAM pair
    assert c["cycles"] == 8000 + 1000 + 4001 + 20
    assert c["seconds"] == pytest.approx(c["cycles"] / 250e6)
    hp = refit_cost(8000, 4001, 20, PRESETS["HWBVH-HP"])
    assert hp["cycles"] == -(-(8000 + 1000 + 4001) // 2) + 20


# --------------------------------------------------------------------------------------
# built-in animations: a valid tree every frame under every strategy
# --------------------------------------------------------------------------------------
from hwrt.animate import STRATEGIES, run  # noqa: E402
from hwrt.config import BENCH_QUICK_TRIANGLES  # noqa: E402
from scenes.animation import load_animation  # noqa: E402

TINY = {"width": 16, "height": 12, "spp": 1}
BUILTINS = {"exploding": {"triangles": 600}, "cloth": {"triangles": 800},
            "marbles": {"physics": "analytic"}, "flythrough": {}}


def _checker(seen):
    def inspect(i, scene, bvh):
        if bvh is not None:
            _containment(bvh, scene.triangles)
            seen.append((i, bvh.meta["sah_cost"]))
    return inspect


@pytest.mark.parametrize("name", list(BUILTINS))
def test_refit_keeps_containment_on_every_frame_of_every_builtin(name):
    anim = load_animation(name, **TINY, **BUILTINS[name])
    seen = []
    res = run(anim, "refit", anim.frames, inspect=_checker(seen))
    assert [i for i, _ in seen] == list(range(anim.frames)) == [f["frame"] for f in res["frames"]]
    assert res["rebuilds"] == 1 and res["frames"][0]["rebuild_reason"] == "first frame"


@pytest.mark.parametrize("name", list(BUILTINS))
@pytest.mark.parametrize("strategy", ["rebuild", "adaptive", "embree"])
def test_strategies_produce_valid_trees(name, strategy):
    anim = load_animation(name, **TINY, **BUILTINS[name])
    seen = []
    res = run(anim, strategy, 24, inspect=_checker(seen))
    assert len(res["frames"]) == 24
    if strategy == "embree":
        # the contract's shape on every frame: each preset, null where no hardware build runs
        none = {"HWBVH-C": None, "HWBVH-HP": None}
        assert seen == [] and all(f["simulated_build_seconds"] == none and
                                  f["time_to_image_simulated_seconds"] == none
                                  for f in res["frames"])
    else:
        assert len(seen) == 24
    for f in res["frames"]:
        assert set(f["simulated_build_seconds"]) == {"HWBVH-C", "HWBVH-HP"}
        assert f["time_to_image_seconds"] == pytest.approx(f["build_seconds"] + f["render_seconds"])
        assert f["rays"]["primary"] == 16 * 12
        if strategy == "rebuild":
            assert set(f["simulated_build_seconds"]) == {"HWBVH-C", "HWBVH-HP"}
            assert f["simulated_energy_joules"]["HWBVH-C"] > 0
        if strategy != "embree":
            # build runs up to a tracer ready to trace; a simulated build leaves the set-up
            setup = f["tracer_setup_seconds"]
            assert 0 < setup < f["build_seconds"]
            for k, sim in f["simulated_build_seconds"].items():
                assert f["time_to_image_simulated_seconds"][k] == \
                    pytest.approx(sim + setup + f["render_seconds"])


def test_exploding_refit_degrades_and_adaptive_rebuilds():
    anim = load_animation("exploding", **TINY, triangles=2000)
    reb = run(anim, "rebuild", 40)["frames"]
    ref = run(anim, "refit", 40)["frames"]
    drift = ref[-1]["sah_cost"] / reb[-1]["sah_cost"]
    assert ref[0]["sah_cost"] == reb[0]["sah_cost"] and drift > 1.5
    ada = run(anim, "adaptive", 40, threshold=1.5)
    later = ada["adaptive_rebuild_frames"]
    assert later and later[0] > 7                       # still until the explosion (0.25 s)
    for f in ada["frames"]:
        assert f["sah_growth"] <= 1.5 or f["rebuilt"]


def test_marbles_with_bullet_when_it_is_installed():
    pytest.importorskip("pybullet")
    anim = load_animation("marbles", **TINY, count=6, subdiv=(4, 8), physics="pybullet")
    assert anim.info["physics"] == "pybullet"
    seen = []
    run(anim, "refit", 20, inspect=_checker(seen))
    a, b = anim.scene(0).triangles, anim.scene(19).triangles
    assert len(seen) == 20 and not np.array_equal(a, b)


def test_a_change_in_triangle_count_forces_a_rebuild():
    from scenes.animation import Animation, Part
    base = load_animation("flythrough", **TINY).base
    grow = lambda i, t: (sphere(4 + (i >= 2), 8), np.zeros((len(sphere(4 + (i >= 2), 8)), 3, 3)))
    anim = Animation("grow", base, [Part(sphere(4, 8), np.zeros((48, 3, 3)), 0, grow)], frames=4)
    res = run(anim, "refit", 4, inspect=_checker([]))
    assert [f["rebuilt"] for f in res["frames"]] == [True, False, True, False]
    assert res["frames"][2]["rebuild_reason"] == "triangle count changed (48 -> 64)"


# --------------------------------------------------------------------------------------
# animated scene files and frame sequences: strict checks
# --------------------------------------------------------------------------------------
import json  # noqa: E402
from pathlib import Path  # noqa: E402

import trimesh  # noqa: E402

from hwrt.cli import main  # noqa: E402


def _ply(path, tris):
    trimesh.Trimesh(np.asarray(tris).reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3),
                    process=False).export(path)


def _scene_file(tmp_path, shapes, animation=None):
    d = {"type": "scene", "camera": {"eye": [0, 1, 4], "target": [0, 0, 0]},
         "film": {"width": 16, "height": 12, "spp": 1},
         "lights": [{"type": "point", "position": [1, 3, 2], "intensity": [10, 10, 10]}],
         "materials": {"white": {"type": "diffuse"}}, "shapes": shapes}
    if animation is not None:
        d["animation"] = animation
    p = tmp_path / "anim.json"
    p.write_text(json.dumps(d))
    return p


def _run_cli(capsys, *argv):
    rc = main(list(map(str, argv)))
    out, err = capsys.readouterr()
    return rc, out, err


BOX = {"type": "box", "min": [-0.5, 0, -0.5], "max": [0.5, 1, 0.5], "material": "white"}


def test_keyframes_interpolate_translate_rotate_scale(tmp_path):
    from scenes.animation import euler_matrix
    keys = [{"time": 0.0, "translate": [0, 0, 0]},
            {"time": 1.0, "translate": [2, 0, 0], "rotate": [0, 90, 0], "scale": 2}]
    p = _scene_file(tmp_path, [dict(BOX, keyframes=keys)], {"frames": 5, "fps": 4})
    anim = load_animation(p)
    t0, mid, end = anim.scene(0).triangles, anim.scene(2).triangles, anim.scene(4).triangles
    R = euler_matrix([0, 45, 0])
    assert np.allclose(mid, (t0.astype(np.float64) * 1.5) @ R.T + [1, 0, 0], atol=1e-5)
    assert np.allclose(end, (t0.astype(np.float64) * 2) @ euler_matrix([0, 90, 0]).T + [2, 0, 0], atol=1e-5)
    assert anim.frames == 5 and anim.fps == 4


@pytest.mark.parametrize("shape_or_anim, message", [
    ({"keyframes": [{"time": 0}, {"time": 1, "rotat": [0, 1, 0]}]},
     "key 'shapes[0].keyframes[1].rotat': unknown key"),
    ({"keyframes": [{"time": 1}, {"time": 0.5}]},
     "key 'shapes[0].keyframes[1].time': 0.5 is not after the previous key's 1"),
    ({"keyframes": [{"time": 0, "translate": [0, "x", 0]}]},
     "key 'shapes[0].keyframes[0].translate': expected 3 finite numbers"),
    ({"animation": {"frames": 3, "speed": 2}}, "key 'animation.speed': unknown key"),
    ({"animation": {"camera": [{"time": 0, "eye": [0, 1, 3]}, {"time": 0, "eye": [1, 1, 3]}]}},
     "key 'animation.camera[1].time'"),
    ({"animation": {"camera": [{"time": 0, "fov": 40}, {"time": 1, "fov": 1000}]}},
     "key 'animation.camera[1].fov': must be at most 179.0"),
    ({"animation": {"fps": 1e308}}, "key 'animation.fps': must be at most 1000.0"),
    ({"keyframes": [{"time": 0}, {"time": 1, "translate": [1e308, 0, 0]}]},
     "key 'shapes[0].keyframes[1].translate': expected 3 finite numbers of magnitude at most"),
    # eye on target at the second frame only: refused before the first frame is written
    ({"animation": {"fps": 2, "camera": [{"time": 0}, {"time": 0.5, "eye": [0, 0, 0], "target": [0, 0, 0]},
                                         {"time": 1, "eye": [0, 1, 4]}]}},
     "key 'animation.camera': eye equals target at time 0.5"),
    # up turned over between keys: zero half way
    ({"animation": {"fps": 2, "camera": [{"time": 0, "up": [0, 1, 0]}, {"time": 1, "up": [0, -1, 0]}]}},
     "key 'animation.camera': up is zero at time 0.5"),
])
def test_bad_scene_files_exit_2_naming_file_and_key(tmp_path, capsys, shape_or_anim, message):
    anim = shape_or_anim.pop("animation", None)
    p = _scene_file(tmp_path, [dict(BOX, **shape_or_anim)], anim)
    out_dir = tmp_path / "out"
    rc, out, err = _run_cli(capsys, "animate", p, "--frames", 2, "-o", out_dir)
    assert rc == 2 and message in err and str(p) in err and len(err.strip().splitlines()) == 1
    assert not out_dir.exists() or not any(out_dir.iterdir())


UNIT_TRIANGLE = {"type": "triangles", "material": "white", "data": [[[0, 0, 0], [1, 0, 0], [0, 1, 0]]]}


def test_keyframes_beyond_the_coordinate_bound_are_refused_before_any_frame(tmp_path, capsys):
    """A translate of 1e15 (itself in bounds) carries the unit triangle's far vertex to
    1e15 + 1 at time 2, the third frame: refused before frame 0 is written."""
    keys = [{"time": 0}, {"time": 2, "translate": [1e15, 0, 0]}]
    p = _scene_file(tmp_path, [dict(UNIT_TRIANGLE, keyframes=keys)], {"frames": 3, "fps": 1})
    out_dir = tmp_path / "out"
    rc, out, err = _run_cli(capsys, "animate", p, "-o", out_dir)
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert str(p) in err and "key 'shapes[0].keyframes'" in err and "at time 2 " in err
    assert "1000000000000001.0" in err                 # the magnitude shown with its digits
    assert not out_dir.exists() or not any(out_dir.iterdir())


def test_a_frame_beyond_the_float32_units_reach_is_refused_before_any_frame(tmp_path, capsys):
    """A unit triangle scaled to 1e13 at its last key (time 2) stays within the coordinate
    bound, but its edges and its distance to the eye (1e13 each) multiply past what the
    float32 units' products hold: refused before frame 0 is written, naming the file and the
    frame."""
    keys = [{"time": 0}, {"time": 1}, {"time": 2, "scale": 1e13}]
    p = _scene_file(tmp_path, [dict(UNIT_TRIANGLE, keyframes=keys)], {"frames": 3, "fps": 1})
    out_dir = tmp_path / "out"
    rc, out, err = _run_cli(capsys, "animate", p, "-o", out_dir)
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert str(p) in err and "frame 2 (time 2) is too large for the float32 units" in err
    assert "scale it down" in err
    assert not out_dir.exists() or not any(out_dir.iterdir())
    # the frames before it are within reach: a run of two renders them
    rc, out, err = _run_cli(capsys, "animate", p, "--frames", 2, "--width", 8, "--height", 6,
                            "-o", out_dir)
    assert rc == 0, err


def test_a_scene_too_small_for_the_float32_units_is_refused_before_any_frame(tmp_path, capsys):
    """A triangle of 1e-14 (a scene in the wrong units): the float32 units' products of three
    lengths would be subnormal, so the run is refused naming the file and frame 0."""
    tiny = dict(UNIT_TRIANGLE, data=[[[0, 0, 0], [1e-14, 0, 0], [0, 1e-14, 0]]])
    p = _scene_file(tmp_path, [dict(tiny, keyframes=[{"time": 0}, {"time": 1}])],
                    {"frames": 2, "fps": 1})
    out_dir = tmp_path / "out"
    rc, out, err = _run_cli(capsys, "animate", p, "-o", out_dir)
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert str(p) in err and "frame 0 (time 0) is too small for the float32 units" in err
    assert "scale it up" in err and "float64" not in err
    assert not out_dir.exists() or not any(out_dir.iterdir())


def test_a_frame_shrunk_too_small_for_the_float32_units_is_refused_before_its_render(tmp_path,
                                                                                     capsys):
    """Scaled to 1e-14 at its last key, the unit triangle leaves the float32 units' reach at
    frame 1: the frames before it are written, that one is refused naming the file and
    frame."""
    keys = [{"time": 0}, {"time": 1, "scale": 1e-14}]
    p = _scene_file(tmp_path, [dict(UNIT_TRIANGLE, keyframes=keys)], {"frames": 2, "fps": 1})
    out_dir = tmp_path / "out"
    rc, out, err = _run_cli(capsys, "animate", p, "--width", 8, "--height", 6, "-o", out_dir)
    assert rc == 2 and str(p) in err and "frame 1 (time 1) is too small for the float32 units" in err
    assert err.rstrip().endswith("(scale it up)"), err
    assert (out_dir / "frame_0000.exr").exists() and not (out_dir / "frame_0001.exr").exists()


def test_float32_reach_covers_sequences_and_the_eye(tmp_path, capsys):
    """The check before the first frame takes a sequence's files (the third scaled by 1e13)
    and a moving eye (1e15 away from triangles of 3e11 at the last key) into account."""
    frames = tmp_path / "frames"
    frames.mkdir()
    for i, k in enumerate((1.0, 1.0, 1e13)):
        _ply(frames / f"ball_{i:04d}.ply", sphere(4, 8) * k)
    out_dir = tmp_path / "out"
    rc, _, err = _run_cli(capsys, "animate", frames / "ball_%04d.ply", "-o", out_dir)
    assert rc == 2 and "frame 2 (time " in err and "too large for the float32 units" in err, err
    assert not out_dir.exists() or not any(out_dir.iterdir())
    big = dict(UNIT_TRIANGLE, data=[[[0, 0, -1], [3e11, 0, -1], [0, 3e11, -1]]])
    camera = [{"time": 0, "eye": [0, 1, 4]}, {"time": 1, "eye": [0, 1, 1e15]}]
    p = _scene_file(tmp_path, [big], {"frames": 3, "fps": 2, "camera": camera})
    rc, _, err = _run_cli(capsys, "animate", p, "-o", out_dir)
    assert rc == 2 and str(p) in err and "frame 2 (time 1) is too large" in err, err
    assert not out_dir.exists() or not any(out_dir.iterdir())


@pytest.mark.parametrize("rotate, ok", [(45, True), (-30, False)])
def test_keyframe_bound_check_decides_rotated_shapes_by_their_vertices(tmp_path, rotate, ok):
    """The triangle (1e15, 0, 0), (0, 1e15, 0), (0, 0, 0) turning 45 degrees about z keeps
    every vertex in bounds though its box's corner (1e15, 1e15, 0) swings out to 1.41e15: no
    error. Turning -30 degrees while growing to 1.2 times its size, its vertex (1e15, 0, 0)
    leaves the bounds at the first frame after time 0."""
    tri = dict(UNIT_TRIANGLE, data=[[[1e15, 0, 0], [0, 1e15, 0], [0, 0, 0]]])
    last = {"time": 1, "rotate": [0, 0, rotate]} if ok else {"time": 1, "rotate": [0, 0, rotate], "scale": 1.2}
    p = _scene_file(tmp_path, [dict(tri, keyframes=[{"time": 0}, last])], {"frames": 2000, "fps": 1000})
    anim = load_animation(p)
    if ok:
        anim.check(2000)
        assert np.abs(anim.scene(500).triangles.astype(np.float64)).max() <= 1e15
    else:
        with pytest.raises(hwbvh.InputError, match=r"key 'shapes\[0\].keyframes': at time 0\.001 the"):
            anim.check(2000)


def test_vectorised_track_gives_each_times_value_bit_for_bit(rng):
    from scenes.animation import Track
    tr = Track(np.sort(rng.uniform(0, 3, 5)), {"v": rng.normal(size=(5, 3)), "s": rng.uniform(1, 2, 5)})
    times = np.concatenate([np.linspace(-1, 4, 2001), tr.times])
    many = tr.at_times(times)
    for i, t in enumerate(times):
        one = tr.at(t)
        assert all(one[k].tobytes() == many[k][i].tobytes() for k in one)
    assert np.array_equal(many["v"][0], tr.channels["v"][0]) and np.array_equal(many["v"][-6], tr.channels["v"][-1])


def test_a_tiny_scene_whose_camera_moves_animates(tmp_path, capsys):
    """The camera track is held to the still scene's rule (eye and target differ): a scene
    1e-9 across, its eye 1e-9 from its target, is no error."""
    p = tmp_path / "tiny.json"
    p.write_text(json.dumps({
        "camera": {"eye": [0, 0, 1e-9], "target": [0, 0, 0]},
        "lights": [{"type": "directional", "direction": [0, 0, -1], "irradiance": [1, 1, 1]}],
        "materials": {"white": {"type": "diffuse"}},
        "shapes": [{"type": "triangles", "material": "white",
                    "data": [[[-1e-9, -1e-9, 0], [1e-9, -1e-9, 0], [0, 1e-9, 0]]]}],
        "animation": {"frames": 2, "fps": 1,
                      "camera": [{"time": 0}, {"time": 1, "eye": [1e-9, 0, 1e-9]}]}}))
    out_dir = tmp_path / "out"
    rc, _, err = _run_cli(capsys, "animate", p, "--width", 8, "--height", 6, "-o", out_dir)
    assert rc == 0, err
    from raytracer.output import read_exr
    for i in (0, 1):
        assert read_exr(out_dir / f"frame_{i:04d}.exr")[0][..., 0].max() > 0  # the triangle is seen


def test_an_eye_1e_200_from_its_target_animates_finite_frames(tmp_path, capsys):
    """Eye and target that differ at all are a camera, however little (the basis is
    normalised without underflow): finite frames, no warning."""
    import warnings
    p = tmp_path / "tiny.json"
    p.write_text(json.dumps({
        "camera": {"eye": [0, 0, 1e-200], "target": [0, 0, 0]},
        "lights": [{"type": "directional", "direction": [0, 0, -1], "irradiance": [1, 1, 1]}],
        "materials": {"white": {"type": "diffuse"}},
        "shapes": [{"type": "triangles", "material": "white",
                    "data": [[[-1, -1, -1], [1, -1, -1], [0, 1, -1]]]}],
        "animation": {"frames": 2, "fps": 1,
                      "camera": [{"time": 0}, {"time": 1, "eye": [1e-200, 0, 1e-200]}]}}))
    out_dir = tmp_path / "out"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rc, _, err = _run_cli(capsys, "animate", p, "--width", 8, "--height", 6, "-o", out_dir)
    assert rc == 0, err
    from raytracer.output import read_exr
    for i in (0, 1):
        rgb = read_exr(out_dir / f"frame_{i:04d}.exr")[0][..., :3]
        assert np.isfinite(rgb).all() and rgb.max() > 0


def test_frame_sequences_bad_inputs(tmp_path, capsys):
    frames = tmp_path / "frames"
    frames.mkdir()
    out_dir = tmp_path / "out"
    rc, _, err = _run_cli(capsys, "animate", frames / "f_%04d.ply", "-o", out_dir)
    assert rc == 2 and "matches no file" in err
    for i in (0, 1, 3):
        _ply(frames / f"f_{i:04d}.ply", sphere(4, 8) + i)
    rc, _, err = _run_cli(capsys, "animate", frames / "f_%04d.ply", "-o", out_dir)
    assert rc == 2 and "f_0002.ply" in err and "missing frame 2" in err
    rc, _, err = _run_cli(capsys, "animate", str(frames / "f_*.ply"), "-o", out_dir)
    assert rc == 2 and "f_0002.ply" in err and "missing frame 2" in err
    bad = sphere(4, 8).astype(np.float64)
    bad[5, 1, 0] = np.nan
    (frames / "f_0003.ply").unlink()
    _ply(frames / "f_0002.ply", bad)            # NaN in the last frame: checked before frame 0
    rc, _, err = _run_cli(capsys, "animate", frames / "f_%04d.ply", "-o", out_dir)
    assert rc == 2 and "f_0002.ply" in err and "NaN" in err
    assert not out_dir.exists() or not list(out_dir.glob("*.exr"))
    rc, _, err = _run_cli(capsys, "animate", frames / "f_%04d.ply", "--frames", 9, "-o", out_dir)
    assert rc == 2 and "only 3" in err



def test_a_glob_with_two_files_for_one_frame_number_names_both(tmp_path, capsys):
    """A repeated number is not a gap: the error names the two files, not a "missing" one."""
    frames = tmp_path / "frames"
    frames.mkdir()
    for name in ("a_0000.ply", "a_0001.ply", "b_0000.ply"):
        _ply(frames / name, sphere(4, 8))
    rc, _, err = _run_cli(capsys, "animate", str(frames / "*.ply"), "-o", tmp_path / "out")
    assert rc == 2 and "missing" not in err
    assert f"two files for frame 0: {frames / 'a_0000.ply'} and {frames / 'b_0000.ply'}" in err


@pytest.mark.parametrize("pattern", ["f_%04d.ply", "f_*.ply"])
def test_a_frame_file_of_a_scene_is_refused_naming_the_scene_key(tmp_path, capsys, pattern):
    """Any frame's fault, not only the first's, names the scene file and the key whose pattern
    holds the frame, then the frame file."""
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(4):
        _ply(frames / f"f_{i:04d}.ply", sphere(4, 8) + i)
    (frames / "f_0002.ply").write_bytes(b"ply\nformat ascii 1.0\n")
    p = _scene_file(tmp_path, [{"type": "frames", "pattern": f"frames/{pattern}",
                                "material": "white"}])
    rc, _, err = _run_cli(capsys, "animate", p, "-o", tmp_path / "out")
    assert rc == 2 and err.startswith(f"hwrt: error: {p}: key 'shapes[0].pattern': ")
    assert "f_0002.ply" in err and err.count("\n") == 1
    (frames / "f_0002.ply").unlink()
    rc, _, err = _run_cli(capsys, "animate", p, "-o", tmp_path / "out")
    assert rc == 2 and err.startswith(f"hwrt: error: {p}: key 'shapes[0].pattern': missing "
                                      f"frame 2: ") and "f_0002.ply" in err
    assert not (tmp_path / "out").exists()


def test_a_scene_files_fps_is_checked_where_the_command_line_replaces_it(tmp_path, capsys):
    p = _scene_file(tmp_path, [BOX], {"fps": "abc"})
    rc, _, err = _run_cli(capsys, "animate", p, "--fps", 10, "--frames", 1, "-o", tmp_path / "o")
    assert rc == 2 and "key 'animation.fps': expected a finite number, got 'abc'" in err
    assert not (tmp_path / "o").exists()

def test_frame_pattern_with_changing_triangle_count_rebuilds_and_writes_everything(tmp_path, capsys):
    frames = tmp_path / "frames"
    frames.mkdir()
    for i, n in enumerate((4, 4, 5, 5)):
        _ply(frames / f"bunny_{i:04d}.ply", sphere(n, 8) + [0, 0.05 * i, 0])
    out_dir = tmp_path / "out"
    rc, out, err = _run_cli(capsys, "animate", frames / "bunny_%04d.ply", "--strategy", "refit",
                            "--width", 16, "--height", 12, "-o", out_dir, "--json")
    assert rc == 0, err
    r = json.loads(out, parse_constant=lambda c: pytest.fail(f"non-strict JSON {c}"))
    assert r["scene"] == "bunny" and r["strategy"] == "refit" and r["output"] == str(out_dir)
    assert [f["rebuilt"] for f in r["frames"]] == [True, False, True, False]
    assert "triangle count changed (48 -> 64)" == r["frames"][2]["rebuild_reason"]
    for f in r["frames"]:
        for key in ("frame", "rebuilt", "build_seconds", "simulated_build_seconds", "render_seconds",
                    "time_to_image_seconds", "sah_cost", "rays"):
            assert key in f
    names = sorted(p.name for p in out_dir.iterdir())
    assert names == ["animation.json", "frame_0000.exr", "frame_0001.exr", "frame_0002.exr",
                     "frame_0003.exr", "frames.csv", "preview.gif"]
    from raytracer.output import read_exr
    px, chans, meta = read_exr(out_dir / "frame_0002.exr")
    assert px.shape == (12, 16, 8) and "Z" in chans and meta["strategy"] == "refit"
    assert len((out_dir / "frames.csv").read_text().splitlines()) == 5


def test_an_interrupted_run_resumes_at_the_first_missing_frame(tmp_path, capsys):
    args = ["animate", "cloth", "--triangles", 300, "--frames", 5, "--strategy", "adaptive",
            "--threshold", 1.05, "--width", 16, "--height", 12, "--json"]
    rc, out, err = _run_cli(capsys, *args, "-o", tmp_path / "full")
    assert rc == 0, err
    full = json.loads(out)
    part = tmp_path / "part"
    rc, out, _ = _run_cli(capsys, *args, "-o", part)
    (part / "frame_0003.exr").unlink()
    (part / "frame_0004.exr").unlink()
    rc, out, err = _run_cli(capsys, *args, "-o", part)
    r = json.loads(out)
    assert rc == 0 and r["resumed_from"] == 3 and len(r["frames"]) == 5
    # the resumed tree is the one an uninterrupted run has (a refit depends only on topology)
    assert [f["sah_cost"] for f in r["frames"]] == [f["sah_cost"] for f in full["frames"]]
    assert [f["rebuilt"] for f in r["frames"]] == [f["rebuilt"] for f in full["frames"]]
    # the human output says so too
    rc, out, _ = _run_cli(capsys, *args[:-1], "-o", part)
    assert rc == 0 and ("resumed: frames 0-4 of 5 were on disk from an earlier run of the same "
                        "settings") in out
    assert "; this run " in out and "; total " not in out     # the wall time is this run's
    # another run's settings are refused instead of mixing frames
    rc, _, err = _run_cli(capsys, *args[:-1], "--spp", 2, "-o", part)
    assert rc == 2 and "holds frames of another run" in err


def test_a_rerun_on_another_structure_is_refused_either_way(tmp_path, capsys):
    """A BVH run's state names no structure: a rerun with --accel is refused, and a BVH
    rerun of a grid run's directory is refused too (not resumed from the grid's frames)."""
    scene = _scene_file(tmp_path, [BOX], animation={"frames": 2, "fps": 1, "camera": [
        {"time": 0}, {"time": 1, "eye": [1, 1, 4]}]})
    for first, then, words in ((["--accel", "grid"], [], "accel: 'grid', now 'bvh'"),
                               ([], ["--accel", "kdtree"], "accel: 'bvh', now 'kdtree'")):
        out_dir = tmp_path / f"out{len(first)}"
        args = ["animate", scene, "-o", out_dir, "--json"]
        rc, _, err = _run_cli(capsys, *args, *first)
        assert rc == 0, err
        rc, _, err = _run_cli(capsys, *args, *then)
        assert rc == 2 and f"holds frames of another run ({words})" in err


def test_a_rerun_resumes_only_frames_made_as_it_would_make_them(tmp_path, capsys):
    """Another seed, or a scene file edited since, makes other frames: refused, not mixed in.
    A verifying rerun renders again the frames its first run did not verify, so its counts
    cover every frame."""
    scene = _scene_file(tmp_path, [BOX], animation={"frames": 3, "fps": 1, "camera": [
        {"time": 0}, {"time": 2, "eye": [1, 1, 4]}]})
    out_dir = tmp_path / "out"
    args = ["animate", scene, "-o", out_dir, "--json"]
    rc, _, err = _run_cli(capsys, *args)
    assert rc == 0, err
    rc, _, err = _run_cli(capsys, *args, "--seed", 7)
    assert rc == 2 and "holds frames of another run (seed: 0, now 7)" in err
    rc, out, err = _run_cli(capsys, *args, "--verify")
    r = json.loads(out)
    assert rc == 0 and r["resumed_from"] == 0 and all("verify" in f for f in r["frames"])
    assert r["verify"]["rays"] == sum(sum(f["rays"].values()) for f in r["frames"]) > 0
    # each frame checked in a render of its own, whose seconds are not the frame's
    assert r["verify"]["same_image"] is True and all(f["verify_seconds"] > 0 for f in r["frames"])
    assert r["verify_seconds_total"] == pytest.approx(sum(f["verify_seconds"] for f in r["frames"]))
    rc, out, err = _run_cli(capsys, *args, "--verify")
    assert rc == 0 and json.loads(out)["resumed_from"] == 3
    # a frame checked without its check's seconds recorded (an older state) is checked again
    state = json.loads((out_dir / "animation.json").read_text())
    del state["frames"][1]["verify_seconds"]
    (out_dir / "animation.json").write_text(json.dumps(state))
    rc, out, err = _run_cli(capsys, *args, "--verify")
    assert rc == 0 and json.loads(out)["resumed_from"] == 1
    assert all(f["verify_seconds"] > 0 for f in json.loads(out)["frames"])
    # a shorter rerun leaves the later frames described in the run's state, and a longer one
    # resumes them
    rc, out, err = _run_cli(capsys, *args, "--frames", 2)
    assert rc == 0 and len(json.loads(out)["frames"]) == 2
    assert [f["frame"] for f in json.loads((out_dir / "animation.json").read_text())["frames"]] == [0, 1, 2]
    (out_dir / "frame_0001.exr").unlink()
    rc, out, err = _run_cli(capsys, *args, "--frames", 2)
    assert rc == 0 and json.loads(out)["resumed_from"] == 1
    rc, out, err = _run_cli(capsys, *args)
    assert rc == 0 and json.loads(out)["resumed_from"] == 3
    d = json.loads(scene.read_text())
    d["materials"]["white"]["reflectance"] = [0.2, 0.4, 0.6]
    scene.write_text(json.dumps(d))
    rc, _, err = _run_cli(capsys, *args)
    assert rc == 2 and err.strip() == (f"hwrt: error: --output {out_dir}: holds frames of another run "
                                         "(made from other contents of the input files); start "
                                         "it over with --fresh or choose another output "
                                         "directory")
    # --fresh starts over: the earlier run's files go, nothing else in the directory
    (out_dir / "notes.txt").write_text("mine")
    rc, out, err = _run_cli(capsys, *args, "--frames", 2, "--fresh")
    r = json.loads(out)
    assert rc == 0 and r["resumed_from"] == 0 and len(r["frames"]) == 2, err
    assert sorted(p.name for p in out_dir.iterdir()) == [
        "animation.json", "frame_0000.exr", "frame_0001.exr", "frames.csv", "notes.txt",
        "preview.gif"]
    state = json.loads((out_dir / "animation.json").read_text())
    assert [f["frame"] for f in state["frames"]] == [0, 1]
    rc, out, err = _run_cli(capsys, *args, "--frames", 2)
    assert rc == 0 and json.loads(out)["resumed_from"] == 2
    # files of no hwrt animate run are still not replaced, --fresh or not
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "frame_0000.exr").write_text("not ours")
    rc, _, err = _run_cli(capsys, *args[:-3], "-o", theirs, "--json", "--fresh")
    assert rc == 2 and "but no animation.json" in err
    assert (theirs / "frame_0000.exr").read_text() == "not ours"


def test_a_rerun_naming_the_same_scene_file_another_way_resumes(tmp_path, capsys, monkeypatch):
    """The scene file by its absolute path, then from its own directory by its name: the same
    run, resumed; a state that recorded the name alone (relative to where it ran) too. Another
    file of the same contents is another run."""
    scene = _scene_file(tmp_path, [BOX], animation={"frames": 2, "fps": 1})
    out_dir = tmp_path / "out"
    rc, _, err = _run_cli(capsys, "animate", scene, "-o", out_dir, "--json")
    assert rc == 0, err
    state = json.loads((out_dir / "animation.json").read_text())
    assert state["parameters"]["source"] == os.path.realpath(scene)
    monkeypatch.chdir(scene.parent)
    rc, out, err = _run_cli(capsys, "animate", scene.name, "-o", out_dir, "--json")
    assert rc == 0 and json.loads(out)["resumed_from"] == 2, err
    state["parameters"]["source"] = scene.name
    (out_dir / "animation.json").write_text(json.dumps(state))
    rc, out, err = _run_cli(capsys, "animate", f"./{scene.name}", "-o", out_dir, "--json")
    assert rc == 0 and json.loads(out)["resumed_from"] == 2, err
    twin = tmp_path / "other" / scene.name
    twin.parent.mkdir()
    twin.write_text(scene.read_text())
    rc, _, err = _run_cli(capsys, "animate", twin, "-o", out_dir, "--json")
    assert rc == 2 and f"holds frames of another run (source: '{os.path.realpath(scene)}', " \
        f"now '{os.path.realpath(twin)}')" in err


def test_a_built_in_animation_is_its_name_whatever_files_share_it(tmp_path, monkeypatch):
    """A built-in's name stays a name in a run's state, though a file or directory of that
    name (its own output directory) stands where the command runs: a rerun from elsewhere is
    the same run."""
    from hwrt.animate import _same_source, _source_path

    monkeypatch.chdir(tmp_path)
    (tmp_path / "marbles").mkdir()
    (tmp_path / "cornell").write_text("")
    assert _source_path("marbles") == "marbles" and _source_path("cornell") == "cornell"
    assert _same_source("marbles", "marbles")
    (tmp_path / "s.json").write_text("{}")
    assert _source_path("s.json") == os.path.realpath(tmp_path / "s.json")
    assert _source_path("f_%04d.ply") == os.path.realpath(tmp_path / "f_%04d.ply")
    assert _same_source("s.json", os.path.realpath(tmp_path / "s.json"))
    assert not _same_source("t.json", os.path.realpath(tmp_path / "s.json"))


def test_a_damaged_frame_is_rendered_again_on_resume(tmp_path, capsys):
    """A frame cut short or replaced since its run (not a whole EXR of the run's size) is not
    carried into the preview: the rerun resumes at it."""
    from raytracer.output import read_exr
    args = ["animate", "cloth", "--triangles", 300, "--frames", 4, "--width", 16, "--height", 12,
            "--json", "-o", tmp_path / "run"]
    rc, out, err = _run_cli(capsys, *args)
    assert rc == 0, err
    good = read_exr(tmp_path / "run" / "frame_0002.exr")[0]
    cut = tmp_path / "run" / "frame_0002.exr"
    cut.write_bytes(cut.read_bytes()[:200])
    rc, out, err = _run_cli(capsys, *args)
    assert rc == 0, err
    r = json.loads(out)
    assert r["resumed_from"] == 2 and len(r["frames"]) == 4
    assert np.array_equal(read_exr(cut)[0], good)
    (tmp_path / "run" / "frame_0001.exr").write_bytes(b"not an image")
    rc, out, err = _run_cli(capsys, *args)
    assert rc == 0 and json.loads(out)["resumed_from"] == 1, err
    # a whole frame of the run, but another frame's: rendered again
    (tmp_path / "run" / "frame_0003.exr").write_bytes((tmp_path / "run" / "frame_0000.exr").read_bytes())
    rc, out, err = _run_cli(capsys, *args)
    assert rc == 0 and json.loads(out)["resumed_from"] == 3, err
    assert read_exr(tmp_path / "run" / "frame_0003.exr")[2]["frame"] == 3


def test_unknown_strategy_and_bad_output_exit_2_before_any_work(tmp_path, capsys):
    rc, _, err = _run_cli(capsys, "animate", "cloth", "--strategy", "bvh", "-o", tmp_path / "o")
    assert rc == 2 and "unknown strategy 'bvh'" in err and not (tmp_path / "o").exists()
    f = tmp_path / "file"
    f.write_text("x")
    rc, _, err = _run_cli(capsys, "animate", "cloth", "--frames", 1, "-o", f)
    assert rc == 2 and str(f) in err
    rc, _, err = _run_cli(capsys, "animate", "cloth", "--threshold", 0.5, "--strategy", "adaptive",
                          "-o", tmp_path / "o")
    assert rc == 2 and "threshold" in err


def test_a_second_run_into_a_directory_in_use_is_refused_and_touches_nothing(tmp_path, capsys):
    """Two runs into one directory would each replace the other's frames and state; the
    second is refused while the first holds it (here: the test holds it, as a run does)."""
    from hwbvh.files import held_directory
    out = tmp_path / "run"
    with held_directory(out, "animate"):
        rc, _, err = _run_cli(capsys, "animate", "cloth", "--triangles", 200, "--frames", 1,
                              "--width", 8, "--height", 8, "--spp", 1, "-o", out)
        assert rc == 2 and "another hwrt animate is writing into it" in err
        assert list(out.iterdir()) == []
    assert not out.exists()                 # made for the run, empty: removed again
    rc, _, err = _run_cli(capsys, "animate", "cloth", "--triangles", 200, "--frames", 1,
                          "--width", 8, "--height", 8, "--spp", 1, "-o", out)
    assert rc == 0 and (out / "frame_0000.exr").exists()


def test_run_checks_its_arguments_before_it_makes_a_directory(tmp_path):
    from hwbvh.errors import ParameterError
    anim = load_animation("cloth", triangles=200, **TINY)
    for kwargs, name in [({"frames": 0}, "frames"), ({"strategy": "bvh"}, "strategy"),
                         ({"strategy": "embree", "verify": True}, "verify")]:
        with pytest.raises(ParameterError) as e:
            run(anim, out_dir=tmp_path / "new" / "run", **kwargs)
        assert e.value.parameter == name
    with pytest.raises(ParameterError, match="is empty"):
        run(anim, frames=1, out_dir="")
    assert list(tmp_path.iterdir()) == []


def test_sigterm_leaves_only_whole_frames_and_the_run_resumes(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time
    out_dir = tmp_path / "out"
    cmd = [sys.executable, "-m", "hwrt.cli", "animate", "cloth", "--triangles", "300", "--frames", "400",
           "--width", "16", "--height", "12", "-o", str(out_dir)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 120
    while not (out_dir / "frame_0003.exr").exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=60)
    assert proc.returncode != 0
    names = os.listdir(out_dir)
    assert not [n for n in names if n.startswith(".tmp")]
    from raytracer.output import read_exr
    done = sorted(n for n in names if n.endswith(".exr"))
    for n in done:
        assert read_exr(out_dir / n)[0].shape == (12, 16, 8)
    r = subprocess.run(cmd[:8] + [str(len(done) + 2)] + cmd[9:] + ["--json"], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert len(done) - 1 <= res["resumed_from"] <= len(done) and len(res["frames"]) == len(done) + 2


def test_bench_animation_writes_its_figures_and_summary(tmp_path, capsys):
    rc, out, err = _run_cli(capsys, "bench", "animation", "--quick", "--frames", 3, "--width", 16,
                            "--height", 12, "--out-dir", tmp_path, "--json")
    assert rc == 0, err
    r = json.loads(out)
    assert [s["animation"] for s in r["summary"]] == ["exploding", "cloth", "marbles", "flythrough"]
    assert r["structures"] == ["grid", "kdtree"]
    assert len(r["rows"]) == 4 * (len(STRATEGIES) + 2) * 3
    for s in r["summary"]:
        assert set(s["structures"]) == {"bvh", "grid", "kdtree"}
        assert all(v["build"] > 0 and v["render"] > 0 for v in s["structures"].values())
    for s in r["summary"]:
        assert s["hw_rebuild_HWBVH-C_vs_refit"] > 0 and s["energy_per_frame_HWBVH-C_joules"] > 0
    for f in r["files"]:
        assert Path(f).parent == tmp_path and Path(f).stat().st_size > 0
    # the file holds what stdout holds but the file list: how the run was made, too
    saved = json.loads((tmp_path / "animation.json").read_text())
    assert saved == {k: v for k, v in r.items() if k != "files"}
    assert saved["setting"] == {"width": 16, "height": 12, "spp": 1, "max_depth": None,
                                "triangles": BENCH_QUICK_TRIANGLES}


def test_errors_name_the_shape_by_its_place_in_the_file(tmp_path, capsys):
    p = _scene_file(tmp_path, [BOX, dict(BOX, rotate_y="x")])
    rc, out, err = _run_cli(capsys, "animate", p, "--frames", 2, "-o", tmp_path / "out")
    assert rc == 2 and "key 'shapes[1].rotate_y'" in err, err


@pytest.mark.parametrize("directory,problem", [
    ("empty", "has no mesh files"), ("missing", "no such directory"),
    ("no-bunny", "has no bunny")])
def test_exploding_takes_its_bunny_from_the_mesh_directory_by_the_benchmarks_rule(
        tmp_path, capsys, monkeypatch, directory, problem):
    """$HWRT_MESHES names the directory exploding's default bunny comes from: one that is
    missing, empty or without a bunny is an error, not a generated sphere in its place."""
    import trimesh
    d = tmp_path / directory
    if directory != "missing":
        d.mkdir()
    if directory == "no-bunny":
        tris = sphere(4, 6)
        trimesh.Trimesh(tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3),
                        process=False).export(d / "ball.ply")
    monkeypatch.setenv("HWRT_MESHES", str(d))
    out = tmp_path / "o"
    rc, _, err = _run_cli(capsys, "animate", "exploding", "--frames", 1, "-o", out)
    assert rc == 2 and err.count("\n") == 1 and f"$HWRT_MESHES {d}: {problem}" in err, err
    assert not out.exists()


def test_exploding_breaks_the_bunny_of_the_mesh_directory(tmp_path, monkeypatch, capsys):
    import trimesh
    with pytest.raises(SystemExit):
        main(["animate", "--help"])
    assert "the bunny of the mesh directory, $HWRT_MESHES, else" in " ".join(
        capsys.readouterr().out.split())
    from hwrt.animate import open_animation
    tris = sphere(4, 6)
    trimesh.Trimesh(tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3),
                    process=False).export(tmp_path / "bunny.ply")
    monkeypatch.setenv("HWRT_MESHES", str(tmp_path))
    assert open_animation("exploding").info["mesh"] == "bunny.ply"
    assert open_animation("exploding", triangles=500).info["mesh"].startswith("generated sphere")


def test_exploding_takes_a_flat_mesh_and_names_a_mesh_with_no_extent(tmp_path, capsys):
    """A mesh flat in y (a sheet lying on the floor) explodes like any other, scaled to the
    frame by its width; a mesh whose vertices all coincide is a one-line error naming it."""
    from hwrt.animate import open_animation
    sheet = np.array([[[0, 0, 0], [4, 0, 0], [0, 0, 4]], [[4, 0, 0], [4, 0, 4], [0, 0, 4]]], float)
    _ply(tmp_path / "sheet.ply", sheet)
    anim = open_animation("exploding", mesh=str(tmp_path / "sheet.ply"))
    tris = anim.parts[-1].tris
    assert np.allclose(tris[..., 1], 0) and np.isclose(np.ptp(tris[..., 0]), 2.0)
    assert np.isclose(tris[..., 0].min(), -1.0)
    rc, _, err = _run_cli(capsys, "animate", "exploding", "--mesh", tmp_path / "sheet.ply",
                          "--frames", 2, "--width", 8, "--height", 6, "-o", tmp_path / "ok")
    assert rc == 0, err
    _ply(tmp_path / "point.ply", np.ones((2, 3, 3)))
    out = tmp_path / "point"
    rc, _, err = _run_cli(capsys, "animate", "exploding", "--mesh", tmp_path / "point.ply",
                          "--frames", 2, "--width", 8, "--height", 6, "-o", out)
    assert rc == 2 and err.count("\n") == 1, err
    assert "point.ply" in err and "every vertex is at one point" in err
    assert not out.exists()


def test_frame_sequence_errors_name_the_pattern_key(tmp_path, capsys, monkeypatch):
    """A frames shape's first file is read as a mesh, but its errors name the key the scene
    file has (``pattern``); a sequence longer than an animation may be, with no frame count,
    is blamed on its pattern, not on an option the user did not give."""
    frames = tmp_path / "seq"
    frames.mkdir()
    (frames / "f_0000.ply").write_text("not a mesh\n")
    shape = {"type": "frames", "pattern": "seq/f_%04d.ply", "material": "white"}
    p = _scene_file(tmp_path, [shape])
    rc, _, err = _run_cli(capsys, "animate", p, "-o", tmp_path / "out")
    assert rc == 2 and "key 'shapes[0].pattern'" in err and "f_0000.ply" in err, err
    assert "filename" not in err
    for i in range(3):
        _ply(frames / f"f_{i:04d}.ply", sphere(4, 8) + i)
    import scenes.animation
    monkeypatch.setattr(scenes.animation, "MAX_FRAMES", 2)
    rc, _, err = _run_cli(capsys, "animate", p, "-o", tmp_path / "out")
    assert rc == 2 and "key 'shapes[0].pattern'" in err and "3 files" in err, err
    assert "--frames" not in err and not (tmp_path / "out").exists()
    # a frame count within the limit renders the sequence's first frames
    rc, _, err = _run_cli(capsys, "animate", p, "--frames", 2, "--width", 8, "--height", 6,
                          "-o", tmp_path / "out")
    assert rc == 0, err
    assert sorted(f.name for f in (tmp_path / "out").glob("*.exr")) == ["frame_0000.exr",
                                                                      "frame_0001.exr"]
    # more frames than the sequence holds: --frames is blamed when it asked for them, the
    # scene's key when the scene did
    monkeypatch.setattr(scenes.animation, "MAX_FRAMES", 120)
    rc, _, err = _run_cli(capsys, "animate", p, "--frames", 5, "-o", tmp_path / "out5")
    assert rc == 2 and err.strip() == \
        f"hwrt: error: --frames: 5 asked for, but the sequence of {p} has only 3", err
    p5 = _scene_file(tmp_path, [shape], {"frames": 5})
    rc, _, err = _run_cli(capsys, "animate", p5, "-o", tmp_path / "out5")
    assert rc == 2 and err.strip() == (f"hwrt: error: {p5}: key 'animation.frames': 5 frames "
                                       "asked for, but the sequence has only 3"), err
    assert not (tmp_path / "out5").exists()


def test_an_unknown_key_of_a_moving_scene_lists_animation_among_the_known(tmp_path, capsys):
    p = _scene_file(tmp_path, [BOX], {"frames": 2})
    d = json.loads(p.read_text())
    d["bogus"] = 1
    p.write_text(json.dumps(d))
    rc, _, err = _run_cli(capsys, "animate", p, "-o", tmp_path / "out")
    assert rc == 2 and f"{p}: key 'bogus': unknown key (known keys: " in err
    assert err.strip().endswith("shapes, animation)"), err
    d["animaton"] = d.pop("bogus")
    p.write_text(json.dumps(d))
    rc, _, err = _run_cli(capsys, "animate", p, "-o", tmp_path / "out")
    assert rc == 2 and "key 'animaton': unknown key (did you mean 'animation'?)" in err


@pytest.mark.parametrize("fps", [0, -5, 1e6, float("nan"), True, "30"])
def test_load_animation_checks_its_frame_rate(fps):
    """The command line's range for --fps holds from Python too (a rate of 0 would divide by
    zero at the first frame)."""
    from hwbvh.errors import ParameterError
    from scenes.animation import load_animation
    with pytest.raises(ParameterError, match="must be a frame rate in") as e:
        load_animation("cloth", fps=fps, triangles=200)
    assert e.value.parameter == "fps"


@pytest.mark.parametrize("triangles", [0, -5, 2**24 + 1, 2.5, True])
def test_load_animation_checks_its_triangle_count(triangles):
    """--triangles' range from Python too: a negative count failed in math, a huge one ran
    out of memory."""
    from hwbvh.errors import ParameterError
    from scenes.animation import load_animation
    with pytest.raises(ParameterError, match="must be an integer in 1..16777216") as e:
        load_animation("exploding", triangles=triangles)
    assert e.value.parameter == "triangles"


@pytest.mark.parametrize("name, triangles", [("exploding", 676), ("cloth", 512)])
def test_a_generated_mesh_too_large_for_a_tree_is_refused_before_it_is_made(
        name, triangles, monkeypatch):
    """A generated mesh that with the rest of the scene would pass what a tree holds
    (--triangles 2^24 makes a sphere of exactly 2^24 triangles, plus the floor's 2) is refused
    before it is made, by its exact count: with a tree that holds the scene's count the
    animation loads, with one triangle less it is refused (the limit shrunk here so the
    meshes stay small)."""
    import scenes.animation as animation
    from hwbvh.errors import ParameterError
    scene = animation.load_animation(name, triangles=triangles, **TINY).scene(0)
    total = len(scene.triangles)
    monkeypatch.setattr(animation, "MAX_PRIMITIVES", total)
    animation.load_animation(name, triangles=triangles, **TINY)
    monkeypatch.setattr(animation, "MAX_PRIMITIVES", total - 1)

    def no_mesh(*args, **kwargs):
        raise AssertionError("the mesh was made")
    monkeypatch.setattr("scenes.meshes.sphere", no_mesh)
    monkeypatch.setattr(animation, "Cloth", no_mesh)
    with pytest.raises(ParameterError, match=f"with the rest of the scene: more than the "
                                             f"2\\^24 = {total - 1} a tree holds") as e:
        animation.load_animation(name, triangles=triangles, **TINY)
    assert e.value.parameter == "triangles" and f"{total} with the rest" in str(e.value)


def test_animate_counts_and_reports_pixels_too_bright_for_float32(tmp_path, capsys):
    # the largest intensity 0.05 before the box's face the camera sees, on the second frame
    keys = [{"time": 0, "translate": [0, 0, -1]}, {"time": 1, "translate": [0, 0, 0]}]
    p = _scene_file(tmp_path, [dict(BOX, keyframes=keys)], {"frames": 2, "fps": 1})
    d = json.loads(p.read_text())
    d["lights"] = [{"type": "point", "position": [0, 0.5, 0.55], "intensity": 3.4e38}]
    p.write_text(json.dumps(d))
    out_dir = tmp_path / "frames"
    rc, out, err = _run_cli(capsys, "animate", p, "-o", out_dir, "--json")
    res = json.loads(out)
    per_frame = [f["pixels_beyond_float32"] for f in res["frames"]]
    assert rc == 0 and per_frame[0] == 0 < per_frame[1] == res["pixels_beyond_float32_total"]
    assert err.endswith(f"hwrt: warning: {per_frame[1]} pixels brighter than float32 holds "
                        f"(3.4e38) are +inf in {out_dir}; lower the scene's light values\n")


def test_a_keyframe_moving_a_shape_too_far_for_float32_is_refused_before_any_frame(tmp_path,
                                                                                  capsys):
    # a unit box moved to x = 1e9 by its second key, where float32 numbers lie 64 apart
    keys = [{"time": 0, "translate": [0, 0, 0]}, {"time": 1, "translate": [1e9, 0, 0]}]
    p = _scene_file(tmp_path, [dict(BOX, keyframes=keys)], {"frames": 3, "fps": 2})
    out_dir = tmp_path / "frames"
    rc, out, err = _run_cli(capsys, "animate", p, "-o", out_dir)
    assert rc == 2 and not out_dir.exists()
    assert err.strip() == (f"hwrt: error: {p}: key 'shapes[0].keyframes': at time 0.5 the shape "
                           f"collapses: this far from the origin its coordinates round to float32 "
                           f"numbers 32 apart, coarse against its size (at most 1.73)")
    # a million from the origin it is kept, as a still shape is
    keys[1]["translate"] = [1e6, 0, 0]
    p = _scene_file(tmp_path, [dict(BOX, keyframes=keys)], {"frames": 3, "fps": 2})
    assert load_animation(p).check(3) is not None


@pytest.mark.parametrize("theirs", ["frames.csv", "frame_0001.exr"])
def test_a_directory_holding_another_programs_file_is_refused(tmp_path, capsys, theirs):
    """A frame, like the CSV, is only ever on disk with the state that lists it (written in
    one set): without a state it is someone else's."""
    out = tmp_path / "mine"
    out.mkdir()
    (out / theirs).write_text("my,data\n")
    rc, _, err = _run_cli(capsys, "animate", "cloth", "--triangles", 200, "--frames", 2,
                          "--width", 16, "--height", 12, "-o", out)
    assert rc == 2 and err.strip() == (f"hwrt: error: --output {out}: holds {theirs} but no "
                                       f"animation.json of an hwrt animate run: a run would "
                                       f"replace it; choose another output directory")
    assert (out / theirs).read_text() == "my,data\n" and len(list(out.iterdir())) == 1


def test_animate_verify_warns_naming_the_frames_whose_check_made_another_image(
        tmp_path, capsys, monkeypatch):
    import raytracer.render as rr
    real = rr.verified_render

    def second_frame_differs(scene, tracer, seed, *a, **k):
        # frame i is rendered with the run's seed + i
        summary, seconds = real(scene, tracer, seed, *a, **k)
        return dict(summary, same_image=seed != 10 + 1), seconds

    monkeypatch.setattr(rr, "verified_render", second_frame_differs)
    scene = _scene_file(tmp_path, [BOX], animation={"frames": 3, "fps": 1})
    rc, out, err = _run_cli(capsys, "animate", scene, "-o", tmp_path / "out", "--verify",
                            "--seed", 10, "--json")
    assert rc == 0, err
    r = json.loads(out)
    assert r["verify"]["same_image"] is False
    assert [f["verify"]["same_image"] for f in r["frames"]] == [True, False, True]
    assert [line for line in err.splitlines() if line.startswith("hwrt: warning")] == [
        "hwrt: warning: the checked render of frame 1 made another image than the timed render: "
        "its answers were checked, the timed render's were not (the renderer is not "
        "deterministic here)"]


def test_frame_axes_tick_whole_frames():
    """A run of three frames is ticked 0, 1, 2, not 0.0, 0.2, ..."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from hwrt.animate import _frame_axis

    fig, ax = plt.subplots()
    ax.plot([0, 1, 2], [3.0, 1.0, 2.0])
    _frame_axis(ax, "frame")
    fig.canvas.draw()
    ticks = [t for t in ax.get_xticks() if 0 <= t <= 2]
    assert ticks and all(float(t).is_integer() for t in ticks) and ax.get_xlabel() == "frame"
    plt.close(fig)
