"""Bad input to hwbvh's public functions: a one-line InputError or ParameterError naming the
parameter or source, never a crash in a kernel, a hang, or a silently wrong answer.

Probes that would read out of bounds in a Numba kernel without their check run in a fresh
interpreter, so that a crash fails one test instead of killing the run."""
import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

import hwbvh
from hwbvh import NODE_DTYPE, InputError
from hwbvh.cycle_model import PRESETS, HwParams, simulate
from hwbvh.errors import ParameterError
from hwbvh.refit import Refitter, refit_cost
from hwbvh import resources

SOUP = """
import sys
import numpy as np
import hwbvh
rng = np.random.default_rng(0)
tris = (rng.uniform(0, 1, (64, 1, 3)) + rng.uniform(-0.05, 0.05, (64, 3, 3))).astype(np.float32)
bvh = hwbvh.build(tris)


def probe(name, f):
    try:
        f()
    except Exception as e:
        print(f"{name}| {type(e).__name__}: {e}", file=sys.stderr, flush=True)
    else:
        print(f"{name}| no error", file=sys.stderr, flush=True)
"""


def soup(n=64, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.uniform(0, 1, (n, 1, 3)) + rng.uniform(-0.05, 0.05, (n, 3, 3))).astype(np.float32)


@pytest.fixture(scope="module")
def tris():
    return soup()


@pytest.fixture(scope="module")
def bvh(tris):
    return hwbvh.build(tris)


def run_probes(code, timeout=120):
    """Run SOUP + ``code`` in a fresh interpreter; {probe name: "Error: message"} of what each
    ``probe`` raised. A kernel crash shows as a negative return code (the signal)."""
    r = subprocess.run([sys.executable, "-c", SOUP + code], capture_output=True, text=True,
                       timeout=timeout)
    assert r.returncode >= 0, f"killed by signal {-r.returncode}; stderr:\n{r.stderr[-3000:]}"
    assert r.returncode == 0, r.stderr[-3000:]
    return dict(line.split("| ", 1) for line in r.stderr.splitlines() if "| " in line)


# --- node arrays: tree_stats, sah_cost, check_nodes ----------------------------------------
def test_tree_stats_refuses_nodes_a_kernel_cannot_walk():
    got = run_probes("""
from hwbvh import tree_stats, sah_cost
far = bvh.nodes.copy(); far["a"][0] = 10**9
probe("far", lambda: tree_stats(far))
probe("far_sah", lambda: sah_cost(far))
probe("strided", lambda: tree_stats(bvh.nodes[::2]))
probe("big_endian", lambda: tree_stats(bvh.nodes.astype(bvh.nodes.dtype.newbyteorder(">"))))
root = bvh.nodes.copy(); root["a"][1] = 0
probe("to_root", lambda: tree_stats(root))
loop = bvh.nodes.copy(); c = loop["a"][0]; loop["a"][c] = c
probe("cycle", lambda: tree_stats(loop))
shared = bvh.nodes.copy(); shared["b"][0] = shared["a"][0]
probe("shared", lambda: sah_cost(shared))
""")
    assert got["far"] == got["far_sah"] == \
        "InputError: nodes: invalid tree: child pointer out of range (node 0)"
    assert got["strided"].startswith("InputError: nodes: invalid tree: child pointer out of range")
    assert got["big_endian"].startswith("InputError: nodes: ") and "little-endian" in got["big_endian"]
    assert got["to_root"] == "InputError: nodes: invalid tree: child pointer out of range (node 1)"
    for k in ("cycle", "shared"):
        assert got[k].startswith("InputError: nodes: invalid tree: node reached twice"), got[k]


@pytest.mark.parametrize("nodes,problem", [
    (np.zeros(0, NODE_DTYPE), "no nodes"),
    (np.zeros((4, 12), np.float32), "got dtype float32"),
    ([1, 2, 3], "got list"),
    (np.zeros((2, 3), NODE_DTYPE), "1-D"),
])
def test_tree_stats_refuses_what_is_not_a_node_array(nodes, problem):
    for f in (hwbvh.tree_stats, hwbvh.sah_cost, hwbvh.check_nodes):
        with pytest.raises(InputError, match=problem) as e:
            f(nodes)
        assert e.value.source == "nodes"


def test_check_nodes_returns_contiguous_nodes_and_checks_leaf_ranges(bvh):
    assert hwbvh.check_nodes(bvh.nodes, n_positions=len(bvh.indices)) is bvh.nodes
    spread = np.zeros(2 * len(bvh.nodes), NODE_DTYPE)
    spread[::2] = bvh.nodes
    view = spread[::2]
    got = hwbvh.check_nodes(view)
    assert got.flags.c_contiguous and got.tobytes() == bvh.nodes.tobytes()
    assert hwbvh.tree_stats(view) == hwbvh.tree_stats(bvh.nodes)
    with pytest.raises(InputError, match=r"^bvh.nodes: invalid tree: leaf index range outside"):
        hwbvh.check_nodes(bvh.nodes, n_positions=len(bvh.indices) - 1, source="bvh.nodes")
    long_leaf = bvh.nodes.copy()
    leaf = np.flatnonzero(long_leaf["flags"] == 1)[0]
    long_leaf["b"][leaf] = 10**6
    with pytest.raises(InputError, match=f"leaf index range outside the index list \\(node {leaf}\\)"):
        hwbvh.check_nodes(long_leaf, len(bvh.indices))
    with pytest.raises(ParameterError, match="n_positions"):
        hwbvh.check_nodes(bvh.nodes, n_positions=-1)


