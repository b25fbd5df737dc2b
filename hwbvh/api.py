"""Build a BVH in the hardware's format, save it, load it back.

>>> bvh = build(triangles)                  # (n, 3, 3) float array, or a mesh path
>>> bvh.nodes                                # NODE_DTYPE records, root at 0
>>> bvh.indices                              # index-list entries (uint32, < 2^24)
>>> save(bvh, "out/bunny")                   # bunny.nodes / bunny.indices / bunny.json
"""
import json
import os
import re
import time
from dataclasses import dataclass, field

import numpy as np

from . import config
from .builder import build_canonical, check_params, check_task_prims
from .errors import InputError, ParameterError, checked_flag, is_integer, json_syntax, shown
from .files import json_object_in, json_text, made_as_written, write_files
from .format import NODE_DTYPE, check_nodes, pack_indices, tree_stats, unpack_indices, validate
from .layout import lay_out
from .parallel import check_threading
from .primitives import as_triangles, load_triangles, primitive_boxes
from .sweep import build_sweep

BUILDERS = ("hwbvh", "sweep")


@dataclass
class Bvh:
    """A BVH in the 384-bit node format with its 24-bit index list.

    nodes : (m,) NODE_DTYPE; indices : (N,) uint32 primitive index per index-list position;
    triangles : (N, 3, 3) float32 (what the indices refer to); meta : the NAME.json contents.
    One that ``build`` or ``load`` returns holds every invariant, and ``traversal.Tracer``
    takes it as it is; a tree made otherwise (or a copy with other arrays) is validated there
    first. Arrays changed in place after ``build`` or ``load`` are not checked again.
    """
    nodes: np.ndarray
    indices: np.ndarray
    triangles: np.ndarray
    meta: dict
    handoff: np.ndarray = field(default=None, repr=False)   # canonical roots, for dumps
    tree: object = field(default=None, repr=False)          # the CanonicalTree

    @property
    def n_prims(self):
        return len(self.indices)

    def handoff_order(self):
        """Primitive indices in the order the upper builder hands them to subtree builders
        (thesis ``mike_rt -U``), and the size of each hand-off."""
        t = self.tree
        if t is None or self.handoff is None:
            raise ParameterError("bvh", "has no build record (loaded from files, refitted or made "
                                        "by hand), so no hand-off order: rebuild it for that")
        starts = t.start[self.handoff].astype(np.int64)
        counts = t.count[self.handoff].astype(np.int64)
        order = np.concatenate([t.ids[s:s + c] for s, c in zip(starts, counts)]) if len(starts) else \
            np.empty(0, np.int32)
        return order, counts


def _path_of(path, parameter):
    """``path`` (str, bytes or os.PathLike) as a str, else ParameterError naming it."""
    if isinstance(path, bytes):                     # a path in the file system's encoding
        return os.fsdecode(path)
    if not isinstance(path, (str, os.PathLike)):
        raise ParameterError(parameter, f"expected a path, got {type(path).__name__}")
    return os.fspath(path)


def _triangles(source, name=None):
    if isinstance(source, (bytes, str, os.PathLike)):
        source = _path_of(source, "source")
    if isinstance(source, str):
        return load_triangles(source), os.fspath(source)
    return as_triangles(source, source=name or "<array>"), name or "<array>"


def _check_capacity(capacity, leaf_size, sweep=False):
    """A subtree builder takes the subtrees of at most ``capacity`` primitives: it must hold
    a leaf (as ``cycle_model.simulate`` requires of w * psize). The sweep builder has no leaf
    size one sets: ``leaf_size`` is then the largest leaf it made."""
    if capacity < leaf_size:
        leaf = f"the largest leaf the sweep builder made ({leaf_size} triangles)" if sweep \
            else f"the leaf size {leaf_size}"
        raise ParameterError("capacity", f"{capacity} is below {leaf}: a subtree builder must "
                                         f"hold a leaf")


