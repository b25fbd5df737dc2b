"""Kernels trust, public functions validate: every public entry of the traversal refuses bad
input with a one-line InputError / ParameterError naming the argument, before any kernel
reads it, and answers every valid input as before."""
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import hwbvh
from hwbvh.errors import InputError, ParameterError
from traversal import Tracer
from traversal.embree_ref import (EmbreeTracer, embree_intersect, embree_occluded, embree_scene,
                                  shared_vertices)
from traversal.camera import primary_rays
from traversal.grid import GridTracer
from traversal.kdtree import KdTreeTracer
from traversal.tracers import CountingTracer, RecordingTracer, VerifyingTracer
from traversal.verify import classify, classify_occluded, verify_mesh, verify_rays

# 64 small triangles and 16 rays straight down at the first 16 centroids: all 16 hit
PRELUDE = """
import numpy as np, hwbvh
rng = np.random.default_rng(0)
tris = (rng.uniform(0, 1, (64, 1, 3)) + rng.uniform(-0.05, 0.05, (64, 3, 3))).astype(np.float32)
o = tris.mean(axis=1)[:16].copy(); o[:, 2] = 3
d = np.zeros((16, 3), np.float32); d[:, 2] = -1
"""
namespace = {}
exec(PRELUDE, namespace)
TRIS, O, D = namespace["tris"], namespace["o"], namespace["d"]
V = TRIS.reshape(-1, 3)
F = np.arange(len(V)).reshape(-1, 3)


@pytest.fixture(scope="module")
def bvh():
    return hwbvh.build(TRIS)


@pytest.fixture(scope="module")
def tracers(bvh):
    return {"bvh": Tracer(bvh), "grid": GridTracer(TRIS), "kdtree": KdTreeTracer(TRIS),
            "embree": EmbreeTracer(V, F)}


REFUSALS = """
def refused(what, f):
    try:
        f()
    except Exception as e:
        print(f"{what} {type(e).__name__} {e}", flush=True)
    else:
        print(f"{what} ACCEPTED", flush=True)
"""


def run_isolated(body):
    """Run ``body`` (after PRELUDE and REFUSALS) in a fresh interpreter, so that a crash in a
    kernel fails the test instead of killing the test run. Returns (returncode, stdout +
    stderr)."""
    r = subprocess.run([sys.executable, "-c", PRELUDE + REFUSALS + textwrap.dedent(body)],
                       capture_output=True, text=True, timeout=300)
    return r.returncode, r.stdout + r.stderr


def test_a_tree_whose_nodes_a_kernel_cannot_walk_is_refused_by_the_tracer():
    code, out = run_isolated("""
    from traversal import Tracer

    def tree(change):
        b = hwbvh.build(tris)
        b.nodes = b.nodes.copy()
        change(b)
        return b

    def far_child(b):
        b.nodes["a"][0] = 10**9
    def far_leaf(b):
        leaf = b.nodes["flags"] == 1
        b.nodes["b"][leaf] = 10**6
    def cycle(b):                      # an inner node points at the root's left child
        inner = np.flatnonzero(b.nodes["flags"] == 0)
        b.nodes["a"][inner[-1]] = b.nodes["a"][0]
    def empty(b):
        b.nodes = b.nodes[:0]
    for change in (far_child, far_leaf, cycle, empty):
        refused(change.__name__, lambda: Tracer(tree(change)).intersect(o, d))
    """)
    assert code >= 0, out                       # a negative code: killed by a signal
    for line in ("far_child InputError bvh.nodes: invalid tree: child pointer out of range "
                 "(node 0)",
                 "far_leaf InputError bvh.nodes: invalid tree: leaf index range outside the "
                 "index list (node",
                 "cycle InputError bvh.nodes: invalid tree: node reached twice (cycle or shared "
                 "child)",
                 "empty InputError bvh.nodes: no nodes"):
        assert line in out, out


def test_classify_refuses_primitive_ids_out_of_range_and_answers_not_one_per_ray():
    code, out = run_isolated("""
    from traversal.verify import classify, classify_occluded
    miss = np.full(16, -1, np.int64)
    refused("far", lambda: classify(tris, o, d, 0.0, np.inf, np.full(16, 10**7, np.int64),
                                    np.ones(16), miss, np.full(16, np.inf)))
    refused("below", lambda: classify(tris, o, d, 0.0, np.inf, miss, np.full(16, np.inf),
                                      np.full(16, -2, np.int64), np.ones(16)))
    refused("few", lambda: classify(tris, o, d, 0.0, np.inf, miss[:4], np.ones(4), miss,
                                    np.ones(16)))
    refused("few_blocked", lambda: classify_occluded(tris, o, d, 0.0, np.inf, np.ones(4, bool),
                                                     np.zeros(4, bool)))
    refused("tris", lambda: classify(tris.reshape(-1, 9), o, d, 0.0, np.inf, miss, np.ones(16),
                                     miss, np.ones(16)))
    refused("float_blocked", lambda: classify_occluded(tris, o, d, 0.0, np.inf, np.ones(16),
                                                       np.zeros(16, bool)))
    refused("two_blocked", lambda: classify_occluded(tris, o, d, 0.0, np.inf,
                                                     np.full(16, 2), np.zeros(16, bool)))
    refused("ragged", lambda: classify(tris, [[0, 0, 0], [1, 1]], d[:2], 0.0, np.inf, miss[:2],
                                       np.ones(2), miss[:2], np.ones(2)))
    """)
    assert code >= 0, out
    assert "far ParameterError ours_prim: primitive ids must be -1 or below len(tris) = 64, " \
           "got 10000000 (ray 0)" in out
    assert "below ParameterError ref_prim: primitive ids must be -1" in out
    assert "few ParameterError ours_prim: must hold one answer per ray (16,), got shape (4,)" in out
    assert "few_blocked ParameterError ours_blocked: must hold one answer per ray (16,)" in out
    assert "tris ParameterError tris: must be (m, 3, 3), got shape (64, 9)" in out
    assert "float_blocked ParameterError ours_blocked: must be booleans (or integers 0 and 1), " \
           "got float64" in out
    assert "two_blocked ParameterError ours_blocked: must be booleans (or integers 0 and 1), " \
           "got 2 (ray 0)" in out
    assert "ragged ParameterError O: must be rows of equal length" in out


