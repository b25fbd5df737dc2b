"""Triangles in, 216-bit primitive records out (thesis 3.3, SPEC section 1).

A primitive record is a float32 AABB ``(minx, miny, minz, maxx, maxy, maxz)`` and a 24-bit
primitive index. ``load_triangles`` reads any mesh trimesh reads; ``as_triangles`` validates
raw ``(n, 3, 3)`` arrays. Both raise :class:`InputError` naming the source and the problem.
"""
import io
import os
import re
import warnings

import numpy as np
from numba import njit

from .config import (AABB_BYTES, MAX_COORDINATE, MAX_FLOAT32_ROUNDING, MAX_PRIMITIVES,
                     OBJ_COMPILED_MIN_BYTES, PLY_HEADER_BYTES, PRIMITIVE_RECORD_BYTES)
from .errors import InputError, ParameterError, json_syntax, shown

MESH_EXTENSIONS = (".ply", ".obj", ".stl", ".off", ".glb", ".gltf")


def _ply_declared(path, header=None):
    """The element counts a PLY header declares ({"vertex": n, "face": m, ...}), or None for
    another file. Read before loading, so a file with more than 2^24 faces is refused
    without parsing it. ``header``: the file's ``_ply_header``, if the caller has it."""
    header = _ply_header(path) if header is None else header
    return None if header is None else {name: count for name, count, _ in header[1]}


# The PLY types a face's vertex indices may have (trimesh's integer types): a binary file's
# float index would be truncated without a word.
_PLY_INTEGER_TYPES = frozenset(("char", "uchar", "short", "ushort", "int", "uint", "int8", "uint8",
                                "int16", "uint16", "int32", "uint32", "int64", "uint64"))
_PLY_FACE_LISTS = ("vertex_indices", "vertex_index")


def _ply_header(path):
    """(format, [(element, count, [(property, item type of a list or None)])], the header's
    length in bytes, its lines) of a PLY file, or None for another file or a header that does
    not end in its first ``PLY_HEADER_BYTES``. The header ends, as trimesh reads it, with the
    first line that holds the word ``end_header``."""
    try:
        with open(path, "rb") as f:
            head = f.read(PLY_HEADER_BYTES)
    except OSError:
        return None
    if not head.startswith(b"ply"):
        return None
    fmt, elements, at = None, [], 0
    while True:
        nl = head.find(b"\n", at)
        words = head[at:len(head) if nl < 0 else nl].decode("ascii", "replace").split()
        if "end_header" in words:
            length = len(head) if nl < 0 else nl + 1
            return fmt, elements, length, head[:length].count(b"\n")
        if nl < 0:
            return None
        at = nl + 1
        if len(words) >= 2 and words[0] == "format":
            fmt = words[1]
        elif len(words) >= 3 and words[0] == "element" and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif len(words) >= 3 and words[0] == "property" and elements:
            item = words[3] if words[1] == "list" and len(words) >= 5 else None
            elements[-1][2].append((words[-1], item))


@njit(cache=True)
def _ascii_bad_face(data, skip, n_faces, more_ok):
    """The first face line of ASCII mesh text ``data`` (``skip`` lines of other elements
    first; a line a face, its count then its indices) whose count is not its number of
    indices (with ``more_ok``, fewer only: an OFF face may carry a colour after them), or whose
    count or indices are not non-negative integers (as a reader of numbers takes them: "+3"
    and "3.0" are 3): (face, what, indices found, count given), what 0: another number of
    indices, 1: a count that is not such an integer, 2: an index that is not one, 3: the text
    ends before the face; (-1, 0, 0, 0) for none."""
    n = data.shape[0]
    pos = 0
    for _ in range(skip):
        while pos < n and data[pos] != 10:
            pos += 1
        pos += 1
    for i in range(n_faces):
        if pos >= n:
            return i, 3, 0, 0
        tokens = 0
        count = -1
        bad_index = False
        while pos < n and data[pos] != 10:
            c = data[pos]
            if c == 32 or c == 9 or c == 13:
                pos += 1
                continue
            value = 0
            digits = 0
            integer = True
            fraction = False                    # past a ".": only zeros keep it an integer
            if c == 43:                         # a leading "+"
                pos += 1
            while pos < n and data[pos] != 10 and data[pos] != 32 and data[pos] != 9 \
                    and data[pos] != 13:
                d = data[pos]
                if 48 <= d <= 57 and not fraction:
                    value = min(value * 10 + (d - 48), 1 << 40)
                    digits += 1
                elif d == 46 and not fraction:
                    fraction = True
                elif not (d == 48 and fraction):
                    integer = False
                pos += 1
            integer = integer and digits > 0
            if tokens == 0:
                count = value if integer else -1
            elif tokens <= count and not integer:
                bad_index = True
            tokens += 1
        pos += 1
        if tokens == 0 or count < 0:
            return i, 1, 0, 0
        if bad_index:
            return i, 2, 0, 0
        if tokens < count + 1 or (tokens > count + 1 and not more_ok):
            return i, 0, tokens - 1, count
    return -1, 0, 0, 0