def build(source, builder="hwbvh", leaf_size=config.DEFAULT_LEAF_SIZE, bins=config.DEFAULT_BINS,
          capacity=config.DEFAULT_CAPACITY, subtree_builders=1,
          block_nodes=config.DEFAULT_BLOCK_NODES, validate_tree=False, task_prims=None,
          source_name=None):
    """Build a BVH over a mesh path or an ``(n, 3, 3)`` triangle array.

    builder : "hwbvh" (the hardware's binned SAH, exact) or "sweep" (full SAH reference,
        which makes its leaves where the SAH stops splitting: it takes no leaf size or bins).
    leaf_size : the most triangles a leaf holds (1..``config.MAX_LEAF_SIZE``).
    bins : SAH bins per axis (``config.MIN_BINS``..``config.MAX_SOFTWARE_BINS``; the hardware's
        binning units have at most ``config.MAX_HARDWARE_BINS``).
    capacity, subtree_builders, block_nodes : where nodes land (never what the tree is).
    validate_tree : check the written tree's invariants after the build (as ``validate``).
    task_prims : the fewest primitives a parallel build task takes (None: the default); it
        changes how the work is shared out, never the tree.
    source_name : what errors and ``meta["source"]`` call an array source (e.g. its file).

    ``Bvh.triangles`` is the tree's own copy of an array source, so a change the caller makes
    to the array in place afterwards does not reach the tree (``refit``, or build again; a
    render of the changed scene with a tracer over the old tree is refused).
    ``meta["build_seconds"]`` times the build alone, but the first build in a process also
    loads (or, the first time ever, compiles) its kernels: ``hwbvh.warm_up()`` first when the
    time matters.
    """
    if builder not in BUILDERS:
        raise ParameterError("builder", f"unknown builder {builder!r} (choose from {', '.join(BUILDERS)})")
    validate_tree = checked_flag(validate_tree, "validate_tree")
    if source_name is not None:
        source_name = _path_of(source_name, "source_name")
    check_params(leaf_size, bins)
    if builder == "sweep":
        for name, v, default in (("leaf_size", leaf_size, config.DEFAULT_LEAF_SIZE),
                                 ("bins", bins, config.DEFAULT_BINS)):
            if v != default:
                raise ParameterError(name, f"the sweep builder takes none: it makes its leaves "
                                           f"where the full SAH stops splitting, got {v!r}")
    check_task_prims(task_prims)
    check_threading()
    ranges = config.LAYOUT_KNOB_RANGES
    for name, v in (("capacity", capacity), ("subtree_builders", subtree_builders),
                    ("block_nodes", block_nodes)):
        lo, hi = ranges[name]
        if not is_integer(v) or not lo <= v <= hi:
            span = "a positive integer below 2^63" if hi == 2**63 - 1 else f"an integer in {lo}..{hi}"
            raise ParameterError(name, f"must be {span}, got {v!r}")
    # as Python integers: a kernel is compiled once per argument type, so a NumPy integer of
    # another width would compile the builder's kernels again
    leaf_size, bins, capacity, subtree_builders, block_nodes = (
        int(v) for v in (leaf_size, bins, capacity, subtree_builders, block_nodes))
    task_prims = None if task_prims is None else int(task_prims)
    if builder == "hwbvh":
        _check_capacity(capacity, leaf_size)
    tris, src = _triangles(source, source_name)
    if isinstance(source, np.ndarray) and np.may_share_memory(tris, source):
        # the tree holds its own: a change the caller makes in place afterwards is then told
        # apart from the tree's triangles (render refuses the pair) instead of traced unseen
        tris = tris.copy()
    if (1 + subtree_builders) * block_nodes + 2 * len(tris) - 1 > config.MAX_NODE_SLOTS:
        raise ParameterError("block_nodes", f"{block_nodes} nodes per block for "
                                            f"{subtree_builders} subtree builders and "
                                            f"{len(tris)} triangles could place nodes beyond the "
                                            f"format's 32-bit child pointers")
    t0 = time.perf_counter()
    boxes = primitive_boxes(tris)
    if builder == "hwbvh":
        tree = build_canonical(boxes, leaf_size=leaf_size, bins=bins, task_prims=task_prims)
        max_leaf = leaf_size
    else:
        tree = build_sweep(boxes)
        max_leaf = tree.leaf_size
        used = tree.stats["nodes"]
        _check_capacity(capacity, int(tree.count[:used][tree.axis[:used] == -1].max()),
                        sweep=True)
    nodes, handoff, info = lay_out(tree, capacity, subtree_builders, block_nodes)
    seconds = time.perf_counter() - t0
    st = tree_stats(nodes)
    meta = {
        "format": TREE_FORMAT,
        "source": src,
        "builder": builder,
        "triangles": int(len(tris)),
        "nodes": st["nodes"],
        "node_slots": info["node_slots"],
        "leaves": st["leaves"],
        "max_depth": st["max_depth"],
        "sah_cost": st["sah_cost"],
        "fallback_splits": tree.stats["fallback_splits"],
        "build_seconds": seconds,
        "parameters": {
            "leaf_size": int(leaf_size) if builder == "hwbvh" else None,
            "max_leaf": int(max_leaf),
            "bins": int(bins) if builder == "hwbvh" else None,
            "capacity": int(capacity),
            "subtree_builders": int(subtree_builders),
            "block_nodes": int(block_nodes),
        },
        "handoffs": info["handoffs"],
        "blocks": info["blocks"],
    }
    bvh = Bvh(nodes=nodes, indices=tree.ids.astype(np.uint32), triangles=tris, meta=meta,
              handoff=handoff, tree=tree)
    bvh._invariants_hold = True                 # as built (the tests hold the builders to it)
    if validate_tree:
        validate(nodes, bvh.indices, len(tris), max_leaf, boxes, source=src)
    return bvh


