"""Where secondary rays start: hit points on their triangles' planes, then offset off them."""
import numpy as np
import pytest

import hwbvh
from hwbvh.errors import ParameterError
from scenes.meshes import grid_sheet, sphere
from traversal import Tracer, raysets
from traversal.offset import offset_origins, points_on_planes

from .late_hits import LateHits


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.mark.parametrize("shift", [0.0, 1e5, -3e-4])
def test_points_on_planes_lands_on_the_plane(shift):
    """Points off their triangles' planes (as a float32 distance leaves them on a sliver) land
    on the planes within float64 rounding of their coordinates, moved along the normal only."""
    rng = np.random.default_rng(4)
    tris = (rng.normal(size=(50, 3, 3)) + shift).astype(np.float32)
    t64 = tris.astype(np.float64)
    g = _unit(np.cross(t64[:, 1] - t64[:, 0], t64[:, 2] - t64[:, 0]))
    a, b = rng.uniform(0, 0.5, size=(2, 50, 1))
    on = t64[:, 0] + a * (t64[:, 1] - t64[:, 0]) + b * (t64[:, 2] - t64[:, 0])
    off = on + g * rng.uniform(-1e-3, 1e-3, size=(50, 1))
    p = points_on_planes(off, tris, np.arange(50))
    scale = np.abs(t64).max() + 1.0
    assert np.abs(np.einsum("ij,ij->i", p - t64[:, 0], g)).max() < 1e-14 * scale
    assert np.abs(p - on).max() < 1e-14 * scale            # the move is along the normal
    assert np.abs(p - off).max() > 1e-4


def test_points_on_planes_refuses_what_it_cannot_place():
    tris = np.eye(3, dtype=np.float32)[None]
    for points, triangles, prim, name, text in (
            (np.zeros((1, 3)), tris, np.array([-1]), "prim", "holds -1, outside 0..0 (a miss?)"),
            (np.zeros((2, 3)), tris, np.array([0]), "prim", "one integer per point (2)"),
            (np.zeros((1, 3)), tris, np.array([0.0]), "prim", "one integer per point"),
            (np.zeros((1, 3)), tris.reshape(1, 9), np.array([0]), "triangles", "(m, 3, 3)"),
            (np.zeros((1, 2)), tris, np.array([0]), "points", "(n, 3)")):
        with pytest.raises(ParameterError) as e:
            points_on_planes(points, triangles, prim)
        assert e.value.parameter == name and text in str(e.value)


def test_verification_shadow_rays_start_in_front_of_their_surface():
    """verify's shadow rays leave from the hit triangle's plane, not from the point at the
    tracer's t: with every hit reported 1e-3 of t beyond its surface, the rays toward the
    light are blocked as often as from exact hits (from the points at t, the floor would
    block nearly all of its own)."""
    tris = np.concatenate([grid_sheet(8, 8, size=6.0, wave=0.0),
                           sphere(16, 32, radius=1.5, center=(0.0, 1.5, 0.0))])
    tracer = Tracer(hwbvh.build(tris))

    def blocked(t):
        o, d, tmax = raysets.shadow(t, tris, 4000, np.float32)
        return tracer.occluded(o, d, 0.0, tmax)

    exact, late = blocked(tracer), blocked(LateHits(tracer))
    assert 0.05 < exact.mean() < 0.5
    assert abs(late.mean() - exact.mean()) < 0.01


def test_offset_origins_leave_to_the_side_of_the_direction():
    p = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0]])
    n = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 2.0]])
    d = np.array([[0.0, 1.0, 1.0], [0.0, 1.0, -1.0]])
    o = offset_origins(p, n, d, np.array([3.0, 3.0]))
    assert o[0, 2] > 3.0 > o[1, 2]
    assert np.array_equal(o[:, :2], p[:, :2])


@pytest.mark.parametrize("change, name, text", [
    ({"ng": np.zeros((1, 3))}, "ng", "must be (2, 3)"),
    ({"points": np.zeros(3)}, "points", "must be (n, 3)"),
    ({"dirs": np.full((2, 3), np.nan)}, "dirs", "must be finite"),
    ({"tri_mag": np.ones(3)}, "tri_mag", "one per point (2)"),
    ({"tri_mag": -1.0}, "tri_mag", "must be >= 0"),
    ({"tri_mag": "big"}, "tri_mag", "must hold numbers"),
    ({"strategy": "far"}, "strategy", "choose from relative, fixed, none"),
])
def test_offset_origins_refuse_bad_input_naming_it(change, name, text):
    """The rows go to a kernel that trusts their shapes: rows of another length would be read
    past their ends."""
    args = {"points": np.zeros((2, 3)), "ng": np.tile([0.0, 0.0, 1.0], (2, 1)),
            "dirs": np.tile([0.0, 1.0, 1.0], (2, 1)), "tri_mag": 1.0, **change}
    with pytest.raises(ParameterError) as e:
        offset_origins(**args)
    assert e.value.parameter == name and text in str(e.value)
