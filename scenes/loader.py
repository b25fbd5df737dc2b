"""Scene dicts in, arrays out.

``load_scene(spec)`` accepts a built-in name, a JSON/TOML scene file (the same dict on disk) or
a mesh file (framed automatically, one point light, a plain diffuse material). ``compile_scene``
turns the dict into triangle, normal, material and light arrays for the renderer. Malformed
scene files raise :class:`InputError` naming the file, the key and the problem.
"""
import datetime
import difflib
import json
import math
import os
import re
import unicodedata
from dataclasses import dataclass

import numpy as np

from hwbvh.config import MAX_COORDINATE, MAX_FLOAT32_ROUNDING, MAX_PRIMITIVES
from traversal.config import FOV_RANGE
from hwbvh.errors import InputError, ParameterError, cut_short, is_integer, json_syntax, shown
from hwbvh.files import absent
from hwbvh.primitives import (MESH_EXTENSIONS, as_triangles, beyond_bound_text, checked_coordinates,
                              extent, float32_step, load_mesh_arrays, within_bound)
from .builtin import BUILTIN, COUNT_LIMITS
from .config import SHEET_RESOLUTION, SPHERE_SUBDIV
from .meshes import grid_sheet, uv_sphere

SCENE_EXTENSIONS = (".json", ".toml")
MATERIAL_TYPES = ("diffuse", "mirror", "dielectric", "plastic")
SHAPE_TYPES = ("mesh", "quad", "box", "sphere", "sheet", "triangles")

# The keys each object of a scene may hold; any other key is an error (a typo such as "light"
# would otherwise be ignored and quietly change the picture). Keys with a leading underscore
# are set by this module, not by scene files.
SCENE_KEYS = ("type", "name", "camera", "film", "integrator", "background", "lights",
              "materials", "shapes", "_source", "_dir")
CAMERA_KEYS = ("type", "eye", "target", "up", "fov")
FILM_KEYS = ("width", "height", "spp", "jitter")
INTEGRATOR_KEYS = ("type", "max_depth", "ambient", "cutoff")
LIGHT_KEYS = {"point": ("type", "position", "intensity"),
              "directional": ("type", "direction", "irradiance")}
MATERIAL_KEYS = {"diffuse": ("type", "reflectance", "specular", "shininess", "mirror"),
                 "plastic": ("type", "reflectance", "specular", "shininess", "mirror"),
                 "mirror": ("type", "reflectance"),
                 "dielectric": ("type", "ior")}
_SHAPE_COMMON = ("type", "material", "_world")
SHAPE_KEYS = {"quad": ("corners",), "box": ("min", "max", "rotate_y"),
              "sphere": ("center", "radius", "subdiv"),
              "sheet": ("resolution", "size", "wave", "height"),
              "triangles": ("data",), "mesh": ("filename", "smooth", "transform")}
TRANSFORM_KEYS = ("scale", "rotate_y", "translate")
# Keys a shape does not take that a scene file's author may reach for: what to write instead.
SHAPE_KEY_HINTS = {"frames": 'a shape of "type": "frames" with a "pattern"'}
# Light (intensities, irradiance, ambient, background): at most float32's largest number,
# since the image is float32 and a larger background or ambient light could only be +inf in
# it. That leaves room for a point light's intensity, which grows with the square of the
# scene's scale (about 1e30 lights a scene at hwbvh's largest coordinates). Shading works in
# float64, so no sum overflows there; a pixel brighter than float32 holds (a light of such
# values close to a surface) is +inf in the image, and the renderer counts such pixels.
MAX_RADIANCE = float(np.finfo(np.float32).max)
# Characters of a key that an error line shows: the line names the key, and a key (a material's
# name) may be as long as the file.
KEY_TEXT_LIMIT = 60
# Names an error line lists (the materials a shape may name), the rest counted: a dozen names of
# that length keep the line within a screen or two.
LISTED_NAMES = 12

# The largest film: a render keeps about 100 bytes per pixel (the film in float64, the image
# and its depth, normal and primitive layers, a sample pass' jitter), so 2^25 pixels (8192 x
# 4096) take some 3.4 GB; more would exhaust an ordinary machine's memory mid-render.
MAX_FILM_PIXELS = 1 << 25
MAX_FILM_SIDE = 1 << 15         # pixels on a side
MAX_SPP = 4096
MAX_DEPTH = 64                  # bounces: between mirrors of reflectance 0.9 a path meets the
                                # default contribution cut-off (1e-3) after about 65
# Frames of an animation (a scene file's animation.frames, hwrt animate's and hwrt bench's
# --frames): the frame times, the camera track and the keyframed shapes' bounds are checked
# for every frame before the first is made, and each frame writes an EXR; beyond this the
# checks alone would take gigabytes and a run would never end.
MAX_FRAMES = 100_000
# The magnitude of each component of a scale (a mesh's transform.scale, a keyframe's scale):
# at most the coordinate bound, and at least its inverse, so that a unit shape scaled down
# stays far above float32's smallest numbers (~1e-38) and the shading normals, divided by the
# scale, stay finite.
SCALE_RANGE = (1.0 / MAX_COORDINATE, MAX_COORDINATE)


def written(v, limit=40):
    """A scene file's value for a message, cut short: ``shown``, but true, false and null
    and the lists that hold them as the file spells them (Python would say True, None); a
    dict built in Python may hold NumPy's values, shown the same way."""
    if isinstance(v, np.ndarray):
        v = v.tolist()
    elif isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, (datetime.date, datetime.time)):       # TOML has dates and times
        return f"the {'time' if isinstance(v, datetime.time) else 'date'} {v.isoformat()}"
    if isinstance(v, (bool, list, tuple)) or v is None:
        try:
            text = json.dumps(v, allow_nan=False)
        except (TypeError, ValueError):
            return shown(v, limit)
        return cut_short(text, limit)
    return shown(v, limit)


# a frame sequence of mesh files: the printf field that numbers the frames
FRAME_FIELD = re.compile(r"%(0?)(\d*)d")


def is_pattern(spec):
    """True for a printf (``%04d``) or glob (``*``, ``?``, ``[``) pattern of mesh files."""
    s = os.fspath(spec)
    return bool(FRAME_FIELD.search(s)) or any(c in s for c in "*?[")


def is_scene(spec):
    return spec in BUILTIN or str(spec).lower().endswith(SCENE_EXTENSIONS)


class _DuplicateKey(ValueError):
    def __init__(self, key):
        super().__init__(key)
        self.key = key


def _unique_keys(pairs):
    """A JSON object's dict, refusing a key given twice (``json``'s own loader keeps the last,
    so a scene would render without the value its author read first)."""
    d = {}
    for k, v in pairs:
        if k in d:
            raise _DuplicateKey(k)
        d[k] = v
    return d


class _Marked(dict):
    """A JSON object read by ``_marking_keys``: ``twice`` is its first key given twice."""
    twice = None


def _marking_keys(pairs):
    d = _Marked()
    for k, v in pairs:
        if k in d and d.twice is None:
            d.twice = k
        d[k] = v
    return d


def _twice_path(obj, path=""):
    """The path ('camera.eye', 'shapes[2].min') of the first key given twice in ``obj`` read
    with ``_marking_keys`` (keys written as Python writes them in a string, so a line break
    stays escaped), or None."""
    part = lambda k: repr(str(k))[1:-1]
    if isinstance(obj, dict):
        if getattr(obj, "twice", None) is not None:
            return _at(path, part(obj.twice))
        items = obj.items()
    elif isinstance(obj, list):
        items = ((None, v) for v in obj)
    else:
        return None
    for i, (k, v) in enumerate(items):
        found = _twice_path(v, _at(path, part(k)) if k is not None else f"{path}[{i}]")
        if found:
            return found
    return None