def warm_up(builder="hwbvh", parallel=False):
    """Load (or, the first time ever, compile) a builder's Numba kernels on a tiny input, so
    that a build timed next measures building, not kernel loading. ``parallel`` also loads the
    data-parallel kernels that meshes above ``config.SEQUENTIAL_MAX_PRIMS`` use. Returns the
    seconds it took."""
    t = time.perf_counter()
    rng = np.random.default_rng(0)
    soup = rng.uniform(0.0, 1.0, (64, 1, 3)) + rng.uniform(-0.05, 0.05, (64, 3, 3))
    build(soup, builder=builder)
    if parallel and builder == "hwbvh":
        build(soup, builder=builder, task_prims=16)
    return time.perf_counter() - t


TREE_EXTENSIONS = (".nodes", ".indices", ".json")      # SPEC 4, in the order they are written
TREE_FORMAT = "hwrt-bvh-1"       # the "format" of a tree's description (PREFIX.json)


def tree_paths(prefix):
    """The files a tree saved under ``prefix`` is: PREFIX.nodes, PREFIX.indices, PREFIX.json. A
    prefix given as one of them (``tree.json``) names the same three, as ``load`` reads it."""
    prefix = tree_prefix(prefix)
    return [prefix + ext for ext in TREE_EXTENSIONS]


def tree_prefix(prefix):
    """The prefix of the tree ``prefix`` names: itself, or without the extension when it is one
    of the tree's files (``tree.json`` names the tree ``tree``), for ``save`` and ``load``
    alike."""
    prefix = os.fspath(prefix)
    stem, ext = os.path.splitext(prefix)
    return stem if ext in TREE_EXTENSIONS and os.path.basename(stem) else prefix


_SEPARATORS = tuple(filter(None, (os.sep, os.altsep)))     # the path separators of this system


def prefix_problem(prefix):
    """Why ``prefix`` cannot name a tree's three files, or None: empty, a directory, ending in
    a path separator or a file name starting with a dot would each write hidden files
    (``.nodes``, ``.json.nodes``, ...); a PREFIX.json that is there and is not a tree's (a
    scene file, when the prefix was given as ``scene.json``) would be replaced."""
    if not prefix:
        return "is empty"
    if os.path.isdir(prefix):
        return "names a directory"
    if prefix.endswith(_SEPARATORS):
        return "ends in a path separator"
    if os.path.basename(prefix).startswith("."):
        return "is a file name starting with a dot (hidden files)"
    meta = tree_paths(prefix)[2]
    # only a regular file is read (a pipe or a device is check_outputs' to refuse)
    if os.path.isfile(meta) and not _holds_tree_meta(meta):
        return (f"is taken: {meta} is there and is not a tree's description, which the tree "
                f"would replace")
    return None


def _holds_tree_meta(path):
    """Whether the file ``path`` holds a tree's description: a JSON object with this format's
    name, or, as ``load`` takes one, with no format named and a triangle count."""
    meta = json_object_in(path, config.TREE_META_READ_BYTES)
    return meta is not None and (meta.get("format") == TREE_FORMAT or
                                 ("format" not in meta and "triangles" in meta))