def test_classify_still_judges_right_answers(bvh):
    h = Tracer(bvh).intersect(O, D)
    te, pe, *_ = embree_intersect(embree_scene(V, F), O, D)
    counts, _ = classify(TRIS, O, D, 0.0, np.inf, h.prim.astype(np.int64), h.t, pe, te)
    assert counts == {"rays": 16, "agree": 16, "tie": 0, "mismatch": 0}
    counts, _ = classify_occluded(TRIS, O, D, 0.0, np.inf, np.ones(16, bool), np.ones(16, bool))
    assert counts["agree"] == 16


def test_classify_judges_the_reported_t_not_only_the_primitive():
    """Two triangles sharing the edge x = 0 at z = 0; rays straight down hit at t = 3. The right
    primitive at a wrong t is a mismatch, whichever side reports it and however wrong (three
    times, infinite, NaN); the two triangles of the edge at the right t stay a tie."""
    tris = np.array([[[-1, -1, 0], [0, -1, 0], [0, 1, 0]],
                     [[0, -1, 0], [1, -1, 0], [0, 1, 0]]], np.float32)
    o = np.array([[-0.5, -0.5, 3], [0, -0.5, 3]], np.float32)
    d = np.array([[0, 0, -1], [0, 0, -1]], np.float32)
    right_t = np.array([3.0, 3.0])
    on_edge_prims = np.array([0, 1])

    def label(ours_prim, ours_t, ref_prim, ref_t):
        return classify(tris, o, d, 0.0, np.inf, np.asarray(ours_prim), np.asarray(ours_t, float),
                        np.asarray(ref_prim), np.asarray(ref_t, float))[1].tolist()

    assert label([0, 0], right_t, [0, 1], right_t) == [0, 1]
    for wrong in (9.0, np.inf, np.nan, 3.1):
        assert label([0, 0], [wrong, 3.0], [0, 0], right_t) == [2, 0], wrong
        assert label([0, 0], right_t, [0, 0], [wrong, 3.0]) == [2, 0], wrong
        assert label([0, 0], [3.0, wrong], [0, 1], right_t) == [0, 2], wrong
        assert label(on_edge_prims, right_t, [0, 0], [3.0, wrong]) == [0, 2], wrong
    # within the tolerance (1e-5 of t + |o|/|d|) a t still agrees
    assert label([0, 0], [3.0 + 2e-5, 3.0], [0, 0], right_t) == [0, 0]


def test_a_t_within_the_units_rounding_on_a_sliver_is_right_but_not_beyond():
    """A sliver whose angle at v0 has sine 2.3e-4 (from the staircase mesh), hit from 3 units
    away: the float32 unit puts the hit 6e-5 off the plane, more than T_TOL_REL's 4.2e-5 but
    well within the unit's rounding estimate eps (|o - v0| / |d| + t) / sin(angle) (9e-4;
    accepted within 4 times it): ours and Embree's t are a tie, not a wrong answer. A t 100
    times as far off (6e-3, past the bound) is still a mismatch, and so is a t within the
    bound but past the ray's t_max; a well-shaped triangle gets no such slack."""
    from traversal.config import T_TOL_REL
    sliver = [[-0.781453013420105, 2.6753320693969727, -3.2097508907318115],
              [0.5268409848213196, 1.4976019859313965, -3.2097508907318115],
              [0.5268409848213196, 1.4976019859313965, -3.2093400955200195]]
    o = np.array([[-0.710060179, 0.682190299, -2.69211292]], np.float32)
    d = np.array([[0.521924436, 0.78387928, -0.336345255]], np.float32)
    scale = np.abs(o).max() / np.linalg.norm(d)

    def reference(tri):
        """Embree's answer, and the triangle's |cos| to the ray."""
        v = np.array(tri, np.float64)
        te, pe, *_ = embree_intersect(embree_scene(v, np.arange(3).reshape(1, 3)), o, d)
        n = np.cross(v[1] - v[0], v[2] - v[0])
        return te, pe, abs(n @ d[0]) / np.linalg.norm(n) / np.linalg.norm(d[0])

    tris = np.array([sliver], np.float32)
    h = Tracer(hwbvh.build(tris)).intersect(o, d)
    te, pe, cos = reference(sliver)
    assert h.prim[0] == pe[0] == 0
    # the unit's point is off the plane by more than T_TOL_REL allows: only the rounding
    # bound accepts it
    assert abs(h.t[0] - te[0]) * cos > T_TOL_REL * (te[0] + scale)
    counts, _ = classify(tris, o, d, 0.0, np.inf, h.prim.astype(np.int64), h.t, pe, te)
    assert counts["mismatch"] == 0 and counts["tie"] == 1
    far = np.array([te[0] + 100 * (h.t[0] - te[0])])
    counts, _ = classify(tris, o, d, 0.0, np.inf, np.array([0]), far, pe, te)
    assert counts["mismatch"] == 1
    late = np.array([te[0] + 2e-3])                 # within the bound, past t_max
    counts, _ = classify(tris, o, d, 0.0, np.array([te[0] + 1e-4]), np.array([0]), late, pe, te)
    assert counts["mismatch"] == 1
    # a well-shaped triangle through the same point: its point 6e-5 off its plane is wrong
    wide = [sliver[0], sliver[1], [0.0, 3.0, -3.2097508907318115]]
    tw, pw, cw = reference(wide)
    assert pw[0] == 0
    counts, _ = classify(np.array([wide], np.float32), o, d, 0.0, np.inf, np.array([0]),
                         np.array([tw[0] + 6e-5 / cw]), pw, tw)
    assert counts["mismatch"] == 1


def _wrapped(tracers):
    """Every tracer, and the wrappers in front of ours."""
    inner = tracers["bvh"]
    return dict(tracers, verifying=VerifyingTracer(inner, TRIS, V, F),
                counting=CountingTracer(inner), recording=RecordingTracer(inner))


