"""Animated scenes: a scene that changes over time, one CompiledScene per frame.

Three sources, one :class:`Animation` interface (``anim.scene(i)`` is frame ``i`` at time
``i / fps``):

* a scene file (JSON/TOML, the same dict as a static scene) whose shapes may carry rigid
  ``keyframes`` and whose ``frames`` shapes are mesh sequences, with an optional top-level
  ``animation`` block (frame count, fps, camera keys)::

      "animation": {"frames": 120, "fps": 30,
                    "camera": [{"time": 0, "eye": [0, 1, 4], "target": [0, 1, 0]},
                               {"time": 4, "eye": [3, 1, 3], "target": [0, 1, 0]}]},
      "shapes": [
        {"type": "mesh", "filename": "bunny.ply", "material": "white",
         "keyframes": [{"time": 0, "translate": [0, 0, 0]},
                       {"time": 2, "translate": [1, 0, 0], "rotate": [0, 90, 0], "scale": 1.5}]},
        {"type": "frames", "pattern": "cloth/frame_%04d.ply", "material": "red"}]

  A key's ``rotate`` is Euler angles in degrees about x, then y, then z; ``scale`` a number or
  three; a point p of the shape goes to ``R (S p) + translate``. Keys are interpolated
  linearly (times strictly increasing, in seconds); a channel a key leaves out keeps the
  previous key's value (identity at the first key); before the first key and after the last
  the shape holds still. A ``frames`` shape reads one mesh file per frame from a printf
  pattern (``%04d``) or a glob; its triangle count may change from frame to frame.
* a frame pattern of mesh files given directly (``'frames/bunny_%04d.ply'`` or a glob), the
  way a mesh file is a scene: a default camera, a light, a plain diffuse material.
* a built-in animation generated in code, after the thesis' test scenes: ``exploding``
  (a mesh breaking into its triangles under gravity), ``cloth`` (a sheet falling and draping
  over a sphere), ``marbles`` (marbles dropped into a bowl, through Bullet when ``pybullet`` is
  importable, else an analytic fall) and ``flythrough`` (a camera moving through a static
  room: the tree never changes).

Every input is checked strictly: unknown keys, keys out of order, a pattern matching nothing, a
missing frame in the middle of a sequence and NaN vertices are each a one-line
:class:`~hwbvh.errors.InputError` naming the file and key.
"""
import glob
import inspect
import math
import os
import re
from dataclasses import dataclass, replace

import numpy as np
from numba import njit

from hwbvh.config import MAX_COORDINATE, MAX_FLOAT32_ROUNDING, MAX_PRIMITIVES
from hwbvh.errors import InputError, ParameterError, is_integer
from hwbvh.files import absent
from hwbvh.primitives import as_triangles, beyond_bound_text, load_mesh_arrays, within_bound
from .builtin import BUILTIN
from .config import (DEFAULT_ANIMATION_SECONDS, DEFAULT_FPS, GENERATED_TRIANGLES, MAX_FPS,
                     MIN_FPS)
from .loader import (FOV_RANGE, FRAME_FIELD, MAX_FRAMES, SCENE_KEYS, Ctx, check_scale,
                     compile_scene, finite, flat_normals, is_pattern, load_scene, mesh_scene,
                     key_text, named_after_file, scene_directory, scene_file, smooth_normals,
                     spec_path, vector_ok, with_frame, written)

KEYFRAME_KEYS = ("time", "translate", "rotate", "scale")
CAMERA_KEY_KEYS = ("time", "eye", "target", "up", "fov")
ANIMATION_KEYS = ("frames", "fps", "camera")
FRAMES_SHAPE_KEYS = ("type", "pattern", "material", "smooth")
GRAVITY = 9.81                     # m/s^2; the built-ins are modelled in metres

# --- built-in animation knobs (each with its reason) ------------------------------------
EXPLODE_AT = 0.25        # s: the mesh stands still for the first frames, so refit starts on a good tree
EXPLODE_SPEED = 1.2      # m/s outward, for a mesh 1 m tall: fragments land within the framed floor
CLOTH_SUBSTEPS = 4       # position-based dynamics steps per frame at 30 fps: stable for the sheet
CLOTH_ITERATIONS = 6     # constraint sweeps per step: the sheet stretches < ~10 % while falling
BULLET_HZ = 240          # Bullet's default step; marbles fall < 1/3 of their radius per step
# A keyframed shape's box corners, placed in float64, may round below a vertex placed the
# same way by a few ulps of the terms summed (~1e-16 each): times within this fraction of
# those terms of the coordinate bound are decided vertex by vertex.
CORNER_ROUNDING = 1e-12


# --------------------------------------------------------------------------------------
# Small helpers
# --------------------------------------------------------------------------------------
def _fail(source, key, problem):
    raise InputError(source, f"key '{key}': {problem}")


def too_many_frames(frames):
    return f"{frames} is more than the {MAX_FRAMES} frames an animation may have"


def _check_keys(source, obj, allowed, path):
    if not isinstance(obj, dict):
        _fail(source, path, "expected an object")
    for k in obj:
        if k not in allowed:
            _fail(source, f"{path}.{key_text(k)}", f"unknown key (known keys: {', '.join(allowed)})")


def _number(source, v, path, lo=None, positive=False, hi=None):
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)) \
            or not finite(v):
        _fail(source, path, f"expected a finite number, got {written(v)}")
    if positive and not v > 0:
        _fail(source, path, f"must be positive, got {written(v)}")
    if lo is not None and v < lo:
        _fail(source, path, f"must be at least {lo}, got {written(v)}")
    if hi is not None and v > hi:
        _fail(source, path, f"must be at most {hi}, got {written(v)}")
    return float(v)


def _vec3(source, v, path):
    if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_)):
        v = [v, v, v]
    try:
        a = np.asarray(v, np.float64)
    except (TypeError, ValueError, OverflowError):     # an integer past float64's range
        a = None
    if a is None or a.shape != (3,) or not np.isfinite(a).all() or not vector_ok(v, a):
        _fail(source, path, f"expected 3 finite numbers of magnitude at most "
                            f"{MAX_COORDINATE:g}, got {written(v)}")
    return a


def euler_matrix(deg):
    """Rotation matrix of Euler angles in degrees, applied about x, then y, then z."""
    return euler_matrices(np.asarray(deg, np.float64)[None])[0]


def euler_matrices(deg):
    """(n, 3, 3) rotation matrices of n triples of Euler angles (n, 3) (see euler_matrix)."""
    ax, ay, az = np.radians(np.asarray(deg, np.float64)).T
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    one, zero = np.ones_like(ax), np.zeros_like(ax)
    Rx = np.stack([one, zero, zero, zero, cx, -sx, zero, sx, cx], -1).reshape(-1, 3, 3)
    Ry = np.stack([cy, zero, sy, zero, one, zero, -sy, zero, cy], -1).reshape(-1, 3, 3)
    Rz = np.stack([cz, -sz, zero, sz, cz, zero, zero, zero, one], -1).reshape(-1, 3, 3)
    return Rz @ Ry @ Rx