def prefix_example(prefix):
    """A prefix of file names to suggest in place of ``prefix``, which ``prefix_problem``
    refuses: ``tree`` in the directory it names, or beside the file name it gives."""
    inside = os.path.isdir(prefix) or prefix.endswith(_SEPARATORS)
    return os.path.join(prefix if inside else os.path.dirname(prefix), "tree")


def tree_files(bvh, prefix):
    """The (path, data) pairs of :func:`tree_paths` for :func:`hwbvh.files.write_files` (alone,
    or in one set with other files); each file's bytes are made as it is written."""
    nodes, indices, meta = tree_paths(prefix)
    return [(nodes, made_as_written(lambda: bvh.nodes)),
            (indices, made_as_written(lambda: pack_indices(bvh.indices))),
            (meta, json_text(bvh.meta, indent=2) + "\n")]


def save(bvh, prefix):
    """Write PREFIX.nodes, PREFIX.indices and PREFIX.json (SPEC 4; a prefix given as one of
    them, ``tree.json``, names the same three): a tree ``load`` reads back as it is, so it is
    checked as ``load`` checks it first (a tree changed after its build may not be one),
    against its triangles where it has them. Returns the three paths."""
    if not all(hasattr(bvh, a) for a in ("nodes", "indices", "meta")):
        raise ParameterError("bvh", f"expected an hwbvh.Bvh, got {type(bvh).__name__}")
    prefix = _path_of(prefix, "prefix")
    problem = prefix_problem(prefix)
    if problem:
        raise ParameterError("prefix", f"{prefix!r} {problem}: give a prefix of file names such "
                                       f"as {prefix_example(prefix)!r}")
    meta = bvh.meta
    if not isinstance(meta, dict):
        raise ParameterError("bvh.meta", f"expected a dict, got {type(meta).__name__}")
    try:
        json_text(meta)
    except (TypeError, ValueError) as e:
        raise ParameterError("bvh.meta", f"cannot be written as JSON ({e})") from None
    indices = np.asarray(bvh.indices) if bvh.indices is not None else None
    if indices is None or indices.ndim != 1 or indices.dtype.kind not in "iu" or \
            (indices.size and (indices.min() < 0 or indices.max() >= config.INDEX_PAD)):
        raise ParameterError("bvh.indices", f"must be a 1-D array of integers in "
                                            f"0..{config.INDEX_PAD - 1} (24 bits, the top value "
                                            f"pads), got {_described(bvh.indices)}")
    tris = getattr(bvh, "triangles", None)
    _checked_tree(meta, check_nodes(bvh.nodes, n_positions=len(indices), source="bvh.nodes"),
                  indices, None if tris is None else as_triangles(tris, source="bvh.triangles"),
                  "bvh.meta", "bvh.nodes", "bvh.indices", "bvh.triangles")
    files = tree_files(bvh, prefix)
    write_files(files)
    return [path for path, _ in files]


def _described(a):
    a = np.asarray(a) if a is not None else None
    return "None" if a is None else f"{a.dtype} of shape {a.shape}"