@pytest.mark.parametrize("query", ["intersect", "occluded"])
def test_none_and_nan_bounds_are_refused_by_every_tracer(tracers, query):
    """None converts to NaN, and a NaN bound fails every comparison: each ray would miss,
    and a NaN tmin would pass a plain negative-tmin check."""
    nan_last = np.r_[np.zeros(15), np.nan]
    for name, tracer in _wrapped(tracers).items():
        ask = getattr(tracer, query)
        for bound, value, shown in (("tmax", None, "None"), ("tmin", None, "None"),
                                    ("tmax", np.nan, "NaN"), ("tmin", np.nan, "NaN"),
                                    ("tmin", nan_last, r"NaN \(ray 15\)"),
                                    ("tmax", np.float32(np.nan), "NaN")):
            with pytest.raises(ParameterError, match=f"^{bound}: must be a number or one per ray, "
                                                     f"got {shown}$") as e:
                ask(O, D, **{bound: value})
            assert e.value.parameter == bound, name
        assert np.count_nonzero(np.asarray(getattr(ask(O, D), "prim", ask(O, D))) >= 0) == 16, name


@pytest.mark.parametrize("query", ["intersect", "occluded"])
def test_an_empty_interval_is_a_miss_in_every_tracer(tracers, query):
    """Embree called a ray with tmax < 0 or tmin > tmax blocked; every other tracer not."""
    for name, tracer in _wrapped(tracers).items():
        for tmin, tmax in ((0.0, -1.0), (5.0, 1.0), (np.inf, np.inf),
                           (np.ones(16), np.r_[np.full(8, 0.5), np.full(8, 10.0)])):
            answer = getattr(tracer, query)(O, D, tmin=tmin, tmax=tmax)
            hit = (answer.prim >= 0) if query == "intersect" else answer
            expect = np.zeros(16, bool) if np.ndim(tmax) == 0 else np.r_[np.zeros(8, bool),
                                                                          np.ones(8, bool)]
            assert hit.tolist() == expect.tolist(), (name, tmin, tmax)
    verifying = _wrapped(tracers)["verifying"]
    assert verifying.summary()["mismatch"] == 0, verifying.summary()


def test_embree_empty_interval_is_not_blocked_in_the_query_functions():
    scene = embree_scene(V, F)
    assert not embree_occluded(scene, O, D, -1.0).any()
    assert embree_occluded(scene, O, D, np.r_[np.full(8, -1e-30), np.full(8, 5.0)]).tolist() == \
        [False] * 8 + [True] * 8
    assert (embree_intersect(scene, O, D, -1.0)[1] == -1).all()


def test_embree_rays_are_checked_as_ours(tracers):
    emb = tracers["embree"]
    scene = emb.scene
    for ask in (emb.intersect, emb.occluded, lambda o, d: embree_intersect(scene, o, d),
                lambda o, d: embree_occluded(scene, o, d, 5.0)):
        with pytest.raises(ParameterError, match=r"^dirs: must be \(n, 3\) with one row per "
                                                 r"origin \(16, 3\), got shape \(4, 3\)$"):
            ask(O, D[:4])
        with pytest.raises(ParameterError, match=r"^dirs: .*got shape \(1, 3\)$"):
            ask(np.repeat(O, 300, 0), D[:1])
        with pytest.raises(ParameterError, match=r"^origins: must be \(n, 3\), got shape \(8, 6\)$"):
            ask(O.reshape(-1, 6), D.reshape(-1, 6))
        with pytest.raises(ParameterError, match=r"^origins: must be \(n, 3\), got shape \(3,\)$"):
            ask(np.zeros(3), np.array([0, 0, 1.0]))
        with pytest.raises(ParameterError, match="^origins: must be real numbers, got complex64$"):
            ask(O.astype(np.complex64), D)
    with pytest.raises(ParameterError, match=r"^tmax: must be a scalar or one value per ray \(16,\)"):
        emb.intersect(O, D, tmax=np.ones(5))
    with pytest.raises(ParameterError, match="^tmax: must be a number or one per ray, got NaN"):
        embree_occluded(scene, O, D, np.nan)


def test_embree_meshes_are_checked():
    for make in (embree_scene, EmbreeTracer, shared_vertices):
        far = F.copy()
        far[0, 0] = 10**6
        with pytest.raises(ParameterError, match=r"^faces: face 0 has a vertex id outside "
                                                 r"\[0, 192\): \[1000000, 1, 2\]$"):
            make(V, far)
        far[0, 0] = -5
        with pytest.raises(ParameterError, match=r"^faces: face 0 has a vertex id outside"):
            make(V, far)
        with pytest.raises(ParameterError, match=r"^faces: must be \(m, 3\), got shape \(48, 4\)$"):
            make(V, F.reshape(-1, 4))
        with pytest.raises(ParameterError, match="^faces: must be integers .*got float64$"):
            make(V, F + 0.7)
        nan = V.copy()
        nan[5] = np.nan
        with pytest.raises(ParameterError, match="^vertices: vertex 5 has a NaN or infinite"):
            make(nan, F)
        with pytest.raises(ParameterError, match=r"^vertices: vertex 0 has a NaN or infinite"):
            make(np.full((3, 3), 1e39), [[0, 1, 2]])           # infinite in float32
        with pytest.raises(ParameterError, match=r"^vertices: must be \(k, 3\), got shape \(288, 2\)$"):
            make(V.reshape(-1, 2), F)
    with pytest.raises(ParameterError, match=r"^faces: face 0 has a vertex id outside \[0, 3\)"):
        shared_vertices(np.zeros((3, 3)), [[0, 1, 99]])
    Vs, Fs = shared_vertices(V, F)
    assert np.array_equal(Vs[Fs], V[F])


def test_a_tracer_refuses_triangles_that_are_not_its_trees(bvh):
    other = (np.random.default_rng(9).uniform(0, 1, (64, 1, 3))
             + np.random.default_rng(9).uniform(-.05, .05, (64, 3, 3))).astype(np.float32) + 3
    with pytest.raises(InputError, match=r"^triangles: a triangle lies outside its leaf's box "
                                         r"\(node \d+\): not the triangles the tree was built over$"):
        Tracer(bvh, triangles=other)
    swapped = hwbvh.build(TRIS)
    swapped.triangles = other
    with pytest.raises(InputError, match="^bvh.triangles: a triangle lies outside its leaf's box"):
        Tracer(swapped)
    with pytest.raises(InputError, match="^triangles: 10 triangles, but the tree has 64 primitives"):
        Tracer(bvh, triangles=TRIS[:10])
    nan = TRIS.copy()
    nan[0] = np.nan
    with pytest.raises(InputError, match="^triangles: triangle 0 has a NaN or infinite coordinate$"):
        Tracer(bvh, triangles=nan)
    with pytest.raises(InputError, match=r"^triangles: must have shape \(n, 3, 3\), got \(64, 9\)$"):
        Tracer(bvh, triangles=TRIS.reshape(-1, 9))
    with pytest.raises(InputError, match="^triangles: must be real numbers, got complex64$"):
        Tracer(bvh, triangles=TRIS.astype(np.complex64))
    with pytest.raises(ParameterError, match="^bvh: expected an hwbvh.Bvh"):
        Tracer({"nodes": bvh.nodes})


