"""The appendix-A units and the raw-format traversal: hard cases, a float64 reference, and
every hit checked against Embree on generated meshes."""
import warnings

import numpy as np
import pytest
from numba import njit

import hwbvh
from traversal import Tracer, raysets
from traversal.aabb_unit import aabb_hit_at, near_far_planes
from traversal.config import GAMMA3_F32
from traversal.embree_ref import embree_occluded, embree_scene
from traversal.triangle_unit import TRI_WORDS, band_eps2, mt_valid_at, preprocess
from traversal.verify import t_tolerance, verify_mesh, verify_rays
from scenes.meshes import grid_sheet, random_soup, sphere, uv_sphere

from .naive import ray_triangle_f64

F32 = np.float32
WIDEN = F32(1 + 2 * GAMMA3_F32)


@njit(error_model="numpy")
def aabb_batch(box, O, D, tmin, tmax, widen, one):
    """Ray i against ``box`` through the AABB unit -> (hit, tnear)."""
    n = O.shape[0]
    hit = np.empty(n, np.bool_)
    tn = np.empty(n, O.dtype)
    for i in range(n):
        ix = one / D[i, 0]
        iy = one / D[i, 1]
        iz = one / D[i, 2]
        kx, ky, kz = near_far_planes(ix, iy, iz)
        hit[i], tn[i] = aabb_hit_at(box, 0, O[i, 0], O[i, 1], O[i, 2], ix, iy, iz, kx, ky, kz,
                                    tmin, tmax, widen)
    return hit, tn


@njit(error_model="numpy")
def mt_batch(rows, O, D, tmin, tmax, eps2, one, edge):
    """Ray i against preprocessed triangle i through the Moller-Trumbore unit -> (hit, t, u, v)."""
    n = O.shape[0]
    hit = np.empty(n, np.bool_)
    out = np.empty((3, n), O.dtype)
    flat = rows.ravel()
    for i in range(n):
        dx = D[i, 0]
        dy = D[i, 1]
        dz = D[i, 2]
        hit[i], out[0, i], out[1, i], out[2, i] = mt_valid_at(
            flat, TRI_WORDS * i, O[i, 0], O[i, 1], O[i, 2], dx, dy, dz, dx * dx + dy * dy + dz * dz,
            tmin[i], tmax[i], eps2, one, edge)
    return hit, out[0], out[1], out[2]


def aabb(box, o, d, tmin=0.0, tmax=np.inf):
    return aabb_batch(np.asarray(box, F32), np.asarray(o, F32), np.asarray(d, F32), F32(tmin),
                      F32(tmax), WIDEN, F32(1))


def test_aabb_unit_signed_zero_directions():
    box = [0, 0, 0, 1, 1, 1]
    # d = (+0, +0, 1) and (-0, -0, 1) from inside the x/y slabs: hit; from outside: miss
    o = [[0.5, 0.5, -1], [0.5, 0.5, -1], [1.5, 0.5, -1], [0.5, -0.5, -1]]
    d = [[0.0, 0.0, 1], [-0.0, -0.0, 1], [-0.0, 0.0, 1], [0.0, -0.0, 1]]
    hit, tn = aabb(box, o, d)
    assert hit.tolist() == [True, True, False, False]
    assert tn[0] == pytest.approx(1.0)


def test_aabb_unit_origin_on_slab_plane_with_zero_direction_is_not_a_false_miss():
    box = [0, 0, 0, 1, 1, 1]
    for plane in (0.0, 1.0):
        for z in (0.0, -0.0):
            hit, _ = aabb(box, [[plane, 0.5, -2]], [[z, 0.0, 1.0]])
            assert hit[0], (plane, z)
            hit, _ = aabb(box, [[0.5, plane, -2]], [[0.0, z, 1.0]])
            assert hit[0], (plane, z)


def test_aabb_unit_interval_and_flat_boxes():
    box = [0, 0, 0, 1, 1, 1]
    assert not aabb(box, [[0.5, 0.5, -2]], [[0, 0, 1]], tmax=1.5)[0][0]   # box starts at t=2
    assert aabb(box, [[0.5, 0.5, -2]], [[0, 0, 1]], tmax=2.0)[0][0]
    assert not aabb(box, [[0.5, 0.5, 2]], [[0, 0, 1]])[0][0]              # behind the ray
    flat = [0, 0, 0.3, 1, 1, 0.3]                                         # zero z extent
    o = np.random.default_rng(0).uniform(0, 1, (1000, 3)).astype(F32)
    o[:, 2] = -1
    d = np.tile([[0.1, -0.05, 1.0]], (1000, 1)).astype(F32)
    o[:, :2] -= 0.13 * d[:, :2] / 1.0                                     # stay inside in x/y
    hit, _ = aabb(flat, np.clip(o, 0.15, 0.85).astype(F32) * [1, 1, 0] + [0, 0, -1], d)
    assert hit.all()


def test_triangle_unit_against_float64_reference():
    rng = np.random.default_rng(3)
    n = 3000
    tris = rng.uniform(-1, 1, (n, 3, 3)).astype(F32)
    o = rng.uniform(-2, 2, (n, 3)).astype(F32)
    target = tris.mean(1) + rng.normal(0, 0.3, (n, 3))
    d = (target - o).astype(F32)
    pre = preprocess(tris)
    hit, t, u, v = mt_batch(pre, o, d, np.zeros(n, F32), np.full(n, np.inf, F32), band_eps2(F32),
                            F32(1), F32(0))
    T_TOL = 1e-4    # float32 t of a unit-scale scene: a few hundred ulps covers the chain
    checked = 0
    for i in range(n):
        ok, tr, ur, vr = ray_triangle_f64(o[i], d[i], tris[i])
        margin = min(ur, vr, 1 - ur - vr) if ok else 0
        if ok and tr >= 0 and margin > 1e-4:
            assert hit[i] and abs(t[i] - tr) <= T_TOL * max(1, tr), i
            checked += 1
        elif not ok or tr < 0:
            if abs(margin) > 1e-4 or tr < -1e-4:
                assert not hit[i], i
    assert checked > 500