# --- refit -----------------------------------------------------------------------------
def test_refitter_checks_the_topology_and_the_index_list_once():
    got = run_probes("""
from hwbvh.refit import Refitter
b = hwbvh.build(tris); b.nodes["a"][0] = 10**9
probe("far", lambda: Refitter(b))
b = hwbvh.build(tris); b.nodes["a"][1] = 0
probe("to_root", lambda: Refitter(b))
b = hwbvh.build(tris); b.indices = b.indices.copy(); b.indices[0] = 10**8
probe("index", lambda: Refitter(b).refit(tris))
b = hwbvh.build(tris); b.nodes["b"][b.nodes["flags"] == 1] = 10**6
probe("leaf_range", lambda: Refitter(b).refit(tris))
r = Refitter(hwbvh.build(tris))
probe("short_tris", lambda: r.refit_nodes(tris[:5]))
probe("short_out", lambda: r.refit_nodes(r.check(tris), out=np.zeros(3, hwbvh.NODE_DTYPE)))
probe("out_dtype", lambda: r.refit_nodes(r.check(tris), out=np.zeros((len(r.nodes), 12), np.float32)))
""")
    assert got["far"] == "InputError: bvh.nodes: invalid tree: child pointer out of range (node 0)"
    assert got["to_root"] == "InputError: bvh.nodes: invalid tree: child pointer out of range (node 1)"
    assert got["index"] == "InputError: bvh.indices: primitive index out of range 0..63"
    assert got["leaf_range"].startswith("InputError: bvh.nodes: invalid tree: leaf index range outside")
    assert got["short_tris"].startswith("ParameterError: tris: expected the (64, 3, 3) float32 array")
    assert got["short_out"].startswith("ParameterError: out: ") and "39 nodes" in got["short_out"]
    assert got["out_dtype"].startswith("ParameterError: out: ")


def test_refit_nodes_into_out_is_the_refit(tris, bvh):
    r = Refitter(bvh)
    moved = r.check(tris + np.float32(0.5))
    out = np.zeros(len(bvh.nodes), NODE_DTYPE)       # pointers of another tree: none
    assert r.refit_nodes(moved, out=out) is out
    assert out.tobytes() == r.refit_nodes(moved).tobytes() == hwbvh.build(moved).nodes.tobytes()


def test_refit_cost_checks_its_arguments(tris, bvh):
    p = PRESETS["HWBVH-C"]
    for args, name in [((-64, -5, -3), "n_prims"), ((64, 0, 3), "n_nodes"), ((64, 128, 3), "n_nodes"),
                       ((64, 39, -1), "max_depth"), ((64, 39, 39), "max_depth"),
                       ((64.0, 39, 5), "n_prims"), ((True, 1, 0), "n_prims")]:
        with pytest.raises(ParameterError) as e:
            refit_cost(*args, p)
        assert e.value.parameter == name
    with pytest.raises(ParameterError) as e:
        refit_cost(64, 39, 5, replace(p, ram_pairs=0))
    assert e.value.parameter == "ram_pairs"
    assert refit_cost(64, 39, 5, "HWBVH-C") == refit_cost(64, 39, 5, p)


def test_the_refit_module_example_runs(tris, bvh):
    import hwbvh.refit as refit_module
    lines = [ln.strip()[4:] for ln in refit_module.__doc__.splitlines() if ln.strip().startswith(">>> ")]
    ns = {"Refitter": Refitter, "refit_cost": refit_cost, "PRESETS": PRESETS, "bvh": bvh,
          "new_triangles": tris + np.float32(1)}
    for line in lines:
        exec(line, ns)
    assert ns["c"]["seconds"] > 0 and ns["moved"].meta["refitted"]
    # the refit built nothing: no build time of its own, and the model says why it takes none
    assert ns["moved"].meta["build_seconds"] is None and bvh.meta["build_seconds"] > 0
    from hwbvh.cycle_model import simulate
    with pytest.raises(ParameterError, match="loaded from files or refitted"):
        simulate(ns["moved"], "HWBVH-C")