# --------------------------------------------------------------------------------------
# Keyframes
# --------------------------------------------------------------------------------------
class Track:
    """Linearly interpolated channels over strictly increasing key times."""

    def __init__(self, times, channels):
        self.times = np.asarray(times, np.float64)
        self.channels = {k: np.asarray(v, np.float64) for k, v in channels.items()}

    def at(self, t):
        """The channels at time ``t``."""
        return {k: v[0] for k, v in self.at_times([t]).items()}

    def at_times(self, times):
        """The channels at each of ``times`` (n,): arrays (n, ...), one row per time."""
        times = np.asarray(times, np.float64)
        ts = self.times
        if len(ts) == 1:
            return {k: np.repeat(v[:1], len(times), axis=0) for k, v in self.channels.items()}
        j = np.clip(np.searchsorted(ts, times, side="right") - 1, 0, len(ts) - 2)
        w = (times - ts[j]) / (ts[j + 1] - ts[j])
        out = {}
        for k, v in self.channels.items():
            shape = (-1,) + (1,) * (v.ndim - 1)
            wk, before, after = w.reshape(shape), (times <= ts[0]).reshape(shape), \
                (times >= ts[-1]).reshape(shape)
            # before the first key and after the last the value holds still
            out[k] = np.where(before, v[0], np.where(after, v[-1], (1 - wk) * v[j] + wk * v[j + 1]))
        return out


def parse_keys(source, keys, path, allowed, defaults, vec_keys, num_keys=(), num_ranges=None):
    """A :class:`Track` from a list of key objects; checks keys, types and time order."""
    if not isinstance(keys, (list, tuple)) or not keys:
        _fail(source, path, "expected a non-empty list of keys")
    times = []
    chans = {k: [] for k in defaults}
    for j, key in enumerate(keys):
        p = f"{path}[{j}]"
        _check_keys(source, key, allowed, p)
        if "time" not in key:
            _fail(source, f"{p}.time", "missing")
        t = _number(source, key["time"], f"{p}.time")
        if times and not t > times[-1]:
            _fail(source, f"{p}.time", f"{t:g} is not after the previous key's {times[-1]:g} "
                                       "(keys must be in increasing time)")
        times.append(t)
        for k in defaults:
            prev = chans[k][-1] if chans[k] else np.asarray(defaults[k], np.float64)
            if k not in key:
                chans[k].append(prev)
            elif k in vec_keys:
                chans[k].append(_vec3(source, key[k], f"{p}.{k}"))
            else:
                lo, hi = (num_ranges or {}).get(k, (None, None))
                chans[k].append(np.float64(_number(source, key[k], f"{p}.{k}",
                                                   positive=k in num_keys, lo=lo, hi=hi)))
    return Track(times, chans)


def rigid_track(source, keys, path):
    tr = parse_keys(source, keys, path, KEYFRAME_KEYS,
                    {"translate": [0, 0, 0], "rotate": [0, 0, 0], "scale": [1, 1, 1]},
                    vec_keys=("translate", "rotate", "scale"))
    # a key without a scale holds the previous key's (or 1), so only keys giving one can fail
    for j, key in enumerate(keys):
        if "scale" in key:
            check_scale(source, tr.channels["scale"][j], f"{path}[{j}].scale")
    # interpolated linearly, a component that changes sign between two keys passes through 0
    # on the way, flattening the shape (and dividing its normals by 0)
    S = np.asarray(tr.channels["scale"], np.float64)
    flips = (np.diff(np.sign(S), axis=0) != 0).any(axis=1)
    if flips.any():
        j = int(np.argmax(flips)) + 1
        _fail(source, f"{path}[{j}].scale",
              f"{S[j].tolist()} changes the sign of a component from the previous key's "
              f"{S[j - 1].tolist()}: interpolated between the keys, the scale passes through 0 "
              "and flattens the shape")
    return tr


def camera_track(source, keys, path, base):
    return parse_keys(source, keys, path, CAMERA_KEY_KEYS,
                      {"eye": base["eye"], "target": base["target"], "up": base["up"],
                       "fov": base["fov"]}, vec_keys=("eye", "target", "up"), num_keys=("fov",),
                       num_ranges={"fov": FOV_RANGE})


# --------------------------------------------------------------------------------------
# Frame sequences
# --------------------------------------------------------------------------------------
class NoFrameFiles(InputError):
    """A frame pattern that names no frame file: none matches it, or it is not a pattern
    frames can be numbered by."""


def _with_frame(text, field, k):
    """``text`` with its frame field (the FRAME_FIELD match ``field``) replaced by frame
    ``k``; any other '%' in it stays as it is (a file may be named 50%_0001.ply)."""
    return text[:field.start()] + field.group(0) % k + text[field.end():]


def expand_pattern(pattern, source=None):
    """The frame files of a printf or glob pattern, in frame order. Raises NoFrameFiles naming
    ``source`` (the pattern, unless given: a scene file and its key) when nothing matches or it
    cannot number frames, and InputError when a frame in the middle of the numbered sequence
    is absent (naming ``source`` where given, else the missing file) or two files of a glob
    carry one frame number (naming ``source``)."""
    given = source is not None
    source = source or pattern
    pattern = os.fspath(pattern)
    if len(FRAME_FIELD.findall(pattern)) > 1:
        raise NoFrameFiles(source, f"pattern {pattern!r} has more than one %d field")
    m = FRAME_FIELD.search(pattern)
    if m:
        d = os.path.dirname(pattern) or "."
        base = os.path.basename(pattern)
        bm = FRAME_FIELD.search(base)
        if bm is None:
            raise NoFrameFiles(source, f"pattern {pattern!r}: the %d field must be in the file "
                                       f"name")
        rx = re.compile("^" + re.escape(base[:bm.start()]) + r"(\d+)" + re.escape(base[bm.end():]) + "$")
        try:
            names = os.listdir(d)
        except OSError:
            names = []
        nums = sorted({int(mm.group(1)) for nm in names if (mm := rx.match(nm))
                       and nm == _with_frame(base, bm, int(mm.group(1)))})
        if not nums:
            raise NoFrameFiles(source, f"pattern {pattern!r} matches no file")
        files = []
        for k in range(nums[0], nums[-1] + 1):
            f = _with_frame(pattern, m, k)
            if not os.path.isfile(f):
                raise InputError(source, f"missing frame {k}: {f} (of the sequence "
                                         f"{nums[0]}..{nums[-1]})") if given else \
                    InputError(f, f"missing frame {k} of the sequence {nums[0]}..{nums[-1]} "
                                  f"({pattern})")
            files.append(f)
        return files
    files = [f for f in glob.glob(pattern) if os.path.isfile(f)]
    if not files:
        raise NoFrameFiles(source, f"pattern {pattern!r} matches no file")
    numbered = [(re.findall(r"\d+", os.path.basename(f)), f) for f in files]
    if all(n for n, _ in numbered):
        keyed = sorted((int(n[-1]), n[-1], f) for n, f in numbered)
        for (a, sa, fa), (b, _, fb) in zip(keyed, keyed[1:]):
            if b == a:
                raise InputError(source, f"two files for frame {a}: {fa} and {fb} (a pattern "
                                         f"that matches one file a frame, such as a printf "
                                         f"%04d field, tells them apart)")
            if b != a + 1:
                name = os.path.basename(fa)
                i = name.rfind(sa)
                missing = os.path.join(os.path.dirname(fa),
                                       name[:i] + str(a + 1).zfill(len(sa)) + name[i + len(sa):])
                raise InputError(source, f"missing frame {a + 1}: {missing}") if given else \
                    InputError(missing, f"missing frame {a + 1} of the sequence matching "
                                        f"{pattern!r}")
        return [f for _, _, f in keyed]
    return sorted(files)


