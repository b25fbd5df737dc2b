"""Packet traversal (traversal.packet): the same answers, bit for bit, as the single-ray path,
on the rays that take it (coherent groups of 16), including the hard cases."""
import re

import numpy as np
import pytest

import hwbvh
from traversal.camera import frame_bounds, primary_rays, tile_order
from scenes.meshes import grid_sheet, random_soup, uv_sphere
from traversal import Tracer, raysets
from traversal.packet import P, coherent, coherent_packet, packet_rays


def pair(tris, **kw):
    bvh = hwbvh.build(tris)
    return Tracer(bvh, **kw), Tracer(bvh, packets=False, **kw)


def rays_down_on_the_sheet(extent, n):
    """n x n rays straight down (-y) from y = 1 over [-extent, extent]^2 in x and z."""
    xs = np.linspace(-extent, extent, n)
    X, Z = np.meshgrid(xs, xs)
    o = np.stack([X.ravel(), np.ones(X.size), Z.ravel()], 1)
    return o, np.tile([0.0, -1.0, 0.0], (len(o), 1))


def same_hits(a, b):
    for name in ("prim", "t", "u", "v", "ng"):
        x, y = getattr(a, name), getattr(b, name)
        assert np.array_equal(x, y), name          # bit for bit (inf == inf, no NaN in outputs)


def scene():
    V, F = uv_sphere(30, 48)
    return np.concatenate([V[F], random_soup(4000, seed=3, size=0.08)]).astype(np.float32)


def camera_rays(tris, w=97, h=61):                 # odd sizes: partial tiles and packets
    lo, hi = raysets.bounds_of(tris)
    eye, target, up = frame_bounds(lo, hi)
    o, d = primary_rays(eye, target, up, 40.0, w, h)
    order = tile_order(w, h)
    return o[order], d[order]