FILE_OVERRIDES = ("width", "height", "spp", "max_depth")      # what a file's scene takes


def spec_path(spec, name="spec", wanted="a built-in name or a file path"):
    """``spec`` (``wanted``) as a string; ParameterError naming ``name`` for anything else (a
    scene dict goes to ``compile_scene``, not here)."""
    try:
        return os.fspath(spec)
    except TypeError:
        hint = " (a scene dict goes to compile_scene)" if isinstance(spec, dict) else ""
        raise ParameterError(name, f"expected {wanted}, got {type(spec).__name__}{hint}") \
            from None


def load_scene(spec, **overrides):
    """A scene dict from a built-in name, a scene file or a mesh file. ``overrides``: a
    built-in scene's parameters; for a file, its film and depth (``FILE_OVERRIDES``)."""
    spec = spec_path(spec)
    if spec in BUILTIN:
        d = BUILTIN[spec](**_builtin_overrides(spec, overrides))
        d.setdefault("_source", spec)
        if "width" in overrides or "height" in overrides:
            _check_film_area(d["film"], "width" if "width" in overrides else "height")
        return d
    for key in overrides:
        if key not in FILE_OVERRIDES:
            raise ParameterError(key, f"a scene or mesh file takes only "
                                      f"{', '.join(FILE_OVERRIDES)}")
    d = _load_scene_file(spec)
    return with_frame(d, **overrides) if overrides else d


def _load_scene_file(spec):
    """The scene dict of a scene file or a mesh file."""
    if not os.path.exists(spec):
        # (animation imports this module)
        from .animation import ANIMATIONS, NoFrameFiles, expand_pattern
        if is_pattern(spec):
            try:
                expand_pattern(spec)
            except NoFrameFiles:
                raise InputError(spec, "no such file, nor mesh files it names as a frame "
                                       "sequence (a %d or glob pattern)") from None
            except InputError:                  # the files of a sequence with a frame missing
                pass
            raise InputError(spec, "a frame sequence (a %d or glob pattern of mesh files): "
                                   "render it with hwrt animate")
        if spec in ANIMATIONS:
            raise InputError(spec, "a built-in animation: render it with hwrt animate")
        raise InputError(spec, absent(spec, "no such scene or file (built-in scenes: " +
                                      ", ".join(BUILTIN) + ")"))
    if os.path.isdir(spec):
        raise InputError(spec, "is a directory, not a scene or mesh file")
    if not os.path.isfile(spec):        # a pipe or a device: a read that never ends or never fills
        raise InputError(spec, "not a regular file (a pipe or a device?): give a scene or mesh "
                               "file")
    low = spec.lower()
    if low.endswith(SCENE_EXTENSIONS) and os.path.getsize(spec) == 0:
        raise InputError(spec, "empty file")            # as an empty mesh file is named
    if low.endswith(".json"):
        try:
            # utf-8-sig: a byte-order mark, which some editors write first, is read past
            with open(spec, encoding="utf-8-sig") as f:
                d = json.load(f, object_pairs_hook=_unique_keys, parse_int=_json_int)
        except json.JSONDecodeError as e:
            raise InputError(spec, f"not valid JSON ({json_syntax(e)})") from None
        except _DuplicateKey as e:
            # read again, marking the objects that hold a key twice, for the key's path (the
            # key alone if the file fails further on)
            try:
                with open(spec, encoding="utf-8-sig") as f:
                    where = _twice_path(json.load(f, object_pairs_hook=_marking_keys,
                                                  parse_int=_json_int))
            except (OSError, ValueError, RecursionError):
                where = None
            where = where or repr(str(e.key))[1:-1]
            raise InputError(spec, f"key '{where}' is given twice in one object") from None
        except (OSError, UnicodeDecodeError, RecursionError, ValueError) as e:
            raise InputError(spec, f"cannot read the scene ({_reason(e)})") from None
    elif low.endswith(".toml"):
        import tomllib
        try:
            with open(spec, "rb") as f:
                d = tomllib.loads(f.read().decode("utf-8-sig"))      # as JSON: past a BOM
        except tomllib.TOMLDecodeError as e:
            raise InputError(spec, f"not valid TOML ({e})") from None
        except (OSError, UnicodeDecodeError, RecursionError, ValueError) as e:
            raise InputError(spec, _long_integer(spec) or f"cannot read the scene ({_reason(e)})") \
                from None
    elif low.endswith(MESH_EXTENSIONS):
        return mesh_scene(spec)
    else:
        raise InputError(spec, "unknown file type (scene: .json/.toml; mesh: " +
                         "/".join(MESH_EXTENSIONS) + ")")
    if not isinstance(d, dict):
        raise InputError(spec, "a scene file must hold an object at the top level")
    _refuse_internal_keys(spec, d)
    d["_source"] = spec
    # where its relative mesh names resolve, fixed as the file is read: a later change of the
    # working directory must not make them name other files
    d["_dir"] = os.path.dirname(os.path.abspath(spec))
    if "name" in d:
        check_name(spec, d["name"])
    else:
        d["name"] = name_of_file(spec, "or give the scene a key 'name'")
    return d


def _builtin_overrides(name, overrides):
    """The keyword arguments of built-in scene ``name``, each a known parameter holding a
    non-negative integer (film sizes and depth are checked again with the scene)."""
    import inspect

    known = inspect.signature(BUILTIN[name]).parameters
    for key, v in overrides.items():
        if key not in known:
            raise ParameterError(key, f"not a parameter of the built-in scene {name!r} "
                                      f"(it takes {', '.join(known)})")
        if key in FRAME_SETTINGS:
            frame_override(key, v)
        if not is_integer(v) or v < 0:
            raise ParameterError(key, f"expected a non-negative integer, got {shown(v)}")
        most = COUNT_LIMITS.get(name, {}).get(key)
        if most is not None and v > most:
            raise ParameterError(key, f"{shown(v)} makes more triangles than the 2^24 a tree "
                                      f"holds: at most {most}")
    return {k: int(v) for k, v in overrides.items()}


def scene_inputs(spec):
    """The files scene ``spec`` reads: a scene file itself and the mesh and frame files its
    shapes name; a mesh file or a built-in scene's name is itself alone. For the outputs'
    check that no output overwrites an input; a problem with one of them is reported when the
    scene is loaded."""
    from .animation import expand_pattern
    inputs = [spec]
    if not str(spec).lower().endswith(SCENE_EXTENSIONS) or not os.path.isfile(spec):
        return inputs
    try:
        shapes = load_scene(spec).get("shapes")
    except InputError:
        return inputs
    scene_dir = os.path.dirname(os.path.abspath(spec))
    for sh in shapes if isinstance(shapes, list) else ():
        for key in ("filename", "pattern"):
            name = sh.get(key) if isinstance(sh, dict) else None
            if not isinstance(name, str):
                continue
            full = os.path.join(scene_dir, name)       # an absolute name stays itself
            if key == "filename":
                inputs.append(full)
                continue
            try:
                inputs += expand_pattern(full)
            except InputError:
                pass
    return inputs


def check_name(source, name):
    """Refuse (InputError naming ``source`` and the key ``name``) a scene name that is not a
    plain file name: the default outputs are named after it (renders/<name>.exr,
    renders/animate-<name>-<strategy>/), so a separator or a "." / ".." would write elsewhere."""
    if not isinstance(name, str) or not name:
        problem = f"expected a non-empty string, got {written(name)}"
    elif not _plain_name(name):
        problem = (f"{written(name)} is not a plain file name (outputs are named after it: no '/', "
                   "'\\', NUL or other control characters, not '.' or '..')")
    else:
        return
    raise InputError(source, f"key 'name': {problem}")


