"""What the uniform grid and the kd-tree share around their kernels: the checked input, the
mesh's padded box, the float32 Moller-Trumbore unit's triangle rows, and the batched
``intersect``/``occluded`` of the tracer interface (``traversal.tracers``).

The float32 unit's domain is narrower than the coordinates the builder accepts
(``hwbvh.config.MAX_COORDINATE``, 1e15, a bound set by the SAH's areas). The unit computes t
as e2 . ((o - v0) x e1) / det: its numerator is a product of three lengths, edge x edge x
origin distance, and it overflows float32 (3.4e38) once that product passes it, about
(7e12)^3. Past that point a ray misses the triangle, or (with tmax = inf) reports it at
t = inf. So every float32 tracer (BVH, grid, kd-tree) checks each batch of rays first
(``triangle_unit.Float32Range``): where its products could pass a quarter of float32's range,
the batch is refused with an error that names the origins (or the directions) and the float64
units, instead of being traced to lost hits. Measured on a mesh of 64 triangles, each a tenth
of the mesh's size, with rays from three mesh sizes away: the tracers trace it whole while it
spans up to 1.3e13 and refuse it from 1.4e13; the unit itself, unchecked, keeps every hit up to
2.5e13 (the bound is a guarantee, not the edge), and finds 2 of 64 at 1e14. Embree, which has
no such check, keeps every hit up to 2e13. The datapath is the hardware's and is kept;
``traversal.Tracer(precision="float64")`` traces the builder's whole domain (every hit on the
same mesh spanning 9.9e14), checking its rays in the same way against float64's range
(``triangle_unit.Float64Range``: only origins beyond about 1e270 reach it).
"""
import numpy as np

from hwbvh.errors import ParameterError, checked_flag
from hwbvh.primitives import checked_coordinates
from .api import Hits, _answers, _rays
from .config import EDGE_EPS_F32
from .triangle_unit import Float32Range, band_eps2, preprocess


def checked_triangles(triangles):
    """(n, 3, 3) triangles (an empty array is allowed) as float32 coordinates held in float64;
    ParameterError / InputError naming 'triangles' on data that are not real numbers, a bad
    shape, or a NaN or infinite coordinate or one beyond ``hwbvh.config.MAX_COORDINATE`` (the
    BVH builder's check, ``checked_coordinates``; the float32 unit's own, narrower domain is
    in the module's docstring)."""
    tris = np.asarray(triangles)
    if tris.dtype.kind not in "fiu":
        raise ParameterError("triangles", f"must be real numbers, got {tris.dtype}")
    if tris.ndim != 3 or tris.shape[1:] != (3, 3):
        raise ParameterError("triangles", f"must be (n, 3, 3), got {tris.shape}")
    tris = checked_coordinates(tris, "triangles")
    return np.ascontiguousarray(tris.astype(np.float32).astype(np.float64))


def padded_box(tris, pad_tri, pad_coord):
    """(lo, hi, box_lo, box_hi): the mesh's bounds, and the same box padded like a triangle's
    (``pad_tri`` of its extent and ``pad_coord`` of its largest coordinate magnitude), never
    flat. An empty mesh has the empty box at the origin."""
    if len(tris):
        lo = tris.min(axis=(0, 1))
        hi = tris.max(axis=(0, 1))
    else:
        lo = hi = np.zeros(3)
    pad = pad_tri * (hi - lo).max() + pad_coord * np.abs(np.r_[lo, hi]).max()
    pad = max(pad, np.finfo(np.float32).tiny)
    return lo, hi, lo - pad, hi + pad


class TriangleStructure:
    """Base of the structures that trace the BVH's float32 triangle unit on their own cells:
    a subclass calls ``_set_unit`` with its triangles and implements ``_trace``."""

    has_counters = False
    concurrent = True                 # queries may come from several threads at once
    dtype = np.float32

    def _set_unit(self, tris, given):
        """The unit's rows of ``tris`` (``checked_triangles``); ``given``: the caller's own
        triangles, kept as the ones traced (``traversal.tracers``) without a copy."""
        self.n_triangles = len(tris)
        self.triangles = given
        self.tris = preprocess(tris, np.float32)
        self.unit_range = Float32Range(self.tris, tris)
        self._tris1 = self.tris.reshape(-1)
        self.eps2 = band_eps2(np.float32)
        self.one = np.float32(1)
        self.edge = np.float32(EDGE_EPS_F32)

    def _trace(self, o, d, tmin, tmax, anyhit, prim, t, u, v, ng):
        """Run the structure's kernel on the checked float32 rays into the outputs."""
        raise NotImplementedError

    def _run(self, origins, dirs, tmin, tmax, anyhit, normals):
        o, d, lo, hi = _rays(origins, dirs, tmin, tmax, np.float32)
        self.unit_range.check(o, d)
        prim, t, u, v, ng = _answers(len(o), anyhit, normals, np.float32)
        self._trace(o, d, lo, hi, anyhit, prim, t, u, v, ng)
        return prim, t, u, v, (ng if normals else None)

    def intersect(self, origins, dirs, tmin=0.0, tmax=np.inf, normals=True):
        """Closest hit per ray in [tmin, tmax] (scalars or (n,) arrays); ``normals=False``
        leaves ng None."""
        prim, t, u, v, ng = self._run(origins, dirs, tmin, tmax, False,
                                      checked_flag(normals, "normals"))
        return Hits(t=t, prim=prim, u=u, v=v, ng=ng)

    def occluded(self, origins, dirs, tmin=0.0, tmax=np.inf):
        """True where any triangle is hit in [tmin, tmax]."""
        return self._run(origins, dirs, tmin, tmax, True, False)[0] >= 0