def load_frame_mesh(path, smooth=False):
    """(triangles float32, normals) of one frame file; NaN or infinite vertices are an error
    naming the file."""
    verts, faces = load_mesh_arrays(path)
    tris = as_triangles(verts[faces], source=path)
    normals = smooth_normals(verts, faces) if smooth else flat_normals(tris)
    return tris, normals


# --------------------------------------------------------------------------------------
# The animation
# --------------------------------------------------------------------------------------
@dataclass
class Part:
    """One shape's triangles. ``motion(i, t)`` gives its (triangles, normals) at frame i /
    time t; None means static. ``material``: an index into the scene's materials, or one per
    triangle (static parts only)."""
    tris: np.ndarray
    normals: np.ndarray
    material: object
    motion: object = None


class Animation:
    """Frames of an animated scene. ``scene(i)`` -> CompiledScene at time ``i / fps``.

    name : str; base : a CompiledScene for everything but geometry (materials, lights, film,
    camera); parts : [Part]; frames : default frame count; camera : callable(t) -> camera
    dict or None; info : dict reported with a run (e.g. which physics ran); inputs : files read.
    """

    def __init__(self, name, base, parts, frames, fps=DEFAULT_FPS, camera=None, info=None,
                 inputs=(), source=None, max_frames=None, frames_key=None):
        self.name = name
        self.base = base
        self.parts = parts
        self.frames = int(frames)
        self.fps = float(fps)
        self.camera = camera
        self.info = dict(info or {})
        self.inputs = [os.path.abspath(p) for p in inputs]
        self.source = source or name
        self.max_frames = max_frames        # a frame sequence has only so many frames
        self.frames_key = frames_key        # the scene key the default frame count came from

    def time(self, i):
        return i / self.fps

    def check(self, frames):
        """Check, before any output, that ``frames`` frames can be produced (a sequence has
        them all, none has NaN vertices, no keyframed shape moves beyond the coordinate bound,
        and the camera can be placed at every frame). Returns (tri_mag, eye_mag), per frame
        (frames,) bounds on the magnitude of every coordinate of the shapes a scene file
        places (still, keyframed or read from a sequence) and of the camera's eye; a built-in
        simulation's parts, made at the scale of the scene around them, are not in tri_mag."""
        if frames > MAX_FRAMES:
            if self.frames_key is not None and frames == self.frames:
                raise InputError(self.source, f"key '{self.frames_key}': the sequence has "
                                              f"{frames} files: {too_many_frames(frames)} (give "
                                              f"a frame count)")
            raise ParameterError("frames", too_many_frames(frames))
        if self.max_frames is not None and frames > self.max_frames:
            if frames != self.frames:               # a count given later (--frames)
                raise ParameterError("frames", f"{frames} asked for, but the sequence of "
                                               f"{self.source} has only {self.max_frames}")
            raise InputError(self.source, f"key 'animation.frames': {frames} frames asked for, "
                                          f"but the sequence has only {self.max_frames}")
        times = np.arange(frames) / self.fps
        tri_mag = np.zeros(frames)
        for p in self.parts:
            if isinstance(p.motion, FrameSequence):
                tri_mag = np.maximum(tri_mag, p.motion.check(frames))
            elif isinstance(p.motion, RigidMotion):
                tri_mag = np.maximum(tri_mag, p.motion.check(times, self.source))
            elif p.motion is None:
                tri_mag = np.maximum(tri_mag, float(np.abs(p.tris).max(initial=0)))
        check_camera = getattr(self.camera, "check", None)      # a scene file's camera track
        if check_camera is not None:                            # (built-in paths are fixed)
            check_camera(times)
        if self.camera is None:
            eye_mag = np.full(frames, float(np.abs(self.base.camera["eye"]).max()))
        elif hasattr(self.camera, "eyes"):
            eye_mag = np.abs(self.camera.eyes(times)).max(axis=1)
        else:                                   # a built-in path: placed frame by frame
            eye_mag = np.array([float(np.abs(self.camera(t)["eye"]).max()) for t in times])
        return tri_mag, eye_mag

    def geometry(self, i):
        """(triangles float32 (n, 3, 3), normals float32 (n, 3, 3), material int32 (n,))."""
        t = self.time(i)
        T, N, M = [], [], []
        for p in self.parts:
            if p.motion is None:
                tris, nrm = p.tris, p.normals
            else:
                tris, nrm = p.motion(i, t)
            T.append(tris)
            N.append(nrm)
            M.append(np.full(len(tris), p.material, np.int32) if np.isscalar(p.material)
                     else np.asarray(p.material, np.int32))
        tris = as_triangles(np.concatenate(T) if len(T) > 1 else T[0], source=self.source)
        return tris, np.concatenate(N).astype(np.float32), np.concatenate(M)

    def scene(self, i):
        tris, normals, material = self.geometry(i)
        cam = self.base.camera if self.camera is None else self.camera(self.time(i))
        V = tris.reshape(-1, 3)
        return replace(self.base, triangles=tris, normals=normals, material=material,
                       camera=cam, vertices=V,
                       faces=np.arange(len(V), dtype=np.int32).reshape(-1, 3))


