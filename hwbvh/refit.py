"""Bottom-up refit of a BVH in the 384-bit node format (thesis 2.4, "BVH Updating", after
Lauterbach et al. [LYTM06]).

The topology stays: every pointer, leaf range, flag and the index list are kept; only word 0 of
each node, its float32 AABB, is rewritten from the primitives' new positions. Leaves first (the
union of their triangles' float32 vertex boxes, exact), then every internal node from its two
children, children always before their parent. With unchanged geometry a refit reproduces the
builder's boxes bit for bit, since the builder's node boxes are unions of the same primitive
boxes.

A refit is only defined while the primitive count stays the same: a different count needs a
rebuild.

>>> r = Refitter(bvh)                 # walks the topology once
>>> moved = r.refit(new_triangles)    # a new Bvh: same topology, new boxes
>>> c = refit_cost(r.n_prims, r.node_count, r.max_depth, PRESETS["HWBVH-C"])
>>> c["seconds"]                      # the hardware model of one refit pass
"""
import math

import numpy as np
from numba import njit, prange

from .errors import InputError, ParameterError
from .config import LEAF_FLAG, MAX_PRIMITIVES
from .format import (BOX_MAX, NODE_DTYPE, WORD_A, WORD_B, WORD_BOX, WORD_FLAGS, check_nodes,
                     node_views, tree_stats)
from .parallel import check_threading
from .primitives import as_triangles


@njit(cache=True)
def _bottom_up_order(u):
    """Reachable nodes in reverse pre-order from the root (every child before its parent),
    split into leaves and internal nodes."""
    nslots = u.shape[0]
    pre = np.empty(nslots, dtype=np.int64)
    stack = np.empty(nslots + 2, dtype=np.int64)
    stack[0] = 0
    sp = 1
    n = 0
    n_leaves = 0
    while sp > 0:
        sp -= 1
        i = stack[sp]
        pre[n] = i
        n += 1
        if u[i, WORD_FLAGS] & LEAF_FLAG:
            n_leaves += 1
        else:
            stack[sp] = u[i, WORD_B]
            stack[sp + 1] = u[i, WORD_A]
            sp += 2
    leaves = np.empty(n_leaves, dtype=np.int64)
    internal = np.empty(n - n_leaves, dtype=np.int64)
    nl = 0
    ni = 0
    for k in range(n - 1, -1, -1):
        i = pre[k]
        if u[i, WORD_FLAGS] & LEAF_FLAG:
            leaves[nl] = i
            nl += 1
        else:
            internal[ni] = i
            ni += 1
    return leaves, internal


@njit(cache=True, parallel=True)
def _refit_leaves(u, f, leaves, entries, tris):
    """Leaf box = union of its triangles' vertex boxes (float32 min/max: exact)."""
    for j in prange(leaves.shape[0]):
        i = leaves[j]
        a = np.int64(u[i, WORD_A])
        c = np.int64(u[i, WORD_B])
        for k in range(3):
            lo = np.float32(np.inf)
            hi = np.float32(-np.inf)
            for p in range(a, a + c):
                t = entries[p]
                for v in range(3):
                    x = tris[t, v, k]
                    if x < lo:
                        lo = x
                    if x > hi:
                        hi = x
            f[i, WORD_BOX + k] = lo
            f[i, WORD_BOX + BOX_MAX + k] = hi


@njit(cache=True)
def _refit_internal(u, f, internal):
    """Internal box = union of its children's boxes, children first (bottom-up order)."""
    for j in range(internal.shape[0]):
        i = internal[j]
        l = u[i, WORD_A]
        r = u[i, WORD_B]
        for k in range(WORD_BOX, WORD_BOX + BOX_MAX):
            f[i, k] = min(f[l, k], f[r, k])
            f[i, k + BOX_MAX] = max(f[l, k + BOX_MAX], f[r, k + BOX_MAX])