def name_of_file(path, remedy=None):
    """The name a scene takes from its file: the file's name without its scene or mesh
    extension (``a.ply`` is 'a', ``a.b.toml`` 'a.b'). Refused (InputError naming the file)
    when that is not a plain file name (a file named ``..toml``, or with a newline in it), as
    the outputs are named after it; ``remedy``: a second way out besides renaming the file."""
    base = os.path.basename(path)
    ext = next((e for e in SCENE_EXTENSIONS + MESH_EXTENSIONS if base.lower().endswith(e)), "")
    return named_after_file(path, base[:len(base) - len(ext)], remedy)


def named_after_file(path, name, remedy=None):
    """``name``, which a scene takes from the name of ``path`` (a file or a frame pattern),
    when it is a plain file name; else InputError naming ``path`` (``name_of_file``)."""
    if _plain_name(name):
        return name
    raise InputError(path, f"its file name makes the scene's name {written(name)}, which is not a "
                           f"plain file name (outputs are named after it): rename the file"
                           + (f" {remedy}" if remedy else ""))


def _plain_name(name):
    """Whether ``name`` can name output files: a non-empty string, not '.' or '..', with no
    separator or control character."""
    return isinstance(name, str) and bool(name) and name not in (".", "..") and not any(
        c in "/\\" or unicodedata.category(c) == "Cc" for c in name)


def vector_ok(v, a, bound=MAX_COORDINATE):
    """Whether the numbers ``a`` read from ``v`` are ordinary: numbers as given, not true/false
    (JSON's booleans would read as 1 and 0) or text ("3" would read as 3, where a scalar key
    refuses it), and none beyond ``bound`` (positions and directions: the coordinates hwbvh
    accepts; light: MAX_RADIANCE), so that no product of them overflows on the way to the
    image."""
    return not _holds_a_non_number(v) and within_bound(a, bound)


def _as_list(v):
    """A NumPy array given in a dict built in Python, as the list a file would give."""
    return v.tolist() if isinstance(v, np.ndarray) else v


def _holds_a_non_number(v):
    """Whether ``v`` (a number, or lists of them, or a NumPy array) holds anything but numbers:
    a true or false, text, None."""
    if isinstance(v, np.ndarray):
        return v.dtype.kind not in "fiuO" or \
            (v.dtype == object and any(map(_holds_a_non_number, v.flat)))
    if isinstance(v, (list, tuple)):
        return any(map(_holds_a_non_number, v))
    return isinstance(v, (bool, np.bool_)) or \
        not isinstance(v, (int, float, np.integer, np.floating))


# The film and depth settings: (default, largest); each is an integer from 1.
FRAME_SETTINGS = {"width": (640, MAX_FILM_SIDE), "height": (480, MAX_FILM_SIDE),
                  "spp": (1, MAX_SPP), "max_depth": (5, MAX_DEPTH)}
FILM_TOO_LARGE = "pixels a film may hold"       # the end of the message for a film too large


def frame_override(key, v):
    """Refuse (ParameterError naming ``key``) a film or depth setting given to ``load_scene``
    or ``with_frame`` that is not an integer within ``FRAME_SETTINGS``' range."""
    hi = FRAME_SETTINGS[key][1]
    if not is_integer(v):
        raise ParameterError(key, f"expected an integer, got {shown(v)}")
    if not 1 <= v <= hi:
        raise ParameterError(key, f"{shown(v)} is out of range (must be in [1, {hi}])")


def _film_setting(ctx, obj, path, key):
    default, hi = FRAME_SETTINGS[key]
    return ctx.num(obj, key, path, default=default, lo=1, hi=hi, integer=True)


def with_frame(d, width=None, height=None, spp=None, max_depth=None):
    """A copy of scene dict ``d`` with the given film and depth settings (None keeps the
    scene's). A film or integrator that is not an object is left for ``compile_scene`` to
    report."""
    if not isinstance(d, dict):
        raise ParameterError("d", f"expected a scene dict, got {type(d).__name__}")
    given = {"width": width, "height": height, "spp": spp}
    for key, v in dict(given, max_depth=max_depth).items():
        if v is not None:
            frame_override(key, v)
    d = dict(d)
    film, integ = d.get("film", {}), d.get("integrator", {"type": "whitted"})
    if not isinstance(film, dict) or not isinstance(integ, dict):
        return d
    # the values replaced are checked as written, so a bad file is refused whatever the
    # options (the others are checked with the scene)
    ctx = Ctx(d.get("_source", "<scene>"))
    for key in given:
        if given[key] is not None and key in film:
            _film_setting(ctx, film, "film", key)
    if max_depth is not None and "max_depth" in integ:
        _film_setting(ctx, integ, "integrator", "max_depth")
    d["film"] = dict(film, **{k: v for k, v in given.items() if v is not None})
    if width is not None or height is not None:
        _check_film_area(d["film"], "width" if width is not None else "height")
    if max_depth is not None:
        d["integrator"] = dict(integ, max_depth=max_depth)
    return d


def _check_film_area(film, key):
    """Refuse (ParameterError naming ``key``, the side just given) a film of more than
    ``MAX_FILM_PIXELS`` whose sides are both in range; a side the scene gives wrong is left
    for ``compile_scene``."""
    w = film.get("width", FRAME_SETTINGS["width"][0])
    h = film.get("height", FRAME_SETTINGS["height"][0])
    ok = all(is_integer(v) and 1 <= v <= MAX_FILM_SIDE for v in (w, h))
    if ok and int(w) * int(h) > MAX_FILM_PIXELS:
        raise ParameterError(key, f"{w} x {h} is more than the {MAX_FILM_PIXELS} {FILM_TOO_LARGE}")


def finite(v):
    """Whether the number ``v`` is finite (an int beyond the float range is not)."""
    try:
        return math.isfinite(v)
    except OverflowError:
        return False


class _LongInteger(float):
    """A JSON integer too long for Python to convert: the float it rounds to (infinity), so
    that its key's check refuses it, shown as what the file holds."""

    def __new__(cls, text):
        self = super().__new__(cls, text)
        self.digits = len(text.lstrip("-"))
        return self

    def __repr__(self):
        return f"an integer of {self.digits} digits"


def _json_int(text):
    """A JSON integer (``_LongInteger`` past 4000 digits; Python converts at most 4300)."""
    return int(text) if len(text) <= 4000 else _LongInteger(text)


def _long_integer(path):
    """'line N: ...' for the first integer of the text file ``path`` too long for Python to
    convert (TOML's reader fails on it without naming its line), or None."""
    try:
        with open(path, "rb") as f:
            for number, line in enumerate(f, 1):
                if re.search(rb"\d{4001,}", line):
                    return f"line {number}: a number of more than 4000 digits"
    except OSError:
        pass
    return None


def _reason(e):
    if isinstance(e, RecursionError):
        return "nested too deeply"
    if isinstance(e, UnicodeDecodeError):
        return "not UTF-8 text"
    return getattr(e, "strerror", None) or str(e).split(":")[0]


