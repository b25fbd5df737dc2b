"""EXR (OpenImageIO) and PNG preview output, written atomically (``hwbvh.files.write_files``):
a temporary file in the target directory, renamed into place only when complete, so an
interrupted render leaves no broken image. ``exr_writer``/``png_writer`` give the writers, so
that an EXR and its preview can be written as one set, both or neither."""
import errno
import os

import numpy as np

from hwbvh.config import MAX_PRIMITIVES
from hwbvh.errors import InputError, ParameterError, checked_flag
from hwbvh.files import check_outputs, write_files

# The channels of an EXR that write_exr writes with its layers, in order (the image's three
# first)
LAYER_CHANNELS = ("R", "G", "B", "Z", "N.X", "N.Y", "N.Z", "prim.id")


def write_exr(path, result, metadata=None, layers=True):
    """Float RGB, plus depth (Z), shading normal (N.X/N.Y/N.Z) and primitive id (prim.id, exact
    in float32 below 2^24) when ``layers``; ``metadata`` (a dict) goes into the header as hwrt:*
    keys: numbers as numbers where the header's types hold them (floats rounded to float32),
    anything else as text. ``path`` is checked as every output is (``check_outputs``)."""
    write = exr_writer(path, result, metadata, layers)
    check_outputs([os.fsdecode(path)])           # checked as a str, whatever path type it came as
    write_files([(path, write)])


def _check_path(path, extension):
    try:
        name = os.fsdecode(path)             # a str, bytes or path object
    except TypeError:
        raise ParameterError("path", f"expected a file path, got {type(path).__name__}") from None
    if os.path.splitext(name)[1].lower() != extension:
        raise ParameterError("path", f"{name}: expected a file name with the extension "
                                     f"{extension}, such as image{extension}")


def _check_image(name, image, shape):
    """``image`` as an array of ``shape`` (None: any size), else ParameterError naming it."""
    a = np.asarray(image)
    if a.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, a.shape)) \
            or a.dtype.kind not in "fiu" or 0 in a.shape:
        want = ", ".join("hw"[k] if s is None else str(s) for k, s in enumerate(shape))
        raise ParameterError(name, f"expected a non-empty ({want}) array of numbers, got "
                                   f"{a.dtype} of shape {a.shape}")
    return a


def exr_writer(path, result, metadata=None, layers=True):
    """A ``write(tmp_path)`` for :func:`hwbvh.files.write_files` (see :func:`write_exr`)."""
    import OpenImageIO as oiio

    _check_path(path, ".exr")
    if not all(hasattr(result, a) for a in ("image", "depth", "normal", "prim")):
        raise ParameterError("result", f"expected a render's result (raytracer.render.render "
                                       f"returns one), got {type(result).__name__}")
    if metadata is None:
        metadata = {}
    if not isinstance(metadata, dict):
        raise ParameterError("metadata", f"expected a dict, got {type(metadata).__name__}")
    for k, v in metadata.items():
        if not (isinstance(k, str) and k):      # each names a header attribute hwrt:<key>
            raise ParameterError("metadata", f"keys must be non-empty strings, got {k!r}")
        if "\0" in k or "\0" in str(v):         # the header's strings end at one: cut short
            raise ParameterError("metadata", f"a key or value holds a NUL character: {k!r}")
    layers = checked_flag(layers, "layers")
    image = _check_image("result.image", result.image, (None, None, 3))
    H, W, _ = image.shape
    chans = [image[..., 0], image[..., 1], image[..., 2]]
    names = list(LAYER_CHANNELS[:3])
    if layers:
        normal = _check_image("result.normal", result.normal, (H, W, 3))
        prim = _check_image("result.prim", result.prim, (H, W))
        # ids go in float32, exact up to 2^24 (the most triangles a tree holds)
        if prim.dtype.kind not in "iu" or prim.min() < -1 or prim.max() >= MAX_PRIMITIVES:
            raise ParameterError("result.prim", f"expected triangle ids, integers from -1 (no "
                                                f"hit) below 2^24, got {prim.dtype} from "
                                                f"{prim.min()} to {prim.max()}")
        chans += [_check_image("result.depth", result.depth, (H, W)), normal[..., 0],
                  normal[..., 1], normal[..., 2], prim.astype(np.float32)]
        names = list(LAYER_CHANNELS)
    pixels = np.ascontiguousarray(np.stack(chans, axis=-1), dtype=np.float32)

    def write(tmp):
        spec = oiio.ImageSpec(W, H, len(names), "float")
        spec.channelnames = tuple(names)
        spec.attribute("compression", "zip")
        for k, v in metadata.items():
            value = _header_value(v)
            spec.attribute(_text(f"hwrt:{k}"), _text(value) if isinstance(value, str) else value)
        _write_image(tmp, path, spec, pixels)
    return write


