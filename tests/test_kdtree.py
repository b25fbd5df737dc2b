"""The SAH kd-tree: every answer against the BVH traversal (same triangle unit, same tie rule,
so the same answers bit for bit), Embree and a float64 brute force, on the hard ray cases; its
depth and references within the stated caps on degenerate input; the CLI's --accel."""
import json

import numba
import numpy as np
import pytest

from hwrt.cli import main
from raytracer.render import make_tracer, render
from traversal import raysets
from traversal.config import KD_MAX_REFS_PER_TRI, KD_PARALLEL_DEPTH, KD_PARALLEL_MIN_TRIS
from traversal.kdtree import LEAF, KdTreeTracer, build_kdtree, max_depth, triangle_pads

from .test_grid import (agrees_with_embree, brute_force_agrees, bvh_tracer, degenerate_cases,
                        indexed, lattice_rays, mesh_case, plane_rays, same_as_bvh, small, soup,
                        sphere, tessellated_cube)


def hard_rays(kd, rng):
    """``lattice_rays`` and rays whose origins lie on split planes (``plane_rays``)."""
    O, D = lattice_rays()
    axes, positions = kd.split_planes()
    assert len(axes) > 10
    o, d = plane_rays(rng, axes, positions, 600)
    return np.asarray(O + o, np.float32), np.asarray(D + d, np.float32)


def test_hard_rays_match_the_bvh_embree_and_the_float64_brute_force():
    tris = tessellated_cube(4)
    kd = KdTreeTracer(tris)
    bvh = bvh_tracer(tris)
    rng = np.random.default_rng(3)
    o, d = hard_rays(kd, rng)
    h = same_as_bvh(kd, bvh, o, d)
    assert (h.prim >= 0).mean() > 0.5
    agrees_with_embree(tris, *indexed(tris), h, o, d)
    assert brute_force_agrees(h, o, d, tris) > 10
    # the same answers whichever step a ray takes: sorted by direction octant, the groups of
    # PACKET_RAYS share one (the branching step); shuffled, hardly any group does (branch-free)
    octant = ((np.signbit(d) * [1, 2, 4]).sum(axis=1))
    for order in (np.argsort(octant, kind="stable"), rng.permutation(len(o))):
        r = kd.intersect(o[order], d[order])
        assert np.array_equal(r.prim, h.prim[order]) and np.array_equal(r.t, h.t[order])
    # intervals: random [tmin, tmax] on the same rays
    lo = rng.uniform(0.0, 1.0, len(o)).astype(np.float32)
    hi = (lo + rng.uniform(0.0, 1.5, len(o))).astype(np.float32)
    same_as_bvh(kd, bvh, o, d, lo, hi)


def test_triangles_listed_by_several_leaves_are_found_where_they_are_hit():
    # long thin triangles crossing many leaves, among small ones: every closest hit as the BVH's
    rng = np.random.default_rng(11)
    long = np.zeros((40, 3, 3), np.float32)
    long[:, 0] = rng.random((40, 3))
    long[:, 1] = long[:, 0] + [1.5, 0.0, 0.0]
    long[:, 2] = long[:, 0] + [0.0, 0.02, 0.01]
    tris = np.concatenate([soup(2000, 3), long])
    kd = KdTreeTracer(tris)
    assert kd.references > len(tris)
    bvh = bvh_tracer(tris)
    for o, d in (raysets.primary(tris, 4000), raysets.incoherent(tris, 4000, 4)):
        h = same_as_bvh(kd, bvh, o, d)
        agrees_with_embree(tris, *indexed(tris), h, o, d)


@pytest.mark.parametrize("mesh", ["sphere", "soup"])
def test_no_mismatch_against_embree(mesh):
    tris, vertices, faces = mesh_case(mesh)
    kd = KdTreeTracer(tris)
    bvh = bvh_tracer(tris)
    for o, d in (raysets.primary(tris, 6000), raysets.incoherent(tris, 6000, 2)):
        h = same_as_bvh(kd, bvh, o, d)
        counts = agrees_with_embree(tris, vertices, faces, h, o, d)
        assert counts["agree"] > 0.99 * counts["rays"]