def test_tiny_triangles_keep_their_hits():
    # 1e-4-sized triangles: det ~ 1e-8; an absolute epsilon (1e-6) would drop them all
    rng = np.random.default_rng(4)
    tris = (rng.uniform(0, 1, (200, 1, 3)) + rng.uniform(-1e-4, 1e-4, (200, 3, 3))).astype(F32)
    c = tris.mean(1)
    o = (c + [0, 0, -1]).astype(F32)
    d = np.tile([[0, 0, 1]], (200, 1)).astype(F32)
    tri = Tracer(hwbvh.build(tris))
    h = tri.intersect(o, d)
    assert (h.prim >= 0).mean() > 0.95


def closed_sphere(n_lat=24, n_lon=40, scale=1.0, shift=0.0):
    V, F = uv_sphere(n_lat, n_lon)
    V = V * scale + shift
    return V[F].astype(F32), V.astype(F32), F.astype(np.int32)


@pytest.mark.parametrize("scale,shift", [(1.0, 0.0), (1e-4, 0.0), (1.0, 1e5), (1e3, -3e3)])
def test_closed_mesh_does_not_leak_through_edges_and_vertices(scale, shift):
    tris, V, F = closed_sphere(scale=scale, shift=shift)
    centre = np.full(3, shift, np.float64)
    tracer = Tracer(hwbvh.build(tris))
    # targets: every vertex and every edge midpoint, in float32 as stored
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]).astype(np.float64)
    targets = np.concatenate([V.astype(np.float64), e.mean(1)])
    d = targets - centre
    # from inside: every ray must hit (nothing escapes)
    h = tracer.intersect(np.tile(centre, (len(d), 1)), d)
    assert (h.prim >= 0).all()
    # from outside, aimed back through the same points: must hit before reaching the centre
    outside = centre + 3 * d
    h = tracer.intersect(outside, -d, 0.0, 3.0)
    assert (h.prim >= 0).all()


def test_axis_parallel_rays_through_grid_vertices_and_edges():
    tris = grid_sheet(16, 16, wave=0.0)                       # flat: y = 0 exactly
    tracer = Tracer(hwbvh.build(tris))
    xs = np.linspace(-1, 1, 33)                               # vertices and edge midpoints
    X, Z = np.meshgrid(xs, xs)
    o = np.stack([X.ravel(), np.ones(X.size), Z.ravel()], 1)
    for d in ([0.0, -1.0, 0.0], [-0.0, -1.0, -0.0]):
        h = tracer.intersect(o, np.tile(d, (len(o), 1)))
        assert (h.prim >= 0).all()
        assert np.allclose(h.t, 1.0)


def test_rays_in_the_plane_and_grazing_rays():
    tris = grid_sheet(8, 8, wave=0.0)
    tracer = Tracer(hwbvh.build(tris))
    o = np.array([[-2, 0, 0.1], [-2, 0, 0.0], [-2, 1e-7, 0.3]])
    d = np.array([[1, 0, 0], [1, 0, 0], [1, 0, 0]])
    h = tracer.intersect(o, d)            # in the plane: parallel band -> no hit, no crash
    assert (h.prim < 0).all()
    # grazing: 1e-3 rad above the plane, aimed at it -> hits near the expected t
    g = np.array([[-1.5, 1e-3 * 1.0, 0.2]])
    h = tracer.intersect(g, np.array([[1.0, -1e-3, 0.0]]))
    assert h.prim[0] >= 0 and abs(h.t[0] - 1.0) < 1e-3


def test_nan_inf_and_zero_rays_miss_quickly():
    tracer = Tracer(hwbvh.build(random_soup(2000)))
    o = np.array([[np.nan, 0, 0], [0, 0, 0], [np.inf, 0, 0], [0, 0, 0], [0, 0, 0]])
    d = np.array([[1, 0, 0], [np.nan, 1, 0], [1, 0, 0], [0, 0, 0], [0, -np.inf, 0]])
    h = tracer.intersect(o, d, counters=True)
    assert (h.prim == -1).all() and np.isinf(h.t).all()
    assert (h.counters == 0).all()


def test_tmin_tmax_boundaries():
    tris = grid_sheet(2, 2, wave=0.0)
    tracer = Tracer(hwbvh.build(tris))
    o = np.tile([[0.1, 1.0, 0.2]], (4, 1))
    d = np.tile([[0.0, -1.0, 0.0]], (4, 1))
    h = tracer.intersect(o, d, tmin=np.array([0, 0, 1.0001, 0.9999]), tmax=np.array([0.9999, 1.0, 5, 1.0001]))
    assert (h.prim >= 0).tolist() == [False, True, False, True]
    occ = tracer.occluded(o, d, tmin=np.array([0, 0, 1.0001, 0.9999]), tmax=np.array([0.9999, 1.0, 5, 1.0001]))
    assert occ.tolist() == [False, True, False, True]


def test_occluded_matches_intersect_and_embree():
    tris, V, F = closed_sphere()
    extra = random_soup(3000, seed=2, size=0.05)
    tris = np.concatenate([tris, extra])
    V2 = np.concatenate([V, extra.reshape(-1, 3)])
    F2 = np.concatenate([F, len(V) + np.arange(len(extra) * 3).reshape(-1, 3)]).astype(np.int32)
    tracer = Tracer(hwbvh.build(tris))
    rng = np.random.default_rng(5)
    o = rng.uniform(-1.5, 1.5, (20000, 3))
    d = rng.normal(size=(20000, 3))
    tmax = rng.uniform(0.05, 2.0, 20000)
    occ = tracer.occluded(o, d, 0.0, tmax)
    h = tracer.intersect(o, d, 0.0, tmax)
    assert np.array_equal(occ, h.prim >= 0)
    emb = embree_occluded(embree_scene(V2, F2), o, d, tmax)
    assert (occ != emb).sum() <= 2            # edge ties only (checked by verify tests)