def save_scene(d, path):
    """Write still scene dict ``d`` (``load_scene``, ``mesh_scene``, a built-in's or one made in
    Python) as a scene file at ``path`` (.json), which ``load_scene`` and ``hwrt render`` read
    back as the same scene. The scene is checked first (``compile_scene``); the module's own
    keys are left out, and mesh file names are written absolute, so the file works from any
    directory. A scene from ``transform_scene`` has no file form: save it before transforming.
    The file is written whole or not at all, and never over one of the files the scene reads.
    Returns ``path``."""
    from hwbvh.files import check_outputs, json_text, write_files

    path = spec_path(path, "path", "a .json file path")
    if not str(path).lower().endswith(".json"):
        raise ParameterError("path", f"a scene is saved as JSON: expected a name ending in "
                                     f".json, got {written(str(path))}")
    if not isinstance(d, dict):
        raise ParameterError("d", f"expected a scene dict, got {type(d).__name__}")
    shapes = d.get("shapes")
    if isinstance(shapes, (list, tuple)) and any(isinstance(sh, dict) and "_world" in sh
                                                 for sh in shapes):
        raise ParameterError("d", "a scene from transform_scene has no file form (its shapes "
                                  "carry the transform): save the scene before transforming it")
    compile_scene(d)
    source = d.get("_source", "<scene>")
    base = scene_directory(d, source)
    out = {k: v for k, v in d.items() if not str(k).startswith("_")}
    out["name"] = d.get("name", "scene")        # a file without one takes the file's name
    out["shapes"] = []
    meshes = []
    for sh in shapes:
        sh = dict(sh)
        if sh.get("type") == "mesh":
            sh["filename"] = os.path.join(base, sh["filename"])   # an absolute name stays
            meshes.append(sh["filename"])
        out["shapes"].append(sh)
    own = scene_file(d, source)
    inputs = meshes + ([own] if os.path.isfile(str(own)) else [])
    check_outputs([path], inputs=inputs)
    write_files([(path, json_text(out, indent=1) + "\n")])
    return path


def scene_file(d, source):
    """The scene file of dict ``d`` read from ``source``, as a path that names it from any
    working directory (``_dir``); else ``source`` itself (a built-in, a mesh, a dict made in
    Python)."""
    if isinstance(d.get("_dir"), str) and isinstance(source, str) and \
            source == d.get("_source"):
        return os.path.join(d["_dir"], os.path.basename(source))
    return source


def scene_directory(d, source):
    """The directory the relative mesh names of scene dict ``d`` resolve against: its scene
    file's, as it was when the file was read (``_dir``), else ``source``'s if that is a file,
    else the working directory (a scene built in Python)."""
    if isinstance(d.get("_dir"), str):
        return d["_dir"]
    return os.path.dirname(os.path.abspath(source)) if os.path.exists(str(source)) else os.getcwd()


def _refuse_internal_keys(spec, d):
    """Keys with a leading underscore are this module's own (``_source``, ``_dir``, a shape's
    ``_world``): from a file they are unknown keys like any other."""
    shapes = d.get("shapes")
    found = [k for k in d if str(k).startswith("_")]
    if isinstance(shapes, list):
        found += [f"shapes[{i}].{k}" for i, sh in enumerate(shapes) if isinstance(sh, dict)
                  for k in sh if str(k).startswith("_")]
    if found:
        raise InputError(spec, f"key '{found[0]}': unknown key")


def _mesh_arrays(path):
    """(vertices, faces) of a mesh file, the coordinates its faces use checked (NaN, infinite
    or beyond MAX_COORDINATE: an error naming the file and the first such triangle) before
    any arithmetic on them, which would warn."""
    verts, faces = load_mesh_arrays(path)
    if not within_bound(verts):
        checked_coordinates(verts[faces], path)
    return verts, faces


def mesh_scene(path, name=None):
    """A mesh alone: default camera framing it, a point light, a plain diffuse material; named
    ``name``, else after the file (``name_of_file``)."""
    from traversal.camera import frame_bounds
    from traversal.raysets import check_extent

    path = spec_path(path, "path", "a mesh file path")
    if name is None:
        name = name_of_file(path)
    elif not _plain_name(name):
        raise ParameterError("name", f"expected a plain file name (outputs are named after it), "
                                     f"got {written(name)}")
    verts, faces = _mesh_arrays(path)
    used = verts[np.unique(faces)]
    check_extent(used, path)
    lo, hi = used.min(0), used.max(0)
    eye, target, up = frame_bounds(lo, hi, 40.0)
    diag = float(np.linalg.norm(hi - lo)) or 1.0
    light = (lo + hi) / 2 + np.array([0.4, 1.0, 0.8]) * diag
    dist2 = float(np.sum((light - (lo + hi) / 2) ** 2))
    return {
        "type": "scene", "name": name, "_source": path,
        "camera": {"type": "perspective", "eye": eye.tolist(), "target": target.tolist(),
                   "up": up.tolist(), "fov": 40.0},
        "film": {"width": 640, "height": 480, "spp": 1},
        "integrator": {"type": "whitted", "max_depth": 5, "ambient": [0.08] * 3},
        "background": [0.15, 0.15, 0.18],
        "lights": [{"type": "point", "position": light.tolist(), "intensity": [2.5 * dist2] * 3}],
        "materials": {"default": {"type": "diffuse", "reflectance": [0.75, 0.72, 0.68]}},
        "shapes": [{"type": "mesh", "filename": os.path.abspath(path), "material": "default",
                    "smooth": False}],
    }


def _three_numbers(v):
    """Whether ``v`` is 3 finite numbers (no bools), as a scene's vectors must be."""
    try:
        a = np.asarray(v, np.float64)
    except (TypeError, ValueError, OverflowError):
        return False
    return a.shape == (3,) and bool(np.isfinite(a).all()) and not _holds_a_non_number(v)


def transform_scene(d, scale=1.0, translate=(0.0, 0.0, 0.0)):
    """The same scene scaled by ``scale`` (> 0) and then translated as a whole (point
    intensities scale by s^2, so the irradiance, and so the image, stays the same). Applied to
    a scene it made, the two transforms compose. A negative scale, which would mirror the
    scene and turn its camera upside down, is refused."""
    import copy

    if not (isinstance(d, dict) and isinstance(d.get("camera"), dict)
            and isinstance(d.get("shapes"), list)):
        raise ParameterError("d", f"expected a scene dict with a camera and shapes (load_scene "
                                  f"makes one), got {type(d).__name__}")
    if not (isinstance(scale, (int, float, np.number)) and not isinstance(scale, bool)
            and np.isfinite(scale) and scale > 0):
        raise ParameterError("scale", f"expected a finite number above 0, got {scale!r}")
    try:
        t = np.asarray(translate, np.float64)
    except (TypeError, ValueError):
        t = None
    if t is None or t.shape != (3,) or not np.isfinite(t).all():
        raise ParameterError("translate", f"expected 3 finite numbers, got {translate!r}")
    s = float(scale)
    d = copy.deepcopy(d)
    P = lambda p: (np.asarray(p, np.float64) * s + t).tolist()
    d["camera"]["eye"] = P(d["camera"]["eye"])
    d["camera"]["target"] = P(d["camera"]["target"])
    for L in d.get("lights", []):
        # (a light that is not a dict, or not a point light as written, is left for
        # compile_scene to report)
        if isinstance(L, dict) and L.get("type") == "point":
            if _three_numbers(L.get("position")):
                L["position"] = P(L["position"])
            if _three_numbers(L.get("intensity")):
                L["intensity"] = (np.asarray(L["intensity"], float) * s * s).tolist()
    for sh in d["shapes"]:
        if not isinstance(sh, dict):
            continue
        # after an earlier transform p -> p * s0 + t0, the two together: p * s0 s + t0 s + t
        s0, t0 = 1.0, np.zeros(3)
        if isinstance(sh.get("_world"), dict):
            s0 = float(sh["_world"]["scale"])
            t0 = np.asarray(sh["_world"]["translate"], np.float64)
        sh["_world"] = {"scale": s0 * s, "translate": (t0 * s + t).tolist()}
    return d


