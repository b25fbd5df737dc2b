"""traversal: the appendix-A AABB and Moller-Trumbore units in Numba, traversing hwbvh's raw
384-bit nodes and 24-bit index list; verification against Embree."""
import hwbvh.kernel_cache  # noqa: F401  (before any kernel: cached kernels stay fresh)
from .api import Hits, Tracer

__all__ = ["Hits", "Tracer"]