def _text(s):
    """``s`` as text the header can hold: a lone surrogate (the undecodable byte of a file name,
    as Python reads it) shown as the byte's escape, \\xff, which UTF-8 can store."""
    try:
        s.encode("utf-8")
        return s
    except UnicodeEncodeError:
        pass
    try:
        return s.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:          # a surrogate no byte stands for: its code point
        return s.encode("utf-8", "backslashreplace").decode("utf-8")


INT32 = np.iinfo(np.int32)


def _header_value(v):
    """An EXR header holds 32-bit integers and floats: an integer beyond 32 bits, a bool, and
    a float that float32 would turn into infinity or zero go in as text, like every other
    value (a float within float32's range goes in rounded to it); a dict, list or tuple goes in
    as JSON text, which reads back with ``json.loads``."""
    if isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_)) \
            and INT32.min <= v <= INT32.max:
        return int(v)
    if isinstance(v, (float, np.floating)):
        x = float(v)
        with np.errstate(over="ignore", under="ignore"):
            f = np.float32(x)
        if (np.isfinite(f) or not np.isfinite(x)) and (f != 0 or x == 0):
            return x
    if isinstance(v, (dict, list, tuple)):
        from hwbvh.files import json_text
        try:
            return json_text(v)
        except (TypeError, ValueError):
            pass
    return str(v)


def _write_image(tmp, path, spec, pixels):
    """``pixels`` to the file ``tmp`` (the temporary file of ``path``) through OpenImageIO. The
    writer is closed before anything propagates, so that an interrupted write cannot finish
    (and create the file again) after the caller has removed the temporary file. A file that
    did not come out whole is an OSError (``write_files`` then names ``path``)."""
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(tmp)
    if out is None:
        raise _image_error(tmp, path, oiio.geterror())
    try:
        if not out.open(tmp, spec) or not out.write_image(pixels):
            raise _image_error(tmp, path, out.geterror())
    finally:
        closed = out.close()
    if not closed:
        raise _image_error(tmp, path, out.geterror())
    _check_whole(tmp, path)


def _check_whole(tmp, path):
    """Check that the image just written to ``tmp`` (for ``path``) is whole. OpenImageIO's
    writers buffer their output and lose a failed last flush without a word (on a full disk
    the file ends short and ``close`` succeeds); they write front to back, so a lost write
    takes the end of the file. A PNG must end in its IEND chunk; an EXR's last scanline must
    read back (1-2 ms for a 640x480 image)."""
    import OpenImageIO as oiio

    if tmp.lower().endswith(".png"):
        with open(tmp, "rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - len(PNG_END)))
            if f.read() != PNG_END:
                raise _image_error(tmp, path, "the file does not end in its IEND chunk")
        return
    inp = oiio.ImageInput.open(tmp)
    if inp is None:
        raise _image_error(tmp, path, oiio.geterror())
    try:
        spec = inp.spec()
        whole = inp.read_scanline(spec.y + spec.height - 1, spec.z, "float") is not None
        problem = inp.geterror()
    finally:
        inp.close()
    if not whole:
        raise _image_error(tmp, path, problem)


# the last 12 bytes of every PNG file: the IEND chunk (length 0, type, CRC)
PNG_END = bytes.fromhex("0000000049454e44ae426082")


def _image_error(tmp, path, detail):
    """The OSError of an image OpenImageIO could not write to ``tmp``, the temporary file of
    ``path``: "No space left on device" when its file system is full (the usual cause, which
    OpenImageIO reports in its own words), else OpenImageIO's message (naming ``path``)."""
    try:
        full = os.statvfs(os.path.dirname(os.path.abspath(tmp))).f_bavail == 0
    except OSError:
        full = False
    if full:
        return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), tmp)
    reason = " ".join(str(detail).replace(tmp, os.fspath(path)).split()) or "no reason given"
    return OSError(errno.EIO, f"OpenImageIO could not write it: {reason}", tmp)


