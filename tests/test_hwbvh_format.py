"""The 384-bit node format, the 24-bit index list, files, the validator, and bad input."""
import json
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

import hwbvh
from hwbvh.config import MAX_COORDINATE
from hwbvh import NODE_DTYPE, InputError
from hwbvh.errors import ParameterError
from hwbvh.format import pack_indices, unpack_indices
from hwbvh.primitives import pack_records, primitive_boxes, unpack_records
from scenes.meshes import random_soup, sphere

from .conftest import shared_mesh


def test_node_dtype_is_the_spec_layout():
    assert NODE_DTYPE.itemsize == 48
    assert [NODE_DTYPE.fields[k][1] for k in ("bounds", "a", "b", "flags", "pad")] == [0, 24, 28, 32, 36]
    n = np.zeros(1, NODE_DTYPE)
    n["bounds"] = [1, 2, 3, 4, 5, 6]
    n["a"], n["b"], n["flags"] = 7, 8, 1
    raw = n.tobytes()
    assert np.frombuffer(raw[:24], "<f4").tolist() == [1, 2, 3, 4, 5, 6]
    assert np.frombuffer(raw[24:36], "<u4").tolist() == [7, 8, 1]
    assert raw[36:] == bytes(12)


def test_kernel_word_offsets_read_the_spec_fields():
    """The 32-bit word offsets the kernels use (derived from NODE_DTYPE) land on the SPEC's
    bytes: box 0..23, a 24..27, b 28..31, flags 32..35, padding 36..47."""
    from hwbvh.config import LEAF_FLAG
    from hwbvh.format import (BOX_MAX, PAD_WORDS, WORD_A, WORD_B, WORD_BOX, WORD_FLAGS, WORD_PAD,
                              WORDS_PER_NODE, node_views)
    assert (WORDS_PER_NODE, WORD_BOX, BOX_MAX, WORD_A, WORD_B, WORD_FLAGS, WORD_PAD, PAD_WORDS) == \
        (12, 0, 3, 6, 7, 8, 9, 3)
    n = np.zeros(2, NODE_DTYPE)
    n["bounds"][1] = [-1, -2, -3, 4, 5, 6]
    n["a"][1], n["b"][1], n["flags"][1] = 0xABCDEF, 77, LEAF_FLAG
    u, f = node_views(n)
    assert f[1, WORD_BOX:WORD_BOX + 3].tolist() == [-1, -2, -3]
    assert f[1, WORD_BOX + BOX_MAX:WORD_BOX + BOX_MAX + 3].tolist() == [4, 5, 6]
    assert (u[1, WORD_A], u[1, WORD_B], u[1, WORD_FLAGS]) == (0xABCDEF, 77, 1)
    assert not u[1, WORD_PAD:WORD_PAD + PAD_WORDS].any() and not u[0].any()
    flat = u.reshape(-1)                     # the flat word view the traversal kernels read
    assert flat[WORDS_PER_NODE * 1 + WORD_A] == 0xABCDEF


def test_index_list_is_24_bit_packed_8_per_word_with_ffffff_tail():
    ids = np.array([0, 1, 0xABCDEF, 0xFFFFFE, 5, 6, 7, 8, 9, 10], np.uint32)
    data = pack_indices(ids)
    assert len(data) == 2 * 24                          # 10 entries -> two 192-bit words
    assert data[6:9] == bytes([0xEF, 0xCD, 0xAB])       # little-endian
    assert data[-18:] == b"\xff" * 18                    # 6 padding entries
    back = unpack_indices(data)
    assert back[:10].tolist() == ids.tolist() and (back[10:] == 0xFFFFFF).all()


def test_primitive_records_are_27_bytes():
    tris = random_soup(100, seed=1)
    boxes = primitive_boxes(tris)
    data = pack_records(boxes)
    assert len(data) == 27 * 100
    b, i = unpack_records(data)
    assert np.array_equal(b, boxes) and np.array_equal(i, np.arange(100))