def _ply_face_problem(path, header):
    """Why the faces of PLY file ``path`` (its ``_ply_header``) cannot be read as written,
    which trimesh reads without a word: in a binary file, indices of a float type (trimesh
    truncates them); in an ASCII file, a face line whose count is not its number of indices
    (trimesh reads the line's first indices whatever its count says), or a count or index
    that is not a non-negative integer (a fraction truncated), with its line. None where the
    faces are sound (or the file is not a PLY file trimesh reads)."""
    if header is None:
        return None
    fmt, elements, length, header_lines = header
    skip = 0
    for name, count, props in elements:
        if name != "face":
            skip += count
            continue
        lists = [item for p, item in props if p in _PLY_FACE_LISTS and item is not None]
        if fmt != "ascii":
            if lists and lists[0] not in _PLY_INTEGER_TYPES:
                return (f"its header declares the faces' vertex indices as {lists[0]}; indices "
                        f"are integers")
            return None
        if len(props) != 1 or not lists:
            return None
        with open(path, "rb") as f:
            body = np.frombuffer(f.read(), np.uint8)[length:]
        face, what, found, given = _ascii_bad_face(body, skip, count, False)
        if face < 0:
            return None
        if what == 3:
            return _ply_cut_short({n: c for n, c, _ in elements}, face)
        line = header_lines + skip + face + 1
        return (f"line {line}: a face's count says {given} indices, the line holds {found}",
                f"line {line}: a face's count is not a non-negative integer",
                f"line {line}: a face's index is not a non-negative integer")[what]
    return None


def _off_face_problem(path):
    """Why the faces of the OFF file ``path`` are not what its counts say, which trimesh reads
    without a word (it takes the face lines there are, and a face line's indices up to its
    count): fewer face lines than the header declares, a face line with fewer indices than
    its count, or a count or index that is not a non-negative integer. Lines as trimesh sees
    them (comments and blank lines dropped, so a face is named by its place, not its line).
    None where the faces are sound, or where trimesh cannot read the file (its own error says
    so)."""
    from trimesh.util import comment_strip, decode_text
    try:
        with open(path, "rb") as f:
            text = comment_strip(decode_text(f.read())).strip()
        parts = re.split("(COFF|OFF)", text, maxsplit=1)
        lines = list(filter(None, map(str.strip, parts[2].splitlines())))
        n_vertices, n_faces = (int(c) for c in lines[0].split()[:2])
    except (OSError, ValueError, IndexError, UnicodeError):
        return None
    faces = lines[n_vertices + 1:n_vertices + 1 + n_faces]
    if len(faces) < n_faces:
        return f"its header declares {n_faces} faces, but it holds {len(faces)}"
    data = np.frombuffer(("\n".join(faces) + "\n").encode("ascii", "replace"), np.uint8)
    face, what, found, given = _ascii_bad_face(data, 0, len(faces), True)
    if face < 0:
        return None
    return (f"face {face + 1}: its count says {given} indices, the line holds {found}",
            f"face {face + 1}: its count is not a non-negative integer",
            f"face {face + 1}: an index is not a non-negative integer")[what]


# OBJ files as trimesh reads them. A line ending in a backslash continues on the next. Vertices,
# texture coordinates and normals are the lines starting "v ", "vt ", "vn " (trimesh numbers
# only those). A face index counts from 1; a negative one counts back from the elements of its
# kind before the face's line, but trimesh counts it back from the file's last, so a file with
# one is handed to trimesh with its negative indices made positive. 0 is no index, yet trimesh
# reads it silently (as the first vertex). The text is rewritten by a compiled pass
# (_obj_resolve); a small file, or one it cannot vouch for (a bad index, or a rare form such as
# "+1", "1/2/3/4" or a continued last line), goes to the line-by-line reader (_obj_resolved_lines),
# which names the line of a bad index and is the reference the compiled pass is tested against.
_OBJ_KINDS = (("vertex", "vertices"), ("texture coordinate", "texture coordinates"),
              ("normal", "normals"))

# a face line with an index that starts with "-" or "0" (negative, zero or zero-padded), found
# at C speed so that only files with one (or with a continued line) are read line by line.
# Later lines are found by their "\n" (the first line is matched on its own): (?m)^ is 3x slower.
_OBJ_ODD_INDEX = rb"[ \t]*f(?:[ \t/]+[1-9][0-9]*)*+[ \t/]+[-0]"
_OBJ_ODD_INDEX_FIRST_LINE = re.compile(_OBJ_ODD_INDEX)
_OBJ_ODD_INDEX_LATER_LINE = re.compile(rb"\n" + _OBJ_ODD_INDEX)
_OBJ_CONTINUATION = re.compile(rb"\\\r?\n")
# A file ending in a continued line: the reader ends it there, as a line of its own. If the file
# ends in a backslash (and at most a CR), removing _OBJ_CONTINUATION leaves that backslash in; if
# it ends "\\\n" or "\\\r\n", the joined text is the same but for a last line holding only
# continuations (as in "f 1 2 3\n\\\n"), which the reader keeps as an empty line and the text
# loses. Such files are rare: all four go to the reader.
_OBJ_CONTINUED_END = (b"\\", b"\\\r", b"\\\n", b"\\\r\n")
# A continued line ending in CR ("...\r\\\n"): the reader strips the CR of a line end only, so if
# the line joined to it is empty that CR stays in the line, which the joined text ends in CRLF.
_OBJ_CR_BEFORE_CONTINUATION = re.compile(rb"\r\\\r?\n")