def test_a_tracer_takes_the_triangles_its_tree_was_built_over(bvh):
    """In their own precision: float64 triangles round to the float32 ones the builder boxed
    (every vertex nudged within its float32 rounding), and a refitted tree holds moved ones."""
    from hwbvh.refit import refit

    nudged = TRIS.astype(np.float64) + np.spacing(TRIS) * 0.4
    h = Tracer(bvh, triangles=nudged, precision="float64").intersect(O, D)
    assert (h.prim >= 0).all() and h.t.dtype == np.float64
    moved = TRIS + np.float32(0.25)
    h = Tracer(refit(bvh, moved)).intersect(O + np.float32(0.25), D)
    assert (h.prim >= 0).all()


def test_float64_triangles_past_their_float32_boxes_are_still_hit():
    """A float64 triangle sticks out of the box the builder made from its float32 rounding (here
    1e6 + 1.03 rounds to 1e6 + 1): the float64 units still hit it out there, at its own t and
    barycentrics, and nothing beyond it."""
    tri = np.array([[[1e6, 0, 0], [1e6 + 1.03, 0, 0], [1e6, 1, 0]]])
    assert np.float32(tri[0, 1, 0]) < tri[0, 1, 0]
    tracer = Tracer(hwbvh.build(tri), triangles=tri, precision="float64")
    o = np.array([[1e6 + 1.01, 0.001, 1.0], [1e6 + 1.02, 0.0001, 1.0], [1e6 + 1.04, 0.0001, 1.0]])
    h = tracer.intersect(o, np.array([[0.0, 0.0, -1.0]] * 3))
    assert h.prim.tolist() == [0, 0, -1]
    assert h.t[:2].tolist() == [1.0, 1.0]
    np.testing.assert_allclose(h.u[:2], [1.01 / 1.03, 1.02 / 1.03], rtol=1e-9)
    # the tree's own node buffer is left as the builder wrote it
    np.testing.assert_array_equal(tracer.nodes, hwbvh.build(tri).nodes)


def test_edge_eps_must_be_a_finite_number_at_least_zero_and_small(bvh):
    for bad in (-1.0, np.nan, np.inf, "x", True, 1.0, 1e300):
        with pytest.raises(ParameterError, match=r"^edge_eps: must be a finite number in \[0, 0.001\], "
                                                 r"got") as e:
            Tracer(bvh, edge_eps=bad)
        assert e.value.parameter == "edge_eps"
    assert (Tracer(bvh, edge_eps=0).intersect(O, D).prim >= 0).all()


def test_rays_and_bounds_that_are_not_real_numbers_are_refused(tracers):
    for name, tracer in tracers.items():
        with pytest.raises(ParameterError, match="^origins: must be real numbers, got complex64$"):
            tracer.intersect(O.astype(np.complex64) + 5j, D)
        with pytest.raises(ParameterError, match="^dirs: must be real numbers, got bool$"):
            tracer.occluded(O, D != 0)
        with pytest.raises(ParameterError, match="^origins: must be real numbers, got object$"):
            tracer.intersect(O.astype(object), D)
        with pytest.raises(ParameterError, match="^tmax: must be real numbers, got complex128$"):
            tracer.intersect(O, D, tmax=10 + 5j)
        with pytest.raises(ParameterError, match="^tmin: must be real numbers, got bool$"):
            tracer.occluded(O, D, tmin=np.zeros(16, bool))
        # integers, lists, float16/float64 and big-endian floats are real numbers
        assert (tracer.intersect(O.astype(">f4").tolist(), D.astype(np.int64)).prim >= 0).all(), name
    for make in (GridTracer, KdTreeTracer):
        with pytest.raises(ParameterError, match="^triangles: must be real numbers, got complex64$"):
            make(TRIS.astype(np.complex64))
        with pytest.raises(ParameterError, match="^triangles: must be real numbers, got bool$"):
            make(TRIS > 0.5)


