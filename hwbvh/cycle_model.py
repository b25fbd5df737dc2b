"""Transaction-level timing model of the HWBVH (thesis ch. 3 and 4.2-4.3; SPEC section 6).

The model is driven by the functional builder's real work: every node's primitive count,
every split and every leaf of the canonical tree. What it times:

* Upper builder (one thread, DRAM): the initial AABB pass (one 192-bit word per primitive), the
  root binning pass, and, for every node above the subtree capacity, one streaming partition
  pass that reads and writes its 216-bit records. Each RAM pair has a read channel and a write
  channel, one 192-bit word per cycle each. After each pass the split of the next node waits
  out the partitioning, binning and SAH latencies (Table 3.3); with one thread nothing hides
  them.
* Hand-off: a node that fits a subtree builder is read back from DRAM into the first idle
  subtree builder, through its w fill ports. When none is idle, the upper builder stalls.
* Subtree builder (on chip): an initial split phase, then for every internal node a partition
  pass on the w partitioning units, plus a 2-cycle thread switch. Records stay in the buffer
  pair the fill put them in (at random, 3.3.1), so a pass takes as many cycles as the busiest
  unit holds records of that node, not count / w. The
  children are binned as the records stream out (partitioning latency 36, binning 32), then the
  thread's SAH calculator pair computes both children's splits in 73 cycles (not pipelined).
  Tsize threads hide these latencies. A thread keeps its left internal child; the right one
  spawns a new thread while a thread context is free, and otherwise waits on this thread's own
  stack (3.3.1: each context has its own stack). A thread whose stack empties ends; it does not
  take work from other threads. The partitioning units visit the
  threads in a fixed round-robin order and wait for a thread whose split is not ready (3.3.2).
* Output: node records (two 192-bit words) and the 24-bit index list (8 per word) leave
  through the write channels, overlapped with construction. A subtree builder cannot finish
  before its share of the channels (shared with the builders building when it starts) has
  carried its output, and the build cannot finish before the channels have carried every word
  written, upper-sort writes included.

Only what a build calls for is simulated. A mesh that fits one subtree builder never starts the
upper builder's DRAM model, and its AABB pass is the fill itself.
"""
import math
from dataclasses import asdict, dataclass
from types import MappingProxyType

import numpy as np
from numba import njit, prange

from .files import figure_png
from . import config
from .config import (AABB_BYTES, CONTROL_LATENCY, DEFAULT_BINS, DEFAULT_CAPACITY,
                     DEFAULT_LEAF_SIZE, INDEX_BYTES, LAT_BINNING, LAT_PARTITION, LAT_PRIM_BUFFER,
                     LAT_SAH, NODE_BYTES, THREAD_SWITCH, WORD_BYTES)
from .config import PRIMITIVE_RECORD_BYTES as RECORD_BYTES
from .errors import ParameterError, is_integer
from .resources import cost


@dataclass(frozen=True)
class HwParams:
    """One instantiation (Table 4.1 for the presets)."""
    w: int = 4                 # partitioning units (and buffer pairs) per subtree builder
    tsize: int = 8             # threads per subtree builder (2*Tsize SAH calculators)
    psize: int = DEFAULT_CAPACITY // 4   # primitives per buffer; capacity = w * psize
    subtree_builders: int = 1
    ram_pairs: int = 1
    clock_mhz: float = 250.0
    leaf_size: int = DEFAULT_LEAF_SIZE
    bins: int = DEFAULT_BINS
    control_latency: int = CONTROL_LATENCY   # cycles per split beyond Table 3.3 (calibrated)

    @property
    def capacity(self):
        return self.w * self.psize


# Read-only, as are their parameters (frozen): a caller's change cannot reach another's runs;
# ``dataclasses.replace`` makes a variant.
PRESETS = MappingProxyType({
    "HWBVH-C": HwParams(w=4, tsize=8, psize=2048, subtree_builders=1, ram_pairs=1, clock_mhz=250.0),
    "HWBVH-HP": HwParams(w=4, tsize=8, psize=2048, subtree_builders=2, ram_pairs=2, clock_mhz=500.0),
})