class RigidMotion:
    """A shape moved by a keyframed rigid transform; ``key`` names the keyframes in errors."""

    def __init__(self, tris, normals, track, key="keyframes"):
        self.tris = np.asarray(tris, np.float64)
        self.normals = np.asarray(normals, np.float64)
        self.track = track
        self.key = key

    def check(self, times, source):
        """Refuse (InputError naming ``source``, the keyframes and the time) a transform that
        carries a vertex beyond MAX_COORDINATE at any of ``times``, before any frame is made.
        The transformed corners of the shape's box bound it at every time in one vectorised
        pass; only the times where they come near the bound (a rotated box's corners reach
        farther than its shape) are decided vertex by vertex, as ``__call__`` places them.
        Returns the bound per time (``reach``)."""
        k = self.track.at_times(times)
        reach = self.reach(k)
        if within_bound(reach):
            self._check_not_coarse(k, reach, times, source)
            return reach
        near = np.flatnonzero(~(reach <= MAX_COORDINATE))
        # a shape holding still (before the first key, after the last) is placed once
        held = np.concatenate([k["rotate"], k["scale"], k["translate"]], axis=1)[near]
        for f in near[np.sort(np.unique(held, axis=0, return_index=True)[1])]:
            v = self._placed(self.track.at(times[f]))
            if not within_bound(v):
                _fail(source, self.key, f"at time {times[f]:g} the shape reaches a coordinate of "
                                        f"magnitude {beyond_bound_text(np.abs(v).max())}, "
                                        f"beyond {MAX_COORDINATE:.0e}")
        return reach

    def _check_not_coarse(self, k, reach, times, source):
        """Refuse, as a still shape's placement is refused (``hwbvh.config.MAX_FLOAT32_ROUNDING``),
        a time at which the shape lies so far from the origin against its size that float32
        rounds its coordinates by more than that share of its size: it would be traced flat or
        empty there. Its size at a time is bounded above by the diagonal of its box under
        the time's scale (no rotation makes a side longer), its coordinates by ``reach``, so
        only shapes surely that coarse are refused."""
        side = self.tris.reshape(-1, 3).max(axis=0) - self.tris.reshape(-1, 3).min(axis=0)
        size = np.linalg.norm(side * np.abs(k["scale"]), axis=1)
        step = np.spacing(reach.astype(np.float32)).astype(np.float64)
        coarse = np.flatnonzero((size > 0) & (step / 2 > MAX_FLOAT32_ROUNDING * size))
        if len(coarse):
            f = coarse[0]
            _fail(source, self.key, f"at time {times[f]:g} the shape collapses: this far from "
                                    f"the origin its coordinates round to float32 numbers "
                                    f"{step[f]:.3g} apart, coarse against its size (at most "
                                    f"{size[f]:.3g})")

    def reach(self, k):
        """Per time of the track's values ``k`` (``Track.at_times``), a bound on the magnitude
        of every coordinate the shape reaches: its box's transformed corners, plus their
        float64 rounding against the vertices' (a few ulps of the terms summed)."""
        lo, hi = self.tris.reshape(-1, 3).min(axis=0), self.tris.reshape(-1, 3).max(axis=0)
        corners = np.array(np.meshgrid(*zip(lo, hi), indexing="ij")).reshape(3, 8).T
        A = euler_matrices(k["rotate"]) * k["scale"][:, None, :]          # R diag(scale)
        placed = np.einsum("fij,cj->fci", A, corners) + k["translate"][:, None, :]
        terms = np.abs(A) @ np.abs(corners).max(axis=0) + np.abs(k["translate"])
        return np.abs(placed).max(axis=(1, 2)) + CORNER_ROUNDING * terms.max(axis=1)

    def _placed(self, k):
        """The triangles under the channel values ``k`` of one time."""
        return (self.tris * k["scale"]) @ euler_matrix(k["rotate"]).T + k["translate"]

    def __call__(self, i, t):
        k = self.track.at(t)
        tris = self._placed(k)
        n = (self.normals / k["scale"]) @ euler_matrix(k["rotate"]).T
        n /= np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-30)
        return tris, n


class FrameSequence:
    """A shape read from one mesh file per frame. ``where``: the scene file and key that name
    the sequence ("scene.json: key 'shapes[1].pattern'"; None for a pattern given alone),
    which a frame file's error then starts with, as the first frame's does."""

    def __init__(self, files, smooth=False, where=None):
        self.files = files
        self.smooth = smooth
        self.where = where

    def _load(self, f):
        try:
            return load_frame_mesh(f, self.smooth)
        except InputError as e:
            if self.where is None:
                raise
            raise InputError(self.where, str(e)) from None

    def check(self, frames):
        """Load the first ``frames`` files (each is refused on its own); returns the largest
        coordinate magnitude of each."""
        return np.array([float(np.abs(self._load(f)[0]).max(initial=0))
                         for f in self.files[:frames]])

    def __call__(self, i, t):
        if i >= len(self.files):
            raise InputError(self.files[-1], f"frame {i} asked for, but the sequence has "
                                             f"{len(self.files)} frames")
        return self._load(self.files[i])


def _check_camera(source, times, eye, target, up):
    """Refuse the first of ``times`` whose camera (rows of ``eye``, ``target``, ``up``) has its
    eye on its target (the still scene's rule, scenes.loader) or a zero up (no roll to take
    from it)."""
    on_target = np.all(eye == target, axis=1)
    no_up = ~np.any(up, axis=1)
    bad = on_target | no_up
    if bad.any():
        f = int(np.argmax(bad))
        problem = "eye equals target" if on_target[f] else "up is zero"
        _fail(source, "animation.camera", f"{problem} at time {times[f]:g}")


def _camera_fn(track, base, source):
    """The camera at a time, a callable; its ``check(times)`` checks the track at all of
    ``times`` at once, before any frame is made."""
    def cam(t):
        k = track.at(t)
        c = dict(base)
        c.update(eye=k["eye"], target=k["target"], up=k["up"], fov=float(k["fov"]))
        _check_camera(source, [t], c["eye"][None], c["target"][None], c["up"][None])
        return c

    def check(times):
        k = track.at_times(times)
        _check_camera(source, times, k["eye"], k["target"], k["up"])
    cam.check = check
    cam.eyes = lambda times: track.at_times(times)["eye"]
    return cam