def test_save_load_roundtrip(tmp_path):
    tris = sphere(16, 24)
    bvh = hwbvh.build(tris, validate_tree=True)
    files = hwbvh.save(bvh, tmp_path / "s")
    assert sorted(os.listdir(tmp_path)) == ["s.indices", "s.json", "s.nodes"]
    back = hwbvh.load(tmp_path / "s", triangles=tris)
    assert back.nodes.tobytes() == bvh.nodes.tobytes()
    assert np.array_equal(back.indices, bvh.indices)
    with open(files[2]) as f:
        assert json.load(f)["sah_cost"] == bvh.meta["sah_cost"]
    for ext in (".nodes", ".indices", ".json"):         # one of its files names the tree
        named = hwbvh.load(str(tmp_path / "s") + ext)
        assert named.nodes.tobytes() == bvh.nodes.tobytes()
    with pytest.raises(InputError, match=r"s\.txt\.json"):
        hwbvh.load(str(tmp_path / "s") + ".txt")
    other = hwbvh.build(sphere(8, 12))          # saved as one of its files: the same three
    assert hwbvh.save(other, tmp_path / "t.json") == [str(tmp_path / f"t{ext}") for ext in
                                                      (".nodes", ".indices", ".json")]
    assert sorted(os.listdir(tmp_path)) == ["s.indices", "s.json", "s.nodes", "t.indices",
                                            "t.json", "t.nodes"]
    assert hwbvh.load(tmp_path / "t.json").nodes.tobytes() == other.nodes.tobytes()
    for bad, problem in (("", "is empty"), (str(tmp_path), "names a directory"),
                         (str(tmp_path / "sub") + os.sep, "ends in a path separator"),
                         (str(tmp_path / ".json"), r"is a file name starting with a dot "
                                                   r"\(hidden files\)")):
        with pytest.raises(ParameterError, match=f"^prefix: .* {problem}: give a prefix of file "
                                                 f"names such as '(.*{os.sep})?tree'$"):
            hwbvh.save(other, bad)         # would write hidden files .nodes etc.
    assert sorted(os.listdir(tmp_path)) == ["s.indices", "s.json", "s.nodes", "t.indices",
                                            "t.json", "t.nodes"]
    # a .json that is not a tree's (a scene file named as the prefix) is not replaced; a
    # tree's is
    (tmp_path / "scene.json").write_text('{"camera": {}}')
    with pytest.raises(ParameterError, match=r"is taken: .*scene\.json is there and is not a "
                                             r"tree's description"):
        hwbvh.save(other, tmp_path / "scene.json")
    assert (tmp_path / "scene.json").read_text() == '{"camera": {}}'
    hwbvh.save(other, tmp_path / "t")
    (tmp_path / "t.json").write_text('{"nodes": 5,\n "triangles": ')     # cut short
    with pytest.raises(InputError, match=r"t\.json: not valid JSON \(Expecting value at line 2, "
                                         r"column 15\)$"):
        hwbvh.load(tmp_path / "t")


def corrupt(bvh, fn):
    nodes = bvh.nodes.copy()
    ids = bvh.indices.copy()
    fn(nodes, ids)
    return nodes, ids


def _first(nodes, leaf):
    return int(np.flatnonzero((nodes["flags"] & 1) == int(leaf))[0])


def _set(field, index, value):
    def fn(n, i):
        n[field][index] = value(n) if callable(value) else value
    return fn


def _set_leaf_count(n, i):
    n["b"][_first(n, 1)] = 9


def _cycle(n, i):
    n["b"][_first(n, 0)] = n["a"][0]      # the root's left child is reached twice


def _child_outside(n, i):
    n["bounds"][int(n["a"][0]), 3] = n["bounds"][0][3] + 1