# --- build knobs -----------------------------------------------------------------------
def test_task_prims_must_be_a_positive_integer():
    # without the check, 0 and -5 split forever: run where a hang is only a timeout
    r = subprocess.run([sys.executable, "-c", SOUP + """
for v in (0, -5, "8", 2.0, True):
    probe(repr(v), lambda: hwbvh.build(tris, task_prims=v))
"""], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr[-3000:]
    got = dict(line.split("| ", 1) for line in r.stderr.splitlines() if "| " in line)
    assert len(got) == 5
    for v, msg in got.items():
        assert msg.startswith("ParameterError: task_prims: must be a positive integer"), (v, msg)


def test_the_tree_does_not_depend_on_task_prims(tris):
    for leaf in (4, 7):
        ref = hwbvh.build(tris, leaf_size=leaf)
        for tp in (1, 2, 3, 8):
            b = hwbvh.build(tris, leaf_size=leaf, task_prims=tp)
            assert b.nodes.tobytes() == ref.nodes.tobytes(), (leaf, tp)
            assert np.array_equal(b.indices, ref.indices)
    assert hwbvh.build(tris, task_prims=1).meta["nodes"] == 39


@pytest.mark.parametrize("knob,value", [
    ("subtree_builders", 2**16 + 1), ("capacity", 2**70), ("capacity", 0),
    ("block_nodes", 2**30), ("block_nodes", 1.5),
])
def test_layout_knobs_are_bounded_before_any_allocation(tris, knob, value):
    with pytest.raises(ParameterError) as e:
        hwbvh.build(tris, **{knob: value})
    assert e.value.parameter == knob


@pytest.mark.parametrize("knob", ["leaf_size", "bins", "capacity", "subtree_builders", "block_nodes",
                                  "task_prims"])
def test_booleans_are_not_integer_knobs(tris, knob):
    for v in (True, np.True_):
        with pytest.raises(ParameterError) as e:
            hwbvh.build(tris, **{knob: v})
        assert e.value.parameter == knob


def test_integer_knobs_still_take_numpy_integers(tris, bvh):
    b = hwbvh.build(tris, leaf_size=np.int64(4), bins=np.int32(16), capacity=np.int64(1 << 40),
                    subtree_builders=np.int8(2), block_nodes=np.uint16(8), task_prims=np.int64(3))
    assert hwbvh.tree_stats(b.nodes)["sah_cost"] == bvh.meta["sah_cost"]


# --- validate and load -------------------------------------------------------------------
def test_validate_checks_its_arguments(tris, bvh):
    boxes = hwbvh.primitive_boxes(tris)
    for kwargs, name in [(dict(prim_boxes=boxes[:3]), "prim_boxes"),
                         (dict(prim_boxes=np.zeros(6, np.float32)), "prim_boxes"),
                         (dict(prim_boxes=boxes.astype(np.complex64)), "prim_boxes"),
                         (dict(n_prims=-1), "n_prims"), (dict(n_prims=0), "n_prims"),
                         (dict(max_leaf=10**30), "max_leaf"), (dict(max_leaf=4.0), "max_leaf"),
                         (dict(entries=bvh.indices.astype(np.float32)), "entries"),
                         (dict(entries=bvh.indices.astype(np.int64) - 1), "entries")]:
        args = dict(nodes=bvh.nodes, entries=bvh.indices, n_prims=64, max_leaf=4) | kwargs
        with pytest.raises(ParameterError) as e:
            hwbvh.validate(**args)
        assert e.value.parameter == name, kwargs
    assert hwbvh.validate(bvh.nodes, bvh.indices, 64, 4, boxes) == 39
    with pytest.raises(InputError, match="^t: .*little-endian"):
        hwbvh.validate(bvh.nodes.astype(NODE_DTYPE.newbyteorder(">")), bvh.indices, 64, 4, source="t")


def test_load_names_a_triangle_count_that_does_not_match(tmp_path, tris, bvh):
    prefix = str(tmp_path / "t")
    hwbvh.save(bvh, prefix)
    with pytest.raises(InputError) as e:
        hwbvh.load(prefix, triangles=tris[:10])
    assert str(e.value) == "triangles: 10 triangles, but the tree has 64 primitives"
    assert hwbvh.load(prefix, triangles=tris).triangles.shape == (64, 3, 3)


@pytest.mark.parametrize("key,value", [
    ("triangles", 64.7), ("triangles", -5), ("triangles", 10**12), ("triangles", True),
    ("triangles", "64"), ("max_leaf", 1e30), ("max_leaf", 0), ("max_leaf", 4.5),
])
def test_load_checks_the_json_counts(tmp_path, bvh, key, value):
    prefix = str(tmp_path / "t")
    hwbvh.save(bvh, prefix)
    with open(prefix + ".json") as f:
        meta = json.load(f)
    if key == "max_leaf":
        meta["parameters"]["max_leaf"] = value
    else:
        meta[key] = value
    with open(prefix + ".json", "w") as f:
        json.dump(meta, f)
    with pytest.raises(InputError, match="must be an integer in 1..") as e:
        hwbvh.load(prefix)
    assert e.value.source == prefix + ".json" and key in e.value.problem


@pytest.mark.parametrize("key,value,problem", [
    ("nodes", 38, "'nodes' is 38, but {p}.nodes reaches 39 nodes"),
    ("node_slots", 1000, "'node_slots' is 1000, but {p}.nodes holds 39 nodes"),
    ("nodes", None, "missing 'nodes'"),
])
def test_load_checks_the_json_node_counts_against_the_tree(tmp_path, bvh, key, value, problem):
    prefix = str(tmp_path / "t")
    hwbvh.save(bvh, prefix)
    with open(prefix + ".json") as f:
        meta = json.load(f)
    if value is None:
        del meta[key]
    else:
        meta[key] = value
    with open(prefix + ".json", "w") as f:
        json.dump(meta, f)
    with pytest.raises(InputError) as e:
        hwbvh.load(prefix)
    assert e.value.source == prefix + ".json" and e.value.problem == problem.format(p=prefix)
    if key == "node_slots":                     # a reader that writes no slot count
        del meta[key]
        with open(prefix + ".json", "w") as f:
            json.dump(meta, f)
        assert len(hwbvh.load(prefix).nodes) == 39


def test_validate_refuses_primitive_boxes_that_are_not_finite(tris, bvh):
    boxes = hwbvh.primitive_boxes(tris).astype(np.float64)
    boxes[5, 1] = np.nan
    with pytest.raises(ParameterError, match=r"^prim_boxes: must be finite .* for primitive 5$"):
        hwbvh.validate(bvh.nodes, bvh.indices, 64, 4, boxes)
    boxes[5, 1] = 1e39                          # beyond float32: infinite there
    with pytest.raises(ParameterError, match=r"^prim_boxes: must be finite"):
        hwbvh.validate(bvh.nodes, bvh.indices, 64, 4, boxes)


def test_load_refuses_json_that_is_not_an_object(tmp_path, bvh):
    prefix = str(tmp_path / "t")
    hwbvh.save(bvh, prefix)
    with open(prefix + ".json", "w") as f:
        json.dump([64], f)
    with pytest.raises(InputError, match="expected a JSON object, got list"):
        hwbvh.load(prefix)


# --- triangle arrays ---------------------------------------------------------------------
def test_a_bytes_source_is_a_path(tmp_path):
    missing = str(tmp_path / "none.ply")
    with pytest.raises(InputError, match="no such file") as e:
        hwbvh.build(missing.encode())
    assert e.value.source == missing



def test_complex_bool_and_string_coordinates_are_refused(tris):
    with pytest.raises(InputError, match="^<array>: triangles must be real numbers, got complex64$"):
        hwbvh.build(tris.astype(np.complex64) + 5j)
    with pytest.raises(InputError, match="got bool$"):
        hwbvh.build(tris > 0.5)
    with pytest.raises(InputError, match="must be real numbers, got <U"):
        hwbvh.build(tris.astype(str))
    with pytest.raises(InputError, match="^triangles: .*complex128"):
        hwbvh.as_triangles(tris.astype(complex), source="triangles")


def test_wider_triangles_that_float32_collapses_are_refused_by_name():
    """The builder works in float32: float64 triangles that it would round together (a small
    mesh far from the origin, or one below float32's smallest numbers) are refused, where a
    tracer would miss them without a word; float32 input is taken as given."""
    tri = np.array([[[-1, -1, 0], [1, -1, 0], [0, 1, 0]]], float)
    for far in (tri * 0.1 + 1e7, tri * 1e-46):
        with pytest.raises(InputError, match="collapse in float32") as e:
            hwbvh.build(far, source_name="m.obj")
        assert str(e.value).startswith("m.obj: ")
    for fine in (tri + 1e5, tri * 1e-30, (tri * 0.1 + 1e7).astype(np.float32)):
        assert hwbvh.build(fine).meta["nodes"] == 1


def test_a_refit_given_no_array_says_what_it_got(bvh):
    from hwbvh.refit import Refitter
    for x, got in ((None, "NoneType"), ("mesh.ply", "str"), (3.0, "float")):
        with pytest.raises(InputError) as e:
            Refitter(bvh).refit(x)
        assert str(e.value) == f"triangles: triangles must be an (n, 3, 3) array, got {got}"


def test_a_refitted_tree_holds_its_own_triangles(tris, bvh):
    """As a built tree does: moving the caller's array afterwards leaves the tree's as fitted."""
    from hwbvh.refit import Refitter
    moved = np.ascontiguousarray(tris, np.float32) + np.float32(0.5)
    tree = Refitter(bvh).refit(moved)
    kept = tree.triangles.copy()
    moved += np.float32(1.0)
    assert np.array_equal(tree.triangles, kept)


def test_object_and_ragged_triangles_give_an_input_error():
    words = np.zeros((1, 3, 3), object)
    words[0, 0, 0] = "x"
    with pytest.raises(InputError, match="real numbers"):
        hwbvh.build(words)
    with pytest.raises(InputError, match="uneven lengths"):
        hwbvh.build([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 0], [1, 0]]])
    numbers = np.zeros((1, 3, 3), object)
    numbers[0, 1, 0] = numbers[0, 2, 1] = 1
    assert hwbvh.build(numbers).meta["triangles"] == 1