def from_scene_dict(d, source=None, fps=None):
    """An Animation from a scene dict whose shapes may carry ``keyframes`` or be ``frames``
    sequences (see the module docstring)."""
    source = source or d.get("_source", "<scene>")
    Ctx(source).keys(d, SCENE_KEYS + ("animation",), "")      # a moving scene's top level
    anim = d.get("animation", {})
    _check_keys(source, anim, ANIMATION_KEYS, "animation")
    frames = anim.get("frames")
    if frames is not None and (not is_integer(frames) or frames < 1):
        _fail(source, "animation.frames", f"expected a positive integer, got {written(frames)}")
    if frames is not None and frames > MAX_FRAMES:
        _fail(source, "animation.frames", too_many_frames(frames))
    shapes = d.get("shapes")
    if not isinstance(shapes, (list, tuple)) or not shapes:
        _fail(source, "shapes", "expected a non-empty list")
    static = {k: v for k, v in d.items() if k not in ("animation", "shapes")}
    scene_dir = scene_directory(d, source)
    own = scene_file(d, source)
    parts, inputs = [], [own] if os.path.exists(str(own)) else []
    base = None
    max_frames = None
    shortest = None                 # the key of the shortest frames sequence
    for i, sh in enumerate(shapes):
        path = f"shapes[{i}]"
        if not isinstance(sh, dict):
            _fail(source, path, "expected an object")
        if sh.get("type") == "frames":
            _check_keys(source, sh, FRAMES_SHAPE_KEYS, path)
            pat = sh.get("pattern")
            if not isinstance(pat, str) or not pat:
                _fail(source, f"{path}.pattern", "missing, empty or not a string")
            if "\0" in pat:
                _fail(source, f"{path}.pattern", "a path cannot hold a NUL byte")
            smooth = sh.get("smooth", False)
            if not isinstance(smooth, (bool, np.bool_)):
                _fail(source, f"{path}.smooth", f"expected true or false, got {written(smooth)}")
            full = pat if os.path.isabs(pat) else os.path.join(scene_dir, pat)
            # what names the sequence in its errors: a pattern given alone (pattern_scene)
            # names itself, a scene file's names the file and key
            where = None if os.path.abspath(source) == full else f"{source}: key '{path}.pattern'"
            files = expand_pattern(full, where)
            inputs += files
            if max_frames is None or len(files) < max_frames:
                max_frames, shortest = len(files), f"{path}.pattern"
            one = dict(static, shapes=[{"type": "mesh", "filename": files[0],
                                        "material": sh.get("material"), "smooth": smooth}])
            try:
                c = compile_scene(one, source=source, first_shape=i)
            except InputError as e:
                # the first frame is read as a mesh shape: its errors belong to the pattern
                as_mesh = f"key '{path}.filename'"
                if not e.problem.startswith(as_mesh):
                    raise
                raise InputError(e.source, f"key '{path}.pattern'{e.problem[len(as_mesh):]}") \
                    from None
            parts.append(Part(c.triangles, c.normals, int(c.material[0]),
                              FrameSequence(files, smooth, where)))
        else:
            keys = sh.get("keyframes")
            plain = {k: v for k, v in sh.items() if k != "keyframes"}
            c = compile_scene(dict(static, shapes=[plain]), source=source, first_shape=i)
            if plain.get("type") == "mesh" and isinstance(plain.get("filename"), str):
                fn = plain["filename"]
                inputs.append(fn if os.path.isabs(fn) else os.path.join(scene_dir, fn))
            motion = None
            if keys is not None:
                motion = RigidMotion(c.triangles, c.normals, rigid_track(source, keys, f"{path}.keyframes"),
                                     f"{path}.keyframes")
            parts.append(Part(c.triangles, c.normals, int(c.material[0]), motion))
        base = base or c
    camera = None
    if "camera" in anim:
        camera = _camera_fn(camera_track(source, anim["camera"], "animation.camera", base.camera),
                            base.camera, source)
    # the file's value is checked even where --fps replaces it, as every other key is
    f = _number(source, anim.get("fps", DEFAULT_FPS), "animation.fps", lo=MIN_FPS, hi=MAX_FPS)
    f = fps if fps is not None else f
    frames_key = None
    if frames is None:
        # a frame count given later (--frames) replaces this one; check() judges the final one
        frames = max_frames if max_frames is not None else \
            int(round(DEFAULT_ANIMATION_SECONDS * f))
        frames_key = shortest
    return Animation(str(d.get("name", "scene")), base, parts, frames, f, camera,
                     inputs=inputs, source=source, max_frames=max_frames, frames_key=frames_key)


def pattern_scene(pattern, smooth=False):
    """A scene dict for a frame pattern of mesh files: framed on the first frame, a point
    light, a plain diffuse material (as a mesh file alone)."""
    files = expand_pattern(pattern)
    stem = re.sub(r"[_\-.]*(%0?\d*d|[*?\[].*)$", "", os.path.splitext(os.path.basename(pattern))[0])
    d = mesh_scene(files[0], name=named_after_file(pattern, stem or "frames"))
    d["shapes"] = [{"type": "frames", "pattern": os.path.abspath(pattern), "material": "default",
                    "smooth": smooth}]
    d["_source"] = pattern
    return d


# --------------------------------------------------------------------------------------
# Built-in animations
# --------------------------------------------------------------------------------------
def _materials():
    from .builtin import _materials as m
    return m()


def _film(width, height, spp, max_depth):
    return {"film": {"width": width, "height": height, "spp": spp},
            "integrator": {"type": "whitted", "max_depth": max_depth, "ambient": [0.05] * 3}}


def _floor(size):
    s = float(size)
    return {"type": "quad", "corners": [[-s, 0, -s], [s, 0, -s], [s, 0, s], [-s, 0, s]],
            "material": "floor"}


def _base_scene(name, shapes, camera, lights, width, height, spp, max_depth, background):
    mats = _materials()
    mats["floor"] = {"type": "diffuse", "reflectance": [0.6, 0.6, 0.6]}
    d = {"type": "scene", "name": name, "camera": camera, "lights": lights,
         "materials": mats, "shapes": shapes, "background": background,
         **_film(width, height, spp, max_depth)}
    return d, compile_scene(d, source=name)


def _unit_height(tris, source=None):
    """Scale to 1 unit tall, centred on the y axis, standing on y = 0; a mesh more than twice
    as wide as it is tall (a flat one included) to 2 units wide instead, so that it stays in
    the frame and on the floor."""
    t = np.asarray(tris, np.float64)
    lo, hi = t.reshape(-1, 3).min(0), t.reshape(-1, 3).max(0)
    size = max(hi[1] - lo[1], 0.5 * max(hi[0] - lo[0], hi[2] - lo[2]))
    if not size > 0:
        raise InputError(source or "mesh", "every vertex is at one point: nothing to explode")
    c = (lo + hi) / 2
    c[1] = lo[1]
    return (t - c) * (1.0 / size)


class Explosion:
    """Every triangle flies off as a rigid fragment: outward and upward from the mesh's
    centre, spinning about its centroid, under gravity, until it lands on the floor (its
    landing time solved exactly, so frames are independent of each other)."""

    def __init__(self, tris, seed=0, at=EXPLODE_AT, speed=EXPLODE_SPEED):
        rng = np.random.default_rng(seed)
        self.tris = tris
        self.c = tris.mean(axis=1)                                   # centroids
        self.local = tris - self.c[:, None, :]
        centre = self.c.mean(axis=0)
        out = self.c - centre
        out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-9)
        self.v = out * speed * rng.uniform(0.4, 1.0, (len(tris), 1)) + [0, 0.8 * speed, 0]
        axis = rng.normal(size=(len(tris), 3))
        self.axis = axis / np.linalg.norm(axis, axis=1, keepdims=True)
        self.omega = rng.uniform(2.0, 12.0, len(tris))                # rad/s
        self.at = at
        radius = np.linalg.norm(self.local, axis=2).max(axis=1)
        rest = radius                                                # centroid height at rest
        # landing: c_y + v_y s - g s^2 / 2 = rest (the later root)
        vy, h = self.v[:, 1], self.c[:, 1] - rest
        self.land = (vy + np.sqrt(np.maximum(vy * vy + 2 * GRAVITY * h, 0))) / GRAVITY

    def __call__(self, i, t):
        s = np.minimum(max(t - self.at, 0.0), self.land)[:, None]
        c = self.c + self.v * s + 0.5 * np.array([0, -GRAVITY, 0]) * s * s
        ang = self.omega * s[:, 0]
        # Rodrigues' rotation of each fragment about its centroid
        k = self.axis[:, None, :]
        p = self.local
        cos, sin = np.cos(ang)[:, None, None], np.sin(ang)[:, None, None]
        rot = p * cos + np.cross(k, p) * sin + k * np.sum(k * p, axis=2, keepdims=True) * (1 - cos)
        tris = rot + c[:, None, :]
        return tris, flat_normals(tris)