@pytest.mark.parametrize("threads", [1, 2])
def test_embree_in_chunks_on_threads_answers_as_one_call(monkeypatch, threads):
    """Embree traces on our threads in chunks: every answer is the one a single embreex call
    gives, bit for bit, whatever the chunk size and thread count."""
    import numba
    from traversal import embree_ref
    tris, V, F = closed_sphere()
    emb = embree_scene(V, F)
    rng = np.random.default_rng(8)
    n = 5003                                  # not a multiple of the chunk size
    o = rng.uniform(-1.5, 1.5, (n, 3)).astype(np.float32)
    d = rng.normal(size=(n, 3)).astype(np.float32)
    tmax = rng.uniform(0.05, 2.0, n).astype(np.float32)
    whole = emb.run(o, d, output=1, dists=tmax.copy())
    blocked = emb.run(o, d, dists=tmax.copy(), query="OCCLUDED") == 0
    monkeypatch.setattr(embree_ref, "EMBREE_CHUNK_RAYS", 97)
    before = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        t, prim, u, v, ng = embree_ref.embree_intersect(emb, o, d, tmax)
        occ = embree_ref.embree_occluded(emb, o, d, tmax)
    finally:
        numba.set_num_threads(before)
    hit = whole["primID"] >= 0
    assert 0 < hit.sum() < n
    assert np.array_equal(prim, whole["primID"])
    assert np.array_equal(t[hit], whole["tfar"][hit]) and np.isinf(t[~hit]).all()
    assert np.array_equal(u[hit], whole["u"][hit]) and np.array_equal(v[hit], whole["v"][hit])
    assert np.array_equal(ng[hit], whole["Ng"][hit]) and not ng[~hit].any()
    assert np.array_equal(occ, blocked)
    assert embree_ref.embree_intersect(emb, o[:0], d[:0])[0].shape == (0,)
    assert embree_ref.embree_occluded(emb, o[:0], d[:0], tmax[:0]).shape == (0,)


@pytest.mark.parametrize("mesh", ["sphere", "soup", "sheet", "sphere-1e5", "sphere-1e-4"])
@pytest.mark.parametrize("kind", ["primary", "random", "bounces", "shadow"])
def test_zero_mismatches_against_embree(mesh, kind):
    if mesh.startswith("sphere"):
        scale, shift = {"sphere": (1, 0), "sphere-1e5": (1, 1e5), "sphere-1e-4": (1e-4, 0)}[mesh]
        tris, V, F = closed_sphere(40, 64, scale, shift)
    else:
        tris = random_soup(5000, seed=1) if mesh == "soup" else grid_sheet(60, 60)
        V, F = tris.reshape(-1, 3), np.arange(len(tris) * 3, dtype=np.int32).reshape(-1, 3)
    counts, *_ = verify_mesh(tris, V, F, kind, 20_000)
    assert counts["mismatch"] == 0, counts
    assert counts["agree"] >= 0.99 * counts["rays"]


@pytest.mark.parametrize("wrong", ["never", "always"])
def test_shadow_sets_verify_the_occluded_answers(wrong):
    """The shadow set is checked as renderers ask it, through ``occluded``: a tracer whose
    closest hits are right but whose any-hit answers are wrong fails it, and each mismatch
    says which answer is wrong and why."""
    from traversal.verify import diagnose_occluded
    tris, V, F = closed_sphere(16, 24)
    good = Tracer(hwbvh.build(tris))

    class WrongOccluded:
        n_triangles = good.n_triangles

        def intersect(self, *a, **kw):
            return good.intersect(*a, **kw)

        def occluded(self, o, d, tmin=0.0, tmax=np.inf):
            return np.full(len(o), wrong == "always")

    counts, labels, (O, D, tmax), ours, ref = verify_mesh(tris, V, F, "shadow", 2000,
                                                          tracer=WrongOccluded())
    assert ours.dtype == ref.dtype == bool and counts["hit"] == ours.sum()
    assert counts["mismatch"] > 100 and (labels == 2).sum() == counts["mismatch"]
    bad = np.flatnonzero(labels == 2)
    rows = diagnose_occluded(tris, O[bad], D[bad], 0.0, tmax[bad], ours[bad], ref[bad])
    assert all(r["class"] == "mismatch" and r["wrong"] == ["ours"] for r in rows)
    why = rows[0]["why"]["ours"]
    assert why.startswith("not blocked, but triangle " if wrong == "never" else
                          "blocked, but no triangle is hit within the tolerances"), why
    # the right tracer passes the same set
    assert verify_mesh(tris, V, F, "shadow", 2000, tracer=good)[0]["mismatch"] == 0


def test_float64_units_agree_with_float32():
    tris = random_soup(3000, seed=8)
    bvh = hwbvh.build(tris)
    rng = np.random.default_rng(1)
    o = rng.uniform(-1, 1, (5000, 3))
    d = rng.normal(size=(5000, 3))
    a = Tracer(bvh).intersect(o, d)
    b = Tracer(bvh, precision="float64").intersect(o, d)
    assert b.t.dtype == np.float64
    assert (a.prim == b.prim).mean() > 0.999


def test_stack_overflow_is_an_error_not_a_wrong_answer():
    tracer = Tracer(hwbvh.build(random_soup(5000)))
    tracer.depth = 1                                  # pretend the tree were shallower
    rng = np.random.default_rng(2)
    with pytest.raises(RuntimeError, match="stack overflow"):
        tracer.intersect(rng.uniform(-1, 1, (1000, 3)), rng.normal(size=(1000, 3)))


def test_counters_count_work():
    tracer = Tracer(hwbvh.build(random_soup(5000)))
    rng = np.random.default_rng(2)
    h = tracer.intersect(rng.uniform(-1, 1, (1000, 3)), rng.normal(size=(1000, 3)), counters=True)
    assert (h.counters[:, 0] >= 1).mean() > 0.9 and h.counters[:, 1].sum() > 0


@pytest.mark.parametrize("scale,shift", [(1.0, 0.0), (1e-4, 0.0), (1.0, 1e5)])
def test_watertight_unit_does_not_leak_and_agrees(scale, shift):
    tris, V, F = closed_sphere(scale=scale, shift=shift)
    centre = np.full(3, shift, np.float64)
    bvh = hwbvh.build(tris)
    tracer = Tracer(bvh, watertight=True)
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]).astype(np.float64)
    targets = np.concatenate([V.astype(np.float64), e.mean(1)])
    h = tracer.intersect(np.tile(centre, (len(targets), 1)), targets - centre)
    assert (h.prim >= 0).all()
    rng = np.random.default_rng(3)
    o = centre + rng.uniform(-2, 2, (5000, 3)) * scale
    d = rng.normal(size=(5000, 3))
    a = Tracer(bvh).intersect(o, d)
    b = tracer.intersect(o, d)
    assert (a.prim == b.prim).mean() > 0.999