def _obj_lines(raw_lines):
    """(number, line) for each line of an OBJ file given as its raw lines (bytes), as trimesh
    reads it: without its line end, a line ending in a backslash joined to the next and numbered
    by its first."""
    parts = []
    for number, raw in enumerate(raw_lines, 1):
        line = raw.removesuffix(b"\n").removesuffix(b"\r")
        if not parts:
            first = number
        if line.endswith(b"\\"):
            parts.append(line[:-1])
            continue
        if parts:
            line, parts = b"".join(parts) + line, []
        yield first, line
    if parts:
        yield first, b"".join(parts)


def _obj_face_index(path, number, word, before, vertex_total):
    """Face index ``word`` ("v", "v/vt", "v//vn", "v/vt/vn") of line ``number`` with its negative
    numbers made positive; ``before`` counts each kind of element before the line."""
    parts, resolved = word.split(b"/"), False
    for kind, part in enumerate(parts[:3]):
        if kind and not part:
            continue                                        # "1//3": no texture coordinate
        try:
            n = int(part)
        except ValueError:
            hint = " (a comment must be on a line of its own)" if word.startswith(b"#") else ""
            shown = word.decode(errors="replace")
            raise InputError(path, f"line {number}: a face holds {shown!r}, which is not an "
                                   f"index{hint}") from None
        if n > 0:
            if kind == 0 and vertex_total is not None and n > vertex_total:
                raise InputError(path, f"line {number}: a face refers to vertex {n}, but the "
                                       f"file has {_obj_count(vertex_total, 0)}")
            continue
        if n == 0:
            raise InputError(path, f"line {number}: face index 0 (OBJ indices start at 1)")
        if before[kind] + n < 0:
            have = (f"no {_OBJ_KINDS[kind][0]} comes" if before[kind] == 0 else
                    f"only {_obj_count(before[kind], kind)} come{'s' if before[kind] == 1 else ''}")
            raise InputError(path, f"line {number}: a face refers to {_OBJ_KINDS[kind][0]} {n}, "
                                   f"counting back from that line, but {have} before it")
        parts[kind], resolved = b"%d" % (before[kind] + n + 1), True
    return b"/".join(parts) if resolved else word


def _obj_count(n, kind):
    """'1 vertex', '3 vertices' (kind 0; 1 and 2 are texture coordinates and normals)."""
    return f"{n} {_OBJ_KINDS[kind][n != 1]}"


def _obj_resolved_lines(path, raw_lines, vertex_total=None):
    """The lines of an OBJ file (as :func:`_obj_lines` reads them) with each negative face index
    made the positive one it means. Raises InputError naming the first face line with an index
    that is not a number, is 0, counts back before the first element of its kind, or (given
    ``vertex_total``) refers past the file's last vertex."""
    before = [0, 0, 0]                  # vertices, texture coordinates, normals so far
    started = False
    for number, line in _obj_lines(raw_lines):
        if not started and line.strip():
            # trimesh strips the whole text, so the first line with content loses its indent
            line, started = line.lstrip(), True
        if line[:2] == b"v ":
            before[0] += 1
        elif line[:3] == b"vt ":
            before[1] += 1
        elif line[:3] == b"vn ":
            before[2] += 1
        else:
            words = line.split()
            if words[:1] == [b"f"]:
                resolved = [_obj_face_index(path, number, w, before, vertex_total)
                            for w in words[1:]]
                if resolved != words[1:]:       # keep the indent: trimesh skips indented lines
                    line = line[:len(line) - len(line.lstrip())] + b" ".join([b"f", *resolved])
        yield line


def _obj_resolved_text(path, data):
    """The text :func:`_obj_resolved_lines` makes of OBJ file ``path`` whose bytes are ``data``
    (each line ending in "\\n"): made by the compiled pass, or for a file that pass leaves to
    it, by the line-by-line reader, which raises InputError naming the line of a bad index."""
    text = _obj_compiled_text(data) if len(data) >= OBJ_COMPILED_MIN_BYTES else None
    if text is None:
        out = io.BytesIO()              # not a list of the lines: each would be an object
        for line in _obj_resolved_lines(path, io.BytesIO(data)):
            out.write(line)
            out.write(b"\n")
        text = out.getvalue()
    return text


def _obj_compiled_text(data):
    """The text :func:`_obj_resolved_lines` makes of OBJ bytes ``data``, made at compiled
    speed; or None for a file with a bad face index or a rare form (see _obj_face_indices),
    or whose last line is continued into nothing, or that has a continued line ending in CR."""
    if data.endswith(_OBJ_CONTINUED_END) or _OBJ_CR_BEFORE_CONTINUATION.search(data):
        return None
    text = _OBJ_CONTINUATION.sub(b"", data)
    # The output never outgrows the text but where an index "-n" is rewritten (and by the "\n"
    # the last line may gain): a face line is otherwise copied or shortened (one space for each
    # run of blanks, no CR). "-n" is 2+ bytes, and its positive index is at most the count of
    # elements of its kind before it, so at most the count of lines: it adds at most that
    # count's digits less 2 bytes. Counting every "-" (coordinates, comments too) keeps this a
    # bound; _obj_resolve writes unchecked, so it must be one.
    index_digits = len(b"%d" % (text.count(b"\n") + 1))
    out = np.empty(len(text) + 1 + max(0, index_digits - 2) * text.count(b"-"), dtype=np.uint8)
    size = _obj_resolve(np.frombuffer(text, dtype=np.uint8), out)
    return out[:size].tobytes() if size >= 0 else None


