"""The uniform grid: every answer against the BVH traversal (same triangle unit, same tie rule,
so the same answers bit for bit), Embree and a float64 brute force, on the hard ray cases; its
memory bounded on degenerate input; the CLI's --accel."""
import json

import numpy as np
import pytest

import hwbvh
from hwrt.cli import main
from raytracer.render import make_tracer, render
from scenes import compile_scene, load_scene
from traversal import Tracer, raysets
from traversal.config import GRID_MAX_CELLS, GRID_MAX_REFS_PER_TRI
from traversal.embree_ref import embree_intersect, embree_scene
from traversal.grid import GridTracer, density_resolution
from traversal.verify import classify

from .naive import ray_triangle_f64


def tessellated_cube(k):
    """The unit cube's surface, each face k x k quads of two triangles: vertices on the 1/k
    lattice, so many rays run exactly through shared edges and vertices."""
    tris = []
    s = np.linspace(0.0, 1.0, k + 1)
    for axis in range(3):
        a, b = (axis + 1) % 3, (axis + 2) % 3
        for side in (0.0, 1.0):
            for i in range(k):
                for j in range(k):
                    q = []
                    for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        p = np.zeros(3)
                        p[axis] = side
                        p[a] = s[i + di]
                        p[b] = s[j + dj]
                        q.append(p)
                    tris += [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
    return np.asarray(tris, np.float32)


def sphere(n_lat=24, n_lon=48):
    th = np.linspace(0, np.pi, n_lat + 1)
    ph = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    v = np.stack([np.outer(np.sin(th), np.cos(ph)), np.outer(np.sin(th), np.sin(ph)),
                  np.outer(np.cos(th), np.ones_like(ph))], -1).reshape(-1, 3)
    faces = []
    for i in range(n_lat):
        for j in range(n_lon):
            a, b = i * n_lon + j, i * n_lon + (j + 1) % n_lon
            c, d = a + n_lon, b + n_lon
            faces += [[a, c, d], [a, d, b]]
    faces = np.asarray(faces, np.int32)
    keep = np.array([len({*f}) == 3 for f in faces])
    return v.astype(np.float32), faces[keep]


def soup(n, seed):
    rng = np.random.default_rng(seed)
    centres = rng.random((n, 1, 3))
    return (centres + rng.normal(scale=0.03, size=(n, 3, 3))).astype(np.float32)


def bvh_tracer(tris):
    return Tracer(hwbvh.build(tris))


def same_as_bvh(grid, bvh, o, d, tmin=0.0, tmax=np.inf):
    g = grid.intersect(o, d, tmin, tmax)
    b = bvh.intersect(o, d, tmin, tmax)
    np.testing.assert_array_equal(g.prim, b.prim)
    np.testing.assert_array_equal(g.t, b.t)
    np.testing.assert_array_equal(g.ng, b.ng)
    np.testing.assert_array_equal(grid.occluded(o, d, tmin, tmax), bvh.occluded(o, d, tmin, tmax))
    return g


def packets_as_single_rays(grid, bvh, o, d, tmin=0.0, tmax=np.inf):
    """The batch through the packet path and ray by ray: the same answers bit for bit, and
    (unless ``bvh`` is None) the BVH's. Returns the packets the closest-hit query traced."""
    grid.packets = False
    single = grid.intersect(o, d, tmin, tmax)
    blocked = grid.occluded(o, d, tmin, tmax)
    grid.packets = True
    h = grid.intersect(o, d, tmin, tmax) if bvh is None else \
        same_as_bvh(grid, bvh, o, d, tmin, tmax)
    traced = grid.last_packets
    np.testing.assert_array_equal(h.prim, single.prim)
    np.testing.assert_array_equal(h.t, single.t)
    np.testing.assert_array_equal(h.u, single.u)
    np.testing.assert_array_equal(h.v, single.v)
    np.testing.assert_array_equal(h.ng, single.ng)
    np.testing.assert_array_equal(grid.occluded(o, d, tmin, tmax), blocked)
    return traced


def agrees_with_embree(tris, vertices, faces, hits, o, d):
    te, pe, *_ = embree_intersect(embree_scene(vertices, faces), o, d)
    counts, _ = classify(tris, o, d, 0.0, np.inf, hits.prim.astype(np.int64), hits.t, pe, te)
    assert counts["mismatch"] == 0, counts
    return counts


def indexed(tris):
    return tris.reshape(-1, 3), np.arange(3 * len(tris), dtype=np.int32).reshape(-1, 3)


def closest_f64(o, d, tris, tmin):
    """(t, clear): the float64 brute force's least t above ``tmin`` (inf: none), counting hits
    within the float32 unit's slack of an edge too, and whether that hit lies clearly inside
    its triangle (a hit on an edge may go either way in float32)."""
    best, clear = np.inf, False
    for tri in tris:
        _, t, u, v = ray_triangle_f64(o, d, tri)
        if min(u, v, 1 - u - v) > -1e-5 and tmin < t < best:
            best, clear = t, min(u, v, 1 - u - v) > 1e-3
    return best, clear


def lattice_rays():
    """Axis-parallel rays on the vertex lattice of ``tessellated_cube`` (through shared edges
    and vertices), starting outside and inside, and diagonals through lattice vertices."""
    lattice = np.linspace(0.0, 1.0, 9)
    O, D = [], []
    for axis in range(3):
        a, b = (axis + 1) % 3, (axis + 2) % 3
        for x in lattice:
            for y in lattice:
                for start, sign in ((-0.5, 1.0), (1.5, -1.0), (0.5, 1.0), (0.5, -1.0)):
                    o = np.zeros(3)
                    o[axis], o[a], o[b] = start, x, y
                    d = np.zeros(3)
                    d[axis] = sign
                    O.append(o)
                    D.append(d)
    for x in lattice:
        for y in lattice:
            O.append([x - 0.5, y - 0.5, -0.5])
            D.append([1.0, 1.0, 1.0])
    return O, D


def plane_rays(rng, axes, positions, n):
    """``n`` rays whose origins lie on one of the planes (axis ``axes[i]`` at ``positions[i]``),
    half of them parallel to it (in the plane), some axis-parallel along it."""
    O, D = [], []
    for _ in range(n):
        o = rng.uniform(-0.2, 1.2, 3)
        i = rng.integers(len(axes))
        k = axes[i]
        o[k] = positions[i]                                   # origin on the plane
        d = rng.normal(size=3)
        if rng.random() < 0.5:
            d[k] = 0.0                                        # and in it
        if rng.random() < 0.3:
            d[(k + 1) % 3] = 0.0                              # axis-parallel along the plane
        O.append(o)
        D.append(d)
    return O, D


def hard_rays(grid, rng):
    """``lattice_rays`` and rays whose origins lie on cell planes (``plane_rays``)."""
    O, D = lattice_rays()
    cs = (grid.gmax - grid.gmin) / np.asarray(grid.resolution)
    axes = np.concatenate([np.full(grid.resolution[k] + 1, k) for k in range(3)])
    positions = np.concatenate([grid.gmin[k] + cs[k] * np.arange(grid.resolution[k] + 1)
                                for k in range(3)])
    o, d = plane_rays(rng, axes, positions, 400)
    return np.asarray(O + o, np.float32), np.asarray(D + d, np.float32)


def mesh_case(mesh):
    """(triangles, vertices, faces) of the "sphere" (indexed) or the "soup" test mesh."""
    if mesh == "sphere":
        vertices, faces = sphere()
        return vertices[faces], vertices, faces
    tris = soup(3000, 1)
    return (tris, *indexed(tris))


def brute_force_agrees(h, o, d, tris, step=7):
    """Every ``step``-th ray: where the float64 brute force's closest hit lies clearly inside a
    triangle, ``h`` has the same t. Returns the number of rays so checked."""
    checked = 0
    for i in range(0, len(o), step):
        best, clear = closest_f64(o[i], d[i], tris, 1e-6)
        if clear:
            assert abs(h.t[i] - best) <= 1e-5 * (1 + best), (i, h.t[i], best)
            checked += 1
    return checked


def test_hard_rays_match_the_bvh_embree_and_the_float64_brute_force():
    tris = tessellated_cube(4)
    grid = GridTracer(tris)
    bvh = bvh_tracer(tris)
    rng = np.random.default_rng(3)
    o, d = hard_rays(grid, rng)
    h = same_as_bvh(grid, bvh, o, d)
    assert (h.prim >= 0).mean() > 0.5
    agrees_with_embree(tris, *indexed(tris), h, o, d)
    # float64 brute force: where its closest hit lies clearly inside a triangle, the same t
    assert brute_force_agrees(h, o, d, tris) > 10
    # intervals: random [tmin, tmax] on the same rays, with explicit resolutions (cell planes
    # on the lattice and off it)
    lo = rng.uniform(0.0, 1.0, len(o)).astype(np.float32)
    hi = (lo + rng.uniform(0.0, 1.5, len(o))).astype(np.float32)
    for res in ((4, 4, 4), (1, 7, 3), 1):
        same_as_bvh(GridTracer(tris, resolution=res), bvh, o, d, lo, hi)


@pytest.mark.parametrize("mesh", ["sphere", "soup"])
def test_no_mismatch_against_embree(mesh):
    tris, vertices, faces = mesh_case(mesh)
    grid = GridTracer(tris)
    bvh = bvh_tracer(tris)
    for kind, (o, d) in (("primary", raysets.primary(tris, 6000)),
                         ("incoherent", raysets.incoherent(tris, 6000, 2))):
        h = same_as_bvh(grid, bvh, o, d)
        counts = agrees_with_embree(tris, vertices, faces, h, o, d)
        assert counts["agree"] > 0.99 * counts["rays"]
        # camera rays in pixel tiles go as packets, random ones ray by ray
        assert (grid.last_packets == 6000 // 16) if kind == "primary" else (grid.last_packets == 0)


def shared_sign_groups(d):
    """Groups of 16 consecutive rays whose directions have one strict sign on some axis: those
    the grid traces as packets."""
    g = np.asarray(d)[:len(d) // 16 * 16].reshape(-1, 16, 3)
    return int(((g > 0).all(1) | (g < 0).all(1)).any(1).sum())


def packet_groups(rng, origins, direction, spread):
    """Groups of 16 rays: origins as given, directions ``direction`` plus up to ``spread`` of
    noise per component, so that each group's rays share the signs the direction has."""
    d = np.asarray(direction, np.float64) + rng.uniform(-spread, spread, (len(origins), 3))
    return np.asarray(origins, np.float32), d.astype(np.float32)


def test_packets_answer_as_single_rays_on_the_hard_cases():
    """Packets of coherent rays: axis-parallel packets on the vertex lattice (through shared
    edges and vertices, the two other components exactly 0), origins on cell planes, packets
    whose lanes share only the major axis' sign, packets with dead lanes (non-finite origin,
    empty interval), lanes that miss the grid beside lanes that hit, lanes starting inside it,
    and per-lane intervals, for closest and any hit, at several resolutions; groups with no
    shared sign go ray by ray."""
    tris = np.concatenate([tessellated_cube(4), soup(400, 8) * np.float32(0.8) + np.float32(0.1)])
    bvh = bvh_tracer(tris)
    rng = np.random.default_rng(11)
    lattice = np.linspace(0.0, 1.0, 9)
    for res in (None, (4, 4, 4), (7, 3, 5), (1, 1, 1)):
        grid = GridTracer(tris, resolution=res)
        cs = (grid.gmax - grid.gmin) / np.asarray(grid.resolution)
        O, D = [], []
        # axis-parallel, 16 lattice origins per packet
        for axis in range(3):
            for sign in (1.0, -1.0):
                xy = np.stack(np.meshgrid(lattice[:4], lattice[4:8]), -1).reshape(-1, 2)
                for shift in (0.0, 0.5):
                    o = np.zeros((16, 3))
                    o[:, axis] = -0.5 if sign > 0 else 1.5
                    o[:, (axis + 1) % 3] = xy[:, 0] + shift
                    o[:, (axis + 2) % 3] = xy[:, 1]
                    d = np.zeros((16, 3))
                    d[:, axis] = sign
                    O.append(o)
                    D.append(d)
        # origins on cell planes (of the packet's major axis, or of another with lanes parallel
        # to those planes or not), sharing one sign
        for _ in range(36):
            k = rng.integers(3)
            o = rng.uniform(-0.2, 1.2, (16, 3))
            o[:, k] = grid.gmin[k] + cs[k] * rng.integers(0, grid.resolution[k] + 1, 16)
            major = (k + rng.integers(3)) % 3
            d = rng.normal(size=(16, 3))
            d[:, major] = np.abs(d[:, major]) + 0.1
            if major != k:
                d[rng.random(16) < 0.4, k] = 0.0             # in the cell plane
            O.append(o)
            D.append(d * rng.choice([-1.0, 1.0]))
        # camera-like fans from outside and from inside the grid, wide and narrow
        for eye, spread in (((0.5, 0.5, -1.0), 0.02), ((0.5, 0.5, -1.0), 0.6),
                            ((0.3, 0.4, 0.5), 0.3), ((2.0, -1.0, 3.0), 0.05)):
            eye = np.asarray(eye)
            o, d = packet_groups(rng, np.tile(eye, (16 * 8, 1)), 0.5 - eye, spread)
            O.append(o)
            D.append(d)
        # lanes that miss the grid's box beside lanes that hit it
        o = np.tile([0.5, 0.5, -1.0], (16, 1))
        d = np.tile([0.0, 0.0, 1.0], (16, 1))
        d[::2, :2] = rng.uniform(0.6, 2.0, (8, 2))
        O.append(o)
        D.append(d)
        o, d = np.concatenate(O).astype(np.float32), np.concatenate(D).astype(np.float32)
        # dead lanes inside packets: a non-finite origin, an empty interval
        o[5, 1] = np.inf
        lo = np.zeros(len(o), np.float32)
        hi = np.full(len(o), np.inf, np.float32)
        hi[37] = -1.0
        assert packets_as_single_rays(grid, bvh, o, d, lo, hi) == shared_sign_groups(d) > 40
        # per-lane intervals, cutting some hits off at either end (any hit: shadow rays)
        lo = rng.uniform(0.0, 1.0, len(o)).astype(np.float32)
        hi = (lo + rng.uniform(0.0, 1.5, len(o))).astype(np.float32)
        packets_as_single_rays(grid, bvh, o, d, lo, hi)
        # groups whose directions share no sign on any axis go ray by ray
        o, d = raysets.incoherent(tris, 320, 4)
        assert packets_as_single_rays(grid, bvh, o, d) == 0


@pytest.mark.parametrize("scale, offset", [(1e-6, 0.0), (1e6, 1e7), (1.0, -3e4)])
def test_packets_on_huge_and_tiny_coordinates(scale, offset):
    """Camera fans and axis-parallel packets on a scaled and moved scene: the packets' bounds
    are widened relative to the coordinates' magnitude, so they answer as single rays."""
    base = np.concatenate([tessellated_cube(3), soup(300, 5)])
    tris = (base.astype(np.float64) * scale + offset).astype(np.float32)
    grid = GridTracer(tris)
    bvh = bvh_tracer(tris)
    o, d = raysets.primary(tris, 1600)
    lattice = (np.linspace(0.0, 1.0, 7)[:4] * scale + offset)
    ao = np.stack(np.meshgrid(lattice, lattice, indexing="ij"), -1).reshape(-1, 2)
    ao = np.column_stack([ao, np.full(16, offset - scale)])
    o = np.concatenate([o, ao]).astype(np.float32)
    d = np.concatenate([d, np.tile([0.0, 0.0, 1.0], (16, 1))]).astype(np.float32)
    assert packets_as_single_rays(grid, bvh, o, d) == len(o) // 16
    assert (grid.intersect(o, d).prim >= 0).mean() > 0.2


@pytest.mark.parametrize("distance", [1e15, 1e20])
def test_axis_parallel_rays_from_distant_origins(distance):
    """Rays along each axis, both ways, from origins ``distance`` away from a unit-sized
    scene: each enters the grid through a face, whatever o + t d rounds to (from 1e15 the sum
    is off by more than a cell), and answers as the BVH does, in packets and ray by ray."""
    tris = np.concatenate([tessellated_cube(3), soup(300, 5)])
    grid = GridTracer(tris)
    bvh = bvh_tracer(tris)
    rng = np.random.default_rng(11)
    O, D = [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            o = rng.uniform(0.05, 0.95, (32, 3))
            o[:, axis] = 0.5 + sign * distance
            d = np.zeros((32, 3))
            d[:, axis] = -sign
            O.append(o)
            D.append(d)
    o, d = np.concatenate(O).astype(np.float32), np.concatenate(D).astype(np.float32)
    assert packets_as_single_rays(grid, bvh, o, d) == len(o) // 16
    assert (grid.intersect(o, d).prim >= 0).all()          # every ray meets the cube


def test_shadow_packets_match_the_bvh():
    """Shadow rays toward a point light, as the renderer traces them: packets of rays from
    nearby surface points, any hit within each lane's own distance to the light."""
    vertices, faces = sphere(32, 64)
    tris = np.concatenate([vertices[faces], soup(1500, 3) * np.float32(2.5) - np.float32(1.25)])
    grid = GridTracer(tris)
    bvh = bvh_tracer(tris)
    o, d, tmax = raysets.shadow(bvh, tris, 4000)
    assert packets_as_single_rays(grid, bvh, o, d, 0.0, tmax) > len(o) // 32
    blocked = grid.occluded(o, d, 0.0, tmax)
    assert 0.05 < blocked.mean() < 0.95


def bounded(grid, n):
    assert grid.references <= GRID_MAX_REFS_PER_TRI * max(n, 1)
    assert len(grid.offsets) - 1 <= GRID_MAX_CELLS
    assert grid.memory_bytes <= 8 * (len(grid.offsets)) + 4 * grid.references + 44 * n
    assert grid.references_per_triangle == grid.references / max(n, 1)


def degenerate_cases():
    rng = np.random.default_rng(7)
    small = soup(2000, 4)
    huge = np.array([[[-10, -10, 0.5], [30, -10, 0.5], [-10, 30, 0.5]]], np.float32)
    many_huge = huge + rng.normal(scale=0.1, size=(300, 3, 3)).astype(np.float32)
    clump = (np.float32(0.5) + rng.normal(scale=1e-4, size=(2000, 3, 3))).astype(np.float32)
    corners = np.array([[[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0]],
                        [[1, 1, 1], [0.99, 1, 1], [1, 0.99, 1]]], np.float32)
    flat = small.copy()
    flat[:, :, 2] = 0.25
    line = np.zeros((50, 3, 3), np.float32)
    line[:, :, 0] = rng.random((50, 3))                       # zero extent in y and z
    point = np.full((20, 3, 3), 0.5, np.float32)
    return {"huge triangle": np.concatenate([small, huge]),
            "many huge triangles": np.concatenate([small, many_huge]),
            "all in one cell": np.concatenate([clump, corners]),
            "flat": flat, "zero-extent axes": line, "a point": point}


@pytest.mark.parametrize("case", list(degenerate_cases()))
def test_degenerate_input_stays_bounded_and_right(case):
    tris = degenerate_cases()[case]
    grid = GridTracer(tris)
    bounded(grid, len(tris))
    bvh = bvh_tracer(tris)
    o, d = raysets.incoherent(tris, 3000, 5)
    axis = np.zeros((300, 3), np.float32)
    axis[np.arange(300), np.arange(300) % 3] = 1.0           # axis-parallel, some in a flat mesh's plane
    ao = np.asarray(tris, np.float32).reshape(-1, 3)[np.random.default_rng(1).integers(0, 3 * len(tris), 300)]
    o = np.concatenate([o, ao - 0.7 * axis])
    d = np.concatenate([d, axis])
    same_as_bvh(grid, bvh, o, d)
    # through packets: fans of rays from a point outside toward the mesh, and the axis-parallel
    # rays grouped by axis
    by_axis = np.argsort(np.arange(300) % 3, kind="stable")
    pts = np.asarray(tris, np.float64).reshape(-1, 3)
    centre = (pts.min(0) + pts.max(0)) / 2
    eye = centre + np.array([0.3, 0.5, 2.0]) * max(np.ptp(pts, 0).max(), 1.0)
    po, pd = packet_groups(np.random.default_rng(2), np.tile(eye, (640, 1)), centre - eye,
                           0.2 * max(np.ptp(pts, 0).max(), 1.0))
    o = np.concatenate([np.asarray(po, np.float32), (ao - 0.7 * axis)[by_axis]])
    d = np.concatenate([np.asarray(pd, np.float32), axis[by_axis]])
    assert packets_as_single_rays(grid, bvh, o, d) == shared_sign_groups(d) >= 40 + 15
    if case == "flat":
        assert grid.resolution[2] == 1
    if case == "many huge triangles":
        # the density heuristic's resolution would need ~300 x cells references: coarsened
        assert np.prod(grid.resolution) < np.prod(density_resolution(np.ptp(tris.reshape(-1, 3), 0), len(tris)))


def test_resolution_and_input_checks():
    tris = soup(200, 2)
    assert GridTracer(tris, resolution=(3, 5, 2)).resolution == (3, 5, 2)
    assert GridTracer(tris, resolution=6).resolution == (6, 6, 6)
    for bad in (0, (2, 0, 2), 2.5, (1, 2)):
        with pytest.raises(ValueError, match="resolution"):
            GridTracer(tris, resolution=bad)
    with pytest.raises(ValueError, match="resolution"):
        GridTracer(np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]] * 40, np.float32), resolution=64)
    with pytest.raises(ValueError, match="NaN or infinite coordinate"):
        GridTracer(np.full((1, 3, 3), np.nan, np.float32))
    empty = GridTracer(np.zeros((0, 3, 3), np.float32))
    h = empty.intersect(np.zeros((2, 3)), np.array([[0, 0, 1.0], [1, 0, 0]]))
    assert (h.prim == -1).all() and np.isinf(h.t).all()
    # rays the unit rejects (zero or non-finite direction, empty interval) miss
    g = GridTracer(tris)
    o = np.full((3, 3), 0.5)
    d = np.array([[0, 0, 0], [np.nan, 0, 1], [0, 0, 1]], np.float64)
    assert (g.intersect(o, d, 0.0, np.array([1.0, 1.0, -1.0])).prim == -1).all()


def small(name, w, h, spp=1):
    return compile_scene(load_scene(name, width=w, height=h, spp=spp))


def test_cornell_renders_like_the_bvh():
    sc = small("cornell", 32, 24)
    bvh, _, _ = make_tracer(sc)
    grid, secs, info = make_tracer(sc, accel="grid")
    assert grid.dtype == np.float32 and grid.has_counters is False
    assert info["memory_bytes"] == grid.memory_bytes and info["references_per_triangle"] > 0
    o = np.tile(np.asarray(sc.camera["eye"], np.float64), (3, 1))
    d = np.array([[0.0, -1.0, 0.0], [0.0, -0.6, -0.8], [0.0, 1.0, 0.0]])
    h = grid.intersect(o, d, 0.0, np.inf, normals=False)
    assert h.prim.dtype == np.int32 and len(h.t) == 3 and h.ng is None
    assert grid.occluded(o, d, 0.0, np.full(3, 1e30)).dtype == bool
    a = render(sc, bvh)
    b = render(sc, grid)
    assert a.stats["rays"] == b.stats["rays"]
    assert (np.abs(a.image - b.image).max(axis=2) > 0.02).mean() < 0.01


def test_cli_accel(tmp_path, capsys):
    assert main(["render", "cornell", "--accel", "grid", "--builder", "sweep"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--accel" in err and "\n" not in err
    assert main(["render", "cornell", "--accel", "grid", "--traversal", "embree",
                 "--builder", "embree"]) == 2
    capsys.readouterr()
    out = tmp_path / "c.exr"
    assert main(["render", "cornell", "--accel", "grid", "-o", str(out), "--width", "16",
                 "--height", "12", "--spp", "1", "--json"]) in (0, None)
    r = json.loads(capsys.readouterr().out)
    assert r["accel"] == "grid" and r["memory_bytes"] > 0 and r["references_per_triangle"] > 0
    # no BVH is built: no builder, traversal or simulated hardware build to report
    assert r["builder"] is None and r["traversal"] is None and r["simulated_build_seconds"] is None
    assert out.exists()
    assert main(["verify", "cornell", "--accel", "grid", "--rays", "2000", "--json",
                 "--mismatches", str(tmp_path / "m.npz")]) in (0, None)
    r = json.loads(capsys.readouterr().out)
    assert r["accel"] == "grid" and r["mismatch"] == 0 and r["rays"] == 2000
    assert r["build_seconds"] >= 0 and r["memory_bytes"] > 0 and r["references_per_triangle"] > 0
