"""The output format of thesis 3.3.5, fixed by SPEC section 4 (little-endian).

A node is 384 bits = 48 bytes = two 192-bit words::

    bytes  0..23  word 0: float32 minx, miny, minz, maxx, maxy, maxz
    bytes 24..27  uint32 a: internal -> left child node index; leaf -> first index-list position
    bytes 28..31  uint32 b: internal -> right child node index; leaf -> primitive count
    bytes 32..35  uint32 flags: bit 0 = leaf, all other bits 0
    bytes 36..47  padding, all zero

Node index = byte offset / 48; the root is node 0. The index list holds 24-bit little-endian
entries, 8 per 192-bit word, the tail of the last word padded with 0xFFFFFF.
"""
import numpy as np
from numba import njit

from .config import INDEX_BYTES, INDEX_PAD, INDICES_PER_WORD, LEAF_FLAG, NODE_BYTES

NODE_DTYPE = np.dtype([
    ("bounds", "<f4", (6,)),   # 24 bytes: word 0, the node AABB
    ("a", "<u4"),              #  4 bytes: left child / first index position
    ("b", "<u4"),              #  4 bytes: right child / primitive count
    ("flags", "<u4"),          #  4 bytes: bit 0 = leaf
    ("pad", "<u4", (3,)),      # 12 bytes: zero
])                             # total: 48 bytes = 384 bits
assert NODE_DTYPE.itemsize == NODE_BYTES

# The kernels read a node as 32-bit words (the same bytes seen as uint32 and as float32), at
# these offsets, derived from NODE_DTYPE. Numba freezes module-level ints into the compiled
# code, so naming the offsets costs nothing.
_WORD = np.dtype("<u4").itemsize
assert all(NODE_DTYPE.fields[k][1] % _WORD == 0 for k in NODE_DTYPE.names)
WORDS_PER_NODE = NODE_DTYPE.itemsize // _WORD          # 12
WORD_BOX = NODE_DTYPE.fields["bounds"][1] // _WORD     # 0: min x, y, z, then max x, y, z
BOX_MAX = NODE_DTYPE["bounds"].shape[0] // 2           # 3: max xyz follow min xyz in a box
WORD_A = NODE_DTYPE.fields["a"][1] // _WORD            # 6: left child / first index position
WORD_B = NODE_DTYPE.fields["b"][1] // _WORD            # 7: right child / primitive count
WORD_FLAGS = NODE_DTYPE.fields["flags"][1] // _WORD    # 8: LEAF_FLAG set on a leaf
WORD_PAD = NODE_DTYPE.fields["pad"][1] // _WORD        # 9
PAD_WORDS = NODE_DTYPE["pad"].shape[0]                 # 3, all zero


def node_views(nodes):
    """(u32 (n, WORDS_PER_NODE), f32 (n, WORDS_PER_NODE)) views of a NODE_DTYPE array, sharing
    its memory."""
    raw = nodes.view(np.uint32).reshape(len(nodes), WORDS_PER_NODE)
    return raw, raw.view(np.float32)