def _check_generated(what, requested, generated, rest):
    """Refuse, before making it, a generated mesh of ``generated`` triangles (for about
    ``requested``) that with the ``rest`` of the scene's triangles would not fit one tree."""
    total = generated + rest
    if total > MAX_PRIMITIVES:
        raise ParameterError("triangles", f"{requested} makes a {what} of {generated} triangles, "
                                          f"{total} with the rest of the scene: more than the "
                                          f"2^24 = {MAX_PRIMITIVES} a tree holds")


def exploding(width=320, height=240, spp=1, max_depth=3, mesh=None, triangles=GENERATED_TRIANGLES,
              seed=0):
    """A mesh (the file ``mesh``, else a generated sphere of about ``triangles`` triangles)
    breaking into its triangles (after Exploding Dragon)."""
    from .meshes import sphere
    src = mesh
    if src is not None:
        verts, faces = load_mesh_arrays(src)
        tris = as_triangles(verts[faces], source=src)
        what = os.path.basename(src)
    cam = {"type": "perspective", "eye": [0.0, 1.6, 3.6], "target": [0.0, 0.35, 0.0], "fov": 45.0}
    lights = [{"type": "point", "position": [1.5, 3.0, 2.0], "intensity": [14, 14, 13]}]
    d, base = _base_scene("exploding", [_floor(3.0)], cam, lights, width, height, spp,
                          max_depth, [0.15, 0.15, 0.18])
    if src is None:
        n_lon = max(8, int(math.sqrt(triangles)))
        n_lat = max(4, triangles // (2 * n_lon) + 1)
        _check_generated("sphere", triangles, 2 * n_lon * (n_lat - 1), len(base.triangles))
        tris = sphere(n_lat, n_lon)
        what = f"generated sphere ({len(tris)} triangles)"
    tris = _unit_height(tris, src)
    parts = [Part(base.triangles, base.normals, base.material),
             Part(tris, flat_normals(tris), base.mat_names.index("red"), Explosion(tris, seed))]
    return Animation("exploding", base, parts, frames=120, info={"mesh": what},
                     inputs=[src] if src else [])


@njit(cache=True)
def _cloth_step(x, xp, cons, rest, dt, iters, sphere_c, sphere_r, thickness, damping, friction):
    """One position-based dynamics step (Mueller et al. 2007): Verlet prediction under
    gravity, Gauss-Seidel distance constraints, then sphere and floor collisions with
    friction."""
    n = x.shape[0]
    g = -9.81 * dt * dt
    for i in range(n):
        for k in range(3):
            v = (x[i, k] - xp[i, k]) * damping
            xp[i, k] = x[i, k]
            x[i, k] += v
        x[i, 1] += g
    for _ in range(iters):
        for c in range(cons.shape[0]):
            a = cons[c, 0]
            b = cons[c, 1]
            dx = x[b, 0] - x[a, 0]
            dy = x[b, 1] - x[a, 1]
            dz = x[b, 2] - x[a, 2]
            ln = math.sqrt(dx * dx + dy * dy + dz * dz)
            if ln > 1e-12:
                s = 0.5 * (ln - rest[c]) / ln
                x[a, 0] += s * dx
                x[a, 1] += s * dy
                x[a, 2] += s * dz
                x[b, 0] -= s * dx
                x[b, 1] -= s * dy
                x[b, 2] -= s * dz
    r = sphere_r + thickness
    for i in range(n):
        dx = x[i, 0] - sphere_c[0]
        dy = x[i, 1] - sphere_c[1]
        dz = x[i, 2] - sphere_c[2]
        d = math.sqrt(dx * dx + dy * dy + dz * dz)
        contact = False
        if d < r and d > 1e-12:
            x[i, 0] = sphere_c[0] + dx * r / d
            x[i, 1] = sphere_c[1] + dy * r / d
            x[i, 2] = sphere_c[2] + dz * r / d
            contact = True
        if x[i, 1] < thickness:
            x[i, 1] = thickness
            contact = True
        if contact:        # friction: keep only part of the velocity along the surface
            for k in range(3):
                xp[i, k] = x[i, k] - (x[i, k] - xp[i, k]) * (1.0 - friction)


class Cloth:
    """A square sheet, held flat above a sphere and released: it falls, drapes over the
    sphere and settles on the floor. State advances frame by frame; asking for an earlier
    frame restarts the simulation."""

    def __init__(self, n, size=2.0, height=1.4, sphere_c=(0.0, 0.5, 0.0), sphere_r=0.5, fps=DEFAULT_FPS):
        xs = np.linspace(-size / 2, size / 2, n + 1)
        X, Z = np.meshgrid(xs, xs, indexing="ij")
        # a small tilt so the sheet does not balance on the sphere's top
        self.x0 = np.stack([X + 0.15, height + 0.05 * X, Z + 0.1], -1).reshape(-1, 3)
        idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
        a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
        c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
        self.faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
        pairs = [np.stack([idx[:-1, :].ravel(), idx[1:, :].ravel()], 1),
                 np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1),
                 np.stack([a, c], 1), np.stack([b, d], 1)]
        self.cons = np.ascontiguousarray(np.concatenate(pairs), np.int64)
        self.rest = np.linalg.norm(self.x0[self.cons[:, 1]] - self.x0[self.cons[:, 0]], axis=1)
        self.sphere_c = np.asarray(sphere_c, np.float64)
        self.sphere_r = float(sphere_r)
        self.thickness = 0.01 * size
        self.fps = fps
        self._reset()

    def _reset(self):
        self.frame = 0
        self.x = self.x0.copy()
        self.xp = self.x0.copy()

    def __call__(self, i, t):
        if i < self.frame:
            self._reset()
        dt = 1.0 / (self.fps * CLOTH_SUBSTEPS)
        while self.frame < i:
            for _ in range(CLOTH_SUBSTEPS):
                _cloth_step(self.x, self.xp, self.cons, self.rest, dt, CLOTH_ITERATIONS,
                            self.sphere_c, self.sphere_r, self.thickness, 0.995, 0.6)
            self.frame += 1
        return self.x[self.faces], smooth_normals(self.x, self.faces)


