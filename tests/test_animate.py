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