CORRUPTIONS = {
    "pointer out of range": lambda n, i: _set("a", _first(n, 0), len(n) + 5)(n, i),
    "cycle": _cycle,
    "flag bits": _set("flags", 3, lambda n: n["flags"][3] | 4),
    "padding": lambda n, i: n["pad"].__setitem__((2, 1), 9),
    "child outside parent": _child_outside,
    "leaf too big": _set_leaf_count,
    "duplicate primitive": lambda n, i: i.__setitem__(1, i[0]),
    "index out of range": lambda n, i: i.__setitem__(0, 1 << 20),
    "inverted box": lambda n, i: n["bounds"].__setitem__((5, 0), 1e9),
}


@pytest.mark.parametrize("what", list(CORRUPTIONS))
def test_validator_catches(what):
    tris = random_soup(500, seed=3)
    bvh = hwbvh.build(tris)
    hwbvh.validate(bvh.nodes, bvh.indices, len(tris), 4, primitive_boxes(tris))
    nodes, ids = corrupt(bvh, CORRUPTIONS[what])
    with pytest.raises(InputError, match="invalid tree"):
        hwbvh.validate(nodes, ids, len(tris), 4, primitive_boxes(tris))


def test_validator_catches_leaf_box_missing_its_primitive():
    tris = random_soup(200, seed=4)
    bvh = hwbvh.build(tris)
    nodes = bvh.nodes.copy()
    leaf = _first(nodes, 1)
    p = bvh.indices[nodes["a"][leaf]]
    tris2 = tris.copy()
    tris2[p] += 100.0                       # the stored tree no longer bounds this triangle
    with pytest.raises(InputError, match="contain its primitive"):
        hwbvh.validate(nodes, bvh.indices, len(tris), 4, primitive_boxes(tris2))


# ---- bad input ------------------------------------------------------------------------
def test_nan_and_inf_are_refused():
    t = random_soup(10)
    t[4, 1, 2] = np.nan
    with pytest.raises(InputError, match="triangle 4 has a NaN"):
        hwbvh.build(t)
    t[4, 1, 2] = np.inf
    with pytest.raises(InputError, match="NaN or infinite"):
        hwbvh.build(t)


def test_empty_and_wrong_shape_and_huge():
    with pytest.raises(InputError, match="no triangles"):
        hwbvh.build(np.zeros((0, 3, 3), np.float32))
    with pytest.raises(InputError, match="shape"):
        hwbvh.build(np.zeros((5, 3), np.float32))
    with pytest.raises(InputError, match="exceeds"):
        hwbvh.build(np.full((2, 3, 3), 1e20, np.float32))


def test_a_coordinate_too_large_for_float32_is_refused_as_too_large_without_warning():
    """Checked in the input's own precision: 1e39 (float64) would be inf after the cast."""
    t = random_soup(5).astype(np.float64)
    t[3, 2, 0] = 1e39
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError, match="^<array>: triangle 3 has a coordinate too large: "
                                             "magnitude 1e\\+39 exceeds 1e\\+15"):
            hwbvh.build(t)


def test_coordinate_checks_in_float16_and_just_beyond_the_bound():
    """float16 input: an inf is refused and valid input builds without a warning (compared in
    float16, the bound 1e15 itself would read as inf); a coordinate a hair beyond the bound
    is shown with the digits that tell it from the bound."""
    t = random_soup(20).astype(np.float16)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert hwbvh.build(t).meta["triangles"] == 20
        t[7, 1, 2] = np.inf
        with pytest.raises(InputError, match="^<array>: triangle 7 has a NaN or infinite"):
            hwbvh.build(t)
    t = random_soup(5).astype(np.float64)
    t[2, 0, 1] = -MAX_COORDINATE * (1 + 2.0 ** -50)
    with pytest.raises(InputError, match=r"triangle 2 has a coordinate too large: magnitude "
                                         r"1000000000000000\.\d+ exceeds 1e\+15"):
        hwbvh.build(t)
    t[2, 0, 1] = -MAX_COORDINATE                    # the bound itself is allowed
    hwbvh.build(t)


