"""hwbvh: the hardware BVH builder of Doyle 2014, simulated exactly, in the 384-bit format."""
from . import kernel_cache  # noqa: F401  (before any kernel: cached kernels stay fresh)
from . import memory  # noqa: F401  (keeps freed memory for the next build)
from . import parallel  # noqa: F401  (pins the threading set-up before any kernel runs)
from .api import Bvh, build, load, save, warm_up
from .errors import InputError
from .format import NODE_DTYPE, check_nodes, sah_cost, tree_stats, validate
from .primitives import as_triangles, load_triangles, primitive_boxes

__all__ = ["Bvh", "build", "load", "save", "warm_up", "InputError", "NODE_DTYPE", "check_nodes",
           "sah_cost", "tree_stats", "validate", "as_triangles", "load_triangles",
           "primitive_boxes"]
