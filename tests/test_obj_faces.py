"""OBJ face indices: the compiled pass that makes negative indices positive writes byte for byte
the text of the line-by-line reader (the reference), and leaves to that reader every small file
(not worth compiling the pass for) and every file with a bad index, so its error names the line."""
import io
import re
import tracemalloc

import numpy as np
import pytest

from hwbvh import primitives
from hwbvh.config import OBJ_COMPILED_MIN_BYTES
from hwbvh.errors import InputError

ELEMENTS = ("v 1 2 3", "vt 0 0", "vn 0 0 1")
# lines that are neither faces nor counted elements, however much they look like them
OTHER = ("", "  ", "\t", "# f -1 0", "o part-1", "g a b", "usemtl m-2", "  v 1 2 3", "v\t1 2 3",
         "vt\t0", "vp 1 -1", "fo -1 -2", "f", "f\t", " f ", "vn", "v")
BLANKS = (" ", " ", " ", "  ", "\t", " \t", "\x0b", "\x0c", "\r", " \\\n", "\\\r\n\t")
# not an index to the reference (an error), or one the compiled pass leaves to it
RARE_PARTS = ("0", "-0", "00", "-00", "+1", "#", "#c", "x", "1-2", "-", "--1", "", "1_0", "1e3",
              "\u00e9", "-" + "1" * 20, "-0000000000000000001")


def _index(rng, count, rare):
    """A random face-index part for an element kind with ``count`` elements before it."""
    if rare and rng.random() < 0.03:
        return str(rng.choice(RARE_PARTS))
    roll = rng.random()
    if count and roll < 0.55:
        n = -int(rng.integers(1, count + 1)) - (rng.random() < 0.005)    # now and then one too far
        return f"-0{-n}" if rng.random() < 0.05 else str(n)
    if roll < 0.6:
        return "1" * 25                                                 # positive: kept as is
    return ("0" if rng.random() < 0.05 else "") + str(rng.integers(1, 40))


def _face(rng, counts, rare):
    slots = int(rng.integers(1, 4))                     # v, v/vt, v/vt/vn
    words = []
    for _ in range(rng.integers(0, 5)):
        parts = [_index(rng, counts[k], rare) for k in range(slots)]
        if slots == 3 and rng.random() < 0.3:
            parts[1] = ""                               # v//vn
        if slots < 3 and rng.random() < 0.05:
            parts.append("")                            # "1/": an empty last slot
        if rare and rng.random() < 0.03:
            parts += [str(rng.choice(("4", "-1", "0", "", "#")))]   # a fourth part: ignored
        words.append("/".join(parts))
    blanks = [str(rng.choice(BLANKS)) for _ in range(len(words) + 1)]
    tail = str(rng.choice(("", "", "", " ", "\t ")))
    return "f" + "".join(b + w for b, w in zip(blanks, words)) + tail


def _random_obj(rng, rare):
    """Random OBJ bytes: elements, faces mostly counting back within range, look-alike lines,
    indents, blank separators of every kind, CRLF and CRCRLF line ends, continued lines;
    with ``rare``, also bad or rare face-index parts, a continued last line and continued lines
    ending in CR."""
    counts = [0, 0, 0]                  # roughly: indents and continuations are not followed
    lines = []
    for _ in range(rng.integers(0, 14)):
        roll = rng.random()
        if roll < 0.4:
            kind = int(rng.integers(3))
            lines.append(ELEMENTS[kind])
            counts[kind] += 1
        elif roll < 0.8:
            lines.append(_face(rng, counts, rare))
        else:
            lines.append(str(rng.choice(OTHER)))
        if rng.random() < 0.08:
            lines[-1] = str(rng.choice((" ", "\t", "\x0c ", "  "))) + lines[-1]
    ends = [str(rng.choice(("\n",) * 12 + ("\r\n", "\r\n", "\r\r\n"))) for _ in lines]
    for k in range(len(ends)):
        if rare and rng.random() < 0.03:    # a CR before a continuation, now and then of nothing
            ends[k] = str(rng.choice(("\r\\\n", "\r\\\r\n", "\r\\\n\n", "\r\\\r\n\n")))
    if ends:
        ends[-1] = str(rng.choice(("\n", "\r\n", "") * 4 + (("\\", "\\\r", "\\\n", "\\\r\n")
                                                            if rare else ())))
    head = str(rng.choice(("",) * 6 + ("\n", "  \n\t", " ")))
    return (head + "".join(line + end for line, end in zip(lines, ends))).encode()