def test_primitive_boxes_checks_what_it_is_given(tris):
    with pytest.raises(InputError, match=r"^tris: triangles must have shape \(n, 3, 3\), got \(4, 9\)"):
        hwbvh.primitive_boxes(np.zeros((4, 9)))
    assert hwbvh.primitive_boxes(tris.tolist()).tobytes() == hwbvh.primitive_boxes(tris).tobytes()


# --- the cycle model and the cost model --------------------------------------------------
def test_simulate_refuses_out_of_range_params_that_hang():
    # without check_params, negative sizes never finish: run where a hang is only a timeout
    got = run_probes("""
from hwbvh.cycle_model import HwParams, simulate
t = bvh.tree
probe("w", lambda: simulate(t, HwParams(w=-4)))
probe("psize", lambda: simulate(t, HwParams(psize=-1)))
""", timeout=60)
    assert got["w"].startswith("ParameterError: w: must be an integer within 1..64")
    assert got["psize"].startswith("ParameterError: psize: ")


@pytest.mark.parametrize("knob,value", [
    ("w", 0), ("w", 3), ("w", 4.0), ("w", 2**40), ("w", "4"), ("w", True), ("tsize", 0),
    ("ram_pairs", 0), ("clock_mhz", 0), ("clock_mhz", -250.0), ("clock_mhz", float("nan")),
    ("subtree_builders", 0), ("control_latency", -10**6), ("control_latency", 10**30),
])
def test_simulate_and_the_cost_model_check_params(bvh, knob, value):
    p = replace(PRESETS["HWBVH-C"], **{knob: value})
    for f in (lambda: simulate(bvh.tree, p), lambda: resources.cost(p), lambda: resources.resources(p),
              lambda: refit_cost(64, 39, 5, p)):
        with pytest.raises(ParameterError) as e:
            f()
        assert e.value.parameter == knob