def pack_indices(ids):
    """Pack primitive indices (each < 2^24) into the 24-bit index list bytes."""
    ids = np.asarray(ids, dtype=np.uint32)
    n = len(ids)
    padded = -(-n // INDICES_PER_WORD) * INDICES_PER_WORD
    full = np.full(padded, INDEX_PAD, dtype="<u4")
    full[:n] = ids
    return full.view(np.uint8).reshape(-1, 4)[:, :INDEX_BYTES].tobytes()


def unpack_indices(data):
    """24-bit index list bytes -> uint32 entries (padding included)."""
    raw = np.frombuffer(data, dtype=np.uint8)
    if raw.size % INDEX_BYTES:
        raise ValueError("index list is not a whole number of 24-bit entries")
    b = raw.reshape(-1, INDEX_BYTES).astype(np.uint32)
    return b[:, 0] | (b[:, 1] << 8) | (b[:, 2] << 16)


# Validator error codes -> messages
_ERRORS = {
    1: "child pointer out of range",
    2: "node reached twice (cycle or shared child)",
    3: "flags has bits other than bit 0 set",
    4: "padding is not zero",
    5: "child AABB is not inside its parent's",
    6: "leaf count outside 1..leaf size",
    7: "leaf index range outside the index list",
    8: "index-list entry used by two leaves",
    9: "primitive index out of range",
    10: "primitive referenced more than once",
    11: "primitive never referenced",
    12: "more than 2N-1 nodes",
    13: "node AABB is inverted or not finite",
    14: "leaf AABB does not contain its primitive's AABB",
    15: "traversal stack overflow (tree deeper than 2N)",
}


@njit(cache=True)
def _validate(u, f, entries, n_prims, max_leaf, prim_boxes, check_boxes):
    nslots = u.shape[0]
    seen = np.zeros(nslots, dtype=np.uint8)
    used_entry = np.zeros(entries.shape[0], dtype=np.uint8)
    prim_seen = np.zeros(n_prims, dtype=np.uint8)
    stack = np.empty(2 * n_prims + 2, dtype=np.int64)
    sp = 0
    stack[sp] = 0
    sp += 1
    nodes = 0
    while sp > 0:
        sp -= 1
        i = stack[sp]
        if seen[i]:
            return 2, i
        seen[i] = 1
        nodes += 1
        if nodes > 2 * n_prims - 1:
            return 12, i
        if u[i, WORD_FLAGS] & ~np.uint32(LEAF_FLAG):
            return 3, i
        for k in range(WORD_PAD, WORD_PAD + PAD_WORDS):
            if u[i, k] != 0:
                return 4, i
        for k in range(WORD_BOX, WORD_BOX + 3):
            lo = f[i, k]
            hi = f[i, k + BOX_MAX]
            if not (lo <= hi) or not np.isfinite(lo) or not np.isfinite(hi):
                return 13, i
        if u[i, WORD_FLAGS] & LEAF_FLAG:
            a = np.int64(u[i, WORD_A])
            c = np.int64(u[i, WORD_B])
            if c < 1 or c > max_leaf:
                return 6, i
            if a + c > entries.shape[0]:
                return 7, i
            for p in range(a, a + c):
                if used_entry[p]:
                    return 8, i
                used_entry[p] = 1
                pid = np.int64(entries[p])
                if pid >= n_prims:
                    return 9, i
                if prim_seen[pid]:
                    return 10, i
                prim_seen[pid] = 1
                if check_boxes:
                    for k in range(3):      # prim_boxes rows: min xyz, max xyz
                        if prim_boxes[pid, k] < f[i, WORD_BOX + k] or \
                                prim_boxes[pid, 3 + k] > f[i, WORD_BOX + BOX_MAX + k]:
                            return 14, i
        else:
            for c in (np.int64(u[i, WORD_A]), np.int64(u[i, WORD_B])):
                if c >= nslots or c == 0:
                    return 1, i
                for k in range(WORD_BOX, WORD_BOX + 3):
                    if f[c, k] < f[i, k] or f[c, k + BOX_MAX] > f[i, k + BOX_MAX]:
                        return 5, c
                if sp >= stack.shape[0]:
                    return 15, i
                stack[sp] = c
                sp += 1
    for p in range(n_prims):
        if not prim_seen[p]:
            return 11, p
    return 0, nodes


def validate(nodes, entries, n_prims, max_leaf, prim_boxes=None, source="<tree>"):
    """Check every invariant SPEC section 4 lists; raise InputError naming ``source``.

    nodes : NODE_DTYPE array; entries : uint32 index-list entries (padding may be included);
    n_prims, max_leaf : integers >= 1; prim_boxes : optional (n_prims, 6) float primitive boxes
    (:func:`hwbvh.primitive_boxes`), which the leaf boxes must contain.
    Returns the number of reachable nodes.
    """
    from .errors import is_integer
    from .config import MAX_PRIMITIVES
    from .errors import InputError, ParameterError

    nodes = _node_array(nodes, source)
    # the counts size the kernel's arrays, so they are bounded before it runs
    for name, v in (("n_prims", n_prims), ("max_leaf", max_leaf)):
        if not is_integer(v) or not 1 <= v <= MAX_PRIMITIVES:
            raise ParameterError(name, f"must be an integer in 1..{MAX_PRIMITIVES}, got {v!r}")
    entries = np.asarray(entries)
    if entries.ndim != 1 or entries.dtype.kind not in "iu":
        raise ParameterError("entries", f"must be a 1-D integer array, got {entries.dtype} of "
                                        f"shape {entries.shape}")
    if entries.size and (entries.min() < 0 or entries.max() > np.iinfo(np.uint32).max):
        raise ParameterError("entries", "index-list entries must lie in 0..2^32-1")
    check = prim_boxes is not None
    if check:
        pb = np.asarray(prim_boxes)
        if pb.shape != (n_prims, 6) or pb.dtype.kind != "f":
            raise ParameterError("prim_boxes", f"must be a ({n_prims}, 6) float array (one box per "
                                               f"primitive), got {pb.dtype} of shape {pb.shape}")
        with np.errstate(over="ignore"):        # beyond float32: infinite, refused below
            pb = np.ascontiguousarray(pb, dtype=np.float32)
        bad = ~np.isfinite(pb).all(axis=1)
        if bad.any():
            # a NaN compares false both ways: its box would pass every containment test
            raise ParameterError("prim_boxes", f"must be finite (in float32), got "
                                               f"{pb[int(np.argmax(bad))].tolist()} for primitive "
                                               f"{int(np.argmax(bad))}")
    else:
        pb = np.zeros((1, 6), np.float32)
    u, f = node_views(nodes)
    code, where = _validate(u, f, np.ascontiguousarray(entries, dtype=np.uint32), int(n_prims),
                            int(max_leaf), pb, check)
    if code:
        what = "primitive" if code == 11 else "node"
        raise InputError(source, f"invalid tree: {_ERRORS[code]} ({what} {where})")
    return int(where)


@njit(cache=True)
def _check_topology(u, n_positions):
    """Walk from the root: every child pointer in 1..n-1, no node reached twice, and (when
    ``n_positions`` >= 0) every leaf's index range inside the first ``n_positions`` positions.
    Each node is pushed at most once, so the stack never exceeds n. Returns (code, node)."""
    nslots = u.shape[0]
    seen = np.zeros(nslots, dtype=np.uint8)
    stack = np.empty(nslots, dtype=np.int64)
    stack[0] = 0
    seen[0] = 1
    sp = 1
    while sp > 0:
        sp -= 1
        i = stack[sp]
        if u[i, WORD_FLAGS] & LEAF_FLAG:
            if n_positions >= 0 and np.int64(u[i, WORD_A]) + np.int64(u[i, WORD_B]) > n_positions:
                return 7, i
            continue
        for c in (np.int64(u[i, WORD_A]), np.int64(u[i, WORD_B])):
            if c >= nslots or c == 0:
                return 1, i
            if seen[c]:
                return 2, c
            seen[c] = 1
            stack[sp] = c
            sp += 1
    return 0, 0


def _node_array(nodes, source):
    """``nodes`` as a contiguous 1-D NODE_DTYPE array with at least one node, or InputError.
    Only the exact little-endian dtype is accepted: the kernels reinterpret the bytes as
    native words, so any other layout or byte order would be read as garbage."""
    from .errors import InputError

    if not isinstance(nodes, np.ndarray):
        raise InputError(source, f"expected a NODE_DTYPE array, got {type(nodes).__name__}")
    if nodes.dtype != NODE_DTYPE:
        if nodes.dtype.names == NODE_DTYPE.names and nodes.dtype.itemsize == NODE_DTYPE.itemsize:
            raise InputError(source, "NODE_DTYPE fields in a non-little-endian byte order; "
                                     "convert with .astype(hwbvh.NODE_DTYPE)")
        raise InputError(source, f"expected a NODE_DTYPE array, got dtype {nodes.dtype}")
    if nodes.ndim != 1:
        raise InputError(source, f"expected a 1-D NODE_DTYPE array, got shape {nodes.shape}")
    if len(nodes) == 0:
        raise InputError(source, "no nodes")
    return np.ascontiguousarray(nodes)


def check_nodes(nodes, n_positions=None, source="nodes"):
    """Check that ``nodes`` can be walked safely; return them as a contiguous NODE_DTYPE array.

    Refuses (InputError naming ``source``) anything that is not a non-empty 1-D array of
    exactly NODE_DTYPE, a child pointer outside 1..len(nodes)-1, and a node reached twice (a
    cycle or a shared child). With ``n_positions`` (the index list's length), every leaf's
    range [a, a + b) must also lie within it. O(n); the boxes are not checked (see
    :func:`validate` for every invariant).
    """
    from .errors import InputError, ParameterError, is_integer

    nodes = _node_array(nodes, source)
    if n_positions is None:
        limit = -1
    elif not is_integer(n_positions) or n_positions < 0:
        raise ParameterError("n_positions", f"must be an integer >= 0, got {n_positions!r}")
    else:
        # a leaf range ends below 2^33 (two uint32 words), so a larger limit changes nothing
        limit = min(int(n_positions), 1 << 40)
    u, _ = node_views(nodes)
    code, where = _check_topology(u, limit)
    if code:
        raise InputError(source, f"invalid tree: {_ERRORS[code]} (node {where})")
    return nodes


@njit(cache=True)
def _tree_stats(u, f):
    """Depth-first walk: SAH cost terms (float64), node/leaf counts, max depth."""
    nslots = u.shape[0]
    stack = np.empty(nslots + 1, dtype=np.int64)
    dstack = np.empty(nslots + 1, dtype=np.int64)
    stack[0] = 0
    dstack[0] = 0
    sp = 1
    lo = WORD_BOX                 # min x, y, z
    hi = WORD_BOX + BOX_MAX       # max x, y, z
    internal_area = 0.0
    leaf_area = 0.0
    nodes = 0
    leaves = 0
    max_depth = 0
    max_leaf = 0
    prims = 0
    while sp > 0:
        sp -= 1
        i = stack[sp]
        d = dstack[sp]
        dx = np.float64(f[i, hi]) - np.float64(f[i, lo])
        dy = np.float64(f[i, hi + 1]) - np.float64(f[i, lo + 1])
        dz = np.float64(f[i, hi + 2]) - np.float64(f[i, lo + 2])
        area = 2.0 * (dx * dy + dy * dz + dz * dx)
        nodes += 1
        if d > max_depth:
            max_depth = d
        if u[i, WORD_FLAGS] & LEAF_FLAG:
            leaves += 1
            c = np.int64(u[i, WORD_B])
            leaf_area += c * area
            prims += c
            if c > max_leaf:
                max_leaf = c
        else:
            internal_area += 2.0 * area
            if sp + 2 > stack.shape[0]:
                break
            stack[sp] = u[i, WORD_B]
            dstack[sp] = d + 1
            stack[sp + 1] = u[i, WORD_A]
            dstack[sp + 1] = d + 1
            sp += 2
    return internal_area, leaf_area, nodes, leaves, max_depth, max_leaf, prims


def sah_cost(nodes):
    """SAH cost of SPEC section 5 (thesis 4.3.3, [PL10]) with T1 = T2 = 1, in float64 on the
    stored float32 AABBs: sum_internal 2*A(n)/A(root) + sum_leaves N_l*A(l)/A(root)."""
    return tree_stats(nodes)["sah_cost"]


def tree_stats(nodes):
    """Node and leaf counts, maximum depth and leaf size, and the SAH cost of the tree rooted
    at node 0. Refuses (InputError naming 'nodes') what :func:`check_nodes` refuses."""
    nodes = check_nodes(nodes)
    u, f = node_views(nodes)
    internal, leaf, n, leaves, depth, max_leaf, prims = _tree_stats(u, f)
    b = nodes["bounds"][0].astype(np.float64)
    d = b[3:] - b[:3]
    root_area = 2.0 * (d[0] * d[1] + d[1] * d[2] + d[2] * d[0])
    if root_area > 0:
        cost = (internal + leaf) / root_area
    else:
        # a zero-area scene (all triangles on a point or a segment): a ray that reaches it
        # reaches every node, so each area ratio counts as 1: both child tests of every
        # internal node and every triangle of every leaf
        cost = float(n - leaves) * 2.0 + float(prims)
    return {"sah_cost": float(cost), "nodes": int(n), "leaves": int(leaves),
            "max_depth": int(depth), "max_leaf_count": int(max_leaf)}