def unit_positions(ids, w):
    """The buffer pair each record is filled into. The fill spreads records over the w pairs
    at random (3.3.1); a fixed hash of the primitive index stands in for that, so a simulation
    is reproducible."""
    return (((ids.astype(np.uint64) * np.uint64(2654435761)) >> np.uint64(7)) % np.uint64(w)).astype(np.int64)


def footprint_bytes(n):
    """Table 4.2: two copies of the AABBs and of the index list,
    2 * (AABB_BYTES + INDEX_BYTES) * N bytes."""
    return 2 * (AABB_BYTES + INDEX_BYTES) * int(n)


@njit(cache=True)
def max_share(unit_pos, start, count, w):
    """Records of a node held by its busiest partitioning unit (each record stays in the buffer
    pair it was filled into, 3.3.1), i.e. the unit-cycles a partition pass takes."""
    if w == 1:
        return count
    share = np.zeros(w, dtype=np.int64)
    for i in range(start, start + count):
        share[unit_pos[i]] += 1
    return share.max()


@njit(cache=True)
def simulate_subtree(cleft, cright, ccount, cstart, unit_pos, root, w, tsize, ctl=0):
    """Cycles a subtree builder needs for the subtree at canonical node ``root`` (after its
    fill), and the busy cycles of its partitioning units and SAH calculators. ``ctl`` is the
    control latency added to every split (``CONTROL_LATENCY``).
    Returns (cycles, pu_busy, sah_busy, partitioned_records)."""
    # the initial split phase: every unit reads its share, the root is binned, then its split
    c0 = ccount[root]
    d0 = max_share(unit_pos, cstart[root], c0, w)
    t0 = LAT_PRIM_BUFFER + d0 + LAT_BINNING + LAT_SAH + ctl
    pu_busy = d0
    sah_busy = LAT_SAH
    if cleft[root] < 0:
        return np.int64(LAT_PRIM_BUFFER + d0 + LAT_PARTITION), pu_busy, 0, np.int64(c0)
    n_alloc = 2 * c0 + 4
    t_node = np.empty(tsize, dtype=np.int64)      # node held by each thread (-1: idle)
    t_ready = np.empty(tsize, dtype=np.int64)     # when its split is ready
    for k in range(tsize):
        t_node[k] = -1
        t_ready[k] = 0
    # each thread context has its own stack (3.3.1) of deferred nodes with computed splits
    depth_cap = n_alloc // 2 + 2
    st_node = np.empty((tsize, depth_cap), dtype=np.int64)
    st_ready = np.empty((tsize, depth_cap), dtype=np.int64)
    sp = np.zeros(tsize, dtype=np.int64)
    t_node[0] = root
    t_ready[0] = t0
    pu_free = 0
    end = t0
    records = 0
    rr = 0
    while True:
        # the partitioning units visit the threads in a fixed round-robin order (3.3.2: "until
        # all threads have been processed", then "from the beginning"), waiting for a thread
        # whose split is not ready yet; idle thread slots are skipped
        k = -1
        for step in range(tsize):
            j = (rr + step) % tsize
            if t_node[j] >= 0:
                k = j
                break
        if k < 0:
            break
        rr = (k + 1) % tsize
        x = t_node[k]
        c = ccount[x]
        start = max(pu_free, t_ready[k])
        dur = max_share(unit_pos, cstart[x], c, w)
        pu_free = start + dur + THREAD_SWITCH
        pu_busy += dur
        records += c
        out = start + dur + LAT_PARTITION            # records (and leaf indices) written
        if out > end:
            end = out
        ready = out + LAT_BINNING + LAT_SAH + ctl    # both children's splits, in parallel
        l = cleft[x]
        r = cright[x]
        li = cleft[l] >= 0
        ri = cleft[r] >= 0
        if li or ri:
            sah_busy += LAT_SAH * ((1 if li else 0) + (1 if ri else 0))
            if ready > end:
                end = ready
        # state S4: continue with an internal child, hand the other to a free thread or stack
        if li and ri:
            t_node[k] = l
            t_ready[k] = ready
            free = -1
            for j in range(tsize):
                if t_node[j] < 0:
                    free = j
                    break
            if free >= 0:                    # a new child spawns a new thread while one is free
                t_node[free] = r
                t_ready[free] = ready
            else:                            # otherwise it waits on this thread's own stack
                st_node[k, sp[k]] = r
                st_ready[k, sp[k]] = ready
                sp[k] += 1
        elif li or ri:
            t_node[k] = l if li else r
            t_ready[k] = ready
        else:
            if sp[k] > 0:                    # pop this thread's stack; an empty stack ends it
                sp[k] -= 1
                t_node[k] = st_node[k, sp[k]]
                t_ready[k] = max(st_ready[k, sp[k]], out)
            else:
                t_node[k] = -1
    return end, pu_busy, sah_busy, records


