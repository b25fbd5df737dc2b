"""Mitsuba 3 as a peer renderer: the same mesh scene, rendered by both, timed and compared.

For a scene that Mitsuba's ``direct`` integrator renders exactly as our Whitted renderer does
(diffuse surfaces with flat normals, point lights), :class:`MitsubaPeer` builds the matching
Mitsuba scene from a :class:`scenes.CompiledScene`:

* camera: ``perspective`` with the same look-at and the same vertical field of view
  (``fov_axis='y'``), the same resolution, an ``hdrfilm`` with a box filter (each sample lands
  in its own pixel, as in ours);
* sampler: ``stratified`` when spp is a perfect square (the strata of ours), else
  ``independent``; the same spp;
* geometry: one ``mi.Mesh`` filled from the triangle arrays, without vertex normals (so the
  shading normal is the face normal), with a ``twosided`` ``diffuse`` BSDF of the same
  reflectance (our surfaces are two-sided);
* lights: ``point`` emitters with the same RGB intensity (radiance kd/pi * I/r^2 * cos in both);
* integrator: ``direct`` with one emitter sample and no BSDF sample: one camera ray and, per
  hit, one shadow ray toward a light, as ours does for a diffuse scene under one light (ours
  skips the shadow ray where the light is behind the surface, and from a surface of
  reflectance 0; Mitsuba traces it).

Mitsuba has no ambient term and no background colour behind a scene without an environment
emitter, so :func:`neutral_scene` sets both to 0 in our scene; comparisons render that scene
with both renderers.

Time to image is load + render: filling the mesh and ``mi.load_dict`` (which builds Mitsuba's
BVH) plus ``mi.render`` and the copy of the image into NumPy. Image agreement is the relative
RMSE of ours against a Mitsuba render (seed a), set against Mitsuba's own seed-to-seed noise
(seed a against seed b): a ratio near 1 means the images differ by no more than two Mitsuba
renders do.

The LLVM variants need a libLLVM (15 or newer) that compiles every kernel Mitsuba asks for; one
that cannot aborts the whole process (LLVM 15 cannot select the ``fmaximum`` intrinsic that
some of Mitsuba's kernels use), so :func:`variant_status` first renders a small scene with the
same plugins in a child process.
"""
import dataclasses
import functools
import importlib.util
import math
import subprocess
import sys
import time

import numpy as np

from hwbvh.errors import InputError
from .config import FLAT_NORMAL_TOLERANCE, PROBE_TIMEOUT_SECONDS

VARIANTS = ("scalar_rgb", "llvm_ad_rgb")


def installed():
    """True when the ``mitsuba`` package can be imported (it is an optional extra)."""
    return importlib.util.find_spec("mitsuba") is not None


def unsupported(scene):
    """Why Mitsuba's ``direct`` integrator cannot render ``scene`` as ours does, or None."""
    used = np.unique(scene.material)
    for m in used:
        name = scene.mat_names[m]
        if scene.ior[m] > 0:
            return f"material '{name}' is a dielectric (only diffuse materials are supported)"
        if scene.kr[m].max() > 0:
            return f"material '{name}' reflects (only diffuse materials are supported)"
        if scene.ks[m] > 0:
            return f"material '{name}' has a highlight (only diffuse materials are supported)"
    for i, light in enumerate(scene.lights):
        if light["type"] != "point":
            return f"lights[{i}] is a {light['type']} light (only point lights are supported)"
    if not scene.lights:
        return "the scene has no light (a point light is needed)"
    tris = scene.triangles.astype(np.float64)
    face = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    face /= np.maximum(np.linalg.norm(face, axis=1, keepdims=True), 1e-300)
    n = scene.normals.astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-300)
    cos = np.abs(np.einsum("tk,tvk->tv", face, n))
    degenerate = np.linalg.norm(face, axis=1) == 0
    if ((cos < 1 - FLAT_NORMAL_TOLERANCE) & ~degenerate[:, None]).any():
        return "the mesh has smooth (per-vertex) normals (only flat normals are supported)"
    return None


def check_supported(scene):
    why = unsupported(scene)
    if why:
        raise InputError(scene.name, f"Mitsuba comparison: {why}")


def neutral_scene(scene):
    """``scene`` with no ambient term and a black background (Mitsuba has neither)."""
    return dataclasses.replace(scene, ambient=np.zeros(3), background=np.zeros(3))


