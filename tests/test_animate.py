"""Dynamic scenes: refit, animated scene descriptions, built-in animations, tree update
strategies and ``hwrt animate``."""
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
from hwrt.animate import STRATEGIES, TreeUpdater, run  # noqa: E402
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
        assert seen == [] and all(f["simulated_build_seconds"] is None for f in res["frames"])
    else:
        assert len(seen) == 24
    for f in res["frames"]:
        assert f["time_to_image_seconds"] == pytest.approx(f["build_seconds"] + f["render_seconds"])
        assert f["rays"]["primary"] == 16 * 12
        if strategy == "rebuild":
            assert set(f["simulated_build_seconds"]) == {"HWBVH-C", "HWBVH-HP"}
            assert f["simulated_energy_joules"]["HWBVH-C"] > 0


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