class Refitter:
    """Refits one tree's topology to new primitive positions, as often as asked.

    bvh : hwbvh.Bvh (nodes and index list; its triangles are the positions it was built on).
    """

    def __init__(self, bvh):
        from .api import Bvh

        if not isinstance(bvh, Bvh):
            raise ParameterError("bvh", f"expected a hwbvh.Bvh, got {type(bvh).__name__}")
        # a refit keeps the topology and boxes every node anew from its children: its trees
        # hold every invariant when the tree it refits does (``Bvh``)
        self._invariants_hold = getattr(bvh, "_invariants_hold", False)
        # The kernels below follow the pointers and index ranges without bounds checks, so
        # the topology and the index list are checked once here.
        indices = np.asarray(bvh.indices)
        if indices.ndim != 1 or indices.dtype.kind not in "iu" or not 1 <= len(indices) <= MAX_PRIMITIVES:
            raise InputError("bvh.indices", f"expected 1..{MAX_PRIMITIVES} integer primitive indices, "
                                            f"got {indices.dtype} of shape {indices.shape}")
        if indices.min() < 0 or indices.max() >= len(indices):
            raise InputError("bvh.indices", f"primitive index out of range 0..{len(indices) - 1}")
        self.nodes = check_nodes(bvh.nodes, n_positions=len(indices), source="bvh.nodes")
        self.indices = np.ascontiguousarray(indices, dtype=np.int64)
        self.meta = dict(bvh.meta)
        self.n_prims = len(indices)
        u, _ = node_views(self.nodes)
        self.leaves, self.internal = _bottom_up_order(u)
        self.max_depth = int(self.meta.get("max_depth") or tree_stats(self.nodes)["max_depth"])

    @property
    def node_count(self):
        return len(self.leaves) + len(self.internal)

    def check(self, triangles, source="triangles"):
        """Validated float32 triangles of the same count as the tree's primitives."""
        tris = as_triangles(triangles, source=source)
        if len(tris) != self.n_prims:
            raise InputError(source, f"{len(tris)} triangles, but the tree was built over "
                                     f"{self.n_prims}: a refit keeps the topology, so a change "
                                     "in triangle count needs a rebuild")
        return tris

    def refit_nodes(self, tris, out=None):
        """The tree's nodes with boxes for ``tris``, the (N, 3, 3) float32 array :meth:`check`
        returns, written into ``out`` (a NODE_DTYPE array as long as the tree's) or a new
        array. Returns the node array."""
        check_threading()
        if not (isinstance(tris, np.ndarray) and tris.dtype == np.float32
                and tris.shape == (self.n_prims, 3, 3)):
            raise ParameterError("tris", f"expected the ({self.n_prims}, 3, 3) float32 array "
                                         f"Refitter.check returns, got {_described(tris)}")
        tris = np.ascontiguousarray(tris)
        if out is None:
            nodes = self.nodes.copy()
        else:
            if not (isinstance(out, np.ndarray) and out.dtype == NODE_DTYPE
                    and out.shape == self.nodes.shape and out.flags.c_contiguous
                    and out.flags.writeable):
                raise ParameterError("out", f"expected a writable contiguous NODE_DTYPE array of "
                                            f"{len(self.nodes)} nodes, got {_described(out)}")
            # the kernels follow out's own pointers: they must be this tree's
            np.copyto(out, self.nodes)
            nodes = out
        u, f = node_views(nodes)
        _refit_leaves(u, f, self.leaves, self.indices, tris)
        _refit_internal(u, f, self.internal)
        return nodes

    def refit(self, triangles):
        """A new :class:`hwbvh.Bvh`: this topology, boxes for ``triangles`` ((N, 3, 3) float),
        its SAH cost recomputed. The tree holds its own copy of the triangles, as ``build``'s
        does, so a change the caller makes to the array in place afterwards does not reach it."""
        tris = self.check(triangles)
        if isinstance(triangles, np.ndarray) and np.may_share_memory(tris, triangles):
            tris = tris.copy()
        nodes = self.refit_nodes(tris)
        return self.tree(nodes, tris, tree_stats(nodes)["sah_cost"])

    def tree(self, nodes, tris, sah_cost):
        """The :class:`hwbvh.Bvh` of ``nodes`` that ``refit_nodes`` made for ``tris``, whose SAH
        cost is ``sah_cost`` (a caller that times the refit and the cost apart passes it). Its
        meta is the built tree's, marked ``refitted``, with ``build_seconds`` None: the refit
        built nothing, and the build's time is not its own."""
        from .api import Bvh

        bvh = Bvh(nodes=nodes, indices=self.indices.astype(np.uint32), triangles=tris,
                  meta=dict(self.meta, sah_cost=sah_cost, refitted=True, build_seconds=None))
        bvh._invariants_hold = self._invariants_hold
        return bvh


def _described(a):
    """An argument as an error shows it: dtype and shape for an array, else its type."""
    if isinstance(a, np.ndarray):
        return f"{'NODE_DTYPE' if a.dtype == NODE_DTYPE else a.dtype} of shape {a.shape}"
    return type(a).__name__


def refit(bvh, triangles):
    """One refit of ``bvh`` to ``triangles`` (see :class:`Refitter`)."""
    return Refitter(bvh).refit(triangles)


def refit_cost(n_prims, n_nodes, max_depth, params):
    """The hardware cost of one refit pass, in the builder's DRAM model (SPEC 6).

    A refit is a memory-bound streaming pass: per primitive one 192-bit word of AABB is read
    (the same record word the builder's initial pass reads, so both start from the same
    input), the 24-bit index list is read (8 entries a word), and every node's second word
    (pointers and flags) is read and its first word (the AABB) written. Reads and writes use
    the separate channels of each RAM pair, one word per channel per cycle, so the pass takes
    max(reads, writes) / R cycles; min/max comparators (latency 1, Table 3.1) keep pace with
    the stream, and a bottom-up pass adds one comparator latency per tree level at the end.
    The model assumes the primitive words arrive in leaf order (as the builder's partitioned
    records leave them), so it is a lower bound: gathers out of order would cost more. It
    charges no energy: no power figure exists for such a unit, and a preset's power belongs
    to the builder alone.

    params : hwbvh.cycle_model.HwParams (its clock and RAM pairs). Returns a dict.
    """
    from .errors import is_integer
    from .config import WORD_BYTES
    from .cycle_model import as_params

    params = as_params(params)
    max_nodes = 2 * n_prims - 1 if is_integer(n_prims) else 1
    for name, v, lo, hi in (("n_prims", n_prims, 1, MAX_PRIMITIVES), ("n_nodes", n_nodes, 1, max_nodes),
                            ("max_depth", max_depth, 0, n_nodes - 1 if is_integer(n_nodes) else 0)):
        # a binary tree over n primitives has at most 2n - 1 nodes, n nodes at most depth n - 1
        if not is_integer(v) or not lo <= v <= hi:
            raise ParameterError(name, f"must be an integer in {lo}..{hi}, got {v!r}")
    index_words = -(-int(n_prims) // 8)
    reads = int(n_prims) + index_words + int(n_nodes)
    writes = int(n_nodes)
    cycles = math.ceil(max(reads, writes) / params.ram_pairs) + int(max_depth)
    seconds = cycles / (params.clock_mhz * 1e6)
    return {"cycles": int(cycles), "seconds": seconds,
            "traffic_bytes": {"aabb": int(n_prims) * WORD_BYTES, "indices": index_words * WORD_BYTES,
                              "nodes": 2 * int(n_nodes) * WORD_BYTES},
            "energy_joules": None}
