"""EXR (OpenImageIO) and PNG preview output, written atomically (``hwbvh.files.write_files``):
a temporary file in the target directory, renamed into place only when complete, so an
interrupted render leaves no broken image. ``exr_writer``/``png_writer`` give the writers, so
that an EXR and its preview can be written as one set, both or neither."""
import os

import numpy as np

from hwbvh.files import write_files


def write_exr(path, result, metadata, layers=True):
    """Float RGB, plus depth (Z), shading normal (N.X/N.Y/N.Z) and primitive id (prim.id, exact
    in float32 below 2^24) when ``layers``; ``metadata`` goes into the header as hwrt:* keys."""
    write_files([(path, exr_writer(path, result, metadata, layers))])


def exr_writer(path, result, metadata, layers=True):
    """A ``write(tmp_path)`` for :func:`hwbvh.files.write_files` (see :func:`write_exr`)."""
    import OpenImageIO as oiio

    H, W, _ = result.image.shape
    chans = [result.image[..., 0], result.image[..., 1], result.image[..., 2]]
    names = ["R", "G", "B"]
    if layers:
        chans += [result.depth, result.normal[..., 0], result.normal[..., 1], result.normal[..., 2],
                  result.prim.astype(np.float32)]
        names += ["Z", "N.X", "N.Y", "N.Z", "prim.id"]
    pixels = np.ascontiguousarray(np.stack(chans, axis=-1), dtype=np.float32)

    def write(tmp):
        spec = oiio.ImageSpec(W, H, len(names), "float")
        spec.channelnames = tuple(names)
        spec.attribute("compression", "zip")
        for k, v in metadata.items():
            spec.attribute(f"hwrt:{k}", str(v) if not isinstance(v, (int, float)) else v)
        _write_image(tmp, path, spec, pixels)
    return write


def _write_image(tmp, path, spec, pixels):
    """``pixels`` to the file ``tmp`` (the temporary file of ``path``) through OpenImageIO. The
    writer is closed before anything propagates, so that an interrupted write cannot finish
    (and create the file again) after the caller has removed the temporary file."""
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(tmp)
    if out is None:
        raise OSError(f"OpenImageIO could not write {path}: {oiio.geterror()}")
    try:
        if not out.open(tmp, spec) or not out.write_image(pixels):
            raise OSError(f"OpenImageIO could not write {path}: {out.geterror()}")
    finally:
        out.close()


def tonemap(image):
    """Clamp and sRGB-encode to 8 bits (for people who just want to look)."""
    x = np.clip(image, 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (srgb * 255 + 0.5).astype(np.uint8)


def write_png(path, image):
    """An 8-bit sRGB preview of ``image`` (see :func:`tonemap`)."""
    write_files([(path, png_writer(path, image))])


def png_writer(path, image):
    """A ``write(tmp_path)`` for :func:`hwbvh.files.write_files` (see :func:`write_png`)."""
    import OpenImageIO as oiio

    px = np.ascontiguousarray(tonemap(image))
    H, W, _ = px.shape

    def write(tmp):
        _write_image(tmp, path, oiio.ImageSpec(W, H, 3, "uint8"), px)
    return write


def read_exr(path):
    """(pixels (h, w, c) float32, channel names, metadata dict of hwrt:* keys)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(os.fspath(path))
    if inp is None:
        raise OSError(oiio.geterror())
    spec = inp.spec()
    px = inp.read_image("float")
    meta = {a.name[5:]: a.value for a in spec.extra_attribs if a.name.startswith("hwrt:")}
    inp.close()
    return px, list(spec.channelnames), meta
