"""Triangles in, 216-bit primitive records out (thesis 3.3, SPEC section 1).

A primitive record is a float32 AABB ``(minx, miny, minz, maxx, maxy, maxz)`` and a 24-bit
primitive index. ``load_triangles`` reads any mesh trimesh reads; ``as_triangles`` validates
raw ``(n, 3, 3)`` arrays. Both raise :class:`InputError` naming the source and the problem.
"""
import os
import re

import numpy as np

from .config import MAX_COORDINATE, MAX_PRIMITIVES, PRIMITIVE_RECORD_BYTES
from .errors import InputError

MESH_EXTENSIONS = (".ply", ".obj", ".stl", ".off", ".glb", ".gltf")


def _ply_face_count(path):
    """Face count declared in a PLY header, or None. Read before loading, so a file with more
    than 2^24 faces is refused without parsing it."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError:
        return None
    if not head.startswith(b"ply"):
        return None
    m = re.search(rb"element\s+face\s+(\d+)", head)
    return int(m.group(1)) if m else None


# a 0 (or -0) among the indices of an OBJ face line ("f 1 2 0", "f 1/0/1 ..."); OBJ counts
# from 1 (negative counts back from the end), so 0 is an error that trimesh reads silently
_OBJ_ZERO_INDEX = re.compile(rb"(?m)^[ \t]*f[ \t][^\n#]*?(?<=[ \t/])-?0+(?=[ \t/\r#]|$)")


def _check_obj_indices(path):
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError:
        return
    m = _OBJ_ZERO_INDEX.search(data)
    if m:
        line = data.count(b"\n", 0, m.start()) + 1
        raise InputError(path, f"line {line}: face index 0 (OBJ indices start at 1)")


def _check_obj_face_range(path):
    """Name the first face of an OBJ file that refers past the file's vertices (trimesh reports
    it as a bare IndexError, 0-based). Run only after a failed load: a good file pays nothing."""
    try:
        with open(path, "rb") as f:
            lines = [ln.split(b"#", 1)[0].split() for ln in f.read().split(b"\n")]
    except OSError:
        return
    count = sum(1 for w in lines if w[:1] == [b"v"])
    for k, words in enumerate(lines, 1):
        for w in words[1:] if words[:1] == [b"f"] else ():
            try:
                n = int(w.split(b"/")[0])
            except ValueError:
                continue
            if not -count <= n <= count:
                back = " (counting back from the last)" if n < 0 else ""
                raise InputError(path, f"line {k}: a face refers to vertex {n}{back}, but the "
                                       f"file has {count} {'vertex' if count == 1 else 'vertices'}")


def check_count(n, source):
    if n == 0:
        raise InputError(source, "mesh has no triangles")
    if n > MAX_PRIMITIVES:
        raise InputError(source, f"{n} triangles is more than the 2^24 = {MAX_PRIMITIVES} "
                                 "primitives a 24-bit index can address")


def as_triangles(tris, source="<array>"):
    """Validate and return a C-contiguous float32 ``(n, 3, 3)`` triangle array.

    tris : (n, 3, 3) array-like of float; vertex coordinates must be finite and within
    +-1e15 (float32 SAH areas times counts must not overflow).
    """
    shape = getattr(tris, "shape", None)
    if shape is not None and len(shape) == 3 and shape[1:] == (3, 3):
        check_count(shape[0], source)       # before any copy: 2^24+ triangles are refused cheaply
    t = np.asarray(tris)
    if t.ndim != 3 or t.shape[1:] != (3, 3):
        raise InputError(source, f"triangles must have shape (n, 3, 3), got {t.shape}")
    check_count(t.shape[0], source)
    return np.ascontiguousarray(checked_coordinates(t, source), dtype=np.float32)


def within_bound(a, bound=MAX_COORDINATE):
    """Whether every number of array ``a`` is finite and of magnitude at most ``bound``, in
    ``a``'s own precision (compared as float64: a float16 array would turn the bound itself
    into inf) and without a temporary of ``a``'s size (NaN fails both comparisons)."""
    a = np.asarray(a)
    if a.dtype.kind != "f":
        a = a.astype(np.float64)    # integers (whose abs can wrap), booleans, objects
    return a.size == 0 or bool(a.max() <= np.float64(bound) and a.min() >= -np.float64(bound))