@njit(cache=True)
def _obj_blank(c):
    """Whether byte ``c`` is ASCII whitespace (" \\t\\n\\v\\f\\r"), what bytes.split() splits on."""
    return c == 32 or 9 <= c <= 13


@njit(cache=True)
def _obj_element_kind(text, s, e):
    """0, 1 or 2 if line ``text[s:e]`` is a vertex, texture coordinate or normal, else -1."""
    if e - s >= 2 and text[s] == 118:                               # "v"
        if text[s + 1] == 32:
            return 0
        if e - s >= 3 and text[s + 2] == 32:
            if text[s + 1] == 116:                                  # "vt "
                return 1
            if text[s + 1] == 110:                                  # "vn "
                return 2
    return -1


@njit(cache=True)
def _obj_face_indices(text, p, e, before, out, o):
    """Write the face indices ``text[p:e]`` (the words after "f") to ``out`` from ``o`` as
    _obj_resolved_lines writes a face line it changes: each word after one space, negative
    numbers made positive (``before`` counts each kind of element before the line). Returns
    (end in ``out``, 1 if a number was negative else 0), or (o, -1) for a part that is not
    -?[0-9]+ (or empty after a "/"), is 0, counts back before the first element of its kind,
    or is a word's fourth: the line-by-line reader decides those."""
    negative = 0
    while True:
        while p < e and _obj_blank(text[p]):
            p += 1
        if p == e:
            return o, negative
        out[o] = 32
        o += 1
        kind = 0
        while True:                                         # one "/"-separated part a pass
            start = p
            if p < e and text[p] == 45:                     # "-"
                p += 1
            digits = p
            value = 0
            nonzero = False
            while p < e and 48 <= text[p] <= 57:
                nonzero |= text[p] != 48
                if p - digits < 18:                         # longer ones are refused below
                    value = value * 10 + (text[p] - 48)
                p += 1
            if p < e and not (text[p] == 47 or _obj_blank(text[p])):
                return o, -1
            if p == start:
                if kind == 0:                               # a word starting "/"
                    return o, -1
            elif p == digits or not nonzero:                # "-" alone, or 0
                return o, -1
            elif digits > start:
                if p - digits > 18 or value > before[kind]:
                    return o, -1
                resolved = before[kind] - value + 1
                width, rest = 1, resolved // 10
                while rest:
                    width, rest = width + 1, rest // 10
                for k in range(width - 1, -1, -1):
                    out[o + k] = 48 + resolved % 10
                    resolved //= 10
                o += width
                negative = 1
            else:
                out[o:o + p - start] = text[start:p]
                o += p - start
            if p == e or text[p] != 47:
                break
            out[o] = 47                                     # "/"
            o += 1
            p += 1
            kind += 1
            if kind == 3:
                return o, -1


@njit(cache=True)
def _obj_resolve(text, out):
    """Write to ``out`` the text _obj_resolved_lines makes of OBJ text ``text`` (its continued
    lines joined), each line ending in "\\n", and return its length; or -1 if a face line holds
    a part that :func:`_obj_face_indices` leaves to the line-by-line reader."""
    n = len(text)
    before = np.zeros(3, dtype=np.int64)    # vertices, texture coordinates, normals so far
    started = False
    o = 0
    i = 0
    while i < n:
        e = i
        while e < n and text[e] != 10:
            e += 1
        following = e + 1
        if e > i and text[e - 1] == 13:
            e -= 1
        s = i
        q = i                               # the line's first byte of content
        while q < e and _obj_blank(text[q]):
            q += 1
        if not started and q < e:
            s, started = q, True            # trimesh strips the whole text
        kind = _obj_element_kind(text, s, e)
        rewritten = False
        if kind >= 0:
            before[kind] += 1
        elif q < e and text[q] == 102 and (q + 1 == e or _obj_blank(text[q + 1])):    # "f"
            out[o:o + q - s] = text[s:q]    # the indent: trimesh skips indented lines
            out[o + q - s] = 102
            end, negative = _obj_face_indices(text, q + 1, e, before, out, o + q - s + 1)
            if negative < 0:
                return -1
            if negative:
                o, rewritten = end, True
        if not rewritten:
            out[o:o + e - s] = text[s:e]
            o += e - s
        out[o] = 10
        o += 1
        i = following
    return o


def trimesh_module():
    """trimesh, imported with SIGINT and SIGTERM held (``files.signals_held``): several of its
    modules wrap their own imports in ``except BaseException``, which would swallow the
    KeyboardInterrupt of a Ctrl-C arriving there; held, the signal is acted on as the import
    ends. Imported where a mesh is first read, so commands that read none do not pay for it."""
    import sys
    module = sys.modules.get("trimesh")
    if module is None:
        from .files import signals_held
        with signals_held():
            import trimesh as module
    return module


def _obj_load_args(path):
    """trimesh.load's arguments for OBJ file ``path``: the path itself, or (for a file with a
    face index starting "-" or "0", or a continued line) its text as :func:`_obj_resolved_text`
    rewrites it. A face index 0 or one counting back before the first vertex raises InputError
    naming its line. Other files pay one C-speed regex search."""
    trimesh = trimesh_module()

    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError:
        return {"file_obj": path}           # trimesh reports it
    if not (_OBJ_ODD_INDEX_FIRST_LINE.match(data) or _OBJ_ODD_INDEX_LATER_LINE.search(data)
            or _OBJ_CONTINUATION.search(data)):
        return {"file_obj": path}
    return {"file_obj": io.BytesIO(_obj_resolved_text(path, data)), "file_type": "obj",
            "resolver": trimesh.resolvers.FilePathResolver(path)}    # its mtllib, as for a path