def test_argument_errors_are_parameter_errors_naming_the_parameter(bvh, tracers):
    """ParameterError is a ValueError: callers that catch ValueError still do."""
    cases = [
        ("precision", lambda: Tracer(bvh, precision="float16")),
        ("dirs", lambda: tracers["bvh"].intersect(O, D[:5])),
        ("tmin", lambda: tracers["grid"].intersect(O, D, tmin=-1.0)),
        ("tmax", lambda: tracers["kdtree"].occluded(O, D, tmax=np.ones(3))),
        ("resolution", lambda: GridTracer(TRIS, resolution=0)),
        ("resolution", lambda: GridTracer(TRIS, resolution=2.5)),
        ("triangles", lambda: KdTreeTracer(np.zeros((4, 3), np.float32))),
        ("triangles", lambda: GridTracer(np.zeros((4, 9), np.float32))),
        ("n", lambda: verify_mesh(TRIS, V, F, n=-5)),
        ("n", lambda: verify_mesh(TRIS, V, F, n=16.5)),
        ("n", lambda: verify_mesh(TRIS, V, F, n=(1 << 26) + 1)),
        ("seed", lambda: verify_mesh(TRIS, V, F, seed=-1)),
        ("seed", lambda: verify_mesh(TRIS, V, F, seed=1.5)),
        ("seed", lambda: verify_mesh(TRIS, V, F, seed="7")),
        ("kind", lambda: verify_mesh(TRIS, V, F, kind="bogus")),
        ("accel", lambda: verify_mesh(TRIS, V, F, accel="bogus")),
        ("kind", lambda: CountingTracer(tracers["bvh"]).work("bogus")),
        ("inner", lambda: CountingTracer(tracers["embree"])),
        ("packets", lambda: Tracer(bvh, packets="no")),
        ("packets", lambda: GridTracer(TRIS, packets="no")),
        ("watertight", lambda: Tracer(bvh, watertight=1)),
        # a tracer or a reference over other geometry than the triangles checked: refused,
        # not reported as mismatches
        ("tracer", lambda: verify_mesh(TRIS, V, F, tracer="x")),
        ("bvh", lambda: verify_mesh(TRIS, V, F, bvh=hwbvh.build(TRIS[:-1]))),
        ("target", lambda: primary_rays((0, 0, 0), (0, 0, 0), (0, 1, 0), 40, 2, 2)),
        ("width", lambda: primary_rays((0, 0, 0), (0, 0, -1), (0, 1, 0), 40, 2.5, 2)),
        ("fov_deg", lambda: primary_rays((0, 0, 0), (0, 0, -1), (0, 1, 0), 180, 2, 2)),
        ("eye", lambda: primary_rays((0, 0), (0, 0, -1), (0, 1, 0), 40, 2, 2)),
        ("jitter", lambda: primary_rays((0, 0, 0), (0, 0, -1), (0, 1, 0), 40, 2, 2,
                                        np.zeros((3, 2)))),
        ("tracer", lambda: verify_mesh(TRIS[:-1], V[:-3], F[:-1], tracer=tracers["grid"])),
        ("scene", lambda: verify_rays(tracers["bvh"], None, TRIS, O, D)),
        ("tracer", lambda: verify_rays(None, embree_scene(V, F), TRIS, O, D)),
        ("scene", lambda: verify_rays(tracers["bvh"], embree_scene(V + 0.5, F), TRIS, O, D)),
        ("scene", lambda: verify_rays(tracers["bvh"], embree_scene(V * 3.0, F), TRIS, O, D)),
        ("inner", lambda: VerifyingTracer(tracers["kdtree"], TRIS[:-1], V[:-3], F[:-1])),
        ("inner", lambda: VerifyingTracer(object(), TRIS, V, F)),
        ("faces", lambda: VerifyingTracer(tracers["bvh"], TRIS, V, F[::-1])),
        ("triangles", lambda: VerifyingTracer(tracers["bvh"], TRIS[0], V, F)),
    ]
    for parameter, call in cases:
        with pytest.raises(ParameterError) as e:
            call()
        assert e.value.parameter == parameter, (parameter, str(e.value))
        assert "\n" not in str(e.value) and str(e.value).startswith(parameter + ": ")
        assert isinstance(e.value, ValueError)


def test_a_refused_query_is_not_recorded(tracers):
    recording = RecordingTracer(tracers["bvh"])
    with pytest.raises(ParameterError):
        recording.intersect(O, D, tmax=None)
    recording.occluded(O, D)
    assert recording.rays() == 16 and [q[0] for q in recording.queries] == ["occluded"]


def _mesh_at(scale):
    """The prelude's triangles and rays scaled by ``scale`` (rays from three mesh sizes away)."""
    t = (TRIS.astype(np.float64) * scale).astype(np.float32)
    o = t.astype(np.float64).mean(axis=1)
    o[:, 2] = 3 * scale
    d = np.zeros((64, 3), np.float32)
    d[:, 2] = -1
    return t, o.astype(np.float32), d


def test_the_float32_units_domain_is_as_documented():
    """traversal.structure states the float32 unit's domain (its t numerator, edge x edge x
    origin distance, overflows float32): every float32 tracer traces the mesh whole up to
    coordinates of 1.3e13 and refuses it, naming the origins and the float64 units, from 1.4e13
    (past the products' guaranteed bound); the unit itself, unchecked, keeps every hit up to
    2.5e13 and loses them at 1e14, where the float64 units still find every one (up to the
    builder's bound)."""
    def finite_hits(tracer, o, d):
        h = tracer.intersect(o, d)
        return int(((h.prim >= 0) & np.isfinite(h.t)).sum())

    def float32_tracers(t):
        return Tracer(hwbvh.build(t)), GridTracer(t), KdTreeTracer(t)

    t, o, d = _mesh_at(1.3e13)
    assert [finite_hits(tr, o, d) for tr in float32_tracers(t)] == [64, 64, 64]
    for scale in (1.4e13, 2.5e13, 1e14):
        t, o, d = _mesh_at(scale)
        for tr in float32_tracers(t):
            with pytest.raises(ParameterError, match=r"^origins: origins up to .* beyond the "
                                                     r"8.51e\+37 .*precision='float64'"):
                tr.intersect(o, d)
            with pytest.raises(ParameterError, match=r"^origins: "):
                tr.occluded(o, d)
    unchecked = []
    for scale in (2.5e13, 1e14):
        t, o, d = _mesh_at(scale)
        tr = Tracer(hwbvh.build(t))
        tr.unit_range = None                 # the unit's own reach, past the guaranteed bound
        unchecked.append(finite_hits(tr, o, d))
    assert unchecked[0] == 64 and unchecked[1] < 32
    assert finite_hits(Tracer(hwbvh.build(t), precision="float64"), o, d) == 64
    t, o, d = _mesh_at(9.9e14 / 1.06)
    assert finite_hits(Tracer(hwbvh.build(t), precision="float64"), o, d) == 64