def _reference(data):
    """(text, None) as the line-by-line reader writes ``data``, or (None, its error)."""
    try:
        lines = primitives._obj_resolved_lines("r.obj", io.BytesIO(data))
        return b"".join(line + b"\n" for line in lines), None
    except InputError as exc:
        return None, str(exc)


def _resolved(data):
    """(text, None) as a file is handed to trimesh, or (None, the error it raises)."""
    try:
        return primitives._obj_resolved_text("r.obj", data), None
    except InputError as exc:
        return None, str(exc)


@pytest.mark.parametrize("rare", [False, True], ids=["common", "rare"])
def test_the_compiled_pass_writes_the_reference_text_or_leaves_the_file_to_it(rare):
    rng = np.random.default_rng(2024 + rare)
    seen = {"compiled": 0, "deferred": 0, "errors": 0, "rewritten": 0}
    for _ in range(3000):
        data = _random_obj(rng, rare)
        text, error = _reference(data)
        compiled = primitives._obj_compiled_text(data)
        assert _resolved(data) == (text, error), data
        if error is not None:
            assert compiled is None, (data, error)
            seen["errors"] += 1
        elif compiled is None:
            # only rare forms (or a continued last line) are left to the line-by-line reader
            assert rare, data
            seen["deferred"] += 1
        else:
            assert compiled == text, data
            seen["compiled"] += 1
            seen["rewritten"] += text != data.replace(b"\r\n", b"\n")
    # not vacuous: each outcome happens, and most files are rewritten by the compiled pass
    assert seen["errors"] > 100 and seen["rewritten"] > 800 and seen["compiled"] > 1000, seen
    assert (seen["deferred"] > 100) == rare, seen


def _padded(data):
    """OBJ bytes ``data`` with a comment line after them that makes the file large enough for
    the compiled pass (a small one is read line by line)."""
    return data + b"#" * OBJ_COMPILED_MIN_BYTES + b"\n"


def test_a_file_with_negative_indices_is_rewritten_without_the_line_by_line_reader(tmp_path,
                                                                                   monkeypatch):
    """CRLF ends, continued lines, indented and tab-separated faces, v//vn and v/vt/vn forms
    and several objects: all taken by the compiled pass, and read as the indices mean."""
    def per_line(*args):
        raise AssertionError("read line by line")
    monkeypatch.setattr(primitives, "_obj_resolved_lines", per_line)
    p = tmp_path / "relative.obj"
    p.write_bytes(_padded(b"  o a\r\nv 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nvn 0 0 1\r\n"
                          b"f -3//-1\t-2//-1 \\\r\n -1//-1 \r\n"
                          b"o b\nv 5 5 5\nvt 0 0\nv 6 5 5\nv 5 6 5\nvt 1 0\n  f -1 -2 -3\n"
                          b"f\t-3/-2/1  -2/-1/1\t-1/-1/-1\n"))
    V, F = primitives.load_mesh_arrays(p)
    assert V[F].tolist() == [[[0, 0, 0], [1, 0, 0], [0, 1, 0]],     # the indented face: skipped
                             [[5, 5, 5], [6, 5, 5], [5, 6, 5]]]