def _count_obj_vertices(f, block_size=1 << 24):
    """Vertices of binary OBJ file ``f`` (lines starting "v " that do not continue the line
    before), counted at C speed a block at a time."""
    def starts(buf):
        return buf.count(b"\nv ") - buf.count(b"\\\nv ") - buf.count(b"\\\r\nv ")
    count, tail = 0, b"\n"                  # the last bytes of the blocks so far; start of file
    while block := f.read(block_size):
        buf = tail + block
        count += starts(buf) - starts(tail)     # the tail's were counted with the block before
        tail = buf[-4:]                         # the longest pattern less one byte
    return count


def _check_obj_face_range(path):
    """Name the first face line of an OBJ file that trimesh cannot read: an index that is not a
    number, refers past the file's vertices or counts back before the first (trimesh reports
    a bare 0-based IndexError or numpy's parse error). Run only after a failed load: a good file
    pays nothing. The file is streamed, so a multi-GB file gets its message in little memory."""
    try:
        with open(path, "rb") as f:
            total = _count_obj_vertices(f)
            f.seek(0)
            for _ in _obj_resolved_lines(path, f, total):
                pass
    except OSError:
        return


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
    try:
        t = np.asarray(tris)
    except (ValueError, TypeError):         # nested sequences of uneven lengths
        raise InputError(source, "triangles must be an (n, 3, 3) array of numbers, got nested "
                                 "sequences of uneven lengths") from None
    if t.ndim == 0:                         # None, a number, a path where an array goes
        raise InputError(source, f"triangles must be an (n, 3, 3) array, got "
                                 f"{type(tris).__name__}")
    if t.ndim != 3 or t.shape[1:] != (3, 3):
        raise InputError(source, f"triangles must have shape (n, 3, 3), got {t.shape}")
    check_count(t.shape[0], source)
    t = checked_coordinates(t, source)
    if t.dtype.itemsize > 4 and len(t):
        _refuse_float32_collapse(t, source)
    return np.ascontiguousarray(t, dtype=np.float32)


def extent(tris):
    """The largest side of the box of (n, 3, 3) ``tris`` (n > 0)."""
    return float((tris.max(axis=(0, 1)) - tris.min(axis=(0, 1))).max())


def float32_step(tris):
    """How far apart float32 numbers lie where ``tris`` reach farthest from the origin, along
    the coarsest axis."""
    with np.errstate(over="ignore"):
        return float(np.spacing(np.abs(tris).max(axis=(0, 1)).astype(np.float32)).max())


def _refuse_float32_collapse(t, source):
    """Refuse (InputError naming ``source``) triangles ``t``, given wider than float32, that
    float32 rounds by more than ``MAX_FLOAT32_ROUNDING`` of their size where they lie: far from
    the origin against their size, or so small that they round to zero. The builder and the
    units work in float32, so every ray would miss them without a word."""
    size, step = extent(t), float32_step(t)
    if size > 0 and step / 2 > MAX_FLOAT32_ROUNDING * size:
        raise InputError(source, f"the triangles collapse in float32, the builder's precision: "
                                 f"where they lie, float32 numbers are {step:.3g} apart, "
                                 f"coarse against their size of {size:.3g} (move them nearer the "
                                 f"origin, or scale them up)")


def within_bound(a, bound=MAX_COORDINATE):
    """Whether every number of array ``a`` is finite and of magnitude at most ``bound``, in
    ``a``'s own precision (compared as float64: a float16 array would turn the bound itself
    into inf) and without a temporary of ``a``'s size (NaN fails both comparisons)."""
    a = np.asarray(a)
    if a.dtype.kind != "f":
        a = a.astype(np.float64)    # integers (whose abs can wrap), booleans, objects
    return a.size == 0 or bool(a.max() <= np.float64(bound) and a.min() >= -np.float64(bound))


def _native_float(t):
    """``t`` (floats, within bounds) as float32 or float64 in native byte order, the
    types the kernels are compiled for: half precision widened (exactly), a foreign byte order
    swapped, anything wider than float64 rounded to it."""
    want = np.dtype(np.float32 if t.dtype.itemsize <= 4 else np.float64)
    return t if t.dtype == want else t.astype(want)