def test_float32_rays_are_checked_against_the_units_range():
    """The check bounds every product of the unit, the direction's length in them: far origins
    on a small mesh are traced (their products stay small), as are long directions; on a mesh
    a million times larger, directions long enough to take the products past the bound are
    refused naming ``dirs`` (unchecked, the unit loses hits there); a NaN ray passes over the
    check (it misses), and so does an infinite one; a finite one far enough is refused."""
    from traversal.triangle_unit import ray_magnitudes
    x = np.array([np.nan, -np.inf, -123.5, 2.0, np.inf, -0.0], np.float32)
    dirs = np.array([2.0, -0.0, 1.0, np.nan, 9.0, 1.0, 0.0, 0.0, 0.0, 0.0, -0.5, 0.25],
                    np.float32)         # rows: (2, -0, 1), a NaN row, a zero row, (0, -0.5, 0.25)
    assert ray_magnitudes(x, dirs) == (123.5, 2.0, 0.5)
    assert ray_magnitudes(x[:2], x[:0]) == (0.0, 0.0, np.inf)
    tr = Tracer(hwbvh.build(TRIS))
    far = O.copy()
    far[:, 2] = np.float32(1e30)
    np.testing.assert_array_equal(tr.intersect(far, D).prim,
                                  Tracer(hwbvh.build(TRIS), precision="float64").intersect(
                                      far, D).prim)
    np.testing.assert_array_equal(tr.intersect(O, D * np.float32(1e37)).prim,
                                  tr.intersect(O, D).prim)
    big, o = TRIS * np.float32(1e6), O * np.float32(1e6)
    tr = Tracer(hwbvh.build(big))
    hit = tr.intersect(o, D).prim
    assert (hit >= 0).all()
    with pytest.raises(ParameterError, match=r"^dirs: directions up to 1e\+30 long take the "
                                             r"float32 unit's products to .*precision='float64'") \
            as caught:
        tr.intersect(o, D * np.float32(1e30))
    e = caught.value               # the way out apart, for a caller whose way out is another
    assert e.remedy.startswith("trace with traversal.Tracer(precision='float64')")
    assert e.finding.endswith("(hits would be lost)") and e.problem == f"{e.finding}: {e.remedy}"
    tr.unit_range = None
    assert (tr.intersect(o, D * np.float32(1e30)).prim == hit).mean() < 0.5
    tr = Tracer(hwbvh.build(big))
    o[0] = np.nan
    o[1, 0] = np.inf
    assert (tr.intersect(o, D).prim[:2] == -1).all()
    o[2, 2] = np.float32(1e33)
    with pytest.raises(ParameterError, match=r"^origins: origins up to 1e\+33 from"):
        tr.occluded(o, D)


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("side", ["min", "max"])
def test_a_vertex_one_ulp_outside_its_leaf_is_refused(bvh, axis, side):
    """Each bound of each leaf is checked: the scene's outermost vertex on one side of one axis,
    moved one float32 ulp further out, leaves its leaf's box (and the root's)."""
    moved = TRIS.copy()
    flat = moved.reshape(-1, 3)
    k = int(np.argmin(flat[:, axis]) if side == "min" else np.argmax(flat[:, axis]))
    flat[k, axis] = np.nextafter(flat[k, axis], np.float32(-np.inf if side == "min" else np.inf))
    with pytest.raises(InputError, match=r"^triangles: a triangle lies outside its leaf's box"):
        Tracer(bvh, triangles=moved)
    Tracer(bvh, triangles=TRIS)


def test_float64_rays_are_checked_against_the_units_range():
    """The float64 units take origins far beyond the builder's coordinates, up to where their
    products would pass a quarter of float64's range; beyond, the rays are refused naming
    ``origins`` (unchecked, most answers are a miss or a hit at t = inf)."""
    big = TRIS.astype(np.float64) * 1e6
    tr = Tracer(hwbvh.build(big), precision="float64")
    aim = big.mean(axis=1)                              # straight down onto each centroid
    down = np.tile([0.0, 0.0, -1.0], (len(aim), 1))
    for z in (1e30, 1e250, 1e290):
        assert (tr.intersect(aim + [0, 0, z], down).prim >= 0).all()
    far = aim + [0, 0, 1e300]
    with pytest.raises(ParameterError, match=r"^origins: origins up to 1e\+300 from the "
                                             r"triangles take the float64 unit's products to "
                                             r".* beyond the 4.49e\+307 .*: scale the scene down$"):
        tr.intersect(far, down)
    tr.unit_range = None
    h = tr.intersect(far, down)
    assert ((h.prim == -1) | (h.t == np.inf)).mean() > 0.5


def test_the_float32_units_refuse_what_they_would_trace_as_misses():
    """The float32 units refuse what they would trace as misses, naming what to change:
    triangles of 1e-20 (every determinant below float32's normal range), and origins or
    directions past float32's range (infinity once converted). The float64 units trace them."""
    import hwbvh
    from hwbvh.errors import ParameterError
    from traversal import Tracer
    from traversal.grid import GridTracer
    from traversal.kdtree import KdTreeTracer
    unit = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float32)
    tiny = unit.astype(np.float64) * 1e-20
    for make in (lambda: Tracer(hwbvh.build(tiny)), lambda: GridTracer(tiny),
                 lambda: KdTreeTracer(tiny)):
        with pytest.raises(ParameterError, match=r"triangles: too small for the float32 unit: "
                                                 r"the largest \|e1\| \|e2\| of its triangles"):
            make()
    f64 = Tracer(hwbvh.build(tiny), precision="float64")
    assert f64.intersect([[2e-21, 2e-21, 1e-20]], [[0, 0, -1.0]]).prim[0] == 0
    assert Tracer(hwbvh.build(unit * 1e-12)).intersect(
        [[2e-13, 2e-13, 1e-12]], [[0, 0, -1.0]]).prim[0] == 0
    tracer = Tracer(hwbvh.build(unit))
    for name, o, d in (("origins", [[0.2, 0.2, 1e39]], [[0, 0, -1.0]]),
                       ("dirs", [[0.2, 0.2, 1.0]], [[0, 0, -1e39]])):
        with pytest.raises(ParameterError, match=f"{name}: holds 1e\\+39, beyond float32's range"):
            tracer.intersect(np.array(o), np.array(d))
        with pytest.raises(ParameterError, match=f"{name}: holds 1e\\+39"):
            tracer.occluded(np.array(o), np.array(d))
    assert tracer.intersect([[0.2, 0.2, 1.0]], [[0, 0, -1.0]]).prim[0] == 0