def test_simulate_names_a_wrong_tree_or_params(tmp_path, tris, bvh):
    p = PRESETS["HWBVH-C"]
    with pytest.raises(ParameterError, match=r"^tree: .*pass bvh\.tree"):
        simulate(bvh, p)
    hwbvh.save(bvh, str(tmp_path / "t"))
    with pytest.raises(ParameterError, match="^tree: .*loaded from files"):
        simulate(hwbvh.load(str(tmp_path / "t")), p)
    with pytest.raises(ParameterError, match="^tree: got None: a Bvh loaded from files"):
        simulate(hwbvh.load(str(tmp_path / "t")).tree, p)
    with pytest.raises(ParameterError, match="^tree: .*'sweep'"):
        simulate(hwbvh.build(tris, builder="sweep").tree, p)
    with pytest.raises(ParameterError, match="^params: .*HwParams"):
        simulate(bvh.tree, None)
    with pytest.raises(ParameterError, match="^params: unknown preset 'HWBVH-X'"):
        simulate(bvh.tree, "HWBVH-X")
    assert simulate(bvh.tree, "HWBVH-HP") == simulate(bvh.tree, PRESETS["HWBVH-HP"])
    with pytest.raises(ParameterError, match="^p: "):
        resources.cost(None)


def test_simulate_refuses_params_that_did_not_build_the_tree(tris):
    t = hwbvh.build(tris, leaf_size=16, bins=8).tree
    with pytest.raises(ParameterError, match="^params: leaf_size 4 and bins 16 did not build"):
        simulate(t, PRESETS["HWBVH-C"])
    r = simulate(t, replace(PRESETS["HWBVH-C"], leaf_size=16, bins=8))
    assert (r["parameters"]["leaf_size"], r["parameters"]["bins"]) == (16, 8)


def test_simulate_node_count_is_a_node_count(bvh):
    p = PRESETS["HWBVH-C"]
    for v in (-1000, 0, 128, 39.0, True):
        with pytest.raises(ParameterError) as e:
            simulate(bvh.tree, p, node_count=v)
        assert e.value.parameter == "node_count"
    assert simulate(bvh.tree, p, node_count=39) == simulate(bvh.tree, p)


def test_cost_of_a_string_knob_names_it():
    with pytest.raises(ParameterError) as e:
        resources.cost(HwParams(w="4"))
    assert e.value.parameter == "w"
    assert resources.cost("HWBVH-C") == resources.cost(PRESETS["HWBVH-C"])


def test_many_subtree_builders_only_place_nodes(tris):
    """Subtree builders beyond any hardware instance are a placement choice, not an error;
    only a layout whose node slots could pass the 32-bit pointers is refused."""
    ref = hwbvh.build(tris)
    many = hwbvh.build(tris, subtree_builders=100, capacity=16)
    assert many.meta["sah_cost"] == ref.meta["sah_cost"]
    with pytest.raises(ParameterError) as e:
        hwbvh.build(tris, subtree_builders=2**16, block_nodes=2**17)
    assert e.value.parameter == "block_nodes"