def checked_coordinates(t, source):
    """``t`` ((n, 3, 3) triangles) in a float type, refused (InputError naming ``source`` and
    the first bad triangle) if a coordinate is NaN, infinite or beyond MAX_COORDINATE.
    Checked in the input's own precision: the float32 cast would turn a coordinate beyond
    float32's range into inf, with numpy's overflow warning."""
    if t.dtype.kind != "f":
        t = t.astype(np.float64)
    if within_bound(t):
        return t
    t64 = t.astype(np.float64)
    ok = (np.abs(t64) <= MAX_COORDINATE).reshape(len(t), 9).all(axis=1)    # NaN is not <=
    bad = int(np.argmin(ok))
    if not np.isfinite(t64[bad]).all():
        raise InputError(source, f"triangle {bad} has a NaN or infinite coordinate")
    big = float(np.abs(t64[bad]).max())
    shown = f"{big:.3g}" if float(f"{big:.3g}") > MAX_COORDINATE else repr(big)
    raise InputError(source, f"triangle {bad} has a coordinate too large: magnitude {shown} "
                             f"exceeds {MAX_COORDINATE:.0e} (float32 SAH costs would overflow)")


def load_mesh_arrays(path):
    """Read a mesh file with trimesh; return (vertices float32 (v,3), faces int64 (f,3))."""
    import trimesh

    path = os.fspath(path)
    if not os.path.exists(path):
        raise InputError(path, "no such file")
    if os.path.isdir(path):
        raise InputError(path, "is a directory, not a mesh file")
    declared = _ply_face_count(path)
    if declared is not None:
        check_count(declared, path)
    if path.lower().endswith(".obj"):
        _check_obj_indices(path)
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for unreadable files
        if isinstance(exc, IndexError) and path.lower().endswith(".obj"):
            _check_obj_face_range(path)
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(path, f"cannot read mesh ({msg})") from None
    faces = getattr(mesh, "faces", None)
    verts = getattr(mesh, "vertices", None)
    if faces is None or verts is None or len(faces) == 0:
        raise InputError(path, "mesh has no triangles")
    faces = np.asarray(faces, dtype=np.int64)
    verts = np.asarray(verts, dtype=np.float64)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(path, "mesh faces are not triangles")
    if faces.min() < 0 or faces.max() >= len(verts):
        raise InputError(path, "a face references a vertex that does not exist")
    return verts, faces


def load_triangles(path):
    """Read a mesh file and return validated float32 triangles ``(n, 3, 3)``."""
    verts, faces = load_mesh_arrays(path)
    return as_triangles(verts[faces], source=os.fspath(path))


def primitive_boxes(tris):
    """Primitive AABBs of triangles, float32 ``(n, 6)``: ``minx, miny, minz, maxx, maxy, maxz``.

    Min and max of float32 vertices are exact, so the boxes are what the hardware reads.
    """
    boxes = np.empty((len(tris), 6), dtype=np.float32)
    np.minimum(np.minimum(tris[:, 0], tris[:, 1]), tris[:, 2], out=boxes[:, :3])
    np.maximum(np.maximum(tris[:, 0], tris[:, 1]), tris[:, 2], out=boxes[:, 3:])
    return boxes


def pack_records(boxes, order=None):
    """Primitive records as the hardware reads them (thesis ``mike_rt -b``): 27 bytes each,
    24 bytes of little-endian float32 AABB then the 24-bit little-endian primitive index.

    order : optional (n,) primitive indices, the record order (default 0..n-1).
    """
    n = len(boxes)
    idx = np.arange(n, dtype=np.uint32) if order is None else np.asarray(order, dtype=np.uint32)
    rec = np.empty((len(idx), PRIMITIVE_RECORD_BYTES), dtype=np.uint8)
    rec[:, :24] = np.ascontiguousarray(boxes[idx], dtype="<f4").view(np.uint8).reshape(-1, 24)
    rec[:, 24:] = idx.astype("<u4").view(np.uint8).reshape(-1, 4)[:, :3]
    return rec.tobytes()


def unpack_records(data):
    """Inverse of :func:`pack_records`: (boxes float32 (n, 6), indices uint32 (n,))."""
    raw = np.frombuffer(data, dtype=np.uint8)
    if raw.size % PRIMITIVE_RECORD_BYTES:
        raise ValueError("record data is not a whole number of 27-byte records")
    rec = raw.reshape(-1, PRIMITIVE_RECORD_BYTES)
    boxes = np.ascontiguousarray(rec[:, :24]).view("<f4").reshape(-1, 6)
    idx = np.zeros((len(rec), 4), dtype=np.uint8)
    idx[:, :3] = rec[:, 24:]
    return boxes.astype(np.float32), idx.view("<u4").reshape(-1)