def test_tile_order_is_a_permutation_of_4x4_blocks():
    order = tile_order(10, 7)
    assert sorted(order) == list(range(70))
    first = order[:16]
    assert set(first % 10) == {0, 1, 2, 3} and set(first // 10) == {0, 1, 2, 3}
    # the partial tile at the right edge (columns 8, 9) comes right after the first row of tiles'
    # second tile, with 2 x 4 pixels
    assert set(order[32:40] % 10) == {8, 9}


def test_packets_give_the_single_ray_answers_on_camera_and_shadow_rays():
    tris = scene()
    pk, single = pair(tris)
    o, d = camera_rays(tris)
    a = pk.intersect(o, d)
    assert pk.last_packets >= 0.9 * len(o) / P       # the packet path really ran
    same_hits(a, single.intersect(o, d))
    assert (a.prim >= 0).mean() > 0.1
    so, sd, st = raysets.shadow(single, tris, 6000)
    occ = pk.occluded(so, sd, 0.0, st)
    assert pk.last_packets > 0
    assert np.array_equal(occ, single.occluded(so, sd, 0.0, st))
    assert 0.05 < occ.mean() < 0.95                # both answers occur


def test_packets_with_per_ray_intervals_and_dead_lanes():
    tris = scene()
    pk, single = pair(tris)
    o, d = camera_rays(tris)
    rng = np.random.default_rng(4)
    tmin = rng.uniform(0, 1.5, len(o))
    tmax = tmin + rng.uniform(0, 3, len(o))
    tmax[::7] = tmin[::7]                          # empty-width intervals
    o = o.copy()
    o[5] = np.nan                                  # invalid rays inside coherent groups
    o[40, 1] = np.inf
    tmin[77] = np.inf                              # an interval starting at infinity
    tmax[90] = tmin[90] - 1
    a = pk.intersect(o, d, tmin, tmax)
    assert pk.last_packets > 0
    same_hits(a, single.intersect(o, d, tmin, tmax))
    assert a.prim[[5, 40, 77, 90]].tolist() == [-1] * 4
    assert np.array_equal(pk.occluded(o, d, tmin, tmax), single.occluded(o, d, tmin, tmax))


@pytest.mark.parametrize("z", [0.0, -0.0])
def test_packets_of_axis_parallel_rays_through_vertices_and_edges(z):
    tris = grid_sheet(16, 16, wave=0.0)            # flat: y = 0 exactly
    pk, single = pair(tris)
    xs = np.linspace(-1, 1, 33)                    # vertices and edge midpoints
    X, Z = np.meshgrid(xs, xs)
    o = np.stack([X.ravel(), np.ones(X.size), Z.ravel()], 1)
    d = np.tile([z, -1.0, z], (len(o), 1))
    a = pk.intersect(o, d)
    assert pk.last_packets == len(o) // P          # the partial last group goes ray by ray
    same_hits(a, single.intersect(o, d))
    assert (a.prim >= 0).all() and np.allclose(a.t, 1.0)
    # origins exactly on slab planes of the boxes, with zero direction components
    o2 = np.stack([X.ravel(), np.zeros(X.size), Z.ravel()], 1)
    d2 = np.tile([1.0, z, z], (len(o2), 1))
    same_hits(pk.intersect(o2 - [2, 0, 0], d2), single.intersect(o2 - [2, 0, 0], d2))


@pytest.mark.parametrize("scale,shift", [(1e-4, 0.0), (1.0, 1e5)])
def test_packets_on_tiny_and_far_away_meshes(scale, shift):
    tris = (scene().astype(np.float64) * scale + shift).astype(np.float32)
    pk, single = pair(tris)
    o, d = camera_rays(tris)
    same_hits(pk.intersect(o, d), single.intersect(o, d))
    assert pk.last_packets > 0


def test_packets_in_float64():
    tris = scene()
    pk, single = pair(tris, precision="float64")
    o, d = camera_rays(tris)
    a = pk.intersect(o, d)
    assert a.t.dtype == np.float64 and pk.last_packets > 0
    same_hits(a, single.intersect(o, d))


def test_packets_and_single_rays_agree_on_shared_axis_aligned_faces():
    """City blocks: boxes side by side, so rays hit triangles that lie exactly on node-box
    planes, where a triangle's t can round an ulp nearer than its box's entry distance. Culling
    such a box on pop without the box test's slack would lose the hit on one path; both paths
    must keep it."""
    import trimesh
    rng = np.random.default_rng(5)
    parts = []
    for i in range(12):
        for j in range(12):
            h = rng.integers(1, 5) * 0.25
            b = trimesh.creation.box(extents=(1.0, h, 1.0))
            b.apply_translation((i + 0.5, h / 2, j + 0.5))
            parts.append(b.vertices[b.faces])
    tris = (np.concatenate(parts) * 0.37).astype(np.float32)
    o, d = raysets.incoherent(tris, 100000, seed=3)
    lo = tris.reshape(-1, 3).min(0)
    cell = np.minimum(((o - lo) / np.ptp(tris.reshape(-1, 3), 0) * 8).astype(int), 7)
    octant = (np.signbit(d) * [1, 2, 4]).sum(1)
    order = np.lexsort((cell[:, 0] + 8 * cell[:, 1] + 64 * cell[:, 2], octant))
    o, d = o[order], d[order]                      # packets of nearby origins, one octant
    pk, single = pair(tris)
    a = pk.intersect(o, d)
    assert pk.last_packets > len(o) // P // 2
    same_hits(a, single.intersect(o, d))
    assert (a.prim >= 0).mean() > 0.5


def test_incoherent_groups_and_counters_go_ray_by_ray():
    tris = scene()
    pk, single = pair(tris)
    o, d = raysets.incoherent(tris, 3000)
    same_hits(pk.intersect(o, d), single.intersect(o, d))
    assert pk.last_packets == 0
    oc, dc = camera_rays(tris)
    h = pk.intersect(oc, dc, counters=True)       # counters model the single-ray unit
    assert pk.last_packets == 0 and h.counters[:, 0].sum() > 0


def test_coherence_test_is_the_direction_octant():
    d = np.array([[1, 2, 3], [0.5, 0.1, 9], [1, 1, 1]], np.float32)
    assert coherent(d, 0, 3)
    d[2, 1] = -1e-30
    assert not coherent(d, 0, 3)
    d[2, 1] = 0.0
    assert coherent(d, 0, 3)
    d[2, 1] = -0.0                 # 1/-0 = -inf: the AABB unit treats -0 as negative
    assert not coherent(d, 0, 3)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_the_packet_coherence_test_is_the_general_one(dtype):
    """The traversal's per-packet test (flat, branch-free) answers as ``coherent`` on P rays,
    signed zeros, infinities and NaN included, wherever the one ray that differs sits."""
    rng = np.random.default_rng(5)
    values = np.array([1.0, 0.25, 0.0, -0.0, -1.0, -3e-30, np.inf, np.nan], dtype)
    for trial in range(400):
        d = np.abs(rng.choice(values, (3 * P, 3))).astype(dtype)
        if trial % 2:                  # a sign flipped in one component of one ray
            d[rng.integers(P, 2 * P), rng.integers(3)] *= -1
        for lo in (0, P, 2 * P - 5):
            hi = min(lo + P, len(d))
            if hi - lo == P:
                assert coherent_packet(d.reshape(-1), lo) == coherent(d, lo, hi)
    d = np.ones((P, 3), dtype)
    assert coherent_packet(d.reshape(-1), 0)
    d[P - 1, 2] = -0.0
    assert not coherent_packet(d.reshape(-1), 0)


def test_signed_zero_directions_mixed_in_a_group():
    pk, single = pair(grid_sheet(16, 16, wave=0.0))
    o, d = rays_down_on_the_sheet(1.0, 33)
    d[::3, 0] = -0.0                               # +0 and -0 alternate within groups
    a = pk.intersect(o, d)
    same_hits(a, single.intersect(o, d))
    assert (a.prim >= 0).all()


def test_packet_stack_overflow_is_an_error():
    tris = scene()
    pk, _ = pair(tris)
    pk.depth = 1
    o, d = camera_rays(tris)
    with pytest.raises(RuntimeError, match="stack overflow"):
        pk.intersect(o, d)


def _overflowing(tracer, o, d):
    """The rays the batch (o, d) reports as overflowing the stack, from its error (0: none)."""
    try:
        tracer.intersect(o, d)
    except RuntimeError as e:
        return int(re.search(r"overflow on (\d+) rays", str(e)).group(1))
    return 0


def test_packet_stack_overflow_counts_every_ray_of_every_overflowing_group():
    """Runs of packets, incoherent groups and a partial group mixed in one batch: the count the
    error reports is the sum over the groups traced alone (a packet overflows as a whole, its
    P rays; a ray traced by itself counts once)."""
    tris = scene()
    pk, _ = pair(tris)
    pk.depth = 4
    o, d = camera_rays(tris, 33, 29)               # 59 full groups and one of 13 rays
    groups = [slice(a, min(a + P, len(o))) for a in range(0, len(o), P)]
    d = d.copy()
    packets = [i for i, g in enumerate(groups) if _overflowing(pk, o[g], d[g]) == P]
    for i in packets[1::4]:                        # some overflowing groups made incoherent:
        d[P * i + 5] *= -1                         # their rays go one by one
    alone = [_overflowing(pk, o[g], d[g]) for g in groups]
    assert any(0 < c < P for c in alone)           # groups whose single rays overflow in part
    assert any(c == P for c in alone)              # and packets that overflow as a whole
    assert _overflowing(pk, o, d) == sum(alone)


@pytest.mark.parametrize("tri_scale,dir_scale", [(1e-12, 1e20), (1e12, 1e-25), (1e12, 1.0),
                                                   (1e-12, 1.0)])
def test_packets_agree_at_extreme_triangle_and_direction_sizes(tri_scale, dir_scale):
    """Tiny triangles seen along huge directions, huge ones along tiny directions, and both
    along unit ones: the parallel band's unscaled terms (|e1|^2 |e2|^2, |d|^2 and their product)
    would overflow, underflow or be NaN here. Both paths must read the band alike (they share
    its scaled terms) and find the float64 answers."""
    tris = (grid_sheet(16, 16, wave=0.0).astype(np.float64) * tri_scale).astype(np.float32)
    pk, single = pair(tris)
    xs = np.linspace(-0.93, 0.93, 40) * tri_scale
    X, Z = np.meshgrid(xs, xs)
    o = np.stack([X.ravel(), np.full(X.size, tri_scale), Z.ravel()], 1)
    d = np.tile(np.array([1e-3, -1.0, 2e-3]) * dir_scale, (len(o), 1))
    a = pk.intersect(o, d)
    assert pk.last_packets == len(o) // P
    same_hits(a, single.intersect(o, d))
    assert (a.prim >= 0).all()
    assert np.array_equal(a.prim, Tracer(hwbvh.build(tris), precision="float64").intersect(o, d).prim)
    assert np.array_equal(pk.occluded(o, d), single.occluded(o, d))


def test_last_packets_is_each_threads_own():
    """A tracer takes queries from several threads at once (the renderer's bands): each thread
    reads the packet count of its own last query."""
    import threading
    pk, _ = pair(grid_sheet(16, 16, wave=0.0))
    o, d = rays_down_on_the_sheet(0.9, 32)
    seen = {}

    def run(n):
        counts = set()
        for _ in range(50):
            pk.intersect(o[:n], d[:n])
            counts.add(pk.last_packets)
        seen[n] = counts
    threads = [threading.Thread(target=run, args=(n,)) for n in (16 * 8, 16 * 40)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert seen == {16 * 8: {8}, 16 * 40: {40}}


def test_packet_rays_is_the_traversals_rule():
    """The report's rule for which rays go in packets counts the packets the traversal traced:
    camera rays, a shuffled batch, signed zeros and a batch that ends in a partial group."""
    tris = scene()
    tracer = Tracer(hwbvh.build(tris), tris)
    o, d = camera_rays(tris)
    rng = np.random.default_rng(3)
    mixed = d.copy()
    mixed[rng.choice(len(d), 40, replace=False)] *= -1
    zeros = d.copy()
    zeros[::37, 0] = -0.0
    traced = []
    for dirs in (d, mixed, zeros, d[: 16 * 9 + 5], rng.permutation(d)):
        tracer.intersect(o[: len(dirs)], dirs)
        assert packet_rays(dirs).sum() == P * tracer.last_packets
        traced.append(tracer.last_packets)
    assert traced[0] > traced[1] > 0 and traced[0] > traced[2] > 0 and traced[3] == 9
    # and the very groups: each group of the mixed batch, traced alone, is a packet exactly
    # where the rule says its rays are
    rule = packet_rays(mixed)
    for g in range(len(mixed) // P):
        rays = slice(g * P, (g + 1) * P)
        tracer.intersect(o[rays], mixed[rays])
        assert tracer.last_packets == int(rule[g * P])


def test_runs_of_packets_between_groups_traced_ray_by_ray():
    """Runs of coherent groups (traced in one call each) broken by incoherent groups, and a
    batch ending in a run, in an incoherent group or in a partial group: every ray gets the
    single-ray answer and every coherent group is one packet."""
    tris = scene()
    pk, single = pair(tris)
    o, d = camera_rays(tris)
    n = 16 * P
    o, d = o[:n], d[:n].copy()
    for g in (0, 3, 4, 9, 15):                  # break these groups: one ray flipped
        d[g * P + 5] *= -1
    for end in (n, n - P, n - P + 7, n - 3 * P):
        pk_hits = pk.intersect(o[:end], d[:end])
        assert pk.last_packets == packet_rays(d[:end]).sum() // P > 0
        same_hits(pk_hits, single.intersect(o[:end], d[:end]))
        assert np.array_equal(pk.occluded(o[:end], d[:end], tmax=pk_hits.t * 0.5),
                              single.occluded(o[:end], d[:end], tmax=pk_hits.t * 0.5))


def test_time_split_of_queries_whose_rays_miss_everything():
    """``bench trees``' split by kind and path on rays that leave the scene at once: no work,
    so no work ratio, and no division by zero; every ray lands in one class."""
    from types import SimpleNamespace
    from hwrt.trees import BUILDERS, _by_path

    tris = scene()
    o, d = camera_rays(tris)
    away = np.ascontiguousarray(o - 100 * d)          # behind the camera, looking away
    queries = [("intersect", away, -d, np.array(0.0, np.float32), np.array(np.inf, np.float32),
                True),
               ("occluded", away[:40], -d[:40], np.zeros(40, np.float32),
                np.full(40, 5.0, np.float32), False)]
    tracers = {b: Tracer(hwbvh.build(tris, builder=b), tris) for b in BUILDERS}
    classes = _by_path(tracers, {b: SimpleNamespace(queries=queries) for b in BUILDERS}, 1)
    assert sum(c["rays"] for c in classes) == len(away) + 40
    assert all(c["work_ratio"] is None and c["ns_per_unit"] is None for c in classes)
    assert all(t.packets for t in tracers.values())


def test_cost_fit_prices_each_term_from_queries_timed_alone():
    """``bench trees``' fit: one row per non-empty query of both trees, four prices, none below
    0, on one thread (the caller's thread count restored after, also when a query fails), and
    no fit from too few queries."""
    import numba
    from hwrt.trees import BUILDERS, FIT_MIN_QUERIES, _cost_fit, _query_work

    def fit_of(tracers, queries, work=None):
        work = work or {b: _query_work(tracers[b], queries[b]) for b in BUILDERS}
        return _cost_fit(tracers, queries, work, 1)

    tris = scene()
    o, d = camera_rays(tris)
    tracers = {b: Tracer(hwbvh.build(tris, builder=b), tris) for b in BUILDERS}
    zero, inf = np.array(0.0, np.float32), np.array(np.inf, np.float32)
    n = FIT_MIN_QUERIES // 2 + 1
    step = len(o) // n // P * P
    queries = [("intersect", o[k * step:(k + 1) * step], d[k * step:(k + 1) * step], zero, inf,
                False) for k in range(n)]
    queries.append(("intersect", o[:0], d[:0], zero, inf, False))      # empty: no row
    was = numba.get_num_threads()
    fit = fit_of(tracers, {b: queries for b in BUILDERS})
    assert numba.get_num_threads() == was
    assert fit["queries"] == 2 * n
    prices = [fit[k] for k in ("ns_per_node", "ns_per_triangle", "ns_per_ray", "us_per_query")]
    assert all(np.isfinite(p) and p >= 0 for p in prices) and sum(prices) > 0
    assert fit["one_thread_ratio"] > 0 and fit["priced_ratio"] > 0
    assert set(fit["by_tree"]) == set(BUILDERS)
    # the same queries through both trees: the prices give the two trees' work as it is
    one = {b: tracers["hwbvh"] for b in BUILDERS}
    same = fit_of(one, {b: queries for b in BUILDERS})
    assert abs(same["priced_ratio"] - 1) < 1e-12
    # "sweep" asked every query twice: its priced work is twice hwbvh's
    twice = fit_of(one, {"hwbvh": queries, "sweep": queries + queries})
    assert abs(twice["priced_ratio"] - 2) < 1e-9
    assert twice["by_tree"]["sweep"]["queries"] == 2 * n and twice["by_tree"]["hwbvh"] is None
    assert fit_of(tracers, {b: queries[:3] for b in BUILDERS}) is None
    bad = [("intersect", o[:16], d[:16], np.array(-1.0, np.float32), inf, False)] * n
    with pytest.raises(ValueError, match="tmin: must not be negative"):
        fit_of(tracers, {b: bad for b in BUILDERS},
               {b: np.zeros((len(bad), 3), np.int64) for b in BUILDERS})   # fails when timed
    assert numba.get_num_threads() == was


def test_nonnegative_least_squares_keeps_prices_at_or_above_zero():
    """Where plain least squares bends a price below 0 to fit terms that move together, the
    fit drops that term; where every price is positive, it is plain least squares."""
    from hwrt.trees import nonnegative_least_squares

    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(1, 10, 40), rng.uniform(1, 10, 40), np.ones(40)])
    y = X @ np.array([2.0, 0.5, 3.0])
    assert np.allclose(nonnegative_least_squares(X, y), [2.0, 0.5, 3.0])
    y2 = X[:, 0] * 2.0 - 0.8 + rng.normal(0, 0.01, 40)    # an intercept below 0
    plain, *_ = np.linalg.lstsq(X, y2, rcond=None)
    assert plain[2] < 0
    p = nonnegative_least_squares(X, y2)
    assert (p >= 0).all() and p[2] == 0
    # a column of zeros and two equal columns: prices still at or above 0, the fit exact
    Z = np.column_stack([X[:, 0], np.zeros(40), X[:, 0], X[:, 1]])
    pz = nonnegative_least_squares(Z, X[:, 0] * 1.5 + X[:, 1] * 0.25)
    assert (pz >= 0).all() and np.allclose(Z @ pz, X[:, 0] * 1.5 + X[:, 1] * 0.25)
    assert (nonnegative_least_squares(Z, np.zeros(40)) == 0).all()
    slope_only, *_ = np.linalg.lstsq(X[:, :1], y2, rcond=None)       # a feasible fit
    assert (slope_only >= 0).all()
    assert np.sum((X @ p - y2) ** 2) <= np.sum((X[:, :1] @ slope_only - y2) ** 2) + 1e-9


def test_stage_split_shares_ratios_and_the_floor_the_untraced_stages_set():
    """``bench trees``' split of the render: shares of hwbvh's time that add up to 1, each
    part's time ratio, and the gap to the work ratio that the other stages leave were the
    queries' time to follow the work ratio: here 0.75 x 0.6 + 0.25 x 1.0 against 0.6 (not
    the kinds' own ratios, 0.5 x 0.8 + 0.25 x 0.5). A stage that took no time (no shadow
    rays) has a share of 0 and no ratio."""
    from hwrt.trees import _stage_split

    def run(intersect, occluded, shade):
        return {"generate": 0.0, "queues": 0.0, "intersect": intersect, "shade": shade,
                "occluded": occluded, "accumulate": 0.0}

    runs = {"hwbvh": [run(2.0, 1.0, 1.0)] * 3, "sweep": [run(1.6, 0.5, 1.0)] * 3}
    s = _stage_split(runs, {"closest": 0.8, "shadow": 0.5}, 0.6)
    assert [s[p]["share"] for p in ("closest", "shadow", "other")] == [0.5, 0.25, 0.25]
    assert [s[p]["ratio"] for p in ("closest", "shadow", "other")] == [0.8, 0.5, 1.0]
    assert [s[p]["work_ratio"] for p in ("closest", "shadow", "other")] == [0.8, 0.5, None]
    assert s["floor_vs_work"] == pytest.approx(0.7 / 0.6 - 1)
    unlit = {"hwbvh": [run(2.0, 0.0, 2.0)], "sweep": [run(1.0, 0.0, 2.0)]}
    s = _stage_split(unlit, {"closest": 0.5, "shadow": None}, 0.5)
    assert s["shadow"]["share"] == 0 and s["shadow"]["ratio"] is None
    assert s["floor_vs_work"] == pytest.approx(0.75 / 0.5 - 1)
    # rays that visit no node with either tree: no work ratio, no floor
    assert _stage_split({"hwbvh": [run(1.0, 1.0, 1.0)], "sweep": [run(1.0, 1.0, 1.0)]},
                        {"closest": None, "shadow": 1.0}, None)["floor_vs_work"] is None