def test_more_than_2_24_primitives_is_refused_without_copying():
    many = np.broadcast_to(np.zeros((1, 3, 3), np.float32), ((1 << 24) + 1, 3, 3))
    with pytest.raises(InputError, match="2\\^24"):
        hwbvh.build(many)


@pytest.mark.parametrize("kw,match", [({"leaf_size": 0}, "leaf"), ({"leaf_size": 1000}, "leaf"),
                                      ({"bins": 1}, "bins"), ({"bins": 65}, "bins"),
                                      ({"capacity": 0}, "capacity"), ({"builder": "x"}, "builder")])
def test_parameters_out_of_range(kw, match):
    with pytest.raises(InputError, match=match):
        hwbvh.build(random_soup(10), **kw)


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "hwrt.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=300)


def write_ply_header_only(path, faces):
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
                     b"property float y\nproperty float z\nelement face %d\n"
                     b"property list uchar int vertex_indices\nend_header\n" % faces)


@pytest.mark.parametrize("setup,match", [
    (lambda d: d / "missing.ply", "no such file"),
    (lambda d: (d / "garbage.ply").write_bytes(b"\x00\x01 not a mesh") and d / "garbage.ply", "not a readable PLY file"),
    (lambda d: (d / "empty.obj").write_text("# nothing\n") and d / "empty.obj", "no triangles"),
    (lambda d: (d / "zero.ply").write_bytes(b"") or d / "zero.ply", "zero.ply: empty file$"),
    (lambda d: (d / "hdr.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 9\np")
     and d / "hdr.ply", "hdr.ply: not a readable PLY file \\(cut short or malformed\\)$"),
    (lambda d: (d / "nan.obj").write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n") and d / "nan.obj", "NaN"),
    (lambda d: write_ply_header_only(d / "big.ply", (1 << 24) + 1) or d / "big.ply", "2\\^24"),
    (lambda d: (d / "short.obj").write_text("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n") and d / "short.obj",
     "short.obj: line 2: a vertex has 2 coordinates, expected 3$"),
    (lambda d: (d / "cut.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n") and d / "cut.ply",
     "cut.ply: its header declares 5 vertices and 1 face, but no face could be read"),
])
def test_cli_bad_input_exits_2_and_writes_nothing(tmp_path, setup, match):
    src_dir = tmp_path / "in"
    src_dir.mkdir()
    mesh = setup(src_dir)
    out = tmp_path / "out"
    r = run_cli("build", mesh, "--out", out / "x", "--dump-aabbs", out / "a.bin", "--json")
    assert r.returncode == 2, r.stderr
    assert r.stdout == ""
    line = r.stderr.strip()
    assert "\n" not in line and str(mesh) in line
    import re
    assert re.search(match, line)
    assert not out.exists() or not any(out.iterdir())


def test_cli_bad_parameter_exits_2(tmp_path):
    p = tmp_path / "m.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    r = run_cli("build", p, "--leaf-size", "0")
    assert r.returncode == 2 and "--leaf-size" in r.stderr


def test_cli_build_json_and_files(tmp_path):
    import trimesh
    tris = sphere(20, 30)
    mesh = trimesh.Trimesh(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3), process=False)
    p = tmp_path / "sphere.ply"
    mesh.export(p)
    r = run_cli("build", p, "--json", "--out", tmp_path / "o" / "s", "--dump-aabbs", tmp_path / "a.bin",
                "--dump-handoff", tmp_path / "h.bin", "--capacity", "256")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    for k in ("triangles", "nodes", "leaves", "max_depth", "sah_cost", "build_seconds", "fallback_splits"):
        assert k in res
    assert res["triangles"] == len(tris)
    back = hwbvh.load(tmp_path / "o" / "s", triangles=tris)
    assert len(back.indices) == len(tris)
    boxes, order = unpack_records((tmp_path / "h.bin").read_bytes())
    assert sorted(order.tolist()) == list(range(len(tris)))
    sizes = json.loads((tmp_path / "h.bin.json").read_text())["handoff_sizes"]
    assert sum(sizes) == len(tris) and max(sizes) <= 256
    _, aorder = unpack_records((tmp_path / "a.bin").read_bytes())
    assert aorder.tolist() == list(range(len(tris)))