def within_caps(kd, n):
    assert kd.max_depth == max_depth(n) and kd.depth <= kd.max_depth
    assert kd.references <= KD_MAX_REFS_PER_TRI * max(n, 1) == kd.max_references
    assert kd.references >= n            # every triangle lies in some leaf
    assert kd.references_per_triangle == kd.references / max(n, 1)
    assert kd.memory_bytes == kd.node_words.nbytes + kd.refs.nbytes + kd.tris.nbytes
    # one node for each two children, leaves hold exactly the references
    leaves = (kd.node_words[:, 1] & 3) == LEAF
    assert kd.nodes == 2 * (kd.nodes - leaves.sum()) + 1 and kd.leaves == leaves.sum()
    assert (kd.node_words[leaves, 1] >> 2).sum() == kd.references


def identical(n=500):
    return np.repeat(np.array([[[0.2, 0.3, 0.4], [0.6, 0.3, 0.5], [0.3, 0.7, 0.45]]], np.float32), n, 0)


@pytest.mark.parametrize("case", list(degenerate_cases()) + ["identical"])
def test_degenerate_input_stays_within_the_caps_and_right(case):
    tris = identical() if case == "identical" else degenerate_cases()[case]
    kd = KdTreeTracer(tris)
    within_caps(kd, len(tris))
    bvh = bvh_tracer(tris)
    o, d = raysets.incoherent(tris, 3000, 5)
    axis = np.zeros((300, 3), np.float32)
    axis[np.arange(300), np.arange(300) % 3] = 1.0           # axis-parallel, some in a flat mesh's plane
    ao = np.asarray(tris, np.float32).reshape(-1, 3)[np.random.default_rng(1).integers(0, 3 * len(tris), 300)]
    o = np.concatenate([o, ao - 0.7 * axis])
    d = np.concatenate([d, axis])
    same_as_bvh(kd, bvh, o, d)
    if case == "identical":
        # no plane separates identical triangles: a leaf with all of them
        assert kd.references == len(tris)
    if case == "many huge triangles":
        assert kd.references < KD_MAX_REFS_PER_TRI * len(tris)


def walk(nodes, refs):
    """The tree in a form that does not depend on where its nodes and references are stored:
    depth-first, (depth, axis, split) per inner node and (depth, its triangles) per leaf."""
    out, stack = [], [(0, 0)]
    while stack:
        node, depth = stack.pop()
        w = int(nodes[node, 1])
        if w & 3 == LEAF:
            first = int(nodes[node, 0])
            out.append((depth, tuple(refs[first:first + (w >> 2)])))
        else:
            out.append((depth, w & 3, float(nodes.view(np.float32)[node, 0])))
            stack += [((w >> 2) + 1, depth + 1), (w >> 2, depth + 1)]
    return out


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two threads")
def test_the_tree_does_not_depend_on_the_thread_count():
    # large enough for the subtrees below KD_PARALLEL_DEPTH to be built on the threads
    tris = np.concatenate([soup(KD_PARALLEL_MIN_TRIS + 2000, 8), tessellated_cube(20)])
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = KdTreeTracer(tris)
        numba.set_num_threads(max(2, threads))
        many = KdTreeTracer(tris)
    finally:
        numba.set_num_threads(threads)
    assert np.array_equal(one.node_words, many.node_words) and np.array_equal(one.refs, many.refs)
    # and the subtrees built apart join into the tree one pass builds (the reference cap is
    # far away here, so no subtree's share of it matters)
    kd = one
    assert kd.references < kd.max_references / 2
    assert max(d for d, *_ in walk(kd.node_words, kd.refs)) > KD_PARALLEL_DEPTH
    t64 = np.asarray(tris, np.float32).astype(np.float64)
    whole = build_kdtree(t64, triangle_pads(t64), kd.box, kd.max_depth, kd.max_references,
                         parallel_depth=-1)
    assert walk(kd.node_words, kd.refs) == walk(whole[0], whole[1])