def test_flags_and_odd_arguments_are_refused_by_name():
    """A flag takes True or False only (a string such as "no" would read as True), and odd
    arguments are ParameterErrors or InputErrors naming the argument, not NumPy's or Python's
    own errors."""
    from types import SimpleNamespace
    from traversal.verify import verify_rays
    unit = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float32)
    bvh = hwbvh.build(unit)
    tracer = Tracer(bvh)
    o, d = [[0.2, 0.2, 1.0]], [[0, 0, -1.0]]
    for kw in ({"normals": "no"}, {"counters": "no"}, {"as_run": 1}):
        with pytest.raises(ParameterError, match=f"{next(iter(kw))}: must be True or False"):
            tracer.intersect(o, d, **kw)
    for other in (GridTracer(unit), EmbreeTracer(unit.reshape(-1, 3), np.arange(3).reshape(1, 3))):
        with pytest.raises(ParameterError, match="normals: must be True or False, got 'no'"):
            other.intersect(o, d, normals="no")
    with pytest.raises(ParameterError, match="validate_tree: must be True or False"):
        hwbvh.build(unit, validate_tree="no")
    for indices, got in (("abc", "<U3"), (None, "None")):
        with pytest.raises(InputError, match=f"bvh.indices: must be an array of integers, got "
                                             f"{got}"):
            Tracer(SimpleNamespace(nodes=bvh.nodes, indices=indices, triangles=unit))
    with pytest.raises(ParameterError, match="O: must be real numbers, got None"):
        verify_rays(tracer, embree_scene(unit.reshape(-1, 3), np.arange(3).reshape(1, 3)), unit,
                    None, d)
    with pytest.raises(ParameterError, match="path: expected a mesh file's path, got NoneType"):
        hwbvh.load_triangles(None)
    from hwbvh.cycle_model import simulate_mesh
    with pytest.raises(ParameterError, match=r"preset: expected a HwParams or a preset name"):
        simulate_mesh(unit, ["x"])


def test_a_tree_not_from_the_builder_is_validated_before_it_is_traced():
    """A tree that hwbvh did not build, load or refit is validated before it is traced (a child
    box shrunk inside it would make every ray miss); one it did is taken as it is (validating
    costs 7 ms on 262k triangles, which a timed build would pay)."""
    import dataclasses
    from types import SimpleNamespace
    from hwbvh.refit import Refitter
    tris = (np.random.default_rng(0).uniform(0, 1, (200, 1, 3))
            + np.random.default_rng(1).uniform(-0.05, 0.05, (200, 3, 3))).astype(np.float32)
    bvh = hwbvh.build(tris)
    shrunk = bvh.nodes.copy()
    shrunk["bounds"][0] = [0, 0, 0, 0.1, 0.1, 0.1]
    for tree in (SimpleNamespace(nodes=shrunk, indices=bvh.indices, triangles=tris),
                 dataclasses.replace(bvh, nodes=shrunk)):
        with pytest.raises(InputError, match="bvh.nodes: invalid tree: child AABB is not inside "
                                             "its parent's"):
            Tracer(tree)
    refitted = Refitter(bvh).refit(tris + np.float32(0.01))
    for tree in (bvh, refitted, SimpleNamespace(nodes=bvh.nodes, indices=bvh.indices,
                                                triangles=tris)):
        assert Tracer(tree).intersect([[0.5, 0.5, 5.0]], [[0, 0, -1.0]]).prim[0] >= 0
    assert refitted._invariants_hold and not getattr(
        dataclasses.replace(bvh, nodes=shrunk), "_invariants_hold", False)


@pytest.mark.parametrize("make", ["bvh", "grid", "kdtree"])
def test_directions_too_short_for_the_float32_unit_are_refused_not_traced_to_lost_hits(make):
    """The unit's determinant is at most |d| |e1| |e2|: directions short enough take it below
    float32's normal numbers and lose hits (at 1e-36 on unit-sized triangles, unchecked, a
    third and more of them); such a batch is refused naming ``dirs``, as the triangles' own
    floor is for unit directions. The float64 units trace them; a zero direction (it hits
    nothing anywhere) is passed over, as are directions of a tiny scene of about unit
    length."""
    from traversal.grid import GridTracer
    from traversal.kdtree import KdTreeTracer
    tracer = {"bvh": lambda t: Tracer(hwbvh.build(t)), "grid": GridTracer,
              "kdtree": KdTreeTracer}[make]
    tr = tracer(TRIS)
    hits = tr.intersect(O, D).prim
    assert (hits >= 0).sum() > 10
    for call in (lambda d: tr.intersect(O, d), lambda d: tr.occluded(O, d)):
        with pytest.raises(ParameterError, match=r"^dirs: directions whose largest coordinate "
                                                 r"is as small as 1e-36.* too close to float32's "
                                                 r"subnormal numbers \(hits would be lost\): give "
                                                 r"directions of about unit length"):
            call(D * np.float32(1e-36))
    from types import SimpleNamespace
    tr.unit_range = SimpleNamespace(check=lambda o, d: None)   # unchecked: the hits it loses
    assert (tr.intersect(O, D * np.float32(1e-36)).prim != hits).sum() > 0
    if make == "bvh":
        wide = Tracer(hwbvh.build(TRIS), precision="float64")
        np.testing.assert_array_equal(wide.intersect(O, D * 1e-36).prim, wide.intersect(O, D).prim)
    still = D.copy()
    still[0] = 0
    np.testing.assert_array_equal(tracer(TRIS).intersect(O, still).prim[1:], hits[1:])
    tiny = tracer(TRIS * np.float32(1e-12))
    np.testing.assert_array_equal(tiny.intersect(O * np.float32(1e-12), D).prim, hits)


@pytest.mark.parametrize("call, name", [
    (lambda r: r.primary(TRIS, -1), "n"), (lambda r: r.primary(TRIS, 1.5), "n"),
    (lambda r: r.primary(TRIS, True), "n"), (lambda r: r.primary_chunks(TRIS, 0), "n"),
    (lambda r: r.incoherent(np.zeros((3, 3)), 5), "tris"),
    (lambda r: r.incoherent(TRIS[:0], 5), "tris"),
    (lambda r: r.incoherent(TRIS.astype(bool), 5), "tris"),
    (lambda r: r.incoherent(TRIS, 10, seed=True), "seed"),
    (lambda r: r.incoherent_chunks(TRIS, 10, seed=-1), "seed"),
    (lambda r: r.primary(TRIS, 4, dtype=np.int32), "dtype"),
    (lambda r: r.incoherent(TRIS, 4, dtype="foo"), "dtype"),
    (lambda r: r.shadow(Tracer(hwbvh.build(TRIS)), TRIS, 0), "n"),
    (lambda r: r.bounces(Tracer(hwbvh.build(TRIS)), TRIS, 5, seed=1.0), "seed")])
def test_ray_sets_name_a_bad_argument_before_any_work(call, name):
    from traversal import raysets
    with pytest.raises(ParameterError) as caught:
        call(raysets)
    assert caught.value.parameter == name


