"""traversal: the appendix-A AABB and Moller-Trumbore units in Numba, traversing hwbvh's raw
384-bit nodes and 24-bit index list; verification against Embree."""
from .api import Hits, Tracer

__all__ = ["Hits", "Tracer"]