def sub_nodes(tree, root):
    """Number of nodes in the canonical subtree at ``root``."""
    return int(_count_nodes(tree.left, tree.right, root))


@njit(cache=True)
def _count_nodes(cleft, cright, root):
    stack = [root]
    n = 0
    while stack:
        i = stack.pop()
        n += 1
        if cleft[i] >= 0:
            stack.append(cleft[i])
            stack.append(cright[i])
    return n


def _upper_plan(tree, capacity):
    """Upper nodes (count > capacity) and hand-off roots, in the upper builder's depth-first
    order: a list of ("upper", node) / ("handoff", node) events."""
    events = []
    stack = [tree.root]
    while stack:
        i = stack.pop()
        if tree.count[i] > capacity:
            events.append(("upper", i))
            stack.append(int(tree.right[i]))
            stack.append(int(tree.left[i]))
        else:
            events.append(("handoff", i))
    return events


def simulate(tree, params, node_count=None):
    """Simulate one build of ``tree`` (a CanonicalTree from the functional builder: a Bvh's
    ``bvh.tree``) on the instantiation ``params`` (a HwParams or a preset's name), which must
    have the tree's leaf size and bins. ``node_count``: the nodes written (default: the tree's).
    Returns a dict of the cycles, seconds, traffic, footprint, energy and more; not the tree's
    SAH cost, which the simulation does not change (``bvh.meta["sah_cost"]``; ``simulate_mesh``
    adds it)."""
    p = as_params(params)
    check_tree(tree, p)
    n = int(tree.n_prims)
    if node_count is not None and not (is_integer(node_count) and 1 <= node_count <= 2 * n - 1):
        # a binary tree over n primitives has 1..2n - 1 nodes
        raise ParameterError("node_count", f"must be an integer in 1..{2 * n - 1}, got {node_count!r}")
    cap = p.capacity
    R = p.ram_pairs
    prims_per_cycle_dram = R * WORD_BYTES / RECORD_BYTES      # records/cycle through R channels
    events = _upper_plan(tree, cap)
    unit_pos = unit_positions(tree.ids, p.w)
    traffic = {"aabb": 0, "upper_sort": 0, "nodes": 0, "indices": 0}
    t = 0                              # the upper builder's clock
    upper_nodes = 0
    upper_records = 0
    upper_write_bytes = 0
    stall = 0
    uses_upper = tree.count[tree.root] > cap
    if uses_upper:
        # initial scene-AABB pass: one 192-bit word per primitive, over R read channels
        t += math.ceil(n / R)
        traffic["aabb"] = n * AABB_BYTES
        # root binning pass, then the root's split
        t += math.ceil(n / prims_per_cycle_dram) + LAT_BINNING + LAT_SAH + p.control_latency
        traffic["upper_sort"] += n * RECORD_BYTES
    builder_free = [0] * p.subtree_builders
    builder_busy = [0] * p.subtree_builders
    pu_busy = 0
    sah_busy = 0
    sub_cycles_total = 0
    records_sub = 0
    handoff_sizes = []
    # when each upper node's split is known: the root's after its binning pass (above); a
    # child's once its parent's partition pass, which bins the children as it goes, has
    # drained through the binning units and the SAH calculators. A node popped from the
    # stack finds its split there (3.3.2: "the required split information will be present
    # on the stack"), so the builder waits only where the split is not yet known.
    split_known = {int(tree.root): t}
    for kind, i in events:
        c = int(tree.count[i])
        if kind == "upper":
            t = max(t, split_known[i])
            # one streaming partition pass: read and write every record once
            t += math.ceil(c / prims_per_cycle_dram) + LAT_PARTITION
            known = t + LAT_BINNING + LAT_SAH + p.control_latency
            split_known[int(tree.left[i])] = split_known[int(tree.right[i])] = known
            traffic["upper_sort"] += 2 * c * RECORD_BYTES
            upper_write_bytes += c * RECORD_BYTES
            upper_nodes += 1
            upper_records += c
            continue
        handoff_sizes.append(c)
        # first idle subtree builder; stall the upper builder while none is
        k = int(np.argmin(builder_free))
        if builder_free[k] > t:
            stall += builder_free[k] - t
            t = builder_free[k]
        if uses_upper:
            fill = max(math.ceil(c / prims_per_cycle_dram), math.ceil(c / p.w))
            traffic["upper_sort"] += c * RECORD_BYTES
        else:
            # the whole scene fits: the fill is the only read, and it is the AABB pass
            fill = max(math.ceil(c * RECORD_BYTES / (R * WORD_BYTES)), math.ceil(c / p.w))
            traffic["aabb"] = c * RECORD_BYTES
        t += fill
        cyc, pb, sb, rec = simulate_subtree(tree.left, tree.right, tree.count, tree.start,
                                            unit_pos, int(i), p.w, p.tsize, p.control_latency)
        # the subtree's output (two words per node, 8 indices per word) leaves through this
        # builder's share of the write channels while it builds: the R channels are shared by
        # the builders building when it starts (an idle builder writes nothing and takes no
        # share; one that starts later counts this one in its own share, not the reverse, so
        # with more builders than channels the share is a bound from below); it can only
        # delay the end
        out_words = 2 * sub_nodes(tree, int(i)) + -(-c // 8)
        building = 1 + sum(1 for j, free in enumerate(builder_free) if j != k and free > t)
        share = max(1.0, building / R)
        cyc = max(int(cyc), math.ceil(out_words * share))
        builder_free[k] = t + int(cyc)
        builder_busy[k] += int(cyc) + fill
        pu_busy += int(pb)
        sah_busy += int(sb)
        sub_cycles_total += int(cyc)
        records_sub += int(rec)
    nodes = int(node_count if node_count is not None else tree.stats["nodes"])
    # every word written (upper-sort writes, nodes, indices) crosses the R write channels
    write_words = -(-upper_write_bytes // WORD_BYTES) + 2 * nodes + -(-n // 8)
    cycles = max([t] + builder_free + [math.ceil(write_words / R)])
    traffic["nodes"] = nodes * NODE_BYTES
    traffic["indices"] = -(-n // 8) * WORD_BYTES
    seconds = cycles / (p.clock_mhz * 1e6)
    sub_time = max(1, sum(builder_busy))
    hw = cost(p)             # this instantiation's own area and power, never a preset's
    return {
        "cycles": int(cycles),
        "clock_hz": p.clock_mhz * 1e6,
        "seconds": seconds,
        "traffic_bytes": traffic,
        "traffic_total_bytes": int(sum(traffic.values())),
        "footprint_bytes": footprint_bytes(n),
        "energy_joules": seconds * hw["active_power_w"],
        "area_mm2": hw["area_mm2"],
        "active_power_w": hw["active_power_w"],
        "resources": dict(hw["resources"], gates=hw["gates"]["total"]),
        "upper_builder": {"used": bool(uses_upper), "nodes": upper_nodes,
                          "records_partitioned": int(upper_records), "stall_cycles": int(stall),
                          "finished_at_cycle": int(t)},
        "subtree_builders": {"handoffs": len(handoff_sizes),
                             "largest_handoff": max(handoff_sizes) if handoff_sizes else 0,
                             "records_partitioned": int(records_sub),
                             "busy_cycles": [int(b) for b in builder_busy]},
        "utilisation": {"partitioning_units": pu_busy / sub_time,
                        "sah_calculators": sah_busy / (sub_time * 2 * p.tsize)},
        "parameters": asdict(p) | {"capacity": cap},
    }


def as_params(params, name="params"):
    """``params`` checked by :func:`check_params`; a preset's name stands for the preset."""
    if isinstance(params, str):
        if params not in PRESETS:
            raise ParameterError(name, f"unknown preset {params!r} (choose from {', '.join(PRESETS)})")
        return PRESETS[params]
    if not isinstance(params, HwParams):
        raise ParameterError(name, f"expected a HwParams or a preset name ({', '.join(PRESETS)}), "
                                   f"got {type(params).__name__}")
    return check_params(params)


def check_tree(tree, params):
    """Refuse (ParameterError 'tree') anything but a build tree the hardware ``params`` builds.

    The cycles come from the tree and the area and power from ``params`` (its bins size the bin
    records), so a tree of another leaf size or bin count would be reported with the time of
    one machine and the cost of another: a mismatch is refused rather than reported."""
    from .api import Bvh
    from .builder import CanonicalTree

    if isinstance(tree, Bvh):
        hint = ("pass bvh.tree" if tree.tree is not None
                else "this Bvh was loaded from files or refitted and has no build tree: "
                     "build it")
        raise ParameterError("tree", f"expected the build tree, got a Bvh ({hint})")
    if tree is None:
        raise ParameterError("tree", "got None: a Bvh loaded from files or refitted has no "
                                     "build tree (bvh.tree); build it")
    if not isinstance(tree, CanonicalTree):
        raise ParameterError("tree", f"expected the build tree (a CanonicalTree, bvh.tree), "
                                     f"got {type(tree).__name__}")
    if tree.builder != "hwbvh":
        raise ParameterError("tree", f"the hardware builds binned SAH trees; this one comes from "
                                     f"the {tree.builder!r} builder")
    if (tree.leaf_size, tree.bins) != (params.leaf_size, params.bins):
        raise ParameterError("params", f"leaf_size {params.leaf_size} and bins {params.bins} did not "
                                       f"build this tree (leaf_size {tree.leaf_size}, bins "
                                       f"{tree.bins}); pass params with the tree's")


def check_params(p):
    """``p`` with its knobs as Python numbers (a NumPy int16 would wrap in the model's
    products, a float16 clock overflow in Hz), or ParameterError (naming the parameter)
    unless every knob is within the hardware's range (``config.KNOB_RANGES``)."""
    from dataclasses import replace
    if not isinstance(p, HwParams):
        raise ParameterError("params", f"expected a HwParams, got {type(p).__name__}")
    numbers = {}
    for k, (lo, hi) in config.KNOB_RANGES.items():
        v = getattr(p, k)
        if k == "clock_mhz":
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                    or not lo <= v <= hi:
                raise ParameterError(k, f"must be a clock in MHz within {lo:g}..{hi:g}, got {v!r}")
            numbers[k] = float(v)
            continue
        if not is_integer(v) or not lo <= v <= hi:
            raise ParameterError(k, f"must be an integer within {lo}..{hi} in the hardware, got {v!r}")
        if k in config.POWER_OF_TWO_KNOBS and v & (v - 1):
            raise ParameterError(k, f"must be a power of two (thesis 3.3), got {v}")
        numbers[k] = int(v)
    p = replace(p, **numbers)
    if p.w * p.psize > config.MAX_PRIMITIVES:
        raise ParameterError("psize", f"w * psize = {p.w * p.psize} exceeds the 24-bit primitive index "
                                  f"({config.MAX_PRIMITIVES})")
    if p.w * p.psize < p.leaf_size:
        # the upper builder splits a node until its primitives fit a subtree builder; a leaf
        # it may not split would never fit one
        raise ParameterError("psize", f"w * psize = {p.w * p.psize} is below the leaf size "
                                      f"{p.leaf_size}: a subtree builder must hold a leaf")
    v = p.control_latency
    if not is_integer(v) or not 0 <= v <= config.MAX_CONTROL_LATENCY:
        raise ParameterError("control_latency", f"must be a non-negative integer up to "
                                                f"{config.MAX_CONTROL_LATENCY}, got {v!r}")
    return replace(p, control_latency=int(v))


def params_for(preset="HWBVH-C", **overrides):
    """A preset (its name, or any HwParams) with some parameters replaced (None values are
    ignored), checked against the hardware's ranges."""
    from dataclasses import fields, replace

    base = as_params(preset, "preset")
    names = {f.name for f in fields(HwParams)}
    kw = {k: v for k, v in overrides.items() if v is not None}
    for k in kw:
        if k not in names:
            raise ParameterError(k, f"not a parameter of the hardware (choose from {', '.join(sorted(names))})")
    return check_params(replace(base, **kw))


def preset_named(params):
    """The name of the preset whose values ``params`` has, or None."""
    return next((name for name, p in PRESETS.items() if p == params), None)


def simulate_mesh(source, preset="HWBVH-C", **overrides):
    """Build ``source`` (mesh path or (n,3,3) triangles) functionally, then simulate it on
    ``preset`` (a preset's name or a HwParams) with ``overrides`` (``params_for``). The result
    says what was simulated: ``preset``, the name of the preset whose values it has (None for
    any other configuration); ``base_preset``, the preset it was made from ("custom" for a
    HwParams that is no preset); ``changed``, the knobs that differ from that one, with their
    values."""
    import time
    from .api import _triangles
    from .builder import build_canonical
    from .format import tree_stats
    from .layout import lay_out
    from .primitives import primitive_boxes

    p = params_for(preset, **overrides)
    tris, _ = _triangles(source)
    tree = build_canonical(primitive_boxes(tris), leaf_size=p.leaf_size, bins=p.bins)
    t = time.perf_counter()
    out = simulate(tree, p)
    out["simulation_seconds"] = time.perf_counter() - t
    nodes, _, _ = lay_out(tree, p.capacity, p.subtree_builders)
    out["sah_cost"] = tree_stats(nodes)["sah_cost"]
    out["triangles"] = int(len(tris))
    base = as_params(preset, "preset")
    changed = {k: v for k, v in asdict(p).items() if getattr(base, k) != v}
    if p.capacity != base.capacity:     # derived (w x Psize), but a knob's effect all the same
        changed["capacity"] = p.capacity
    # named by its values, as explore names its configurations: HWBVH-C with HWBVH-HP's
    # builders, channels and clock is HWBVH-HP
    out["preset"] = preset_named(p)
    out["base_preset"] = (preset if isinstance(preset, str) else preset_named(base)) or "custom"
    out["changed"] = changed
    return out


@njit(cache=True, parallel=True)
def _sweep_kernel(cleft, cright, ccount, cstart, unit_pos_by_w, root, ws, ts, ctl):
    """Build cycles (fill excluded) of the subtree at ``root`` for every (w, Tsize) pair, in
    parallel over the pairs."""
    out = np.zeros((ws.shape[0], ts.shape[0]), dtype=np.int64)
    for q in prange(ws.shape[0] * ts.shape[0]):
        a = q // ts.shape[0]
        b = q % ts.shape[0]
        cyc, _, _, _ = simulate_subtree(cleft, cright, ccount, cstart, unit_pos_by_w[a], root,
                                        ws[a], ts[b], ctl)
        out[a, b] = cyc
    return out


def subtree_design_space(mesh, out_dir, leaf_sizes=(4, 8, 32, 64), grid=(2, 4, 8, 16), jobs=None,
          n_subtrees=5, lo=4096, hi=8192, control_latency=CONTROL_LATENCY, write=True):
    """Design-space exploration as thesis 4.2.1 runs it, on subtrees of lo..hi primitives cut
    from a real mesh (the upper builder's hand-offs): the subtree builder alone, its capacity
    held (Psize = capacity / w), w and Tsize over ``grid``, the thesis' leaf sizes 4, 8, 32 and
    64; a CSV of cycles per (leaf size, w, Tsize) and Figs. 4.2 (speedup over w = Tsize = 2)
    and 4.3 (cycles against leaf size). As in the thesis, the fill is factored out of the
    cycles; ``fill_share`` compares the fill through the w ports with the build (thesis: 3.6%
    on average, 8.8% at most). ``write``: write the files into ``out_dir`` (else the result's
    ``files`` holds them, ``hwbvh.files.write_files`` pairs)."""
    import csv
    import io
    import os
    from .api import _triangles, write_files
    from .builder import build_canonical
    from .primitives import primitive_boxes

    if jobs:
        import numba
        numba.set_num_threads(max(1, min(int(jobs), numba.config.NUMBA_NUM_THREADS)))
    tris, src = _triangles(mesh)
    boxes = primitive_boxes(tris)
    base = build_canonical(boxes)
    # subtrees the upper builder would hand off, restricted to lo..hi primitives
    cands = [i for kind, i in _upper_plan(base, hi) if kind == "handoff" and lo <= base.count[i] <= hi]
    if not cands:
        cands = [base.root]
    cands = cands[:n_subtrees]
    ws = np.array(grid, dtype=np.int64)
    ts = np.array(grid, dtype=np.int64)
    rows = []
    shares = []
    for leaf in leaf_sizes:
        total = np.zeros((len(ws), len(ts)), dtype=np.int64)
        for root in cands:
            ids = base.ids[base.start[root]:base.start[root] + base.count[root]]
            sub = build_canonical(boxes[ids], leaf_size=int(leaf))
            upw = np.stack([unit_positions(sub.ids, w) for w in ws])
            build = _sweep_kernel(sub.left, sub.right, sub.count, sub.start, upw, int(sub.root),
                                  ws, ts, int(control_latency))
            fill = -(-len(ids) // ws)[:, None]             # the fill through w ports
            total += build
            shares.append((fill / build).ravel())
        ref = total[0, 0]
        for a, w in enumerate(ws):
            for b, t in enumerate(ts):
                rows.append({"leaf_size": int(leaf), "w": int(w), "tsize": int(t),
                             "cycles": int(total[a, b]), "speedup": float(ref / total[a, b])})
    buf = io.StringIO()
    wr = csv.DictWriter(buf, fieldnames=list(rows[0]))
    wr.writeheader()
    wr.writerows(rows)
    csv_path = os.path.join(out_dir, "subtree_design_space.csv")
    files = [(csv_path, buf.getvalue())] + _sweep_plots(rows, out_dir, leaf_sizes, grid)
    if write:
        write_files(files)
    shares = np.concatenate(shares)
    out = {"csv": csv_path, "plots": [p for p, _ in files[1:]],
           "subtrees": [int(base.count[c]) for c in cands],
           "rows": rows, "mesh": src, "control_latency": int(control_latency),
           "fill_share": {"mean": float(shares.mean()), "max": float(shares.max()),
                          "thesis_mean": 0.036, "thesis_max": 0.088}}
    if not write:
        out["files"] = files
    return out




def _sweep_plots(rows, out_dir, leaf_sizes, grid):
    import os
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def get(leaf, w, t, key):
        return next(r[key] for r in rows if r["leaf_size"] == leaf and r["w"] == w and r["tsize"] == t)

    files = []
    # Fig. 4.2 style: speedup over w = Tsize = 2 against Tsize, one line per w, per leaf size
    shown = [l for l in leaf_sizes if l in (4, 8, 32, 64)] or list(leaf_sizes)[:4]
    fig, axes = plt.subplots(2, 2, figsize=(9, 7), squeeze=False)
    for ax, leaf in zip(axes.ravel(), shown):
        for w in grid:
            ax.plot(grid, [get(leaf, w, t, "speedup") for t in grid], marker="o", label=f"w = {w}")
        ax.set_xscale("log", base=2)
        ax.set_xticks(grid, [str(g) for g in grid])
        ax.set_title(f"leaf size {leaf}")
        ax.set_xlabel("Tsize")
        ax.set_ylabel("speedup over w=2, Tsize=2")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    files.append((os.path.join(out_dir, "fig4_2_speedup.png"), figure_png(fig, dpi=110)))
    # Fig. 4.3 style: cycles against leaf size, one panel per Tsize, one line per w
    fig, axes = plt.subplots(2, 2, figsize=(9, 7), squeeze=False)
    for ax, t in zip(axes.ravel(), grid):
        for w in grid:
            ax.plot(leaf_sizes, [get(l, w, t, "cycles") for l in leaf_sizes], marker="o", label=f"w = {w}")
        ax.set_xscale("log", base=2)
        ax.set_xticks(list(leaf_sizes), [str(l) for l in leaf_sizes])
        ax.set_title(f"Tsize = {t}")
        ax.set_xlabel("leaf size")
        ax.set_ylabel("cycles (sum over subtrees, fill factored out)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    files.append((os.path.join(out_dir, "fig4_3_leaf_size.png"), figure_png(fig, dpi=110)))
    return files