@pytest.mark.parametrize("large", [False, True], ids=["small", "large"])
@pytest.mark.parametrize("data, line", [
    (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -3\nf -1 -2 -4\n", "line 5: a face refers to vertex -4"),
    (b"v 0 0 0\r\nv 1 0 0\r\nf -1 \\\r\n -2 \\\n0\r\n", "line 3: face index 0"),
    (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -3 # c\n", "line 4: a face holds '#'"),
])
def test_a_bad_index_in_a_file_with_negative_ones_is_named_by_its_line(tmp_path, data, line,
                                                                       large):
    """Read line by line from the start (small), or once the compiled pass leaves it (large)."""
    p = tmp_path / "bad.obj"
    p.write_bytes(_padded(data) if large else data)
    with pytest.raises(InputError, match=f"^{re.escape(str(p))}: {line}"):
        primitives.load_mesh_arrays(p)


def test_a_small_file_is_read_line_by_line_without_compiling_the_pass(tmp_path, monkeypatch):
    """The compiled pass costs seconds to compile where Numba's cache is empty: a small file
    does without it, and a file just large enough takes it."""
    calls = []
    real = primitives._obj_compiled_text

    def compiled(data):
        calls.append(len(data))
        return real(data)
    monkeypatch.setattr(primitives, "_obj_compiled_text", compiled)
    face = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -3\n"
    p = tmp_path / "small.obj"
    small = face + b"#" * (OBJ_COMPILED_MIN_BYTES - len(face) - 2) + b"\n"
    p.write_bytes(small)
    V, F = primitives.load_mesh_arrays(p)
    assert V[F].tolist() == [[[0, 1, 0], [1, 0, 0], [0, 0, 0]]] and calls == []
    assert primitives._obj_resolved_text("r.obj", small + b"\n") == _reference(small + b"\n")[0]
    assert calls == [len(small) + 1]


@pytest.mark.parametrize("data", [
    b"v 0 0 0\nv 1 0 0\nv 0 1 0\ng x\r\\\r\n\nf -1 -2 -3\n",    # a CR kept before an empty line
    b"v 0 0 0\nv 1 0 0\nv 0 1 0\ng x\r\\\n",                     # ... or the end of the file
    b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -3\n\\\n",                # an empty continued last line
    b"\\\r\n",
])
def test_the_compiled_pass_leaves_a_continuation_it_would_join_otherwise(data):
    text, error = _reference(data)
    assert error is None and primitives._obj_compiled_text(data) in (None, text)
    assert primitives._obj_resolved_text("r.obj", _padded(data)) == _reference(_padded(data))[0]


def _buffer_sizes(monkeypatch):
    """(output buffer size, text size) of each run of the compiled pass from now on."""
    sizes = []
    real = primitives._obj_resolve

    def resolve(text, out):
        size = real(text, out)
        sizes.append((len(out), size))
        return size
    monkeypatch.setattr(primitives, "_obj_resolve", resolve)
    return sizes


def test_the_compiled_output_buffer_is_tight_and_holds_the_largest_growth(monkeypatch):
    """Each "-1" becomes the count of vertices before it (5 digits here), as the bound allows;
    "-" in coordinates and comments do not make the buffer much larger than the file."""
    sizes = _buffer_sizes(monkeypatch)
    grown = b"v 0 0 0\n" * 10000 + b"f" + b" -1" * 30000 + b"\n"
    assert primitives._obj_compiled_text(grown) == _reference(grown)[0]
    assert sizes[-1] == (len(grown) + 1 + 3 * 30000, len(grown) + 3 * 30000)
    signed = b"v -1.5 -2.5 -3.5 # -x-\n" * 20000 + b"f -1 -2 -3\n"
    assert primitives._obj_compiled_text(signed) == _reference(signed)[0]
    assert sizes[-1][0] < 2 * len(signed), sizes


def test_the_line_by_line_reader_writes_its_text_without_an_object_per_line():
    data = b"v 0 0 0\nf -1 -1 -1\n" * 6000
    tracemalloc.start()
    try:
        text = primitives._obj_resolved_text("r.obj", data)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert text == _reference(data)[0] and peak < 2 * len(text), (peak, len(text))