def load(prefix, triangles=None):
    """Read PREFIX.nodes / .indices / .json and validate every invariant. ``triangles``
    (optional (N, 3, 3)) also checks that leaf boxes contain their primitives. A prefix given
    as one of the three files (``x.nodes``) names its tree (``tree_prefix``), as in ``save``."""
    prefix = tree_prefix(_path_of(prefix, "prefix"))
    try:
        with open(prefix + ".json", encoding="utf-8") as f:
            meta = json.load(f)
    except OSError as e:
        raise InputError(prefix + ".json", e.strerror or "cannot read") from None
    except UnicodeDecodeError:
        raise InputError(prefix + ".json", "not UTF-8 text") from None
    except json.JSONDecodeError as e:
        raise InputError(prefix + ".json", f"not valid JSON ({json_syntax(e)})") from None
    except RecursionError:
        raise InputError(prefix + ".json", "not a tree's description (nested too deeply)") \
            from None
    if not isinstance(meta, dict):
        raise InputError(prefix + ".json", f"expected a JSON object, got {type(meta).__name__}")
    if meta.get("format", TREE_FORMAT) != TREE_FORMAT:     # another program's description
        raise InputError(prefix + ".json", f"its format is {meta['format']!r}, not a tree's "
                                           f"description ({TREE_FORMAT!r})")
    n = _json_count(meta, ("triangles",), config.MAX_PRIMITIVES, prefix + ".json")
    tris = None
    if triangles is not None:
        tris = as_triangles(triangles, source="triangles")
        if len(tris) != n:
            raise InputError("triangles", f"{len(tris)} triangles, but the tree has {n} primitives")
    try:
        with open(prefix + ".nodes", "rb") as f:
            raw = f.read()
        with open(prefix + ".indices", "rb") as f:
            idx = f.read()
    except OSError as e:
        raise InputError(e.filename, e.strerror or "cannot read") from None
    if len(raw) % NODE_DTYPE.itemsize:
        raise InputError(prefix + ".nodes", f"size {len(raw)} is not a multiple of 48 bytes")
    nodes = np.frombuffer(raw, dtype=NODE_DTYPE).copy()
    word = config.INDEX_BYTES * config.INDICES_PER_WORD
    words = -(-n // config.INDICES_PER_WORD)
    if len(idx) != words * word:
        raise InputError(prefix + ".indices", f"size {len(idx)} bytes: {n} triangles take "
                                              f"{words} whole {word}-byte words, {words * word} "
                                              f"bytes")
    entries = unpack_indices(idx)
    if (entries[n:] != config.INDEX_PAD).any():
        raise InputError(prefix + ".indices", f"the last word's tail after entry {n} is not "
                                              f"padding (0xFFFFFF)")
    _checked_tree(meta, nodes, entries[:n], tris, prefix + ".json", prefix + ".nodes",
                  prefix + ".indices", "triangles")
    bvh = Bvh(nodes=nodes, indices=entries[:n].copy(), triangles=tris, meta=meta)
    bvh._invariants_hold = True                 # as validated above
    return bvh


def _checked_tree(meta, nodes, entries, tris, meta_name, nodes_name, indices_name, tris_name):
    """The invariants of a tree as ``load`` reads it and ``save`` writes it (InputError naming
    the part): its description's counts, every invariant of the nodes over the ``entries``
    (and leaf boxes around ``tris`` given: a sound tree whose leaves do not hold them names
    ``tris_name``, other triangles than its own), and the node count it states."""
    n = _json_count(meta, ("triangles",), config.MAX_PRIMITIVES, meta_name)
    # no builder writes a leaf above MAX_LEAF_SIZE (the sweep builder's limit is below it)
    max_leaf = _json_count(meta, ("parameters", "max_leaf"), config.MAX_LEAF_SIZE, meta_name)
    if len(entries) != n:
        raise InputError(indices_name, f"{len(entries)} entries, but {meta_name} says {n} "
                                       f"triangles")
    if tris is not None and len(tris) != n:
        raise InputError(meta_name, f"says {n} triangles, the tree has {len(tris)}")
    reached = validate(nodes, entries, n, max_leaf, source=nodes_name)
    if tris is not None:
        try:
            validate(nodes, entries, n, max_leaf, primitive_boxes(tris), source=nodes_name)
        except InputError as e:         # the boxes are all that changed: a leaf's box
            node = re.search(r"\(node (\d+)\)", str(e))
            where = f" (node {node.group(1)} of {nodes_name})" if node else ""
            raise InputError(tris_name, f"a triangle lies outside its leaf's box{where}: not "
                                        f"the triangles the tree was built over") from None
    # the counts a reader reports must be the tree's own
    for key, got in (("nodes", reached), ("node_slots", len(nodes))):
        if key in meta or key == "nodes":
            said = _json_count(meta, (key,), 2 * config.MAX_PRIMITIVES, meta_name)
            if said != got:
                raise InputError(meta_name, f"{key!r} is {said}, but {nodes_name} "
                                            f"{'reaches' if key == 'nodes' else 'holds'} "
                                            f"{got} nodes")


def _json_count(meta, keys, hi, source):
    """The integer at ``meta[keys[0]][keys[1]]...``, which must lie in 1..hi; InputError naming
    ``source`` and the key otherwise."""
    name = ".".join(keys)
    v = meta
    for k in keys:
        if not isinstance(v, dict) or k not in v:
            raise InputError(source, f"missing {name!r}")
        v = v[k]
    if not is_integer(v) or not 1 <= v <= hi:
        raise InputError(source, f"{name!r} must be an integer in 1..{hi}, got {shown(v)}")
    return int(v)