# --------------------------------------------------------------------------------------
@dataclass
class CompiledScene:
    name: str
    triangles: np.ndarray     # (n, 3, 3) float32
    normals: np.ndarray       # (n, 3, 3) float32 shading normals per vertex
    material: np.ndarray      # (n,) int32
    mat_names: list
    kd: np.ndarray            # (m, 3) diffuse reflectance
    ks: np.ndarray            # (m,) Blinn-Phong highlight weight
    shininess: np.ndarray     # (m,)
    kr: np.ndarray            # (m, 3) mirror reflectance
    ior: np.ndarray           # (m,) index of refraction, 0 = not a dielectric
    lights: list              # dicts: type, position/direction, intensity/irradiance (np arrays)
    camera: dict
    width: int
    height: int
    spp: int
    max_depth: int
    ambient: np.ndarray
    background: np.ndarray
    cutoff: float
    jitter: bool = True
    vertices: np.ndarray = None  # indexed form for Embree: (v, 3) float32
    faces: np.ndarray = None     # (n, 3) int32


def key_text(key, limit=KEY_TEXT_LIMIT):
    """A key of a scene file as a message names it, cut short: an error is one line, and a key
    (a material's name) may be as long as the file."""
    return cut_short(str(key), limit)


def _listed(names, most=LISTED_NAMES):
    """Names for a message (``key_text`` each), the first ``most`` of them and how many more."""
    shown_names = ", ".join(key_text(n) for n in names[:most])
    return shown_names + (f" and {len(names) - most} more" if len(names) > most else "")


def _at(path, key):
    """The key ``key`` of the object at ``path`` ("" for the scene itself), as messages name it."""
    return f"{path}.{key_text(key)}" if path else key_text(key)


class Ctx:
    """Checks of one scene source's values: each failure an InputError naming the source and
    the key."""

    def __init__(self, source):
        self.source = source

    def fail(self, key, problem):
        raise InputError(self.source, f"key '{key}': {problem}")

    def keys(self, obj, allowed, path, hints=None):
        """Fail on the first key of ``obj`` not in ``allowed``, suggesting the closest one
        (or ``hints[key]``, for a key that belongs elsewhere)."""
        for key in obj:
            if key not in allowed:
                where = _at(path, key)
                close = difflib.get_close_matches(str(key), [a for a in allowed if a[0] != "_"], 1)
                known = "known keys: " + ", ".join(a for a in allowed if a[0] != "_")
                hint = (f"did you mean {hints[key]}? {known}" if key in (hints or {}) else
                        f"did you mean '{close[0]}'?" if close else known)
                self.fail(where, f"unknown key ({hint})")

    def obj(self, d, key, path=None, default=None):
        """``d[key]``, which must be an object (dict); ``default`` when absent."""
        v = d.get(key, default)
        if not isinstance(v, dict):
            self.fail(path or key, "expected an object")
        return v

    def flag(self, obj, key, path, default):
        v = obj.get(key, default)
        if not isinstance(v, (bool, np.bool_)):
            self.fail(_at(path, key), f"expected true or false, got {written(v)}")
        return bool(v)

    def vec(self, obj, key, path, n=3, default=None, bound=MAX_COORDINATE):
        if key not in obj:
            if default is None:
                self.fail(_at(path, key), "missing")
            return np.asarray(default, np.float64)
        v = given = obj[key]
        if isinstance(v, (int, float, np.integer, np.floating)) and \
                not isinstance(v, (bool, np.bool_)) and n == 3:
            v = [v, v, v]
        try:
            a = np.asarray(v, np.float64)
        except (TypeError, ValueError):
            a = None
        except OverflowError:                           # an integer past float64's range
            a = np.full(n, np.inf)
        if a is None or a.shape != (n,) or _holds_a_non_number(v):
            self.fail(_at(path, key), f"expected {n} numbers, got {written(given)}")
        if not np.isfinite(a).all() or not vector_ok(v, a, bound):
            self.fail(_at(path, key), f"expected {n} finite numbers of magnitude at most "
                                       f"{bound:g}, got {written(given)}")
        return a

    def num(self, obj, key, path, default=None, lo=None, hi=None, integer=False, wanted=None):
        """A number at obj[key], finite and within [lo, hi] (either may be None: no bound);
        ``wanted`` words the range for the error (default: from the bounds)."""
        if key not in obj:
            if default is None:
                self.fail(_at(path, key), "missing")
            return default
        v = obj[key]
        # numbers as JSON and TOML give them, and NumPy's (a dict built in Python)
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
            self.fail(_at(path, key), f"expected {'an integer' if integer else 'a number'}, "
                                       f"got {written(v)}")
        if not finite(v):
            self.fail(_at(path, key), f"expected a finite number, got {written(v)}")
        if integer and not is_integer(v):       # 4.0 too: TOML and JSON write integers apart
            self.fail(_at(path, key), f"expected an integer, got {written(v)}")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            if wanted is None:
                wanted = f"at least {lo}" if hi is None else \
                    (f"at most {hi}" if lo is None else f"in [{lo}, {hi}]")
            self.fail(_at(path, key), f"{written(v)} is out of range (must be {wanted})")
        return int(v) if integer else float(v)


def _unit_rows(v):
    ln = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(ln > 0, v / np.where(ln > 0, ln, 1), 0)


def flat_normals(tris):
    """(n, 3, 3) per-corner shading normals equal to each face's unit normal (in float64: a
    float32 mesh of large coordinates would overflow the squared lengths)."""
    tris = np.asarray(tris, np.float64)
    n = _unit_rows(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]))
    return np.repeat(n[:, None, :], 3, axis=1)


def smooth_normals(verts, faces):
    """Per-corner shading normals ``(f, 3, 3)`` of an indexed mesh, in float64: at each vertex,
    the sum of the normals of the faces around it in face order, each weighted by its area (the
    cross product's length is twice the area), normalised. A corner whose vertex sum vanishes
    (a degenerate fan) keeps its face's own normal (zero for a face without area: shading then
    takes the geometric normal). Still meshes and every frame of an animation use this one."""
    v = np.asarray(verts, np.float64)
    f = np.asarray(faces, np.int64)
    tris = v[f]
    area_n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    corners = f.reshape(-1)                  # face by face, so each vertex sums in face order
    weights = np.repeat(area_n, 3, axis=0)
    summed = np.stack([np.bincount(corners, weights=weights[:, k], minlength=len(v))
                       for k in range(3)], axis=1)
    corner_n = _unit_rows(summed)[f]
    flat = flat_normals(tris)
    return np.where(np.linalg.norm(corner_n, axis=-1, keepdims=True) > 0, corner_n, flat)


def _quad(c):
    c = np.asarray(c, np.float64)
    return np.stack([c[[0, 1, 2]], c[[0, 2, 3]]])


def _box(lo, hi, rot_y):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    P = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]])
    quads = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 4, 7, 3], [1, 2, 6, 5], [0, 1, 5, 4], [3, 7, 6, 2]]
    if rot_y:
        c = (lo + hi) / 2
        a = np.radians(rot_y)
        R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        P = (P - c) @ R.T + c
    return np.concatenate([_quad(P[q]) for q in quads])


def check_scale(source, s, key):
    """Refuse (InputError naming ``source`` and ``key``) a scale (three numbers) with a
    component whose magnitude is outside SCALE_RANGE: 0 flattens the shape, and a scale
    beyond the range carries its coordinates out of float32's useful range."""
    mag = np.abs(np.asarray(s, np.float64))
    if not mag.all():
        raise InputError(source, f"key '{key}': a scale of 0 flattens the shape, got "
                                 f"{np.asarray(s).tolist()}")
    if not ((mag >= SCALE_RANGE[0]) & (mag <= SCALE_RANGE[1])).all():
        raise InputError(source, f"key '{key}': each component's magnitude must lie in "
                                 f"[{SCALE_RANGE[0]:g}, {SCALE_RANGE[1]:g}], got "
                                 f"{np.asarray(s).tolist()}")