def test_save_and_load_name_a_bad_argument_and_never_write_a_broken_tree(tris, tmp_path):
    import os
    with pytest.raises(ParameterError) as e:
        hwbvh.load(None)
    assert e.value.parameter == "prefix"
    with pytest.raises(ParameterError) as e:
        hwbvh.save(object(), tmp_path / "t")
    assert e.value.parameter == "bvh"
    b = hwbvh.build(tris)
    b.nodes["a"][0] = 10**6
    with pytest.raises(InputError, match="bvh.nodes: invalid tree"):
        hwbvh.save(b, tmp_path / "t")
    assert os.listdir(tmp_path) == []
    good = hwbvh.build(tris)
    hwbvh.save(good, os.fsencode(tmp_path / "g"))
    assert hwbvh.load(tmp_path / "g").nodes.tobytes() == good.nodes.tobytes()


def test_a_capacity_below_the_leaf_size_is_refused_as_simulate_refuses_it(tris):
    # the sweep builder's leaf size is not the user's to set: the message names the largest
    # leaf it made (not its cap), and any capacity that holds that leaf builds
    sweep = hwbvh.build(tris, builder="sweep", validate_tree=True)
    t = sweep.tree
    used = t.stats["nodes"]
    largest = int(t.count[:used][t.axis[:used] == -1].max())
    for builder, leaf, what in (("hwbvh", 4, "the leaf size 4"),
                                ("sweep", largest, f"the largest leaf the sweep builder made "
                                                   f"({largest} triangles)")):
        with pytest.raises(ParameterError) as e:
            hwbvh.build(tris, builder=builder, capacity=leaf - 1)
        assert str(e.value) == (f"capacity: {leaf - 1} is below {what}: a subtree builder must "
                                f"hold a leaf")
        hwbvh.build(tris, builder=builder, capacity=leaf, validate_tree=True)
    assert largest < sweep.meta["parameters"]["max_leaf"]
    assert hwbvh.build(tris, capacity=4).meta["handoffs"] > 0


def _with(bvh, **changes):
    from types import SimpleNamespace
    parts = {"nodes": bvh.nodes, "indices": bvh.indices, "meta": bvh.meta,
             "triangles": bvh.triangles}
    return SimpleNamespace(**{**parts, **changes})


def test_save_refuses_what_load_would_refuse_or_read_back_changed(tmp_path, bvh):
    """save refuses what load would refuse (an inner box shrunk, a repeated index, a description
    without counts) and indices it would write as others (beyond 24 bits, not integers),
    naming the part, and writes nothing then."""
    shrunk = bvh.nodes.copy()
    shrunk["bounds"][0] = [0, 0, 0, 0.1, 0.1, 0.1]
    repeated = bvh.indices.copy()
    repeated[1] = repeated[0]
    cases = [(_with(bvh, nodes=shrunk), "bvh.nodes: invalid tree: child AABB is not inside"),
             (_with(bvh, indices=repeated), "bvh.nodes: invalid tree: primitive referenced more"),
             (_with(bvh, meta={}), "bvh.meta: missing 'triangles'"),
             (_with(bvh, meta=None), "bvh.meta: expected a dict, got NoneType"),
             (_with(bvh, meta={**bvh.meta, "source": b"x"}), "bvh.meta: cannot be written as JSON"),
             (_with(bvh, indices=bvh.indices + 2 ** 24), "bvh.indices: must be a 1-D array of "
                                                         "integers in 0..16777214"),
             (_with(bvh, indices=bvh.indices.astype(float)), "bvh.indices: must be a 1-D array"),
             (_with(bvh, indices=None), "bvh.indices: must be a 1-D array")]
    for tree, message in cases:
        with pytest.raises(InputError) as e:
            hwbvh.save(tree, tmp_path / "t")
        assert str(e.value).startswith(message), str(e.value)
    assert list(tmp_path.iterdir()) == []
    hwbvh.save(bvh, tmp_path / "t")
    back = hwbvh.load(tmp_path / "t", bvh.triangles)
    assert np.array_equal(back.indices, bvh.indices) and back.nodes.tobytes() == bvh.nodes.tobytes()
    named = hwbvh.build(bvh.triangles, source_name=b"mesh.ply")
    assert named.meta["source"] == "mesh.ply"
    with pytest.raises(ParameterError, match="source_name: expected a path, got int"):
        hwbvh.build(bvh.triangles, source_name=1)