def checked_coordinates(t, source):
    """``t`` ((n, 3, 3) triangles) in a float type, refused (InputError naming ``source`` and
    the first bad triangle) if a coordinate is NaN, infinite or beyond MAX_COORDINATE.
    Checked in the input's own precision: the float32 cast would turn a coordinate beyond
    float32's range into inf, with numpy's overflow warning. Integers are converted; booleans,
    complex numbers (whose imaginary part a cast would drop), strings (which a cast would parse)
    and other kinds are refused."""
    kind = t.dtype.kind
    if kind == "O":
        if any(isinstance(x, (str, bytes, bool, np.bool_)) for x in t.flat):
            # a cast would parse the text and take a truth value as 0 or 1
            raise InputError(source, "triangles must be real numbers, got an object array "
                                     "holding text or truth values")
        try:
            t = t.astype(np.float64)
        except OverflowError:                   # a Python integer past float64's range
            raise InputError(source, f"a coordinate is too large: magnitude beyond float64's "
                                     f"range exceeds {MAX_COORDINATE:.0e}") from None
        except (ValueError, TypeError):
            raise InputError(source, "triangles must be real numbers, got an object array holding "
                                     "something else") from None
    elif kind in "iu":
        t = t.astype(np.float64)
    elif kind != "f":
        raise InputError(source, f"triangles must be real numbers, got {t.dtype}")
    if within_bound(t):
        return _native_float(t)
    t64 = t.astype(np.float64)
    ok = (np.abs(t64) <= MAX_COORDINATE).reshape(len(t), 9).all(axis=1)    # NaN is not <=
    bad = int(np.argmin(ok))
    if not np.isfinite(t64[bad]).all():
        raise InputError(source, f"triangle {bad} has a NaN or infinite coordinate")
    shown = beyond_bound_text(np.abs(t64[bad]).max())
    raise InputError(source, f"triangle {bad} has a coordinate too large: magnitude {shown} "
                             f"exceeds {MAX_COORDINATE:.0e} (float32 SAH costs would overflow)")


def beyond_bound_text(big):
    """A magnitude beyond MAX_COORDINATE as an error shows it: three digits, or every digit
    where three would round it onto the bound ("1e+15 exceeds 1e+15")."""
    big = float(big)
    short = f"{big:.3g}"
    return short if float(short) > MAX_COORDINATE else repr(big)


def _ply_cut_short(declared, faces):
    """Why a PLY file whose header declares ``declared`` element counts gave only ``faces``
    faces."""
    got = "no face" if faces == 0 else f"only {faces} face{'s' if faces != 1 else ''}"
    return (f"its header declares {_elements(declared)}, but {got} could be read: the file "
            f"ends early or does not match its header")


def _elements(declared):
    """'5 vertices and 1 face': a PLY header's element counts in words."""
    plural = {"vertex": "vertices"}
    return " and ".join(f"{n} {k if n == 1 else plural.get(k, k + 's')}"
                        for k, n in declared.items())


def _obj_vertex_problem(path):
    """'line N: ...' for the first vertex, texture or normal line of the OBJ file ``path`` that
    trimesh cannot read as meant, or None: a comment after its values (trimesh takes none), a
    value that is not a number, or a vertex with fewer than 3 coordinates (trimesh then reads
    every vertex with that few). Run only to explain a load, as _check_obj_face_range."""
    with open(path, "rb") as f:
        for number, line in enumerate(f, 1):
            values, hash_, _ = line.partition(b"#")
            words = values.split()
            if not words or words[0] not in (b"v", b"vt", b"vn"):
                continue
            if hash_:
                return (f"line {number}: a comment after the values; put it on a line of its "
                        f"own")
            for w in words[1:]:
                try:
                    float(w)
                except ValueError:
                    return f"line {number}: {shown(w.decode('utf-8', 'replace'))} is not a number"
            if words[0] == b"v" and len(words) < 4:
                return (f"line {number}: a vertex has {len(words) - 1} coordinate"
                        f"{'s' if len(words) != 2 else ''}, expected 3")
    return None


# A binary STL: an 80-byte header, the triangle count (uint32), 50 bytes per triangle
STL_HEADER_BYTES = 84
STL_TRIANGLE_BYTES = 50


def _stl_cut_short(path):
    """Why the binary STL file ``path`` cannot hold the triangles its header counts, or None
    (an ASCII STL, or a whole binary one): trimesh reads a binary file cut short as an empty
    mesh."""
    size = os.path.getsize(path)
    with open(path, "rb") as f:
        head = f.read(STL_HEADER_BYTES)
    # ASCII text (or no header): the count's four bytes are characters; as a count they would
    # be at least 0x09090909, far beyond MAX_PRIMITIVES
    if len(head) < STL_HEADER_BYTES or all(32 <= c < 127 or c in b"\t\r\n" for c in head[80:84]):
        return None
    n = int.from_bytes(head[80:84], "little")
    want = STL_HEADER_BYTES + STL_TRIANGLE_BYTES * n
    if size >= want:
        return None
    return (f"its header counts {n} triangle{'s' if n != 1 else ''} ({want} bytes), but the "
            f"file holds {size} bytes: it is cut short")


def _gltf_document(path):
    """(document, problem): the JSON of the .gltf file ``path`` (None where it cannot be
    read) and why not (None for a file that cannot be opened: the caller says so)."""
    import json
    try:
        with open(path, encoding="utf-8-sig") as f:
            return json.load(f), None
    except UnicodeDecodeError:
        return None, "not UTF-8 text"
    except json.JSONDecodeError as e:
        return None, f"not valid JSON ({json_syntax(e)})"
    except (OSError, ValueError, RecursionError):
        return None, None


def _gltf_buffer_candidates(uri):
    """The names trimesh tries for a buffer's ``uri``, in order: as written, without a leading
    "/", and its last part alone, each stripped of spaces (it decodes no "%20")."""
    return uri.strip(), uri.strip().lstrip("/"), os.path.split(uri)[-1].strip()