def _bounded(ctx, tris, key, what):
    """Refuse, naming ``key``, a shape made from in-bound keys whose triangles still reach
    beyond MAX_COORDINATE (a rotated box's corners, a sphere's centre plus its radius)."""
    if not within_bound(tris):
        ctx.fail(key, f"{what} reaches a coordinate of magnitude "
                      f"{beyond_bound_text(np.abs(tris).max())}, beyond {MAX_COORDINATE:.0e}")


def _has_area(tris):
    """Which of triangles ``tris``, rounded to float32 (as the builder and renderer see them),
    keep an area: the cross product is taken in float64, where the products of float32
    numbers neither overflow nor underflow."""
    with np.errstate(under="ignore"):
        t = tris.astype(np.float32).astype(np.float64)
    return np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]).any(axis=1)


def _no_collapse(ctx, mesh, scaled, moved, path):
    """Refuse a transform under which triangles of ``mesh`` with an area in float32 lose it in
    the final coordinates ``moved`` (``scaled`` plus the translation): a scale small against
    the mesh's coordinates rounds its vertices together, and so does a translation large
    against the mesh's size. The key named is the scale when the scaled mesh has already
    lost those triangles, else the translation. A translation that rounds the vertices by
    more than ``MAX_FLOAT32_ROUNDING`` of the mesh's size is refused too."""
    lost = _has_area(mesh) & ~_has_area(moved)
    n = int(lost.sum())
    if n:
        if (lost & ~_has_area(scaled)).any():
            key, cause = "scale", "at this scale"
        else:
            key, cause = "translate", "moved this far from the origin"
        ctx.fail(f"{path}.transform.{key}", f"the mesh collapses: {n} of its {len(mesh)} "
                                            f"triangles lose their area in float32 {cause}")
    if not len(moved):
        return
    size, step, own = extent(scaled), float32_step(moved), float32_step(scaled)
    if size > 0 and step > own and step / 2 > MAX_FLOAT32_ROUNDING * size:
        ctx.fail(f"{path}.transform.translate",
                 f"the mesh collapses: moved this far from the origin, its coordinates round to "
                 f"float32 numbers {step:.3g} apart, coarse against its size of {size:.3g}")


def _not_coarse(ctx, tris, key, what, sized=False):
    """Refuse a shape placed so far from the origin, against its size, that float32 rounds its
    coordinates by more than ``MAX_FLOAT32_ROUNDING`` of that size (as a mesh's
    translation is refused): a unit box at x = 1e9 would be traced as a flat or empty one.
    A shape given no extent (a box with min = max, a sheet of size 0) has none to lose and
    renders nothing; one whose keys give it an extent (``sized``: a sphere's radius is above
    0) and that has none left has rounded to a point (a radius of 1e-18 beside a centre at
    1): as coarse as can be."""
    if not len(tris):
        return
    size, step = extent(tris), float32_step(tris)
    if (size > 0 or sized) and step / 2 > MAX_FLOAT32_ROUNDING * size:
        ctx.fail(key, f"{what} collapses: this far from the origin its coordinates round to "
                      f"float32 numbers {step:.3g} apart, coarse against its size of {size:.3g}")


def _type_problem(obj, what, types):
    """What is wrong with an object's 'type': missing, or not one of ``types``."""
    choose = f"(choose from {', '.join(types)})"
    if "type" not in obj:
        return f"missing: every {what} names its type {choose}"
    return f"unknown {what} type {written(obj['type'])} {choose}"


def _sphere_triangles(subdiv):
    """Triangles of a sphere of ``subdiv`` [n_lat, n_lon] (``meshes.uv_sphere``)."""
    return 2 * subdiv[1] * (subdiv[0] - 1)


def _sheet_triangles(resolution):
    """Triangles of a sheet of ``resolution`` [nx, ny] (``meshes.grid_sheet``)."""
    return 2 * resolution[0] * resolution[1]


def _planned_triangles(sh):
    """The triangles a shape will make, read from its keys before it is built; None for a
    mesh (its file holds the count) and for keys ``_shape`` refuses."""
    if not isinstance(sh, dict):
        return None
    typ = sh.get("type")
    if typ in ("quad", "box"):
        return 2 if typ == "quad" else 12
    if typ == "triangles":
        data = sh.get("data")
        return len(data) if isinstance(data, (list, tuple, np.ndarray)) else None
    if typ in ("sphere", "sheet"):
        key, lo, default = ("subdiv", 3, SPHERE_SUBDIV) if typ == "sphere" else \
            ("resolution", 1, SHEET_RESOLUTION)
        v = _as_list(sh.get(key, default))
        if isinstance(v, (list, tuple)) and len(v) == 2 and \
                all(is_integer(x) and x >= lo for x in v):
            return (_sphere_triangles if typ == "sphere" else _sheet_triangles)(v)
    return None


def _refuse_scene_size(ctx, i, total):
    ctx.fail(f"shapes[{i}]", f"brings the scene to {total} triangles, more than the 2^24 "
                             f"({MAX_PRIMITIVES}) a tree holds")


def _check_scene_size(ctx, shapes, first_shape):
    """Refuse, before any shape is built, a scene whose generated shapes together make more
    triangles than a tree holds, naming the shape that passes the limit (one shape alone
    beyond it is refused by ``_shape``, naming its key). Building them first could take
    gigabytes and many seconds."""
    total = 0
    for i, sh in enumerate(shapes, first_shape):
        n = _planned_triangles(sh)
        if n is None or n > MAX_PRIMITIVES:
            continue
        total += n
        if total > MAX_PRIMITIVES:
            _refuse_scene_size(ctx, i, total)