def test_verify_mesh_refuses_triangles_its_mesh_does_not_index_before_building():
    from traversal.verify import verify_mesh
    V = TRIS.reshape(-1, 3)
    F = np.arange(len(V)).reshape(-1, 3)
    with pytest.raises(ParameterError, match="^faces: vertices\\[faces\\] are not the triangles"):
        verify_mesh(TRIS[:10], V, F, n=100)
    counts = verify_mesh(TRIS, V, F, n=100)[0]
    assert counts["mismatch"] == 0


def test_the_sweep_builder_refuses_the_knobs_it_does_not_take():
    with pytest.raises(ParameterError, match="^leaf_size: the sweep builder takes none"):
        hwbvh.build(TRIS, builder="sweep", leaf_size=8)
    with pytest.raises(ParameterError, match="^bins: the sweep builder takes none"):
        hwbvh.build(TRIS, builder="sweep", bins=2)
    assert hwbvh.build(TRIS, builder="sweep", leaf_size=hwbvh.config.DEFAULT_LEAF_SIZE).meta[
        "builder"] == "sweep"


def test_verifying_a_zero_direction_ray_warns_of_nothing():
    """A zero direction is a miss by definition, for both tracers: agreed, with no warning."""
    import warnings
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float32)
    O = np.array([[0.2, 0.2, 1], [0.2, 0.2, 1]], np.float32)
    D = np.array([[0, 0, -1], [0, 0, 0]], np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        counts = verify_rays(Tracer(hwbvh.build(tri)), embree_scene(tri.reshape(-1, 3),
                                                                    np.arange(3).reshape(1, 3)),
                             tri, O, D)[0]
    assert counts == {"rays": 2, "agree": 2, "tie": 0, "mismatch": 0, "hit": 1}


def test_a_mesh_that_holds_its_faces_both_ways_round_passes_the_scene_probe():
    """A double-sided mesh (every face twice, the second reversed) is the scene it says: the
    probe takes Embree's hit on either copy."""
    rng = np.random.default_rng(4)      # a jittered sheet: Embree takes either copy
    g = np.stack(np.meshgrid(np.arange(6.0), np.arange(6.0)), -1).reshape(-1, 2)
    V = np.c_[g[:, 0] + rng.uniform(-.2, .2, len(g)), rng.uniform(-.05, .05, len(g)),
              g[:, 1] + rng.uniform(-.2, .2, len(g))].astype(np.float32)
    F = np.array([[i * 6 + j, i * 6 + j + 1, i * 6 + j + 6] for i in range(5) for j in range(5)] +
                 [[i * 6 + j + 1, i * 6 + j + 7, i * 6 + j + 6] for i in range(5) for j in range(5)])
    F = np.r_[F, F[:, ::-1]]
    tris = V[F]
    O = np.c_[np.linspace(0.3, 4.7, 32), np.full(32, 2.0), np.linspace(4.6, 0.2, 32)]
    D = np.tile([0.0, -1.0, 0.0], (32, 1))
    counts = verify_rays(Tracer(hwbvh.build(tris)), embree_scene(V, F), tris,
                         O.astype(np.float32), D.astype(np.float32))[0]
    assert counts["rays"] == 32 and counts["mismatch"] == 0


def test_a_loaded_tree_without_its_triangles_says_where_they_are(tmp_path):
    """A tree read by hwbvh.load carries no triangles; the error names the mesh it was built
    from, and the triangles read from it make the tracer."""
    mesh = tmp_path / "quad.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n")
    hwbvh.save(hwbvh.build(str(mesh)), tmp_path / "t")
    loaded = hwbvh.load(tmp_path / "t")
    with pytest.raises(InputError, match=f"built from {mesh}") as e:
        Tracer(loaded)
    assert "\n" not in str(e.value)
    tracer = Tracer(loaded, triangles=hwbvh.load_triangles(loaded.meta["source"]))
    hit = tracer.intersect(np.array([[0.5, 0.25, 1.0]]), np.array([[0.0, 0.0, -1.0]]))
    assert hit.prim[0] >= 0 and hit.t[0] == 1.0


def test_triangles_in_half_precision_or_a_foreign_byte_order_are_traced_as_float32(bvh):
    """The builder takes them; the tracer's kernels are compiled for native float32 and
    float64 only, and Numba's typing error leaked."""
    want = Tracer(bvh).intersect(O, D).prim
    for dtype in (">f4", ">f8"):
        tracer = Tracer(bvh, triangles=TRIS.astype(dtype))
        assert tracer.tris.dtype == np.float32 and np.array_equal(tracer.intersect(O, D).prim, want)
    # rounded to half precision they are other triangles than the tree's, and said to be
    with pytest.raises(InputError, match="not the triangles the tree was built over"):
        Tracer(bvh, triangles=TRIS.astype(np.float16))


def test_an_object_array_of_text_or_truth_values_is_not_triangles():
    """A cast would parse the text ("1") and take True as 1, as a text or bool array is not."""
    for bad in (np.full((2, 3, 3), "1", object), np.full((2, 3, 3), b"1", object),
                np.full((2, 3, 3), True, object)):
        with pytest.raises(InputError, match="triangles must be real numbers, got an object array "
                                             "holding text or truth values"):
            hwbvh.as_triangles(bad)
    assert hwbvh.as_triangles(TRIS.astype(object)).shape == TRIS.shape


def test_verify_rays_refuses_bounds_not_one_per_ray_and_a_flag_that_is_not_one(bvh):
    from traversal.embree_ref import embree_scene
    scene = embree_scene(V, F)
    for kw, message in ((dict(tmax=np.full(len(O) + 3, 9.0)), r"^tmax: must be a number or one "
                                                               r"per ray \(16\), got shape \(19,\)"),
                        (dict(tmax=[9.0] * 10), r"^tmax: must be a number or one per ray"),
                        (dict(anyhit="no"), "^anyhit: must be True or False")):
        with pytest.raises(ParameterError, match=message):
            verify_rays(Tracer(bvh), scene, TRIS, O, D, **kw)
    counts = verify_rays(Tracer(bvh), scene, TRIS, O, D, tmax=np.full(len(O), 9.0))[0]
    assert counts["hit"] == len(O)