def _gltf_buffers(path, doc):
    """(uri, declared byteLength or None, path read or None, the candidate names under the
    file's directory) of each buffer file a .gltf document names, found as trimesh finds it:
    the first of ``_gltf_buffer_candidates`` that lies under the file's directory and exists
    (trimesh reads nothing outside it). ``data:`` URIs are not files."""
    from pathlib import Path
    buffers = doc.get("buffers") if isinstance(doc, dict) else None
    root = Path(os.path.dirname(os.path.abspath(path))).resolve()
    for b in buffers if isinstance(buffers, list) else ():
        uri = b.get("uri") if isinstance(b, dict) else None
        if not isinstance(uri, str) or uri.lower().startswith("data:"):
            continue
        size = b.get("byteLength")
        size = size if isinstance(size, int) and not isinstance(size, bool) else None
        inside = []
        for name in _gltf_buffer_candidates(uri):
            try:
                p = (root / name).resolve()
            except (OSError, ValueError, RuntimeError):
                continue
            if name and p.is_relative_to(root):
                inside.append((name, p))
        where = next((str(p) for _, p in inside if os.path.isfile(p)), None)   # False on errors
        yield uri, size, where, [name for name, _ in inside]


def gltf_buffer_files(path):
    """The buffer files the .gltf file ``path`` reads (none for another file, or one that
    cannot be read): inputs of a run as much as the file itself, so that no output replaces
    one."""
    if not str(path).lower().endswith(".gltf") or not os.path.isfile(path):
        return []
    doc, _ = _gltf_document(path)
    return [where for _, _, where, _ in _gltf_buffers(path, doc) if where]


def _gltf_problem(path):
    """Why the .gltf file ``path`` cannot be read (not JSON; a buffer file it names missing,
    outside its directory, or shorter than the file says), or None; trimesh's own errors name
    neither the file nor the problem."""
    from urllib.parse import unquote
    doc, problem = _gltf_document(path)
    if doc is None:
        return problem
    here = os.path.dirname(path)
    for uri, size, where, inside in _gltf_buffers(path, doc):
        if where is None:
            if not inside or inside[0] != uri.strip():
                nor = f" (nor is {os.path.join(here, inside[-1])} there)" if inside else ""
                return (f"its buffer {uri} lies outside the file's directory, the only place "
                        f"its buffers are read from{nor}")
            missing = f"its buffer file {os.path.join(here, inside[0])} is not there"
            if unquote(uri) != uri and os.path.isfile(os.path.join(here, unquote(uri))):
                missing += f" ({unquote(uri)} is: a buffer's name is read as written, %XX " \
                           f"undecoded)"
            return missing
        got = os.path.getsize(where)
        if size is not None and got < size:
            shown_where = where if os.path.isabs(path) else os.path.relpath(where)
            return (f"its buffer file {shown_where} holds {got} bytes, fewer than the {size} "
                    f"its byteLength gives")
    return _gltf_accessor_problem(doc)


# glTF accessors: bytes per component (by componentType) and components per element (by type)
_GLTF_COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_GLTF_TYPE_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def _gltf_accessor_problem(doc):
    """The first accessor of a .gltf document that reads past its buffer view (or names one
    that is not there), said as such, or None (trimesh's error is NumPy's reshape message)."""
    def number(d, key, default=None):
        v = d.get(key, default)
        return v if isinstance(v, int) and not isinstance(v, bool) else None

    if not isinstance(doc, dict):
        return None
    views = doc.get("bufferViews") if isinstance(doc.get("bufferViews"), list) else []
    accessors = doc.get("accessors") if isinstance(doc.get("accessors"), list) else []
    for i, a in enumerate(accessors):
        if not isinstance(a, dict) or "bufferView" not in a:
            continue
        v = number(a, "bufferView")
        if v is None or not 0 <= v < len(views) or not isinstance(views[v], dict):
            return f"its accessor {i} names buffer view {a.get('bufferView')!r}, which it has not"
        count, offset = number(a, "count"), number(a, "byteOffset", 0)
        size = _GLTF_COMPONENT_BYTES.get(a.get("componentType"))
        width = _GLTF_TYPE_WIDTH.get(a.get("type"))
        have = number(views[v], "byteLength")
        stride = number(views[v], "byteStride", 0) or (size or 0) * (width or 0)
        if None in (count, offset, size, width, have) or count < 1:
            continue
        need = offset + stride * (count - 1) + size * width
        if need > have:
            return (f"its accessor {i} reads {need} bytes of buffer view {v}, which holds "
                    f"{have}")
    return None


def _utf8_name(path):
    try:
        path.encode("utf-8")
        return True
    except UnicodeEncodeError:
        return False