def _shape(ctx, sh, i, scene_dir):
    path = f"shapes[{i}]"
    if not isinstance(sh, dict):
        ctx.fail(path, "expected an object")
    typ = sh.get("type")
    if typ not in SHAPE_TYPES:
        ctx.fail(f"{path}.type", _type_problem(sh, "shape", SHAPE_TYPES))
    ctx.keys(sh, _SHAPE_COMMON + SHAPE_KEYS[typ], path, SHAPE_KEY_HINTS)
    if typ == "quad":
        c = sh.get("corners")
        try:
            c = np.asarray(c, np.float64)
        except (TypeError, ValueError, OverflowError):
            c = None
        if c is None or c.shape != (4, 3) or not within_bound(c) or \
                not vector_ok(sh["corners"], c):
            ctx.fail(f"{path}.corners", f"expected 4 corners of 3 finite numbers of magnitude at "
                                        f"most {MAX_COORDINATE:g}")
        tris = _quad(c)
        _not_coarse(ctx, tris, f"{path}.corners", "the quad")
        normals = flat_normals(tris)
    elif typ == "box":
        lo, hi = ctx.vec(sh, "min", path), ctx.vec(sh, "max", path)
        if not (lo <= hi).all():
            ctx.fail(f"{path}.min", "min must not exceed max")
        tris = _box(lo, hi, ctx.num(sh, "rotate_y", path, default=0.0))
        _bounded(ctx, tris, f"{path}.rotate_y", "rotated, the box")
        _not_coarse(ctx, tris, f"{path}.min", "the box")
        normals = flat_normals(tris)
    elif typ == "sphere":
        c = ctx.vec(sh, "center", path)
        r = ctx.num(sh, "radius", path, lo=1e-30)
        sub = _as_list(sh.get("subdiv", SPHERE_SUBDIV))
        if not (isinstance(sub, (list, tuple)) and len(sub) == 2 and
                all(is_integer(x) and x >= 3 for x in sub)):
            ctx.fail(f"{path}.subdiv", f"expected [n_lat, n_lon] integers >= 3, got {written(sub)}")
        if _sphere_triangles(sub) > MAX_PRIMITIVES:
            ctx.fail(f"{path}.subdiv", f"{written(sub)} makes more than the 2^24 triangles a tree holds")
        V, F = uv_sphere(sub[0], sub[1])
        tris = V[F] * r + c
        _bounded(ctx, tris, f"{path}.radius", "the sphere")
        _not_coarse(ctx, tris, f"{path}.center", "the sphere", sized=True)
        normals = V[F]                                   # radial, outward
    elif typ == "sheet":
        res = _as_list(sh.get("resolution", SHEET_RESOLUTION))
        if not (isinstance(res, (list, tuple)) and len(res) == 2 and
                all(is_integer(x) and x >= 1 for x in res)):
            ctx.fail(f"{path}.resolution", f"expected [nx, ny] positive integers, got {written(res)}")
        if _sheet_triangles(res) > MAX_PRIMITIVES:
            ctx.fail(f"{path}.resolution",
                     f"{written(res)} makes more than the 2^24 triangles a tree holds")
        # each within the coordinate bound before any arithmetic (which would overflow, with
        # numpy's warnings); the sheet's y is height plus up to |wave|, checked after
        big = MAX_COORDINATE
        size = ctx.num(sh, "size", path, default=2.0, lo=0, hi=big, wanted=f"in [0, {big:g}]")
        wave = ctx.num(sh, "wave", path, default=0.15, lo=-big, hi=big,
                       wanted=f"of magnitude at most {big:g}")
        height = ctx.num(sh, "height", path, default=0.0, lo=-big, hi=big,
                         wanted=f"of magnitude at most {big:g}")
        tris = grid_sheet(res[0], res[1], size=size, wave=wave).astype(np.float64)
        tris[:, :, 1] += height
        _bounded(ctx, tris, f"{path}.{'height' if abs(height) >= abs(wave) else 'wave'}",
                 "with its height and wave, the sheet")
        _not_coarse(ctx, tris, f"{path}.height", "the sheet")
        normals = flat_normals(tris)
    elif typ == "triangles":
        tris = _triangle_data(ctx, sh.get("data"), f"{path}.data")
        if not within_bound(tris):
            ctx.fail(f"{path}.data", f"expected finite coordinates of magnitude at most "
                                     f"{MAX_COORDINATE:g}")
        _not_coarse(ctx, tris, f"{path}.data", "the set of triangles")
        normals = flat_normals(tris)
    else:  # mesh
        fn = sh.get("filename")
        if not isinstance(fn, str) or not fn:
            ctx.fail(f"{path}.filename", "missing, empty or not a string")
        if "\0" in fn:
            ctx.fail(f"{path}.filename", "a path cannot hold a NUL byte")
        full = fn if os.path.isabs(fn) else os.path.join(scene_dir, fn)
        smooth = ctx.flag(sh, "smooth", path, False)
        tf = sh.get("transform", {})
        if not isinstance(tf, dict):
            ctx.fail(f"{path}.transform", "expected an object with scale/rotate_y/translate")
        ctx.keys(tf, TRANSFORM_KEYS, f"{path}.transform")
        # the transform is checked before the mesh is read: a bad key is named at once
        s = ctx.vec(tf, "scale", f"{path}.transform", default=[1, 1, 1])
        check_scale(ctx.source, s, f"{path}.transform.scale")
        a = np.radians(ctx.num(tf, "rotate_y", f"{path}.transform", default=0.0))
        t = ctx.vec(tf, "translate", f"{path}.transform", default=[0, 0, 0])
        try:
            verts, faces = _mesh_arrays(full)
        except InputError as e:                 # names the mesh file; add the scene's key
            ctx.fail(f"{path}.filename", str(e))
        tris = verts[faces]
        normals = smooth_normals(verts, faces) if smooth else flat_normals(tris)
        if tf:
            R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
            scaled = (tris * s) @ R.T
            _bounded(ctx, scaled, f"{path}.transform.scale", "scaled, the mesh")
            moved = scaled + t
            _bounded(ctx, moved, f"{path}.transform.translate", "moved, the mesh")
            _no_collapse(ctx, tris, scaled, moved, path)
            tris = moved
            normals = (normals / s) @ R.T
            normals /= np.maximum(np.linalg.norm(normals, axis=2, keepdims=True), 1e-30)
    w = sh.get("_world")
    if w:
        tris = tris * float(w["scale"]) + np.asarray(w["translate"], np.float64)
    return tris, normals


def _reflectance(ctx, obj, key, path, default):
    """Three reflectances, each in [0, 1] (more would add light at every bounce)."""
    v = ctx.vec(obj, key, path, default=default)
    if (v < 0).any() or (v > 1).any():
        ctx.fail(_at(path, key), f"reflectances must lie in [0, 1], got {v.tolist()}")
    return v


def _light(ctx, obj, key, path, default=None):
    """A light or radiance value (three numbers up to MAX_RADIANCE): a negative one would
    paint negative pixels."""
    v = ctx.vec(obj, key, path, default=default, bound=MAX_RADIANCE)
    if (v < 0).any():
        ctx.fail(_at(path, key), f"must not be negative, got {v.tolist()}")
    return v


# a number as JSON, TOML or NumPy gives it; true and false are not numbers
_is_number = np.frompyfunc(lambda x: isinstance(x, (int, float, np.integer, np.floating))
                           and not isinstance(x, (bool, np.bool_)), 1, 1)


def _triangle_data(ctx, data, key):
    """A ``triangles`` shape's data as (n, 3, 3) float64: a non-empty list of triangles of 3
    points of 3 numbers, nested as written (a flat list of numbers is refused, not reshaped);
    ``true``, ``false`` and strings are not numbers."""
    try:
        items = np.asarray(data, dtype=object)
    except (TypeError, ValueError):             # ragged nesting
        items = None
    if items is not None and items.ndim == 1 and items.shape[0] == 0:
        ctx.fail(key, "expected at least one triangle, got an empty list")
    ok = items is not None and items.ndim == 3 and items.shape[1:] == (3, 3)
    if ok and not (isinstance(data, np.ndarray) and data.dtype.kind in "fiu"):
        ok = bool(_is_number(items).all())
    if ok:
        try:
            return np.asarray(items, np.float64)
        except OverflowError:
            ctx.fail(key, f"expected numbers of magnitude at most {MAX_COORDINATE:g}, got an "
                          f"integer past float64's range")
        except (TypeError, ValueError):
            pass
    ctx.fail(key, "expected a list of triangles, each 3 points of 3 numbers")