def test_loader_reads_other_formats(tmp_path):
    import trimesh
    tris = sphere(6, 8)
    m = trimesh.Trimesh(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3), process=False)
    for ext in ("obj", "stl", "off", "glb", "ply"):
        p = tmp_path / f"m.{ext}"
        m.export(p)
        got = hwbvh.load_triangles(p)
        assert got.shape == tris.shape


def test_bunny_reproduces_thesis_table_4_4():
    """Table 4.4: HWBVH 57.85 / 42,469 nodes; sweep 57.24 / 49,157 nodes."""
    p = shared_mesh("bunny.ply")
    hw = hwbvh.build(p, validate_tree=True).meta
    sw = hwbvh.build(p, builder="sweep", validate_tree=True).meta
    assert hw["sah_cost"] == pytest.approx(57.85, rel=2e-3)
    assert hw["nodes"] == pytest.approx(42469, rel=2e-3)
    assert sw["sah_cost"] == pytest.approx(57.24, rel=2e-3)
    assert sw["nodes"] == pytest.approx(49157, rel=2e-3)


def test_sweep_beats_binned_on_a_smooth_mesh():
    tris = sphere(60, 90)
    hw = hwbvh.build(tris).meta["sah_cost"]
    sw = hwbvh.build(tris, builder="sweep", validate_tree=True).meta["sah_cost"]
    assert sw < hw


def test_slot_assignment_grows_its_stack_past_a_wrong_depth():
    """The layout's pre-order stack is sized from the tree's recorded depth; handed a depth
    that is too small, it grows instead of writing past its end, and places the same slots."""
    from hwbvh.layout import assign_slots
    from scenes.meshes import random_soup
    tree = hwbvh.build(random_soup(2000, seed=4)).tree
    depth = int(tree.stats["max_depth"])
    assert depth > 4
    args = (tree.left, tree.right, tree.count, tree.root, 64, 2, 256)
    right = assign_slots(*args, depth)
    grown = assign_slots(*args, 0)
    for a, b in zip(right, grown):
        assert np.array_equal(a, b)


def test_build_names_its_out_prefix_when_the_directory_cannot_be_made(tmp_path, capsys):
    from hwrt.cli import main
    p = tmp_path / "m.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "file").write_text("")
    prefix = tmp_path / "file" / "x"
    assert main(["build", str(p), "--out", str(prefix)]) == 2
    assert capsys.readouterr().err == (f"hwrt: error: --out {prefix}: cannot create a directory "
                                       f"under {tmp_path / 'file'}: it is a file\n")


@pytest.mark.parametrize("ext", [".ply", ".obj", ".stl"])
def test_a_mesh_whose_file_name_is_not_utf8_is_read(tmp_path, ext):
    """File names are bytes; one that no UTF-8 reading takes (Latin-1 from another system)
    names a file all the same."""
    import trimesh
    from hwbvh.primitives import load_mesh_arrays
    tris = sphere(4, 8)
    data = trimesh.Trimesh(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3),
                           process=False).export(file_type=ext[1:])
    name = os.fsdecode(os.fsencode(tmp_path) + b"/caf\xe9" + ext.encode())
    with open(name, "wb") as f:
        f.write(data.encode() if isinstance(data, str) else data)
    v, f = load_mesh_arrays(name)
    assert len(f) == len(tris) and np.allclose(v[f], tris, atol=1e-6)