def tonemap(image):
    """Clamp and sRGB-encode to 8 bits (for people who just want to look)."""
    x = np.clip(image, 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (srgb * 255 + 0.5).astype(np.uint8)


def write_png(path, image):
    """An 8-bit sRGB preview of ``image`` (see :func:`tonemap`); ``path`` is checked as
    every output is (``check_outputs``)."""
    write = png_writer(path, image)
    check_outputs([os.fsdecode(path)])
    write_files([(path, write)])


def png_writer(path, image):
    """A ``write(tmp_path)`` for :func:`hwbvh.files.write_files` (see :func:`write_png`)."""
    import OpenImageIO as oiio

    _check_path(path, ".png")
    px = np.ascontiguousarray(tonemap(_check_image("image", image, (None, None, 3))))
    H, W, _ = px.shape

    def write(tmp):
        _write_image(tmp, path, oiio.ImageSpec(W, H, 3, "uint8"), px)
    return write


def read_render(path):
    """(``raytracer.render.RenderResult``, metadata) of an EXR that ``write_exr`` wrote with its
    layers: the image, depth, normal and primitive-id layers as a render returns them (``stats``
    empty; the header's hwrt:* values are the metadata)."""
    from .render import RenderResult

    px, chans, meta = read_exr(path)
    if tuple(chans) != LAYER_CHANNELS:
        raise InputError(os.fspath(path), f"holds the channels {', '.join(chans)}, not the "
                                          f"layers write_exr writes ({', '.join(LAYER_CHANNELS)})")
    return RenderResult(image=px[..., :3].copy(), depth=px[..., 3].copy(),
                        normal=px[..., 4:7].copy(), prim=px[..., 7].astype(np.int32)), meta


def read_exr(path):
    """(pixels (h, w, c) float32, channel names, metadata dict of hwrt:* keys). A file that is
    missing or not a readable image raises ``InputError`` naming it."""
    import OpenImageIO as oiio

    try:
        name = os.fsdecode(path)
    except TypeError:
        raise ParameterError("path", f"expected a file path, got {type(path).__name__}") from None
    if not os.path.isfile(name):
        raise InputError(name, "no such file" if not os.path.exists(name) else "not a file")
    inp = oiio.ImageInput.open(name)
    if inp is None:
        raise InputError(name, f"not a readable image ({_oiio_problem(oiio.geterror(), name)})")
    try:
        spec = inp.spec()
        px = inp.read_image("float")
        problem = _oiio_problem(inp.geterror(), name) if px is None else None
    finally:
        inp.close()
    if px is None:
        raise InputError(name, f"cannot be read ({problem or 'unknown error'})")
    meta = {a.name[5:]: a.value for a in spec.extra_attribs if a.name.startswith("hwrt:")}
    return px, list(spec.channelnames), meta


def _oiio_problem(message, name):
    """OpenImageIO's error text on one line, without the file name it repeats."""
    text = " ".join(message.split())
    for quoted in (f'"{name}"', f"({name})", name):
        text = text.replace(quoted, "")
    return " ".join(text.replace(" :", ":").split()) or "unknown error"