def test_the_depth_cap_ends_the_paths_the_sah_would_deepen():
    # with perfect splits the SAH keeps splitting a dense mesh: the cap is what ends its paths,
    # every leaf lies at or above it, and a lower cap gives a tree exactly that deep that still
    # answers every ray as the BVH does
    tris = sphere(64, 128)
    tris = tris[0][tris[1]]
    kd = KdTreeTracer(tris)
    depths = [d for d, *rest in walk(kd.node_words, kd.refs) if len(rest) == 1]
    assert kd.depth == kd.max_depth == max(depths) == max_depth(len(tris))
    low = kd.max_depth - 6
    t64 = np.asarray(tris, np.float32).astype(np.float64)
    nodes, refs, depth = build_kdtree(t64, triangle_pads(t64), kd.box, low, kd.max_references)
    assert depth == low and max(d for d, *_ in walk(nodes, refs)) == low
    assert len(refs) < kd.references
    kd.node_words, kd.refs, kd.depth = nodes, refs, depth
    o, d = raysets.incoherent(tris, 3000, 9)
    same_as_bvh(kd, bvh_tracer(tris), o, d)


def test_reference_cap_is_enforced():
    # overlapping huge triangles make every split duplicate them: the cap must hold the tree
    rng = np.random.default_rng(2)
    huge = np.array([[[-10, -10, 0.5], [30, -10, 0.5], [-10, 30, 0.5]]], np.float32)
    tris = np.concatenate([soup(3000, 6), huge + rng.normal(scale=0.3, size=(1500, 3, 3)).astype(np.float32)])
    kd = KdTreeTracer(tris)
    within_caps(kd, len(tris))


def test_input_checks_and_rays_the_unit_rejects():
    with pytest.raises(ValueError, match="NaN or infinite coordinate"):
        KdTreeTracer(np.full((1, 3, 3), np.nan, np.float32))
    with pytest.raises(ValueError, match="triangles"):
        KdTreeTracer(np.zeros((4, 3), np.float32))
    empty = KdTreeTracer(np.zeros((0, 3, 3), np.float32))
    h = empty.intersect(np.zeros((2, 3)), np.array([[0, 0, 1.0], [1, 0, 0]]))
    assert (h.prim == -1).all() and np.isinf(h.t).all()
    kd = KdTreeTracer(soup(200, 2))
    o = np.full((3, 3), 0.5)
    d = np.array([[0, 0, 0], [np.nan, 0, 1], [0, 0, 1]], np.float64)
    assert (kd.intersect(o, d, 0.0, np.array([1.0, 1.0, -1.0])).prim == -1).all()


def test_cornell_renders_like_the_bvh():
    sc = small("cornell", 32, 24)
    bvh, _, _ = make_tracer(sc)
    kd, secs, info = make_tracer(sc, accel="kdtree")
    assert kd.dtype == np.float32 and kd.has_counters is False
    assert info["accel"] == "kdtree" and info["memory_bytes"] == kd.memory_bytes
    assert info["references_per_triangle"] >= 1 and info["depth"] <= info["max_depth"]
    a = render(sc, bvh)
    b = render(sc, kd)
    assert a.stats["rays"] == b.stats["rays"]
    assert (np.abs(a.image - b.image).max(axis=2) > 0.02).mean() < 0.01


def test_cli_accel(tmp_path, capsys):
    assert main(["render", "cornell", "--accel", "kdtree", "--builder", "sweep"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--accel" in err and "\n" not in err
    # a builder the kd-tree would not use is refused even when it names the default
    assert main(["render", "cornell", "--accel", "kdtree", "--builder", "hwbvh"]) == 2
    assert "--accel" in capsys.readouterr().err
    out = tmp_path / "c.exr"
    assert main(["render", "cornell", "--accel", "kdtree", "-o", str(out), "--width", "16",
                 "--height", "12", "--spp", "1", "--json"]) in (0, None)
    r = json.loads(capsys.readouterr().out)
    assert r["accel"] == "kdtree" and r["memory_bytes"] > 0 and r["references_per_triangle"] >= 1
    assert out.exists()
    assert main(["verify", "cornell", "--accel", "kdtree", "--rays", "2000", "--json",
                 "--mismatches", str(tmp_path / "m.npz")]) in (0, None)
    r = json.loads(capsys.readouterr().out)
    assert r["accel"] == "kdtree" and r["mismatch"] == 0 and r["rays"] == 2000
    assert r["build_seconds"] >= 0 and r["memory_bytes"] > 0 and r["references_per_triangle"] >= 1