def compile_scene(d, source=None, first_shape=0):
    """Validate a scene dict and turn it into arrays (see :class:`CompiledScene`).
    ``first_shape``: the index errors give the first shape (a part of a larger scene)."""
    if not isinstance(d, dict):
        raise InputError(source or "<scene>", f"a scene must be an object (a dict), got "
                                              f"{type(d).__name__}")
    if not (is_integer(first_shape) and first_shape >= 0):
        raise ParameterError("first_shape", f"must be an integer >= 0, got {first_shape!r}")
    if source is not None and not isinstance(source, (str, os.PathLike)):
        raise ParameterError("source", f"must be a file name or None, got "
                                       f"{type(source).__name__}")
    source = source or d.get("_source", "<scene>")
    ctx = Ctx(source)
    shapes = d.get("shapes")
    moving = ["animation"] if "animation" in d else [
        f"shapes[{i}].{'keyframes' if 'keyframes' in sh else 'type'}"
        for i, sh in enumerate(shapes if isinstance(shapes, (list, tuple)) else [], first_shape)
        if isinstance(sh, dict) and ("keyframes" in sh or sh.get("type") == "frames")]
    if moving:
        ctx.fail(moving[0], "the scene moves: render it with hwrt animate (--verify checks its "
                            "frames)")
    ctx.keys(d, SCENE_KEYS, "")
    for key in ("camera", "shapes", "materials"):
        if key not in d:
            ctx.fail(key, "missing")
    if d.get("type", "scene") != "scene":
        ctx.fail("type", f"expected 'scene', got {written(d.get('type'))}")
    check_name(source, d.get("name", "scene"))
    mats = d["materials"]
    if not isinstance(mats, dict) or not mats:
        ctx.fail("materials", "expected a non-empty object of named materials")
    names = list(mats)
    for name in names:
        if not isinstance(name, str):           # JSON's keys are; a Python dict's may not be
            ctx.fail("materials", f"material names must be strings, got {written(name)}")
    kd = np.zeros((len(names), 3)); ks = np.zeros(len(names)); sh_ = np.full(len(names), 32.0)
    kr = np.zeros((len(names), 3)); ior = np.zeros(len(names))
    for k, name in enumerate(names):
        m = mats[name]
        p = _at("materials", name)
        if not isinstance(m, dict):
            ctx.fail(p, f"expected an object, got {written(m)}")
        if m.get("type") not in MATERIAL_TYPES:
            ctx.fail(f"{p}.type", _type_problem(m, "material", MATERIAL_TYPES))
        t = m["type"]
        ctx.keys(m, MATERIAL_KEYS[t], p)
        if t in ("diffuse", "plastic"):
            kd[k] = _reflectance(ctx, m, "reflectance", p, [0.7, 0.7, 0.7])
            ks[k] = ctx.num(m, "specular", p, default=0.0 if t == "diffuse" else 0.3, lo=0, hi=1)
            sh_[k] = ctx.num(m, "shininess", p, default=32.0, lo=1)
            kr[k] = _reflectance(ctx, m, "mirror", p, [0, 0, 0] if t == "diffuse" else [0.04] * 3)
        elif t == "mirror":
            kr[k] = _reflectance(ctx, m, "reflectance", p, [0.9, 0.9, 0.9])
        else:
            ior[k] = ctx.num(m, "ior", p, default=1.5, lo=1.0, hi=4.0)
            if ior[k] == 1.0:
                ior[k] = 1.0 + 1e-6
    shapes = d["shapes"]
    if not isinstance(shapes, (list, tuple)) or not shapes:
        ctx.fail("shapes", "expected a non-empty list")
    scene_dir = scene_directory(d, source)
    _check_scene_size(ctx, shapes, first_shape)
    all_t, all_n, all_m = [], [], []
    total = 0
    for i, sh in enumerate(shapes, first_shape):
        tris, normals = _shape(ctx, sh, i, scene_dir)
        total += len(tris)
        if total > MAX_PRIMITIVES:                      # a mesh's count is known once read
            _refuse_scene_size(ctx, i, total)
        mname = sh.get("material")
        if "material" not in sh:
            ctx.fail(f"shapes[{i}].material", f"missing (defined: {_listed(names)})")
        if not isinstance(mname, str) or mname not in mats:
            ctx.fail(f"shapes[{i}].material", f"unknown material {written(mname)} "
                                              f"(defined: {_listed(names)})")
        all_t.append(tris)
        all_n.append(normals)
        all_m.append(np.full(len(tris), names.index(mname), np.int32))
    tris = as_triangles(np.concatenate(all_t), source=source)
    cam = ctx.obj(d, "camera")
    ctx.keys(cam, CAMERA_KEYS, "camera")
    if cam.get("type", "perspective") != "perspective":
        ctx.fail("camera.type", f"unknown camera type {written(cam['type'])} (the camera is 'perspective')")
    camera = {"eye": ctx.vec(cam, "eye", "camera"), "target": ctx.vec(cam, "target", "camera"),
              "up": ctx.vec(cam, "up", "camera", default=[0, 1, 0]),
              "fov": ctx.num(cam, "fov", "camera", default=40.0, lo=FOV_RANGE[0], hi=FOV_RANGE[1])}
    if np.array_equal(camera["eye"], camera["target"]):
        ctx.fail("camera.target", "must differ from camera.eye")
    if not np.any(camera["up"]):
        ctx.fail("camera.up", "must not be zero (it sets the camera's roll)")
    film = ctx.obj(d, "film", default={})
    ctx.keys(film, FILM_KEYS, "film")
    integ = ctx.obj(d, "integrator", default={})
    ctx.keys(integ, INTEGRATOR_KEYS, "integrator")
    if integ.get("type", "whitted") != "whitted":
        ctx.fail("integrator.type", f"unknown integrator {written(integ['type'])} (the renderer is 'whitted')")
    lights = []
    if not isinstance(d.get("lights", []), (list, tuple)):
        ctx.fail("lights", "expected a list")
    for i, L in enumerate(d.get("lights", [])):
        p = f"lights[{i}]"
        if not isinstance(L, dict):
            ctx.fail(p, "expected an object")
        if L.get("type") not in tuple(LIGHT_KEYS):
            ctx.fail(f"{p}.type", _type_problem(L, "light", tuple(LIGHT_KEYS)))
        ctx.keys(L, LIGHT_KEYS[L["type"]], p)
        if L["type"] == "point":
            lights.append({"type": "point", "position": ctx.vec(L, "position", p),
                           "intensity": _light(ctx, L, "intensity", p)})
        else:
            dv = ctx.vec(L, "direction", p)
            if not np.linalg.norm(dv) > 0:
                ctx.fail(f"{p}.direction", "must not be zero")
            lights.append({"type": "directional", "direction": dv / np.linalg.norm(dv),
                           "irradiance": _light(ctx, L, "irradiance", p)})
    V = tris.reshape(-1, 3)
    width = _film_setting(ctx, film, "film", "width")
    height = _film_setting(ctx, film, "film", "height")
    if width * height > MAX_FILM_PIXELS:
        ctx.fail("film.width", f"{width} x {height} is more than the {MAX_FILM_PIXELS} "
                               f"{FILM_TOO_LARGE}")
    return CompiledScene(
        name=str(d.get("name", "scene")), triangles=tris,
        normals=np.concatenate(all_n).astype(np.float32), material=np.concatenate(all_m),
        mat_names=names, kd=kd, ks=ks, shininess=sh_, kr=kr, ior=ior, lights=lights,
        camera=camera,
        width=width, height=height,
        spp=_film_setting(ctx, film, "film", "spp"),
        max_depth=_film_setting(ctx, integ, "integrator", "max_depth"),
        ambient=_light(ctx, integ, "ambient", "integrator", default=[0.03] * 3),
        background=_light(ctx, d, "background", "", default=[0, 0, 0]),
        cutoff=ctx.num(integ, "cutoff", "integrator", default=1e-3, lo=0, hi=1),
        jitter=ctx.flag(film, "jitter", "film", True),
        vertices=V, faces=np.arange(len(V), dtype=np.int32).reshape(-1, 3))


def load_scene_geometry(spec):
    """(name, triangles, vertices, faces) of a scene, for verification."""
    c = compile_scene(load_scene(spec))
    return c.name, c.triangles, c.vertices, c.faces