def test_load_refuses_an_index_list_not_in_whole_padded_words(tmp_path):
    """The index list is whole 192-bit words, the last one's tail padded with 0xFFFFFF: a file
    cut short, with its padding overwritten or with a word too many is damaged, not a tree."""
    bvh = hwbvh.build(soup(61))                 # 61 entries: three of padding
    hwbvh.save(bvh, tmp_path / "t")
    good = (tmp_path / "t.indices").read_bytes()
    n = len(bvh.indices)
    assert len(good) == -(-n // 8) * 24 and good.endswith(b"\xff" * 9)
    for data, problem in ((good[:-3], f"size {len(good) - 3} bytes: {n} triangles take"),
                          (good + b"\xff" * 24, f"size {len(good) + 24} bytes"),
                          (good[:-3] + b"\0\0\0", f"the last word's tail after entry {n} is "
                                                  f"not padding")):
        (tmp_path / "t.indices").write_bytes(data)
        with pytest.raises(InputError) as e:
            hwbvh.load(tmp_path / "t")
        assert str(e.value).startswith(f"{tmp_path / 't.indices'}: {problem}"), str(e.value)
    (tmp_path / "t.indices").write_bytes(good)
    (tmp_path / "t.json").write_bytes(b"\xff\xfe")
    with pytest.raises(InputError, match="t.json: not UTF-8 text"):
        hwbvh.load(tmp_path / "t")


def _binary_stl(n):
    """A binary STL of n triangles (header, count, then 50 bytes each)."""
    import struct
    rows = b"".join(struct.pack("<3f", 0, 0, 1) + np.float32([[0, 0, k], [1, 0, k], [0, 1, k]])
                    .tobytes() + b"\0\0" for k in range(n))
    return b"\0" * 80 + struct.pack("<I", n) + rows


def _ascii_ply(faces, index_type="int", n_faces=None):
    """An ASCII PLY of four vertices (header lines 1-9, vertices 10-13) and ``faces``, one line
    each (``n_faces``: the count its header declares, by default theirs)."""
    return (f"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
            f"property float z\nelement face {len(faces) if n_faces is None else n_faces}\n"
            f"property list uchar {index_type} vertex_indices\nend_header\n"
            "0 0 0\n1 0 0\n0 1 0\n0 0 1\n" + "".join(f + "\n" for f in faces))


def _binary_ply_float_indices():
    """A binary PLY of one triangle whose header declares float indices (0.0, 1.0, 2.0)."""
    import struct
    return (b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
            b"property float y\nproperty float z\nelement face 1\n"
            b"property list uchar float vertex_indices\nend_header\n"
            + np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0]]).tobytes()
            + struct.pack("<B3f", 3, 0.0, 1.0, 2.0))


GLTF_WITH_BUFFER = json.dumps({
    "asset": {"version": "2.0"}, "buffers": [{"uri": "gone.bin", "byteLength": 36}],
    "bufferViews": [{"buffer": 0, "byteLength": 36}],
    "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                   "min": [0, 0, 0], "max": [1, 1, 0]}],
    "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}], "nodes": [{"mesh": 0}],
    "scenes": [{"nodes": [0]}], "scene": 0})


@pytest.mark.parametrize("name,data,problem", [
    ("cut.stl", _binary_stl(12)[:84 + 50 * 5 + 17],
     "its header counts 12 triangles (684 bytes), but the file holds 351 bytes: it is cut short"),
    ("syntax.gltf", "{ not json", "not valid JSON (Expecting property name enclosed in double "
                                  "quotes at line 1, column 3)"),
    ("nobuffer.gltf", GLTF_WITH_BUFFER, "gone.bin is not there"),
    ("outside.gltf", GLTF_WITH_BUFFER.replace("gone.bin", "../gone.bin"),
     "its buffer ../gone.bin lies outside the file's directory, the only place its buffers are "
     "read from"),
    ("short.gltf", GLTF_WITH_BUFFER.replace("gone.bin", "short.bin"),
     "its buffer file {dir}/short.bin holds 20 bytes, fewer than the 36 its byteLength gives"),
    ("count.gltf", GLTF_WITH_BUFFER.replace("gone.bin", "whole.bin").replace('"count": 3',
                                                                             '"count": 300'),
     "its accessor 0 reads 3600 bytes of buffer view 0, which holds 36"),
    ("word.obj", "v 0 0 0\nv 1 0 0\nv 0 1 abc\nf 1 2 3\n", "line 3: 'abc' is not a number"),
    ("note.obj", "v 0 0 0 # origin\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
     "line 1: a comment after the values; put it on a line of its own"),
    ("long.stl", "solid " + "n" * 100 + "\nendsolid\n", "mesh has no triangles"),
    # PLY faces trimesh reads without a word: by their first three indices whatever the count,
    # a float index truncated
    ("count.ply", _ascii_ply(["3 0 1 2", "255 0 1 3"]),
     "line 15: a face's count says 255 indices, the line holds 3"),
    ("short.ply", _ascii_ply(["3 0 1"]), "line 14: a face's count says 3 indices, the line holds 2"),
    ("odd_header.ply", _ascii_ply(["3 0 1"]).replace("end_header", "comment a\fb\r c\n  end_header"),
     "line 15: a face's count says 3 indices, the line holds 2"),
    ("word.ply", _ascii_ply(["3 0 1 x"]), "line 14: a face's index is not a non-negative integer"),
    ("half.ply", _ascii_ply(["3 0.5 1 2"], "float"),
     "line 14: a face's index is not a non-negative integer"),
    ("floats.ply", _binary_ply_float_indices(),
     "its header declares the faces' vertex indices as float; indices are integers"),
    ("ends.ply", _ascii_ply(["3 0 1 2"], n_faces=2),
     "its header declares 4 vertices and 2 faces, but only 1 face could be read"),
    # OFF faces trimesh reads without a word: the face lines there are, each up to its count
    ("fewer.off", "OFF\n4 3 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 1 3\n",
     "its header declares 3 faces, but it holds 2"),
    ("short.off", "OFF\n# a comment\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n\n3 0 1\n",
     "face 2: its count says 3 indices, the line holds 2")])