def relative_rmse(image, reference):
    """sqrt(sum (image - reference)^2 / sum reference^2) over all pixels and channels."""
    a = np.asarray(image, np.float64)
    b = np.asarray(reference, np.float64)
    return float(np.sqrt(np.sum((a - b) ** 2) / max(np.sum(b * b), 1e-300)))


def _indexed(triangles):
    """(vertices (v, 3) float32, faces (n, 3) uint32) with shared corners stored once, as a mesh
    file holds them (Mitsuba then loads what it would load from the file)."""
    corners = np.ascontiguousarray(triangles.reshape(-1, 3), np.float32)
    keys = corners.view(np.dtype((np.void, 12))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    return corners[first], inverse.reshape(-1, 3).astype(np.uint32)


def _sampler(spp):
    side = math.isqrt(spp)
    return "stratified" if side * side == spp else "independent"


@functools.cache
def _probe_result(variant):
    """(True, "") when ``variant`` renders a small mesh scene in a child process, else (False,
    the reason). A child, because a libLLVM that cannot compile a kernel aborts the process."""
    code = ("import sys; from hwrt.mitsuba_peer import _probe; _probe(sys.argv[1])")
    try:
        p = subprocess.run([sys.executable, "-c", code, variant], capture_output=True, text=True,
                           timeout=PROBE_TIMEOUT_SECONDS)
    except subprocess.TimeoutExpired:
        return False, f"a small test render took more than {PROBE_TIMEOUT_SECONDS} s"
    if p.returncode == 0:
        return True, ""
    lines = [ln.strip() for ln in (p.stderr or "").splitlines() if ln.strip()]
    why = next((ln for ln in lines if "LLVM ERROR" in ln), None) or (lines[-1] if lines else "")
    why = why.split("! ")[0].split(". ")[0][:160]          # its first sentence
    return False, why or f"a small test render failed (exit status {p.returncode})"


def variant_status(variant):
    """(usable, reason): whether this Mitsuba variant works here, and why not."""
    if not installed():
        return False, "mitsuba is not installed (pip install 'mitsuba>=3.5')"
    import mitsuba as mi
    if variant not in mi.variants():
        return False, f"this mitsuba build has no variant {variant}"
    if variant.startswith("scalar"):
        return True, ""
    return _probe_result(variant)


def versions():
    """{"mitsuba", "drjit", "llvm"}: the versions a comparison ran with ("llvm": the libLLVM the
    LLVM variants compile with, once one of them has been used; else None)."""
    import drjit
    import mitsuba as mi
    out = {"mitsuba": mi.__version__, "drjit": drjit.__version__, "llvm": None}
    try:
        from drjit.detail import llvm_version
        v = llvm_version()
        out["llvm"] = ".".join(str(x) for x in v) if v and v[0] else None
    except Exception:            # no LLVM backend (or a Dr.Jit without this query)
        pass
    return out


def _probe(variant):
    """A small render with every plugin the comparison uses (run in a child process)."""
    from scenes import compile_scene
    tris = np.array([[[-1, -1, 0], [1, -1, 0], [1, 1, 0]], [[-1, -1, 0], [1, 1, 0], [-1, 1, 0]]],
                    np.float64)
    d = {"camera": {"eye": [0, 0, 4], "target": [0, 0, 0], "fov": 40},
         "film": {"width": 8, "height": 6, "spp": 4},
         "lights": [{"type": "point", "position": [0, 0, 2], "intensity": 1}],
         "materials": {"m": {"type": "diffuse"}},
         "shapes": [{"type": "triangles", "data": tris.tolist(), "material": "m"}]}
    peer = MitsubaPeer(compile_scene(d, source="<probe>"), variant)
    image = peer.time_to_image(seed=0)["image"]
    if not np.isfinite(image).all() or image.max() <= 0:
        raise RuntimeError(f"{variant}: the test render is black or not finite")


class MitsubaPeer:
    """One CompiledScene as a Mitsuba 3 scene in one variant (see the module docstring)."""

    def __init__(self, scene, variant="scalar_rgb"):
        from traversal.camera import look_at_basis

        if variant not in VARIANTS:
            raise ValueError(f"variant must be one of {', '.join(VARIANTS)}, got {variant!r}")
        check_supported(scene)
        import mitsuba as mi
        self.mi = mi
        self.variant = variant
        self.scene = scene
        self.vertices, self.faces = _indexed(scene.triangles)
        cam = scene.camera
        _, up, _ = look_at_basis(cam["eye"], cam["target"], cam["up"])   # up orthogonal to the view
        far = float(np.linalg.norm(self.vertices - np.asarray(cam["eye"]), axis=1).max())
        self.camera = {"eye": [float(x) for x in cam["eye"]],
                       "target": [float(x) for x in cam["target"]], "up": up.tolist(),
                       "fov": float(cam["fov"]), "near_clip": far * 1e-5, "far_clip": far * 4}
        self.sampler = _sampler(scene.spp)
        # one mesh per material, each with its own compact vertex array (prepared here, untimed)
        self.parts = []
        for m in np.unique(scene.material):
            faces = self.faces[scene.material == m]
            used, local = np.unique(faces, return_inverse=True)
            self.parts.append((f"mesh_{int(m)}", self.vertices[used],
                               local.reshape(-1, 3).astype(np.uint32), [float(x) for x in scene.kd[m]]))
        mi.set_variant(variant)

    def _dict(self):
        mi = self.mi
        c = self.camera
        sc = self.scene
        d = {"type": "scene",
             "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
             "sensor": {"type": "perspective", "fov": c["fov"], "fov_axis": "y",
                        "near_clip": c["near_clip"], "far_clip": c["far_clip"],
                        "to_world": mi.ScalarTransform4f().look_at(origin=c["eye"], target=c["target"],
                                                                   up=c["up"]),
                        "sampler": {"type": self.sampler, "sample_count": sc.spp},
                        "film": {"type": "hdrfilm", "width": sc.width, "height": sc.height,
                                 "rfilter": {"type": "box"}, "pixel_format": "rgb"}}}
        for i, L in enumerate(sc.lights):
            d[f"light_{i}"] = {"type": "point", "position": [float(x) for x in L["position"]],
                               "intensity": {"type": "rgb", "value": [float(x) for x in L["intensity"]]}}
        return d

    def _meshes(self):
        """One mi.Mesh per material, filled from the arrays, with a two-sided diffuse BSDF."""
        mi = self.mi
        out = {}
        for name, verts, faces, kd in self.parts:
            props = mi.Properties()
            props["bsdf"] = mi.load_dict({"type": "twosided", "bsdf": {
                "type": "diffuse", "reflectance": {"type": "rgb", "value": kd}}})
            mesh = mi.Mesh(name, len(verts), len(faces), props=props, has_vertex_normals=False)
            p = mi.traverse(mesh)
            p["vertex_positions"] = type(p["vertex_positions"])(verts.ravel())
            p["faces"] = type(p["faces"])(faces.ravel())
            p.update()
            out[name] = mesh
        return out

    def load(self):
        """(mitsuba scene, seconds): fill the meshes and load the scene (Mitsuba builds its BVH)."""
        mi = self.mi
        mi.set_variant(self.variant)
        t = time.perf_counter()
        d = self._dict()
        d.update(self._meshes())
        ms = mi.load_dict(d)
        return ms, time.perf_counter() - t

    def render(self, mscene, seed=0):
        """(image (H, W, 3) float32, seconds)."""
        mi = self.mi
        mi.set_variant(self.variant)
        t = time.perf_counter()
        image = np.array(mi.render(mscene, seed=seed, spp=self.scene.spp), dtype=np.float32)
        return image, time.perf_counter() - t

    def time_to_image(self, seed=0):
        """{"load_seconds", "render_seconds", "total_seconds", "image"} of one cold-scene run
        (warm the variant first with one untimed call)."""
        ms, load_s = self.load()
        image, render_s = self.render(ms, seed)
        return {"load_seconds": load_s, "render_seconds": render_s,
                "total_seconds": load_s + render_s, "image": image[..., :3]}


def image_agreement(ours, peer, seeds=(1, 2)):
    """How far our image is from Mitsuba's, in units of Mitsuba's own seed-to-seed noise.

    ``ours``: our render (H, W, 3) of the scene ``peer`` was made from (a
    :func:`neutral_scene`). Returns {"ours_vs_mitsuba": relative RMSE of ours against Mitsuba
    (seed a), "mitsuba_vs_mitsuba": relative RMSE of Mitsuba (seed b) against Mitsuba (seed a),
    "ratio": the first over the second (None when Mitsuba's two renders are identical),
    "seeds": [a, b]}."""
    ms, _ = peer.load()
    a, _ = peer.render(ms, seeds[0])
    b, _ = peer.render(ms, seeds[1])
    ours_err = relative_rmse(ours, a[..., :3])
    noise = relative_rmse(b[..., :3], a[..., :3])
    return {"ours_vs_mitsuba": ours_err, "mitsuba_vs_mitsuba": noise,
            "ratio": ours_err / noise if noise > 0 else None, "seeds": list(seeds)}