def test_zero_area_triangles_are_never_hit():
    rng = np.random.default_rng(11)
    good = random_soup(500, seed=4)
    pts = rng.uniform(-1, 1, (100, 1, 3))
    degenerate = np.concatenate([pts.repeat(3, axis=1),                                   # points
                                 np.stack([pts[:, 0], pts[:, 0] + 0.1, pts[:, 0] + 0.2], 1)])  # segments
    tris = np.concatenate([good, degenerate]).astype(np.float32)
    tracer = Tracer(hwbvh.build(tris))
    # aim straight at the degenerate ones: their point, or the middle of their segment
    targets = np.concatenate([degenerate[:100, 0], degenerate[100:, 1]]).astype(np.float64)
    o = targets + rng.normal(size=targets.shape)
    h = tracer.intersect(o, targets - o)
    assert not (h.prim >= len(good)).any()


def test_an_answer_within_the_units_rounding_of_its_triangle_is_a_tie_but_a_hole_is_not():
    """Two triangles sharing an edge, a ray through B just past the edge (outside A by 3e-4 in
    A's barycentrics, beyond BARY_TOL). Seen from 600 triangle sizes away at cos 0.1 to the
    normal, the float32 unit's rounding of the barycentrics is ~1e-3: an answer on A is a tie
    with one on B. Seen head-on from close by, the same answer on A is a mismatch. A ray that
    passes through B (entered by more than BARY_TOL) to a triangle behind is a hole: a mismatch
    however grazing; and so is a miss there. The any-hit test judges alike."""
    from traversal.verify import classify, classify_occluded
    A = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    B = [[1, 0, 0], [1, 1, 0], [0, 1, 0]]
    C = [[-5, -5, -1], [5, -5, -1], [-5, 5, -1]]                 # far behind, below both
    tris = np.array([A, B, C], np.float32)
    delta = 3e-4
    P = np.array([0.5 + delta / 2, 0.5 + delta / 2, 0.0])
    graze = np.array([np.sqrt(1 - 0.01), 0.0, -0.1])              # cos 0.1 to the normal
    cases = {"grazing": (P - 600 * graze, graze), "head-on": (P + [0, 0, 2], np.array([0, 0, -1.0]))}
    got = {}
    for name, (o, d) in cases.items():
        O = np.array([o], np.float32)
        D = np.array([d], np.float32)
        t = float(np.linalg.norm(P - o))
        t_behind = t + 1.0 / abs(d[2])
        for other, (p_ours, t_ours) in {"A": (0, t), "C": (2, t_behind), "miss": (-1, np.inf)}.items():
            counts, _ = classify(tris, O, D, 0.0, np.inf, np.array([p_ours]), np.array([t_ours]),
                                 np.array([1]), np.array([t]))
            got[name, other] = max((k for k in ("tie", "mismatch") if counts[k]), default="agree")
        # any-hit, up to just past B: a shadow ray let through B is a hole; without B, a
        # shadow ray blocked by A alone is right within the unit's rounding (grazing) only
        tmax = np.array([t + 0.5])
        for label, kept, ours, ref in (("let through", [0, 1, 2], False, True),
                                       ("blocked by A", [0, 2], True, False)):
            counts, _ = classify_occluded(tris[kept], O, D, 0.0, tmax, np.array([ours]),
                                          np.array([ref]))
            got[name, label] = "mismatch" if counts["mismatch"] else "tie"
    assert got == {("grazing", "A"): "tie", ("grazing", "C"): "mismatch",
                   ("grazing", "miss"): "mismatch", ("grazing", "let through"): "mismatch",
                   ("grazing", "blocked by A"): "tie",
                   ("head-on", "A"): "mismatch", ("head-on", "C"): "mismatch",
                   ("head-on", "miss"): "mismatch", ("head-on", "let through"): "mismatch",
                   ("head-on", "blocked by A"): "mismatch"}


def test_diagnose_names_the_wrong_answer_and_why():
    """Two parallel triangles the ray enters head-on at t = 1 and t = 2 and one it passes by:
    each way an answer can fail the re-test is named, for the answer that fails it, and an
    answer that agrees or ties is named by none."""
    from traversal.verify import classify, diagnose
    big = lambda z: [[-5, -5, z], [5, -5, z], [-5, 5, z]]
    aside = [[10, 10, 0.5], [11, 10, 0.5], [10, 11, 0.5]]
    tris = np.array([big(1.0), big(2.0), aside], np.float32)
    cases = [  # (ours, embree, t_min, t_max) -> (wrong, why's start for the wrong ones)
        ((0, 1.0), (0, 1.0), 0.0, np.inf, [], []),
        ((1, 2.0), (0, 1.0), 0.0, np.inf, ["ours"], ["lies behind triangle 0, which the ray enters at t = 1,"]),
        ((-1, np.inf), (0, 1.0), 0.0, np.inf, ["ours"], ["misses triangle 0, which the ray enters at t = 1,"]),
        ((0, 1.0), (0, 1.5), 0.0, np.inf, ["embree"], ["reports t = 1.5, where triangle 0's plane lies at t = 1"]),
        ((2, 0.5), (0, 1.0), 0.0, np.inf, ["ours"], ["its point lies outside triangle 2 by "]),
        ((0, 1.0), (1, 2.0), 1.5, np.inf, ["ours"], ["triangle 0 lies at t = 1, before the ray starts (t_min 1.5)"]),
        ((1, 2.0), (0, 1.0), 0.0, 1.5, ["ours"], ["triangle 1 lies at t = 2, past the ray's end (t_max 1.5)"]),
        ((1, 2.0), (-1, np.inf), 0.0, np.inf, ["ours", "embree"],
         ["lies behind triangle 0", "misses triangle 0"]),
    ]
    n = len(cases)
    O = np.tile(np.float32([-1.0, -1.0, 0.0]), (n, 1))
    D = np.tile(np.float32([0.0, 0.0, 1.0]), (n, 1))
    pick = lambda k, f: np.array([c[k][f] for c in cases])
    tmin, tmax = (np.array([c[k] for c in cases]) for k in (2, 3))
    args = (tris, O, D, tmin, tmax, pick(0, 0), pick(0, 1), pick(1, 0), pick(1, 1))
    rows = diagnose(*args)
    assert [r["class"] for r in rows] == ["agree"] + ["mismatch"] * (n - 1)
    _, labels = classify(*args)
    assert [r["class"] for r in rows] == [("agree", "tie", "mismatch")[k] for k in labels]
    for r, case in zip(rows, cases):
        wrong, why = case[4], case[5]
        assert r["wrong"] == wrong and sorted(r["why"]) == sorted(wrong)
        for name, start in zip(wrong, why):
            assert r["why"][name].startswith(start), (name, r["why"][name])
    assert "inside it by 0.2 (barycentric), |cos| 1" in rows[1]["why"]["ours"]