def cloth(width=320, height=240, spp=1, max_depth=3, triangles=GENERATED_TRIANGLES,
          fps=DEFAULT_FPS):
    """A cloth sheet of about ``triangles`` triangles falling and draping over a sphere (after
    the thesis' Cloth scene), by position-based dynamics in Numba."""
    n = max(2, int(round(math.sqrt(triangles / 2))))
    cam = {"type": "perspective", "eye": [0.0, 2.2, 3.4], "target": [0.0, 0.45, 0.0], "fov": 45.0}
    lights = [{"type": "point", "position": [1.5, 3.5, 2.0], "intensity": [16, 16, 15]}]
    ball = {"type": "sphere", "center": [0.0, 0.5, 0.0], "radius": 0.5, "subdiv": [24, 48],
            "material": "white"}
    d, base = _base_scene("cloth", [_floor(3.0), ball], cam, lights, width, height, spp,
                          max_depth, [0.2, 0.2, 0.25])
    _check_generated("sheet", triangles, 2 * n * n, len(base.triangles))
    sim = Cloth(n, fps=fps)
    parts = [Part(base.triangles, base.normals, base.material)]
    tris0, n0 = sim(0, 0.0)
    parts.append(Part(tris0, n0, base.mat_names.index("red"), sim))
    return Animation("cloth", base, parts, frames=120, fps=fps,
                     info={"grid": [n, n], "physics": "position-based dynamics"})


def _bowl(radius, center, n_lat=24, n_lon=48):
    """The lower half of a sphere, open at the top, as an indexed mesh."""
    from .meshes import uv_sphere
    V, F = uv_sphere(n_lat, n_lon, radius, center)
    keep = (V[F][:, :, 1] <= center[1] + 1e-9).all(axis=1)
    return V, F[keep]


def _import_pybullet():
    """pybullet, or None (it is an optional extra)."""
    try:
        import pybullet
    except ImportError:
        return None
    return pybullet


class Marbles:
    """Rigid poses of ``count`` marbles dropped into a bowl, frame by frame: through Bullet
    (pybullet, DIRECT mode, as the thesis' mike_rt drove its dynamic scenes) or, without it,
    analytically: each marble falls straight down onto a resting place packed in rings up the
    bowl's wall, released one after another, bottom ring first."""

    def __init__(self, count, marble_r, bowl_r, bowl_c, bowl_mesh, physics, fps, seed=0):
        self.count, self.r, self.R = count, marble_r, bowl_r
        self.c = np.asarray(bowl_c, np.float64)
        self.fps = fps
        rng = np.random.default_rng(seed)
        self.rest = self._rest_places()
        self.release = np.arange(count) * 0.08                       # s between releases
        self.drop_h = self.c[1] + 0.3 + rng.uniform(0, 0.4, count)
        self.spin = rng.normal(size=(count, 3))
        self.physics = physics
        self.poses = []                                              # per frame (pos, rot)
        if physics == "pybullet":
            self._bullet_setup(bowl_mesh, rng)

    def _rest_places(self):
        """Rings of marbles resting on the bowl's inner wall (the centre at distance R - r
        from the bowl's centre), from the bottom up."""
        places, rr = [], self.R - self.r
        theta = 0.0
        while len(places) < self.count:
            if theta == 0.0:
                ring = [0.0]
            else:
                circ = 2 * np.pi * rr * np.sin(theta)
                k = max(1, int(circ / (2.05 * self.r)))
                ring = list(np.arange(k) * 2 * np.pi / k + theta)
            for phi in ring:
                if len(places) < self.count:
                    places.append(self.c + rr * np.array([np.sin(theta) * np.cos(phi), -np.cos(theta),
                                                          np.sin(theta) * np.sin(phi)]))
            theta += 2.05 * self.r / rr
            if theta > np.pi / 2:                                    # the rim: a second layer
                theta, rr = 0.0, rr - 2.05 * self.r
        return np.array(places)

    def _bullet_setup(self, bowl_mesh, rng):
        p = _import_pybullet()
        self.p = p
        self.cid = p.connect(p.DIRECT)
        p.setGravity(0, -GRAVITY, 0, physicsClientId=self.cid)
        p.setTimeStep(1.0 / BULLET_HZ, physicsClientId=self.cid)
        V, F = bowl_mesh
        shape = p.createCollisionShape(p.GEOM_MESH, vertices=V.tolist(), indices=F.ravel().tolist(),
                                       flags=p.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=self.cid)
        p.createMultiBody(0, shape, physicsClientId=self.cid)
        ball = p.createCollisionShape(p.GEOM_SPHERE, radius=self.r, physicsClientId=self.cid)
        self.bodies = []
        for i in range(self.count):
            start = self.rest[i].copy()
            start[1] = self.drop_h[i] + 0.25 * i * self.r
            b = p.createMultiBody(0.01, ball, basePosition=start.tolist(), physicsClientId=self.cid)
            p.changeDynamics(b, -1, restitution=0.3, lateralFriction=0.5, rollingFriction=1e-4,
                             physicsClientId=self.cid)
            self.bodies.append(b)
        self.steps = 0

    def _bullet_pose(self, i):
        p = self.p
        per_frame = BULLET_HZ / self.fps
        while len(self.poses) <= i:
            target = int(round(len(self.poses) * per_frame))
            while self.steps < target:
                p.stepSimulation(physicsClientId=self.cid)
                self.steps += 1
            pos = np.empty((self.count, 3))
            rot = np.empty((self.count, 3, 3))
            for k, b in enumerate(self.bodies):
                x, q = p.getBasePositionAndOrientation(b, physicsClientId=self.cid)
                pos[k] = x
                rot[k] = np.asarray(p.getMatrixFromQuaternion(q)).reshape(3, 3)
            self.poses.append((pos, rot))
        return self.poses[i]

    def _analytic_pose(self, t):
        s = np.maximum(t - self.release, 0.0)
        y = self.drop_h - 0.5 * GRAVITY * s * s
        fall_end = np.sqrt(2 * np.maximum(self.drop_h - self.rest[:, 1], 0) / GRAVITY)
        pos = self.rest.copy()
        pos[:, 1] = np.maximum(y, self.rest[:, 1])
        ang = 4.0 * np.minimum(s, fall_end)                          # spin while falling
        rot = np.stack([euler_matrix(np.degrees(a * sp)) for a, sp in zip(ang, self.spin)])
        return pos, rot

    def pose(self, i, t):
        return self._bullet_pose(i) if self.physics == "pybullet" else self._analytic_pose(t)