def test_a_damaged_mesh_file_is_named_with_what_is_wrong(tmp_path, name, data, problem):
    path = tmp_path / name
    (path.write_bytes if isinstance(data, bytes) else path.write_text)(data)
    (tmp_path / "short.bin").write_bytes(bytes(20))
    (tmp_path / "whole.bin").write_bytes(bytes(36))
    (tmp_path.parent / "gone.bin").write_bytes(bytes(36))      # there, but not read from there
    with pytest.raises(InputError) as e:
        hwbvh.load_triangles(path)
    assert str(e.value).startswith(str(path) + ": ") and \
        problem.format(dir=tmp_path) in str(e.value)


def test_a_gltf_files_buffer_is_an_input_no_output_may_replace(tmp_path):
    """``hwrt build mesh.gltf --dump-aabbs mesh.bin`` replaced the mesh's own buffer."""
    from hwbvh.files import OutputPathError, check_outputs
    buffer = tmp_path / "mesh.bin"
    buffer.write_bytes(np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0]]).tobytes())
    mesh = tmp_path / "mesh.gltf"
    mesh.write_text(GLTF_WITH_BUFFER.replace("gone.bin", "mesh.bin"))
    with pytest.raises(OutputPathError) as e:
        check_outputs([buffer], inputs=[mesh])
    assert str(e.value) == f"{buffer}: is an input of this run; an output may not overwrite an input"
    check_outputs([tmp_path / "other.bin"], inputs=[mesh])
    # and its contents: the studies' cells and an animation's frames are keyed by them
    from hwbvh.files import content_digest
    before = content_digest(mesh)
    buffer.write_bytes(np.float32([[0, 0, 0], [2, 0, 0], [0, 1, 0]]).tobytes())
    assert content_digest(mesh) != before


def test_the_damage_checks_only_explain_a_file_that_does_not_load(tmp_path):
    """They run once trimesh has failed (the PLY and OFF faces' checks, before: trimesh reads
    bad faces without failing): a file it reads (an ASCII STL in capitals after a byte-order
    mark, a buffer named with a literal %20, an ASCII PLY of mixed faces with CRLF line ends,
    an OFF file with a two-vertex face, colours and comments) loads."""
    (tmp_path / "whole.stl").write_bytes(_binary_stl(3))
    assert hwbvh.load_triangles(tmp_path / "whole.stl").shape == (3, 3, 3)
    (tmp_path / "caps.stl").write_text("\ufeffSOLID x\nfacet normal 0 0 1\nouter loop\n"
                                       "vertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\n"
                                       "endfacet\nendsolid x\n", encoding="utf-8")
    assert hwbvh.load_triangles(tmp_path / "caps.stl").shape == (1, 3, 3)
    (tmp_path / "lit%20.bin").write_bytes(np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0]]).tobytes())
    (tmp_path / "lit.gltf").write_text(GLTF_WITH_BUFFER.replace("gone.bin", "lit%20.bin"))
    assert hwbvh.load_triangles(tmp_path / "lit.gltf").shape == (1, 3, 3)
    # faces of three and four indices, spaces and tabs around them, CRLF line ends
    (tmp_path / "mixed.ply").write_bytes(_ascii_ply(["3 0 1 2", "  4\t0 1 2 3  "]).replace(
        "\n", "\r\n").encode())
    assert hwbvh.load_triangles(tmp_path / "mixed.ply").shape == (3, 3, 3)
    # what a reader of numbers takes as integers ("+1", "2.0", a float type holding them), the
    # word end_header inside a comment's word, int64 indices
    (tmp_path / "numbers.ply").write_text(_ascii_ply(["3 0 +1 2.0", "3.0 0 1 3"], "float").replace(
        "end_header", "comment not_the_end_header_yet\nend_header", 1))
    assert hwbvh.load_triangles(tmp_path / "numbers.ply").shape == (2, 3, 3)
    (tmp_path / "wide.ply").write_text(_ascii_ply(["3 0 1 2"], "int64"))
    assert hwbvh.load_triangles(tmp_path / "wide.ply").shape == (1, 3, 3)
    # an OFF face of two vertices (no triangle), colours after a face's indices, comments
    (tmp_path / "colours.off").write_text("OFF # counts next\n4 3 0\n0 0 0\n1 0 0\n0 1 0\n"
                                          "0 0 1\n2 0 1\n3 0 1 2 255 0 0\n4 0 1 2 3 # quad\n")
    assert hwbvh.load_triangles(tmp_path / "colours.off").shape == (3, 3, 3)