def test_verify_replay_of_a_mismatch_file(tmp_path):
    import json
    import subprocess
    import sys
    import trimesh
    tris, V, F = closed_sphere(8, 12)
    mesh = tmp_path / "s.ply"
    trimesh.Trimesh(V, F, process=False).export(mesh)
    rays = tmp_path / "m.npz"
    np.savez(rays, origins=np.zeros((3, 3)), dirs=np.eye(3), tmax=np.full(3, np.inf),
             ours_prim=np.zeros(3), ours_t=np.zeros(3), embree_prim=np.zeros(3), embree_t=np.zeros(3))
    r = subprocess.run([sys.executable, "-m", "hwrt.cli", "verify", str(mesh), "--replay", str(rays), "--json"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert res["rays"] == 3 and res["mismatch"] == 0 and len(res["replayed"]) == 3
    assert res["mismatch_ours_wrong"] == res["mismatch_embree_wrong"] == 0
    assert all(x["wrong"] == [] and x["why"] == {} for x in res["replayed"])
    assert all(x["ours"][0] >= 0 for x in res["replayed"])        # from inside, every ray hits
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not an npz")
    r = subprocess.run([sys.executable, "-m", "hwrt.cli", "verify", str(mesh), "--replay", str(bad)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 2 and "bad.npz" in r.stderr


def test_geometric_normals_are_the_hit_triangles_and_zero_on_a_miss():
    # the kernel writes e1 x e2 of the hit triangle (in the working precision); a miss gets 0
    tris = random_soup(2000, seed=11)
    tracer = Tracer(hwbvh.build(tris))
    rng = np.random.default_rng(4)
    o = rng.uniform(-1.2, 1.2, (5000, 3))
    d = rng.normal(size=(5000, 3))
    h = tracer.intersect(o, d)
    hit = h.prim >= 0
    assert 0 < hit.sum() < len(hit)
    t64 = np.asarray(tris, np.float64)[h.prim[hit]]
    ref = np.cross(t64[:, 1] - t64[:, 0], t64[:, 2] - t64[:, 0])
    np.testing.assert_allclose(h.ng[hit], ref, rtol=1e-4, atol=1e-6 * np.abs(ref).max())
    assert not h.ng[~hit].any()
    assert not h.u[~hit].any() and not h.v[~hit].any() and np.isinf(h.t[~hit]).all()
    bare = tracer.intersect(o, d, normals=False)
    assert bare.ng is None and np.array_equal(bare.prim, h.prim) and np.array_equal(bare.t, h.t)


def test_answers_do_not_depend_on_the_thread_count_or_batch_split():
    # every ray is independent: one thread, two threads, and a batch cut into pieces agree
    import numba
    tris = random_soup(3000, seed=12)
    tracer = Tracer(hwbvh.build(tris))
    rng = np.random.default_rng(6)
    o = rng.uniform(-1.2, 1.2, (7001, 3))            # not a multiple of the 64-ray chunk
    d = rng.normal(size=(7001, 3))
    both = tracer.intersect(o, d)
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = tracer.intersect(o, d)
    finally:
        numba.set_num_threads(old)
    parts = [tracer.intersect(o[a:a + 1000], d[a:a + 1000]) for a in range(0, 7001, 1000)]
    assert np.array_equal(one.prim, both.prim) and np.array_equal(one.t, both.t)
    assert np.array_equal(one.u, both.u) and np.array_equal(one.ng, both.ng)
    assert np.array_equal(np.concatenate([p.prim for p in parts]), both.prim)
    assert np.array_equal(np.concatenate([p.t for p in parts]), both.t)
    assert np.array_equal(tracer.occluded(o, d, 0.0, 0.5), tracer.intersect(o, d, 0.0, 0.5).prim >= 0)


def _scale_meshes():
    """A closed sphere and a waved grid (indexed, for Embree), at scale 1."""
    tris, V, F = closed_sphere()
    grid = grid_sheet(30, 30)
    return {"sphere": (V.astype(np.float64), F),
            "grid": (grid.reshape(-1, 3).astype(np.float64),
                     np.arange(len(grid) * 3, dtype=np.int32).reshape(-1, 3))}


@pytest.mark.parametrize("scale", [1e12, 1e-12])
@pytest.mark.parametrize("mesh", ["sphere", "grid"])
def test_hits_on_1e12_and_1e_12_meshes_match_float64_and_embree(mesh, scale):
    """Such meshes are legal input (hwbvh accepts coordinates up to 1e15); the float32 unit's
    parallel band once read every ray on them as parallel. Every answer agrees with Embree (or
    both are right, by the verifier's float64 re-test), hits the float64 tracer's primitive, and
    its t is within the verifier's tolerance of the float64 t. At 1e12 on camera, random, bounce
    and shadow rays. At 1e-12 on camera and random rays, t on camera rays: a ray that starts
    within float32 rounding of a 1e-14-sized triangle (a bounce, a shadow ray, the odd random
    one) gets its t from a numerator (~|s| |e1| |e2| ~ 1e-40) that is subnormal in float32, a
    limit of the datapath (Embree's as well), not of the band: the verifier calls such a ray a
    mismatch (both t are off the float64 t by ~1e-4), and it is one on the right primitive."""
    V, F = _scale_meshes()[mesh]
    V = (V * scale).astype(F32)
    tris = V[F]
    kinds = ["primary", "random"] + (["bounces", "shadow"] if scale > 1 else [])
    bvh = hwbvh.build(tris)
    f64 = Tracer(bvh, precision="float64")
    for kind in kinds:
        counts, labels, (o, d, tmax), h, ref = verify_mesh(tris, V, F, kind, 4000, bvh=bvh)
        if kind == "shadow":            # any-hit answers: those of the float64 units
            assert counts["mismatch"] == 0, counts
            assert np.array_equal(h, f64.occluded(o, d, 0.0, tmax))
            # and their closest hits, checked below as the other sets'
            counts, labels, h, (_, pe) = verify_rays(Tracer(bvh), embree_scene(V, F), tris, o,
                                                     d, tmax)
        else:
            pe = ref[1]
        subnormal_t = labels == 2 if scale < 1 and kind != "primary" else np.zeros(len(o), bool)
        assert np.array_equal(h.prim[subnormal_t], pe[subnormal_t]), kind
        assert subnormal_t.sum() <= 0.005 * counts["rays"], (kind, counts)
        assert counts["mismatch"] == subnormal_t.sum(), (kind, counts)
        assert counts["agree"] >= 0.99 * counts["rays"], (kind, counts)
        ref = f64.intersect(o, d, 0.0, np.inf if tmax is None else tmax)
        assert np.array_equal(h.prim, ref.prim), kind
        hit = h.prim >= 0
        assert kind in ("bounces", "shadow") or hit.mean() > 0.1, kind
        if scale > 1 or kind == "primary":
            err = np.abs(h.t[hit] - ref.t[hit])
            assert (err <= t_tolerance(o[hit], d[hit], ref.t[hit])).all(), kind


def test_power_of_two_scales_change_no_answer():
    """A power-of-two scale is exact in the builder (boxes, SAH comparisons) and in both units,
    so the answers must not change: a scene at 2^40 (~1e12) gives the same primitives and
    barycentrics, bit for bit, and t times 2^40; at 2^-40 (~1e-12) the same primitives and
    barycentrics, and t within the verifier's tolerance (t's numerator is partly subnormal
    there);
    directions scaled by 2^80 or 2^-80 (|d|^2 out of float32 range) divide t by that and
    change nothing else, and so in float64 by 2^600 or 2^-600 (out of its range)."""
    for mesh, (V, F) in _scale_meshes().items():
        tris = V[F].astype(F32)
        o = np.concatenate([raysets.primary(tris, 3000)[0], raysets.incoherent(tris, 3000, seed=2)[0]])
        d = np.concatenate([raysets.primary(tris, 3000)[1], raysets.incoherent(tris, 3000, seed=2)[1]])
        o, d = o.astype(F32), d.astype(F32)
        bvh = hwbvh.build(tris)
        ref = Tracer(bvh).intersect(o, d)
        assert 0.2 < (ref.prim >= 0).mean() < 0.9
        for k in (40, -40):
            c = F32(2.0 ** k)
            h = Tracer(hwbvh.build(tris * c)).intersect(o * c, d)
            assert np.array_equal(h.prim, ref.prim) and np.array_equal(h.u, ref.u) and \
                np.array_equal(h.v, ref.v), (mesh, k)
            if k > 0:
                assert np.array_equal(h.t, ref.t * c), (mesh, k)
            else:
                hit = ref.prim >= 0
                err = np.abs(h.t[hit] - ref.t[hit] * c)
                assert (err <= t_tolerance(o[hit] * c, d[hit], ref.t[hit] * c)).all(), (mesh, k)
        for k in (80, -80):
            c = F32(2.0 ** k)
            assert np.array_equal((d * c) / c, d)                      # exact, no subnormals
            h = Tracer(bvh).intersect(o, d * c)
            assert np.array_equal(h.prim, ref.prim) and np.array_equal(h.u, ref.u) and \
                np.array_equal(h.v, ref.v) and np.array_equal(h.t, ref.t / c), (mesh, k)
        ref64 = Tracer(bvh, precision="float64").intersect(o, d)
        for k in (600, -600):
            c = 2.0 ** k
            h = Tracer(bvh, precision="float64").intersect(o, d.astype(np.float64) * c)
            assert np.array_equal(h.prim, ref64.prim) and np.array_equal(h.u, ref64.u) and \
                np.array_equal(h.v, ref64.v) and np.array_equal(h.t, ref64.t / c), (mesh, k)


def test_shared_vertices_index_the_same_triangles_bit_for_bit():
    """Embree gets an indexed mesh: each distinct vertex once, the triangles unchanged (a
    signed zero stays its own vertex: bitwise equality, nothing merged that differs)."""
    from traversal.embree_ref import shared_vertices

    rng = np.random.default_rng(3)
    pts = rng.normal(size=(40, 3)).astype(np.float32)
    pts[0] = [0.0, 1.0, 2.0]
    pts[1] = [-0.0, 1.0, 2.0]
    soup = pts[rng.integers(0, 40, size=(200, 3))]
    V, F = shared_vertices(soup.reshape(-1, 3), np.arange(600).reshape(-1, 3))
    assert F.dtype == np.int32 and V.dtype == np.float32
    assert len(V) == len(np.unique(soup.reshape(-1, 3).view(np.uint32), axis=0)) <= 40
    assert np.array_equal(V[F].view(np.uint32), soup.view(np.uint32))


def _one_triangle(accel):
    """A tracer of ``accel`` on one triangle at z = 1, and two rays that hit it (from below and
    from above)."""
    from traversal.embree_ref import EmbreeTracer
    from traversal.grid import GridTracer
    from traversal.kdtree import KdTreeTracer

    tris = np.array([[[0, 0, 1], [1, 0, 1], [0, 1, 1]]], np.float32)
    tracer = {"bvh": lambda: Tracer(hwbvh.build(tris)), "grid": lambda: GridTracer(tris),
              "kdtree": lambda: KdTreeTracer(tris),
              "embree": lambda: EmbreeTracer(tris.reshape(-1, 3), np.arange(3).reshape(1, 3))}[accel]()
    o = np.array([[0.2, 0.2, 0.0], [0.2, 0.2, 2.0]], np.float32)
    d = np.array([[0, 0, 1], [0, 0, -1]], np.float32)
    return tracer, o, d


@pytest.mark.parametrize("accel", ["bvh", "grid", "kdtree", "embree"])
def test_a_negative_tmin_is_refused_by_every_structure(accel):
    """Intervals start at the origin or after it (Embree's rule too); the units' widened
    comparisons assume it, so a negative t_min is an error, not a silent wrong answer."""
    tracer, o, d = _one_triangle(accel)
    assert tracer.intersect(o, d, 0.0).prim.tolist() == [0, 0]
    for tmin in (-1.0, np.array([0.0, -1e-30], np.float32)):
        with pytest.raises(ValueError, match="tmin: must not be negative"):
            tracer.intersect(o, d, tmin)
        with pytest.raises(ValueError, match="tmin: must not be negative"):
            tracer.occluded(o, d, tmin, 5.0)


@pytest.mark.parametrize("accel", ["bvh", "grid", "kdtree"])
def test_an_interval_of_the_wrong_shape_is_named(accel):
    tracer, o, d = _one_triangle(accel)
    assert tracer.occluded(o, d, np.zeros(1), 5.0).tolist() == [True, True]   # (1,) broadcasts
    with pytest.raises(ValueError, match=r"^tmax: must be a scalar or one value per ray \(2,\)"):
        tracer.intersect(o, d, 0.0, np.ones(3))
    with pytest.raises(ValueError, match=r"^tmin: must be a scalar or one value per ray \(2,\)"):
        tracer.occluded(o, d, np.zeros((2, 1)))


@pytest.mark.parametrize("accel", ["grid", "kdtree"])
def test_structures_refuse_coordinates_the_bvh_refuses(accel):
    """Beyond hwbvh's coordinate bound the float32 unit overflows (at 1e20 every ray missed):
    the grid and the kd-tree refuse such meshes as the BVH's builder does."""
    from hwbvh.config import MAX_COORDINATE
    from traversal.grid import GridTracer
    from traversal.kdtree import KdTreeTracer

    make = {"grid": GridTracer, "kdtree": KdTreeTracer}[accel]
    tris = np.array([[[0, 0, 1], [1, 0, 1], [0, 1, 1]]], np.float32)
    with pytest.raises(ValueError, match="^triangles: triangle 0 has a coordinate too large: "
                                         "magnitude 1e\\+20 exceeds"):
        make(tris * np.float32(1e20))
    # beyond float32's range: checked before the cast, so no overflow warning and no "NaN"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match="^triangles: triangle 0 has a coordinate too large"):
            make(tris.astype(np.float64) * 1e39)
    with pytest.raises(ValueError, match="^triangles: triangle 0 has a NaN or infinite"):
        make(np.where(tris > 0, np.float32(np.inf), tris))
    make(tris * np.float32(MAX_COORDINATE / 2))


def test_compile_kernels_compiles_what_real_queries_run():
    """The tree-less compilation (a first run's second core) must give the very specialisation
    real queries call, or a first render would compile the traversal twice. In a fresh
    process, so that no earlier test has compiled it already."""
    import subprocess
    import sys
    code = ("import numpy as np, hwbvh\n"
            "from traversal import Tracer\n"
            "from traversal.api import compile_kernels\n"
            "from traversal.traverse import trace_chunks\n"
            "from scenes.meshes import random_soup\n"
            "compile_kernels()\n"
            "before = set(trace_chunks.signatures)\n"
            "tracer = Tracer(hwbvh.build(random_soup(500, seed=1)))\n"
            "rng = np.random.default_rng(3)\n"
            "o = rng.uniform(-1, 1, (300, 3)); d = rng.normal(size=(300, 3))\n"
            "tracer.intersect(o, d, normals=False); tracer.intersect(o, d)\n"
            "tracer.occluded(o, d, tmax=np.full(300, 0.5))\n"
            "print(len(before), set(trace_chunks.signatures) == before)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert r.stdout.split() == ["1", "True"], r.stdout + r.stderr


def test_every_form_of_input_gives_the_same_answers_and_is_left_as_it_was():
    """Rays as float32 arrays ready for the kernels are used as they are; float64, read-only,
    Fortran-ordered and strided inputs are converted. All give the same answers, and the
    caller's arrays are never written."""
    tracer = Tracer(hwbvh.build(random_soup(500, seed=4)))
    rng = np.random.default_rng(8)
    o = rng.uniform(-1.5, 1.5, (300, 3)).astype(np.float32)
    d = rng.normal(size=(300, 3)).astype(np.float32)
    tmax = rng.uniform(0.5, 3.0, 300).astype(np.float32)
    want = tracer.intersect(o, d, 0.0, tmax)
    read_only = [a.copy() for a in (o, d, tmax)]
    for a in read_only:
        a.flags.writeable = False
    wide = np.zeros((300, 6), np.float32)
    wide[:, ::2] = o
    forms = {"ready": (o.copy(), d.copy(), tmax.copy()),
             "float64": (o.astype(np.float64), d.astype(np.float64), tmax.astype(np.float64)),
             "read-only": tuple(read_only),
             "fortran": (np.asfortranarray(o), np.asfortranarray(d), tmax.copy()),
             "strided": (wide[:, ::2], d.copy(), tmax.copy())}
    for name, (fo, fd, ft) in forms.items():
        kept = [a.copy() for a in (fo, fd, ft)]
        h = tracer.intersect(fo, fd, 0.0, ft)
        assert np.array_equal(h.prim, want.prim) and np.array_equal(h.t, want.t), name
        assert np.array_equal(tracer.occluded(fo, fd, 0.0, ft), want.prim >= 0), name
        assert all(np.array_equal(a, k) for a, k in zip((fo, fd, ft), kept)), name
    # a scalar t_min that rounds to -0 in float32 is no error (as the rays' own -0 is none)
    assert np.array_equal(tracer.intersect(o, d, -1e-50, tmax).prim, want.prim)


def test_scalar_bounds_serve_batches_of_every_size():
    """Scalar and 0-d bounds become kept arrays of each value (``api._filled``): batches that
    grow, shrink, are empty or longer than what is kept all get exactly their own bounds, and
    ``release_kept_bounds`` leaves answers as they were."""
    from traversal.api import release_kept_bounds
    from traversal.config import KEPT_BOUND_RAYS

    tracer = Tracer(hwbvh.build(random_soup(400, seed=6)))
    rng = np.random.default_rng(2)
    o = rng.uniform(-1.5, 1.5, (KEPT_BOUND_RAYS + 40, 3)).astype(np.float32)
    d = rng.normal(size=(KEPT_BOUND_RAYS + 40, 3)).astype(np.float32)
    for n in (100, 3000, 7, 0, KEPT_BOUND_RAYS + 40, 100):
        for lo, hi in ((0.0, 1.5), (np.float32(0.25), np.array(2.0, np.float32)),
                       (np.array(0.0), np.inf)):
            h = tracer.intersect(o[:n], d[:n], lo, hi)
            want = tracer.intersect(o[:n], d[:n], np.full(n, lo, np.float32),
                                    np.full(n, hi, np.float32))
            assert np.array_equal(h.prim, want.prim) and np.array_equal(h.t, want.t), (n, lo, hi)
            assert np.array_equal(tracer.occluded(o[:n], d[:n], lo, hi), want.prim >= 0)
            assert (h.t[h.prim >= 0] >= np.float32(lo)).all()
        release_kept_bounds() if n == 7 else None


def test_a_kept_float_bound_is_checked_as_the_first_time():
    """A Python float bound is kept after its first checks (``api._interval``): the same value
    as t_max (where negatives are allowed) does not let it through as t_min later, a NaN is
    never kept, and -0.0 is kept apart from 0.0."""
    from hwbvh.errors import ParameterError
    from traversal.api import _interval, release_kept_bounds

    release_kept_bounds()
    assert (_interval(-0.5, 8, np.float32, "tmax") == -0.5).all()
    for _ in range(2):
        with pytest.raises(ParameterError, match="tmin.*must not be negative"):
            _interval(-0.5, 8, np.float32, "tmin", nonnegative=True)
        with pytest.raises(ParameterError, match="tmax.*NaN"):
            _interval(float("nan"), 8, np.float32, "tmax")
    zero = _interval(0.0, 8, np.float32, "tmin", nonnegative=True)
    negzero = _interval(-0.0, 8, np.float32, "tmin", nonnegative=True)
    assert not np.signbit(zero).any() and np.signbit(negzero).all()
    assert _interval(0.0, 8, np.float64, "tmin").dtype == np.float64
    assert len(_interval(0.0, 3, np.float32, "tmin")) == 3


def test_an_empty_range_of_chunks_writes_nothing():
    """``trace_chunks`` over no chunk (an empty batch: the warm-up query is one) must not write
    its per-range entries: the arrays have none. Empty views into a larger array catch a write
    past them."""
    from traversal.traverse import trace_chunks

    tracer = Tracer(hwbvh.build(random_soup(50, seed=1)))
    none3 = np.zeros((0, 3), np.float32)
    none = np.zeros(0, np.float32)
    sentinel = np.full(8, -7, np.int64)
    overflow, traced = sentinel[2:2], sentinel[5:5]
    trace_chunks(0, 0, tracer._u1, tracer._f1, tracer.index_bytes, tracer._tris1, tracer.row_of,
                 tracer.raw,
                 none3, none3, none3.reshape(-1), none3.reshape(-1), none, none, tracer.eps2,
                 tracer.one, tracer.widen, tracer.edge, tracer.depth, False, True,
                 np.zeros(0, np.int32), none, none, none, none3, np.zeros((0, 2), np.int64),
                 overflow, traced)
    assert (sentinel == -7).all()
    h = tracer.intersect(none3, none3)
    assert len(h.prim) == 0 and tracer.occluded(none3, none3).shape == (0,)


def test_prefetch_is_a_hint_that_never_faults():
    """The traversal's prefetch compiles to LLVM's prefetch, and an address far outside the
    array (a leaf's row read as a node, say) is harmless; the traversal's own request for what
    a node visit reads next is three of them."""
    from numba import njit

    from traversal.prefetch import prefetch
    from traversal.traverse import _prefetch_below

    @njit
    def touch(a, far):
        prefetch(a, far)
        prefetch(a, -far)
        return a[0]

    a = np.arange(4.0)
    assert touch(a, 10 ** 12) == 0.0
    assert touch.inspect_llvm(touch.signatures[0]).count("call void @llvm.prefetch") == 2

    @njit
    def below(u, tris, rec):
        _prefetch_below(u, tris, rec)

    tracer = Tracer(hwbvh.build(random_soup(50, seed=1)))
    below(tracer._u1, tracer._tris1, 0)
    assert below.inspect_llvm(below.signatures[0]).count("call void @llvm.prefetch") == 3


def test_a_tree_whose_index_list_misses_a_triangle_is_refused():
    tris = random_soup(50, seed=1)
    bvh = hwbvh.build(tris)
    bvh.indices = bvh.indices.copy()
    bvh.indices[3] = bvh.indices[4]                 # one triangle twice, another never
    with pytest.raises(ValueError, match="bvh.indices"):
        Tracer(bvh)


def test_tracer_sizes_its_stack_from_the_trees_depth():
    """The set-up takes the depth in the walk that checks the leaves; it is the tree's."""
    for tris, kw in ((random_soup(3000, seed=2), {}), (sphere(40, 80), {"leaf_size": 1}),
                     (grid_sheet(20, 20), {"builder": "sweep"})):
        bvh = hwbvh.build(tris, **kw)
        assert Tracer(bvh).depth == hwbvh.tree_stats(bvh.nodes)["max_depth"] > 0


def test_ray_sets_and_verification_made_a_slice_at_a_time_equal_the_whole(monkeypatch):
    """Slices of 1000 rays (not a multiple of a tile row) make the same primary and incoherent
    rays, bit for bit, as one piece (camera.primary_rays in tile order; one NumPy stream), and
    verification by slices gives the same labels and answers."""
    from traversal import verify
    from traversal.camera import frame_bounds, primary_rays, tile_order
    tris, V, F = closed_sphere()
    n = 5003
    lo, hi = raysets.bounds_of(tris)
    eye, target, up = frame_bounds(lo, hi)
    w = int(np.ceil(np.sqrt(n * 4 / 3)))
    h = -(-n // w)
    o, d = primary_rays(eye, target, up, 40.0, w, h)
    order = tile_order(w, h)[:n]
    rng = np.random.default_rng(4)
    oi = rng.uniform(lo, hi, (n, 3))
    di = rng.normal(size=(n, 3))
    di /= np.linalg.norm(di, axis=1, keepdims=True)
    whole = verify_mesh(tris, V, F, "bounces", 3000)
    whole_shadow = verify_mesh(tris, V, F, "shadow", 3000)
    monkeypatch.setattr(raysets, "MAKE_CHUNK", 1000)
    monkeypatch.setattr(verify, "VERIFY_CHUNK", 700)
    for a, b in zip(raysets.primary(tris, n), (o[order], d[order])):
        assert np.array_equal(a, b)
    for a, b in zip(raysets.incoherent(tris, n, 4), (oi, di)):
        assert np.array_equal(a, b)
    sliced = verify_mesh(tris, V, F, "bounces", 3000)
    assert sliced[0] == whole[0] and np.array_equal(sliced[1], whole[1])
    assert all(np.array_equal(x, y) for x, y in zip(sliced[2][:2], whole[2][:2]))
    assert np.array_equal(sliced[3].t, whole[3].t) and np.array_equal(sliced[4][1], whole[4][1])
    sliced = verify_mesh(tris, V, F, "shadow", 3000)
    assert sliced[0] == whole_shadow[0] and np.array_equal(sliced[1], whole_shadow[1])
    assert np.array_equal(sliced[3], whole_shadow[3]) and np.array_equal(sliced[4], whole_shadow[4])