class MarbleMotion:
    def __init__(self, sim, tris, normals):
        self.sim = sim
        self.tris = tris            # one marble, centred at the origin
        self.normals = normals

    def __call__(self, i, t):
        pos, rot = self.sim.pose(i, t)
        tris = np.einsum("mij,nvj->mnvi", rot, self.tris) + pos[:, None, None, :]
        nrm = np.einsum("mij,nvj->mnvi", rot, self.normals)
        return tris.reshape(-1, 3, 3), nrm.reshape(-1, 3, 3)


def marbles(width=320, height=240, spp=1, max_depth=3, count=40, subdiv=(8, 16),
            physics="auto", fps=DEFAULT_FPS, seed=0):
    """``count`` marbles dropped into a bowl (after the thesis' Marbles scene). ``physics``:
    "pybullet" (Bullet, an optional extra), "analytic", or "auto" (Bullet when importable)."""
    from .meshes import uv_sphere
    if physics not in ("auto", "pybullet", "analytic"):
        raise ParameterError("physics", f"unknown physics {physics!r} (choose from auto, pybullet, analytic)")
    if physics != "analytic" and _import_pybullet() is None:
        if physics == "pybullet":
            raise ParameterError("physics", "pybullet is not installed (pip install 'pybullet>=3.2')")
        physics = "analytic"
    elif physics == "auto":
        physics = "pybullet"
    R, bc = 1.0, np.array([0.0, 1.0, 0.0])
    V, F = _bowl(R, bc)
    cam = {"type": "perspective", "eye": [0.0, 2.6, 2.6], "target": [0.0, 0.55, 0.0], "fov": 45.0}
    lights = [{"type": "directional", "direction": [-0.3, -1.0, -0.4], "irradiance": [2.4, 2.3, 2.1]}]
    d, base = _base_scene("marbles", [_floor(3.0), {"type": "triangles", "data": V[F].tolist(),
                                                    "material": "white"}],
                          cam, lights, width, height, spp, max_depth, [0.5, 0.6, 0.8])
    parts = [Part(base.triangles, base.normals, base.material)]
    r = 0.08
    MV, MF = uv_sphere(subdiv[0], subdiv[1], r)
    one, one_n = MV[MF], (MV / r)[MF]
    sim = Marbles(count, r, R, bc, (V, F), physics, fps, seed)
    kinds = ["glass", "mirror", "red", "green"]
    for k, name in enumerate(kinds):          # one part per material, marbles k, k+4, ...
        sel = np.arange(k, count, len(kinds))
        if len(sel):
            sub = _Subset(sim, sel)
            parts.append(Part(*MarbleMotion(sub, one, one_n)(0, 0.0), base.mat_names.index(name),
                              MarbleMotion(sub, one, one_n)))
    return Animation("marbles", base, parts, frames=120, fps=fps,
                     info={"physics": physics, "marbles": count})


class _Subset:
    """The poses of some of the marbles."""

    def __init__(self, sim, sel):
        self.sim, self.sel = sim, sel

    def pose(self, i, t):
        pos, rot = self.sim.pose(i, t)
        return pos[self.sel], rot[self.sel]


def flythrough(width=320, height=240, spp=1, max_depth=3, slats=120, fps=DEFAULT_FPS):
    """A camera flying through the static room scene: the geometry, and so the tree, never
    changes (the baseline)."""
    from .builtin import room
    d = room(width=width, height=height, spp=spp, max_depth=max_depth, slats=slats)
    base = compile_scene(d, source="flythrough")

    def cam(t):
        a = 0.6 * np.pi + 0.8 * np.pi * min(t / 4.0, 1.0)
        c = dict(base.camera)
        c["eye"] = np.array([2.6 * np.cos(a), 1.5 + 0.3 * np.sin(2 * a), -0.3 + 2.2 * np.sin(a)])
        c["target"] = np.array([0.6 * np.cos(a + 0.9), 1.2, -1.0])
        return c
    return Animation("flythrough", base, [Part(base.triangles, base.normals, base.material)],
                     frames=120, fps=fps, camera=cam)


ANIMATIONS = {"exploding": exploding, "cloth": cloth, "marbles": marbles, "flythrough": flythrough}


def load_animation(spec, width=None, height=None, spp=None, max_depth=None, fps=None, **params):
    """An :class:`Animation` from a built-in animation name (``params`` go to it), a frame
    pattern of mesh files, or anything ``load_scene`` reads (a scene file, which may animate,
    a static built-in scene, a mesh file)."""
    spec = spec_path(spec)
    film = {k: v for k, v in (("width", width), ("height", height), ("spp", spp),
                              ("max_depth", max_depth)) if v is not None}
    if fps is not None and (isinstance(fps, bool) or not isinstance(fps, (int, float, np.number))
                            or not MIN_FPS <= fps <= MAX_FPS):
        raise ParameterError("fps", f"must be a frame rate in [{MIN_FPS}, {MAX_FPS}], got "
                                    f"{fps!r}")
    if spec in ANIMATIONS:
        fn = ANIMATIONS[spec]
        accepted = inspect.signature(fn).parameters
        for k in params:
            if params[k] is not None and k not in accepted:
                raise ParameterError(k, f"the built-in animation '{spec}' has no parameter {k!r}")
        n = params.get("triangles")
        if n is not None and params.get("mesh") is not None:
            raise ParameterError("triangles", "makes a generated mesh: a mesh given brings its "
                                              "own triangles")
        if n is not None and (not is_integer(n) or not 1 <= n <= MAX_PRIMITIVES):
            # the command line's --triangles range: a tree holds at most 2^24 triangles
            raise ParameterError("triangles", f"must be an integer in 1..{MAX_PRIMITIVES}, "
                                              f"got {written(n)}")
        kw = {k: v for k, v in {**film, **params}.items() if v is not None and k in accepted}
        if fps is not None and "fps" in accepted:
            kw["fps"] = fps
        anim = fn(**kw)
        if fps is not None:
            anim.fps = float(fps)
        return anim
    extra = [k for k, v in params.items() if v is not None]
    if extra:
        takers = [name for name, fn in ANIMATIONS.items()
                  if extra[0] in inspect.signature(fn).parameters]
        raise ParameterError(extra[0], "no built-in animation takes it" if not takers else
                             f"only the built-in animation{'s' if len(takers) > 1 else ''} "
                             f"{' and '.join(takers)} take{'' if len(takers) > 1 else 's'} it")
    if is_pattern(spec) and not os.path.exists(spec):
        d = pattern_scene(spec)
    elif not os.path.exists(spec) and spec not in BUILTIN:
        raise InputError(spec, absent(spec, "no such animation, scene or file (built-in "
                                            f"animations: {', '.join(ANIMATIONS)}; scenes: "
                                            f"{', '.join(BUILTIN)})"))
    else:
        d = load_scene(spec)
    d = with_frame(d, **film)
    return from_scene_dict(d, fps=fps)