def load_mesh_arrays(path):
    """Read a mesh file with trimesh; return (vertices float32 (v,3), faces int64 (f,3))."""
    trimesh = trimesh_module()

    if isinstance(path, bytes):                     # a path in the file system's encoding
        path = os.fsdecode(path)
    if not isinstance(path, (str, os.PathLike)):
        raise ParameterError("path", f"expected a mesh file's path, got {type(path).__name__}")
    path = os.fspath(path)
    if not os.path.exists(path):
        from .files import absent
        raise InputError(path, absent(path, "no such file"))
    if os.path.isdir(path):
        raise InputError(path, "is a directory, not a mesh file")
    if not os.path.isfile(path):                    # a pipe or a device: no size to read
        raise InputError(path, "not a regular file (a pipe or a device?): give a mesh file")
    if not path.lower().endswith(MESH_EXTENSIONS):
        raise InputError(path, "unknown mesh file type (expected " + "/".join(MESH_EXTENSIONS)
                         + ")")
    if os.path.getsize(path) == 0:
        raise InputError(path, "empty file")
    low = path.lower()
    header = _ply_header(path) if low.endswith(".ply") else None
    declared = _ply_declared(path, header) or {}
    if "face" in declared:
        check_count(declared["face"], path)
    faces_problem = _ply_face_problem(path, header) if low.endswith(".ply") else \
        _off_face_problem(path) if low.endswith(".off") else None
    if faces_problem:
        raise InputError(path, faces_problem)
    obj = low.endswith(".obj")
    load_args = _obj_load_args(path) if obj else {"file_obj": path}
    if load_args["file_obj"] is path and not _utf8_name(path) and not path.lower().endswith(".gltf"):
        # trimesh encodes a name it opens as UTF-8; a name in another encoding (bytes no
        # UTF-8 reading takes) is read here and handed over as its bytes
        with open(path, "rb") as f:
            load_args = {"file_obj": io.BytesIO(f.read()),
                         "file_type": os.path.splitext(path)[1][1:].lower()}
    try:
        # trimesh derives normals and the like on load, and warns of overflow there for a
        # coordinate too large; the coordinates themselves are checked after, with one message
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            mesh = trimesh.load(**load_args, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for unreadable files
        if obj:
            _check_obj_face_range(path)
        # what trimesh's own message does not say (it names neither the file nor the problem)
        problem = _obj_vertex_problem(path) if obj else \
            _gltf_problem(path) if low.endswith(".gltf") else \
            _stl_cut_short(path) if low.endswith(".stl") else None
        if problem:
            raise InputError(path, problem) from None
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if isinstance(exc, KeyError):          # a reader looked up what the file does not hold
            msg = f"it has no {msg}"
        elif isinstance(exc, IndexError):      # a reader ran past what the file holds
            msg = "cut short or malformed"
        ext = os.path.splitext(path)[1].lower()
        raise InputError(path, f"not a readable {ext[1:].upper()} file ({msg})") from None
    faces = getattr(mesh, "faces", None)
    verts = getattr(mesh, "vertices", None)
    if faces is None or verts is None or len(faces) == 0:
        cut = _stl_cut_short(path) if low.endswith(".stl") else None
        if cut:                             # trimesh reads a binary STL cut short as empty
            raise InputError(path, cut)
        if declared.get("face"):            # the reader stopped short of what the header says
            raise InputError(path, _ply_cut_short(declared, 0))
        raise InputError(path, "mesh has no triangles")
    faces = np.asarray(faces, dtype=np.int64)
    verts = np.asarray(verts, dtype=np.float64)
    if verts.ndim != 2 or verts.shape[1] != 3:
        raise InputError(path, (obj and _obj_vertex_problem(path)) or
                         f"vertices have {verts.shape[-1]} coordinates, expected 3")
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
    Anything but a real-valued ``(n, 3, 3)`` array is checked and converted by
    :func:`as_triangles` first (InputError naming 'tris').
    """
    if not (isinstance(tris, np.ndarray) and tris.ndim == 3 and tris.shape[1:] == (3, 3)
            and tris.dtype.kind == "f"):
        tris = as_triangles(tris, source="tris")
    boxes = np.empty((len(tris), 6), dtype=np.float32)
    # axis by axis over 1-D strided views: the same element-wise min and max as on (n, 3)
    # views, at a third of the time
    for c in range(3):
        v0, v1, v2 = tris[:, 0, c], tris[:, 1, c], tris[:, 2, c]
        np.minimum(np.minimum(v0, v1), v2, out=boxes[:, c])
        np.maximum(np.maximum(v0, v1), v2, out=boxes[:, 3 + c])
    return boxes


def pack_records(boxes, order=None):
    """Primitive records as the hardware reads them (thesis ``mike_rt -b``): 27 bytes each,
    24 bytes of little-endian float32 AABB then the 24-bit little-endian primitive index.

    order : optional (n,) primitive indices, the record order (default 0..n-1).
    """
    n = len(boxes)
    idx = np.arange(n, dtype=np.uint32) if order is None else np.asarray(order, dtype=np.uint32)
    rec = np.empty((len(idx), PRIMITIVE_RECORD_BYTES), dtype=np.uint8)
    aabbs = np.ascontiguousarray(boxes[idx], dtype="<f4").view(np.uint8)
    rec[:, :AABB_BYTES] = aabbs.reshape(-1, AABB_BYTES)
    rec[:, AABB_BYTES:] = idx.astype("<u4").view(np.uint8).reshape(-1, 4)[:, :3]
    return rec.tobytes()


def unpack_records(data):
    """Inverse of :func:`pack_records`: (boxes float32 (n, 6), indices uint32 (n,))."""
    raw = np.frombuffer(data, dtype=np.uint8)
    if raw.size % PRIMITIVE_RECORD_BYTES:
        raise ValueError("record data is not a whole number of 27-byte records")
    rec = raw.reshape(-1, PRIMITIVE_RECORD_BYTES)
    boxes = np.ascontiguousarray(rec[:, :AABB_BYTES]).view("<f4").reshape(-1, 6)
    idx = np.zeros((len(rec), 4), dtype=np.uint8)
    idx[:, :3] = rec[:, AABB_BYTES:]
    return boxes.astype(np.float32), idx.view("<u4").reshape(-1)