def test_a_saved_tree_read_back_without_triangles_says_where_they_are(tmp_path):
    """A tree read by load has no triangles: the tracer's refusal points to the mesh file it
    was built from, or, for a refitted tree, to the triangles it was refitted to (its mesh
    file's would lie outside its boxes)."""
    import trimesh
    from hwbvh.refit import refit
    from traversal import Tracer

    tris = sphere(8, 12)
    mesh = tmp_path / "ball.ply"
    trimesh.Trimesh(tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3),
                    process=False).export(mesh)
    built = hwbvh.build(str(mesh))
    hwbvh.save(built, tmp_path / "built")
    with pytest.raises(InputError, match=r"built from .*ball\.ply: triangles=hwbvh\."
                                         r"load_triangles\(that file\)"):
        Tracer(hwbvh.load(tmp_path / "built"))
    moved = refit(built, hwbvh.load_triangles(str(mesh)) * 2)
    hwbvh.save(moved, tmp_path / "moved")
    with pytest.raises(InputError, match=r"a refitted tree: the triangles it was refitted to"):
        Tracer(hwbvh.load(tmp_path / "moved"))
    Tracer(hwbvh.load(tmp_path / "moved"), triangles=moved.triangles)


def test_a_tree_description_nested_too_deeply_is_named_not_a_recursion_error(tmp_path):
    tris = np.float32([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 0, 1], [0, 1, 1]]])
    hwbvh.save(hwbvh.build(tris), tmp_path / "t")
    (tmp_path / "t.json").write_text("[" * 100000 + "]" * 100000)
    with pytest.raises(InputError, match=r"t\.json: not a tree's description \(nested too "
                                         r"deeply\)$"):
        hwbvh.load(tmp_path / "t")


def test_load_with_other_triangles_names_the_triangles_not_the_tree(tmp_path):
    """The tree on disk is sound; it is the triangles given that do not fit its leaves."""
    tris = random_soup(200, seed=4)
    hwbvh.save(hwbvh.build(tris), tmp_path / "t")
    with pytest.raises(InputError, match=r"^triangles: a triangle lies outside its leaf's box "
                                         r"\(node \d+ of .*t\.nodes\): not the triangles the "
                                         r"tree was built over$"):
        hwbvh.load(tmp_path / "t", triangles=tris + np.float32(0.5))
    assert hwbvh.load(tmp_path / "t", triangles=tris).meta["triangles"] == 200


def test_load_refuses_a_description_in_another_format(tmp_path):
    """save would not replace such a file (it is not a tree's description); load does not read
    it as one either. A description without a format name is read, as older ones are."""
    tris = random_soup(50, seed=4)
    hwbvh.save(hwbvh.build(tris), tmp_path / "t")
    meta = json.loads((tmp_path / "t.json").read_text())
    (tmp_path / "t.json").write_text(json.dumps(dict(meta, format="other")))
    with pytest.raises(InputError, match=r"t\.json: its format is 'other', not a tree's "
                                         r"description \('hwrt-bvh-1'\)$"):
        hwbvh.load(tmp_path / "t")
    del meta["format"]
    (tmp_path / "t.json").write_text(json.dumps(meta))
    assert hwbvh.load(tmp_path / "t").meta["triangles"] == 50


@pytest.mark.parametrize("leaf_size", [1, 2, 4, 16])
def test_a_zero_area_scene_costs_every_test_of_its_tree(leaf_size):
    """All triangles on one point: no area ratio is defined, and a ray that reaches the scene
    reaches every node, so the cost is both child tests of each internal node and every
    triangle of every leaf, whatever the leaf size (a deeper tree never costs less than one
    leaf)."""
    tris = np.full((10, 3, 3), 0.25, np.float32)
    meta = hwbvh.build(tris, leaf_size=leaf_size).meta
    internal = meta["nodes"] - meta["leaves"]
    assert meta["sah_cost"] == 2 * internal + 10
