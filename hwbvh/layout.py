"""Tree output logic (thesis 3.3.5, SPEC sections 3-4): where each node lands in memory.

* Nodes are written depth-first; an internal node's AABB is written first and a gap left for
  its child pointers, filled when the children's addresses are known, so the left child
  directly follows its parent.
* The upper builder writes the nodes above the subtree capacity; each node that fits is handed,
  in the upper builder's depth-first order, to a subtree builder. The functional model hands
  them out round-robin (builder ``h mod K`` gets hand-off h); the cycle model decides real
  idleness. Builders keep writing into the block they hold and take the next fixed-size block
  from the pool when it is full, so a right child (or a whole subtree) may live in another block.
* The root is node 0. Unused slots at the end of partly filled blocks are zero records that no
  pointer reaches; the file ends at the last written node.

The result never changes the tree: only placement. Index-list order is the depth-first leaf
order, which is also the order the subtree builders write their index lists in.
"""
import numpy as np
from numba import njit

from .config import LEAF_FLAG
from .format import NODE_DTYPE, WORD_A, WORD_B, WORD_BOX, WORD_FLAGS, node_views


@njit(cache=True)
def assign_slots(cleft, cright, ccount, root, capacity, n_builders, block_nodes, max_depth):
    m = cleft.shape[0]
    final = np.full(m, -1, dtype=np.int64)
    cur_block = np.full(n_builders + 1, -1, dtype=np.int64)
    fill = np.zeros(n_builders + 1, dtype=np.int64)
    next_block = 0
    handoff = np.empty(m, dtype=np.int32)       # canonical root of each hand-off
    n_handoff = 0
    # a pre-order stack never holds more than depth + 1 pending nodes
    stack = np.empty(max_depth + 3, dtype=np.int64)
    sstream = np.empty(max_depth + 3, dtype=np.int64)
    sp = 1
    stack[0] = root
    sstream[0] = 0
    max_slot = -1
    while sp > 0:
        sp -= 1
        i = stack[sp]
        st = sstream[sp]
        if ccount[i] > capacity:
            st = 0
        elif st == 0:
            st = 1 + n_handoff % n_builders
            handoff[n_handoff] = i
            n_handoff += 1
        if cur_block[st] < 0 or fill[st] == block_nodes:
            cur_block[st] = next_block
            next_block += 1
            fill[st] = 0
        slot = cur_block[st] * block_nodes + fill[st]
        fill[st] += 1
        final[i] = slot
        if slot > max_slot:
            max_slot = slot
        if cleft[i] >= 0:
            if sp + 2 > stack.shape[0]:         # never on a correct depth; grow, don't trust
                # element by element: a slice assignment compiles a shape check whose error
                # message alone takes seconds of a first run's compilation
                bigger = np.empty(2 * stack.shape[0] + 2, dtype=np.int64)
                bigger_st = np.empty(2 * sstream.shape[0] + 2, dtype=np.int64)
                for k in range(sp):
                    bigger[k] = stack[k]
                    bigger_st[k] = sstream[k]
                stack = bigger
                sstream = bigger_st
            stack[sp] = cright[i]
            sstream[sp] = st
            stack[sp + 1] = cleft[i]
            sstream[sp + 1] = st
            sp += 2
    return final, handoff[:n_handoff], max_slot + 1, next_block


@njit(cache=True)
def write_records(cbox, cleft, cright, cstart, ccount, final, u, f):
    for i in range(cleft.shape[0]):
        s = final[i]
        if s < 0:
            continue
        for k in range(6):
            f[s, WORD_BOX + k] = cbox[i, k]
        if cleft[i] < 0:
            u[s, WORD_A] = cstart[i]
            u[s, WORD_B] = ccount[i]
            u[s, WORD_FLAGS] = LEAF_FLAG
        else:
            u[s, WORD_A] = final[cleft[i]]
            u[s, WORD_B] = final[cright[i]]
            u[s, WORD_FLAGS] = 0


def lay_out(tree, capacity, n_builders=1, block_nodes=256):
    """Place a :class:`~hwbvh.builder.CanonicalTree` in memory.

    Returns (nodes NODE_DTYPE array, handoff (h,) int64 canonical roots, info dict).
    """
    final, handoff, nslots, blocks = assign_slots(tree.left, tree.right, tree.count, tree.root,
                                                  int(capacity), int(n_builders), int(block_nodes),
                                                  int(tree.stats["max_depth"]))
    nodes = np.zeros(nslots, dtype=NODE_DTYPE)
    u, f = node_views(nodes)
    write_records(tree.box, tree.left, tree.right, tree.start, tree.count, final, u, f)
    return nodes, handoff, {"node_slots": int(nslots), "blocks": int(blocks),
                            "handoffs": int(len(handoff))}
