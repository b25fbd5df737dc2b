"""The Whitted renderer: analytic scenes with known answers, scale invariance, only the passes a
scene calls for, EXR output, and malformed scene files."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from hwbvh.errors import InputError, ParameterError
from traversal.camera import look_at_basis, primary_rays
from raytracer.output import read_exr, read_render, write_exr
from raytracer.render import fresnel_dielectric, make_tracer, render
from scenes import compile_scene, load_scene, transform_scene

REL_TOL = 1e-4   # float32 hit distances feed 1/r^2 and cos: a few ulps of relative error


def run(d, builder="hwbvh", traversal="numba", **kw):
    sc = compile_scene(d)
    tracer, _, _ = make_tracer(sc, builder, traversal)
    return sc, render(sc, tracer, **kw)


def base(shapes, materials, lights=(), w=32, h=32, eye=(0, 3, 0.0001), target=(0, 0, 0),
         fov=60, ambient=(0, 0, 0), depth=5, spp=1, jitter=False):
    return {"type": "scene", "name": "t",
            "camera": {"eye": list(eye), "target": list(target), "up": [0, 0, -1], "fov": fov},
            "film": {"width": w, "height": h, "spp": spp, "jitter": jitter},
            "integrator": {"max_depth": depth, "ambient": list(ambient)},
            "background": [0, 0, 0], "lights": list(lights), "materials": materials,
            "shapes": shapes}


def test_diffuse_plane_under_point_light_matches_closed_form():
    kd, I, hgt = 0.5, 7.0, 1.5
    d = base([{"type": "quad", "corners": [[-9, 0, -9], [9, 0, -9], [9, 0, 9], [-9, 0, 9]],
               "material": "m"}],
             {"m": {"type": "diffuse", "reflectance": [kd] * 3}},
             [{"type": "point", "position": [0.3, hgt, -0.2], "intensity": [I] * 3}])
    sc, res = run(d)
    o, dirs = primary_rays(sc.camera["eye"], sc.camera["target"], sc.camera["up"], sc.camera["fov"], 32, 32)
    t = -o[:, 1] / dirs[:, 1]
    P = o + dirs * t[:, None]
    to = np.array([0.3, hgt, -0.2]) - P
    r2 = (to ** 2).sum(1)
    expected = kd / np.pi * I * (to[:, 1] / np.sqrt(r2)) / r2      # L = kd/pi * I cos / r^2
    got = res.image.reshape(-1, 3)
    np.testing.assert_allclose(got[:, 0], expected, rtol=REL_TOL)
    assert res.stats["rays"]["reflection"] == res.stats["rays"]["refraction"] == 0


def test_mirror_reproduces_what_it_faces():
    wall = {"L": {"type": "diffuse", "reflectance": [0.9, 0.1, 0.1]},
            "R": {"type": "diffuse", "reflectance": [0.1, 0.8, 0.2]},
            "mirror": {"type": "mirror", "reflectance": [0.8, 0.8, 0.8]}}
    shapes = [{"type": "quad", "corners": [[-5, -5, 3], [0, -5, 3], [0, 5, 3], [-5, 5, 3]], "material": "L"},
              {"type": "quad", "corners": [[0, -5, 3], [5, -5, 3], [5, 5, 3], [0, 5, 3]], "material": "R"}]
    mirror = {"type": "quad", "corners": [[-6, -6, 0], [6, -6, 0], [6, 6, 0], [-6, 6, 0]], "material": "mirror"}
    kw = dict(w=40, h=30, fov=50, ambient=(1, 1, 1))
    d_mirror = base(shapes + [mirror], wall, eye=(0, 0, 2), target=(0, 0, 0), **kw)
    d_mirror["camera"]["up"] = [0, 1, 0]
    d_direct = base(shapes, wall, eye=(0, 0, -2), target=(0, 0, 1), **kw)
    d_direct["camera"]["up"] = [0, 1, 0]
    _, a = run(d_mirror)
    _, b = run(d_direct)
    np.testing.assert_allclose(a.image, 0.8 * b.image[:, ::-1], rtol=1e-5, atol=1e-6)
    assert a.stats["rays"]["reflection"] > 0


def test_glass_slab_shifts_the_background_as_snell_predicts():
    n, h, top = 1.5, 0.4, 1.5
    mats = {"red": {"type": "diffuse", "reflectance": [1, 0, 0]},
            "green": {"type": "diffuse", "reflectance": [0, 1, 0]},
            "glass": {"type": "dielectric", "ior": n}}
    shapes = [{"type": "quad", "corners": [[-90, 0, -90], [0, 0, -90], [0, 0, 90], [-90, 0, 90]], "material": "red"},
              {"type": "quad", "corners": [[0, 0, -90], [90, 0, -90], [90, 0, 90], [0, 0, 90]], "material": "green"},
              {"type": "box", "min": [-80, top - h, -80], "max": [80, top, 80], "material": "glass"}]
    d = base(shapes, mats, w=48, h=36, eye=(-1.2, 3.0, 0.0001), target=(0.6, 0, 0), fov=40,
             ambient=(1, 1, 1), depth=8)
    d["camera"]["up"] = [0, 1, 0]
    sc, res = run(d)
    o, dirs = primary_rays(sc.camera["eye"], sc.camera["target"], sc.camera["up"], sc.camera["fov"], 48, 36)
    # analytic: through the slab the direction bends by Snell's law, then is restored on exit
    t1 = (top - o[:, 1]) / dirs[:, 1]
    p1 = o + dirs * t1[:, None]
    cos_i = -dirs[:, 1]
    sin_t = np.sqrt(1 - cos_i ** 2) / n
    horiz = dirs[:, [0, 2]] / np.linalg.norm(dirs[:, [0, 2]], axis=1, keepdims=True)
    shift_in = h * sin_t / np.sqrt(1 - sin_t ** 2)               # horizontal run inside the glass
    x_exit = p1[:, 0] + horiz[:, 0] * shift_in
    x_ground = x_exit + dirs[:, 0] / -dirs[:, 1] * (top - h)
    predicted_green = x_ground > 0
    got = res.image.reshape(-1, 3)
    got_green = got[:, 1] > got[:, 0]
    safe = np.abs(x_ground) > 0.02                                 # away from the edge
    assert (predicted_green == got_green)[safe].all()
    # and the slab really moved the edge: without it, some of those pixels change colour
    x_straight = o[:, 0] + dirs[:, 0] * (-o[:, 1] / dirs[:, 1])
    assert ((x_straight > 0) != predicted_green).sum() >= 8


@pytest.mark.parametrize("eye, target, up, want_w", [
    ([0, 0, 1e-200], [0, 0, 0], [0, 1, 0], [0, 0, -1]),         # |w|^2 underflows
    ([0, 0, 5e-324], [0, 0, 0], [0, 1e-300, 0], [0, 0, -1]),    # subnormal offset, tiny up
    ([3e-310, 0, 0], [0, 4e-310, 0], [0, 0, 1], [-0.6, 0.8, 0]),
    ([0, 0, 1e15], [0, 0, -1e15], [1e15, 1e15, 1e15], [0, 0, -1])])
def test_camera_basis_of_an_eye_any_distance_from_its_target(eye, target, up, want_w):
    """The scene check refuses only an eye equal to its target, so the basis must be
    orthonormal however little they differ, and a tiny up still sets the roll."""
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        u, v, w = look_at_basis(eye, target, up)
    B = np.array([u, v, w])
    np.testing.assert_allclose(B @ B.T, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(w, want_w, atol=1e-12)
    up_dir = np.asarray(up, np.float64) / np.max(np.abs(up))
    assert np.dot(v, up_dir) > 0 and abs(np.dot(u, up_dir)) < 1e-15   # up's roll kept


def test_camera_basis_of_ordinary_cameras_is_the_plain_formula(rng):
    """Normalising exactly-rescaled vectors changes no bit where the plain formula works
    (the renderer's images are compared bit for bit with a reference's)."""
    for _ in range(2000):
        s = 10.0 ** rng.uniform(-12, 14)
        eye, target, up = rng.normal(size=3) * s, rng.normal(size=3) * s, rng.normal(size=3)
        w = target - eye
        w /= np.linalg.norm(w)
        u = np.cross(w, up)
        u /= np.linalg.norm(u)
        got = look_at_basis(eye, target, up)
        for a, b in zip(got, (u, np.cross(u, w), w)):
            assert a.tobytes() == b.tobytes()


def test_up_along_the_view_direction_picks_another_up():
    for up in ([0, 0, 1], [0, 0, -1e-200], [0, 0, 0], [0, 0, 1e15]):
        u, v, w = look_at_basis([0, 0, 1], [0, 0, 0], up)
        B = np.array([u, v, w])
        np.testing.assert_allclose(B @ B.T, np.eye(3), atol=1e-15)


@pytest.mark.parametrize("sine", [7e-13, 1.3e-12])
def test_up_nearly_along_the_view_is_judged_by_angle_not_length(sine):
    """Whether up is too close to the view direction to set the roll depends on the angle
    alone: the same up at any length gives the same basis."""
    up = np.array([0.0, sine, -1.0])     # the fallback's up would roll the camera otherwise
    bases = [look_at_basis([0, 0, 1], [0, 0, 0], up * s) for s in (1.0, 1.5, 1.99, 1e-100, 3e90)]
    for b in bases[1:]:
        np.testing.assert_array_equal(np.array(b), np.array(bases[0]))
    u = bases[0][0]
    assert (abs(u[0]) == 1.0) == (sine > 1e-12)         # up's own roll only above the cut-off


def test_an_eye_1e_200_from_its_target_renders_a_finite_image(tmp_path, capsys):
    import warnings
    from hwrt.cli import main
    scene = {"camera": {"eye": [0, 0, 1e-200], "target": [0, 0, 0]}, "film": {"width": 8, "height": 6},
             "lights": [{"type": "directional", "direction": [0, 0, -1], "irradiance": [1, 1, 1]}],
             "materials": {"white": {"type": "diffuse"}},
             "shapes": [{"type": "triangles", "material": "white",
                         "data": [[[-1, -1, -1], [1, -1, -1], [0, 1, -1]]]}]}
    (tmp_path / "s.json").write_text(json.dumps(scene))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rc = main(["render", str(tmp_path / "s.json"), "-o", str(tmp_path / "o.exr")])
    assert rc == 0, capsys.readouterr().err
    rgb = read_exr(tmp_path / "o.exr")[0][..., :3]
    assert np.isfinite(rgb).all() and rgb.max() > 0              # the triangle ahead is seen


def test_fresnel_limits():
    F, cos_t, tir = fresnel_dielectric(1.0, 1.0, 1.5)
    assert F == pytest.approx(0.04) and not tir                    # ((n-1)/(n+1))^2 at normal incidence
    F, cos_t, tir = fresnel_dielectric(0.0, 1.0, 1.5)
    assert F == pytest.approx(1.0)                                 # grazing
    F, cos_t, tir = fresnel_dielectric(0.3, 1.5, 1.0)
    assert tir and F == 1.0                                        # past the critical angle


@pytest.mark.parametrize("scale,shift,edge_frac", [
    (1e-3, 0.0, 0.03), (1e3, 0.0, 0.03), (1e3, 1e5, 0.03),
    # 1e12: legal coordinates (up to hwbvh's 1e15) where the float32 band's squares overflow
    # unless scaled (triangle_unit), which had read every ray as parallel.
    (1e12, 0.0, 0.03),
    # The unit-sized box moved to 1e5: float32 spacing there (0.0078) is 0.4% of the box, so the
    # 48x96 glass sphere's vertices move by ~1/13 of a triangle and its refraction speckles. The
    # geometry itself changed; acne or leaks would instead darken whole walls (median check).
    (1.0, 1e5, 0.08)])
def test_same_image_at_any_scale(scale, shift, edge_frac):
    d = load_scene("cornell", width=96, height=72, spp=1)
    d["film"]["jitter"] = False
    _, ref = run(d)
    _, got = run(transform_scene(d, scale, (shift, shift, shift)))
    diff = np.abs(got.image - ref.image).max(axis=2)
    # Edges move by float32 quantisation of the coordinates (1e5 + 1 has ulp 0.0078 on a
    # 2-unit box), so a thin fraction of edge pixels may differ; acne or leaks would not be thin.
    assert (diff > 0.05).mean() < edge_frac, (diff > 0.05).mean()
    assert diff.mean() < 0.01
    assert np.median(diff) < 1e-3


def test_only_the_passes_a_scene_calls_for():
    mats = {"m": {"type": "diffuse", "reflectance": [0.5] * 3}}
    quad = [{"type": "quad", "corners": [[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], "material": "m"}]
    _, res = run(base(quad, mats))
    assert res.stats["rays"] == {"primary": 1024, "shadow": 0, "reflection": 0, "refraction": 0}
    _, res = run(base(quad, mats, [{"type": "directional", "direction": [0, -1, 0], "irradiance": [1] * 3}]))
    r = res.stats["rays"]
    assert r["shadow"] > 0 and r["reflection"] == r["refraction"] == 0
    assert res.stats["passes"]["depth"] == 1


def test_a_surface_without_diffuse_or_specular_light_casts_no_shadow_rays():
    """A perfect mirror and a black diffuse surface would add 0 for every light: hits on them
    cast no shadow ray, and the image is the one that adding those zeros made."""
    sun = [{"type": "directional", "direction": [0, -1, 0], "irradiance": [1] * 3}]
    quad = lambda x0, x1, m: {"type": "quad", "corners": [[x0, 0, -3], [x1, 0, -3], [x1, 0, 3],
                                                          [x0, 0, 3]], "material": m}
    mats = {"mirror": {"type": "mirror", "reflectance": [0.8] * 3},
            "black": {"type": "diffuse", "reflectance": [0, 0, 0]},
            "white": {"type": "diffuse", "reflectance": [0.5] * 3}}
    for m in ("mirror", "black"):
        _, res = run(base([quad(-3, 3, m)], mats, sun, ambient=(0.1,) * 3))
        assert res.stats["rays"]["shadow"] == 0 and res.stats["passes"]["shadow"] is False
        assert (res.prim >= 0).all() and (res.image == 0).all()
    # beside a lit surface: only the lit surface's hits cast shadow rays (the mirror's
    # reflections leave upward and miss)
    sc, res = run(base([quad(-3, 0, "mirror"), quad(0, 3, "white")], mats, sun))
    on_white = int((sc.material[res.prim[res.prim >= 0]] == 2).sum())
    assert 0 < res.stats["rays"]["shadow"] == on_white < int((res.prim >= 0).sum())
    # and the rays it no longer casts added nothing: the white half alone, the same image
    _, alone = run(base([quad(0, 3, "white")], mats, sun))
    assert alone.stats["rays"]["shadow"] == on_white
    assert np.array_equal(res.image, alone.image)


def test_reproducible_and_verified():
    d = load_scene("cornell", width=48, height=36, spp=2)
    sc = compile_scene(d)
    tracer, _, _ = make_tracer(sc)
    from traversal.tracers import VerifyingTracer
    checked = VerifyingTracer(tracer, sc.triangles, sc.vertices, sc.faces)
    a = render(sc, checked, seed=3)
    b = render(sc, tracer, seed=3)
    assert np.array_equal(a.image, b.image)
    v = checked.summary()
    assert v["mismatch"] == 0 and v["rays"] > 3000 and v["shadow"]["rays"] > 1000


def test_a_verified_render_is_a_second_render_checked_apart():
    """``verified_render`` asks the render's queries again, each checked against Embree, and
    says whether its image is the timed render's; ``render --verify`` reports the check's
    seconds apart from the render's, which are those of the unchecked render."""
    from raytracer.render import verified_render
    sc = compile_scene(load_scene("cornell", width=40, height=30, spp=1))
    tracer, _, _ = make_tracer(sc)
    res = render(sc, tracer, seed=5)
    summary, seconds = verified_render(sc, tracer, 5, res.image)
    assert summary["same_image"] and summary["mismatch"] == 0 and seconds > 0
    assert summary["rays"] == sum(res.stats["rays"].values())
    other = res.image.copy()
    other[0, 0, 0] += 1
    assert not verified_render(sc, tracer, 5, other)[0]["same_image"]
    # another seed's rays make another image
    assert not verified_render(sc, tracer, 6, res.image)[0]["same_image"]
    # an image that cannot be the render's is refused, not reported as another image
    for wrong in (np.zeros(3, np.float32), res.image.astype(np.float64), res.image[:, :-1],
                  res.image.tolist()):
        with pytest.raises(ParameterError, match="^image: expected the render's image"):
            verified_render(sc, tracer, 5, wrong)


def test_render_verify_reports_the_check_apart(tmp_path, capsys):
    from hwrt.cli import main
    out = tmp_path / "c.exr"
    assert main(["render", "cornell", "--width", "32", "--height", "24", "--spp", "1",
                 "-o", str(out), "--verify", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    v = r["verify"]
    assert v["same_image"] is True and v["mismatch"] == 0
    assert v["rays"] == sum(r["rays"].values()) and r["verify_seconds"] > 0
    assert main(["render", "cornell", "--width", "32", "--height", "24", "--spp", "1",
                 "-o", str(out), "--verify"]) == 0
    captured = capsys.readouterr()
    assert "verify_seconds: " in captured.out and "same_image" in captured.out
    assert "warning" not in captured.err


def test_render_verify_warns_when_the_check_made_another_image(tmp_path, capsys, monkeypatch):
    """A check whose render differs from the timed one did not check the timed render's
    queries: one warning line on stderr, the image still written."""
    import raytracer.render as rr
    from hwrt.cli import main
    real = rr.verified_render

    def differing(*a, **k):
        summary, seconds = real(*a, **k)
        return dict(summary, same_image=False), seconds

    monkeypatch.setattr(rr, "verified_render", differing)
    out = tmp_path / "c.exr"
    assert main(["render", "cornell", "--width", "16", "--height", "12", "--spp", "1",
                 "-o", str(out), "--verify", "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["verify"]["same_image"] is False and out.exists()
    warnings = [line for line in captured.err.splitlines() if line.startswith("hwrt: warning")]
    assert warnings == ["hwrt: warning: the checked render made another image than the timed "
                        "render: its answers were checked, the timed render's were not (the "
                        "renderer is not deterministic here)"]


def test_embree_path_renders_the_same_image():
    d = load_scene("cornell", width=64, height=48, spp=1)
    d["film"]["jitter"] = False
    _, a = run(d)
    _, b = run(d, builder="embree", traversal="embree")
    differ = np.abs(a.image - b.image).max(axis=2) > 0.02
    assert differ.mean() < 0.02
    # where first hits differ, they are ties: rays through the box's corner edges hit either
    # face at the same distance
    other = a.prim != b.prim
    np.testing.assert_allclose(a.depth[other], b.depth[other], rtol=1e-5)


def test_exr_to_a_directory_or_with_a_nul_in_its_metadata_is_refused(tmp_path):
    """A directory named x.exr is an output error as for the command line's outputs; a NUL in
    a key or value would cut the header's text short without a word."""
    sc = compile_scene(load_scene("cornell", width=8, height=6, spp=1))
    res = render(sc, make_tracer(sc)[0])
    (tmp_path / "dir.exr").mkdir()
    with pytest.raises(InputError, match="is a directory; give a file path"):
        write_exr(tmp_path / "dir.exr", res)
    for meta in ({"j": "x\0y"}, {"a\0b": 1}):
        with pytest.raises(ParameterError, match="^metadata: a key or value holds a NUL"):
            write_exr(tmp_path / "m.exr", res, meta)
    assert not (tmp_path / "m.exr").exists()


def test_exr_layers_metadata_and_atomic_write(tmp_path):
    d = load_scene("cornell", width=20, height=10, spp=1)
    _, res = run(d)
    out = tmp_path / "x.exr"
    write_exr(out, res, {"scene": "cornell", "build_seconds": 0.5})
    px, names, meta = read_exr(out)
    assert names == ["R", "G", "B", "Z", "N.X", "N.Y", "N.Z", "prim.id"]
    # read back as a render's result, every layer bit for bit
    back, meta2 = read_render(out)
    assert meta2 == meta and back.prim.dtype == np.int32
    for layer in ("image", "depth", "normal", "prim"):
        assert np.array_equal(getattr(back, layer), getattr(res, layer)), layer
    plain = tmp_path / "other" / "plain.exr"
    write_exr(plain, res, layers=False)
    with pytest.raises(InputError, match="holds the channels R, G, B, not the layers"):
        read_render(plain)
    assert px.shape == (10, 20, 8)
    np.testing.assert_array_equal(px[..., :3], res.image)
    assert meta["scene"] == "cornell" and float(meta["build_seconds"]) == 0.5
    assert sorted(os.listdir(tmp_path)) == ["other", "x.exr"]
    # numbers the header's float32 would turn into infinity or zero go in as text
    write_exr(out, res, {"big": 1e300, "small": 1e-300, "zero": 0.0, "inf": float("inf"),
                         "third": 1 / 3, "wide": 2**40, "flag": True})
    meta = read_exr(out)[2]
    assert (meta["big"], meta["small"], meta["wide"], meta["flag"]) == \
        ("1e+300", "1e-300", str(2**40), "True")
    assert meta["zero"] == 0.0 and meta["inf"] == float("inf")
    # a dict or list goes in as JSON text, which reads back
    write_exr(out, res, {"run": {"builder": "hwbvh", "leaf": 4, "seeds": [1, 2]}})
    assert json.loads(read_exr(out)[2]["run"]) == {"builder": "hwbvh", "leaf": 4, "seeds": [1, 2]}
    assert meta["third"] == pytest.approx(1 / 3, rel=1e-7)


def test_reading_what_is_not_an_exr_names_the_file(tmp_path):
    junk = tmp_path / "junk.exr"
    junk.write_text("not an image")
    cases = [(tmp_path / "missing.exr", "missing.exr: no such file"), (tmp_path, "not a file"),
             (junk, "junk.exr: not a readable image (")]
    for path, text in cases:
        for read in (read_exr, read_render):
            with pytest.raises(InputError) as e:
                read(path)
            assert text in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(ParameterError, match="expected a file path, got int"):
        read_exr(3)


def cli(*args):
    return subprocess.run([sys.executable, "-m", "hwrt.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=600)


BAD_SCENES = {
    "syntax.json": ("{ not json", "not valid JSON"),
    "cut.json": ('{"camera":\n  "ab', "not valid JSON \\(Unterminated string starting at line 2, "
                                     "column 3\\)$"),
    "nocamera.json": ({"materials": {"m": {"type": "diffuse"}}, "shapes": [{"type": "quad", "material": "m",
                      "corners": [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]}]}, "key 'camera': missing"),
    "badmat.json": ({"camera": {"eye": [0, 0, 1], "target": [0, 0, 0]}, "materials": {"m": {"type": "diffuse"}},
                     "shapes": [{"type": "quad", "material": "nope",
                                 "corners": [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]}]},
                    "key 'shapes\\[0\\].material': unknown material 'nope'"),
    "badvec.json": ({"camera": {"eye": [0, "x", 1], "target": [0, 0, 0]}, "materials": {"m": {"type": "diffuse"}},
                     "shapes": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m"}]},
                    "key 'camera.eye'"),
    "zeroup.json": ({"camera": {"eye": [0, 0, 3], "target": [0, 0, 0], "up": [0, 0, 0]},
                     "materials": {"m": {"type": "diffuse"}},
                     "shapes": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m"}]},
                    "key 'camera.up': must not be zero"),
    "badshape.toml": ('[camera]\neye=[0,0,1]\ntarget=[0,0,0]\n[materials.m]\ntype="diffuse"\n'
                      '[[shapes]]\ntype="cone"\nmaterial="m"\n', "key 'shapes\\[0\\].type': unknown shape type"),
    "badnum.toml": ('[camera]\neye=[0,0,1]\ntarget=[0,0,0]\nfov=-5\n[materials.m]\ntype="diffuse"\n'
                    '[[shapes]]\ntype="sphere"\ncenter=[0,0,0]\nradius=1\nmaterial="m"\n', "key 'camera.fov'"),
    "frameshape.json": ({"camera": {"eye": [0, 0, 3], "target": [0, 0, 0]}, "materials": {"m": {"type": "diffuse"}},
                         "shapes": [{"type": "frames", "pattern": "f_%04d.ply", "material": "m"}]},
                        "key 'shapes\\[0\\].type': the scene moves: render it with hwrt animate"),
    "keyframed.json": ({"camera": {"eye": [0, 0, 3], "target": [0, 0, 0]}, "materials": {"m": {"type": "diffuse"}},
                        "shapes": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m"},
                                   {"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m",
                                    "keyframes": [{"time": 0}]}]},
                       "key 'shapes\\[1\\].keyframes': the scene moves: render it with hwrt animate"),
    "meshframes.json": ({"camera": {"eye": [0, 0, 3], "target": [0, 0, 0]}, "materials": {"m": {"type": "diffuse"}},
                         "shapes": [{"type": "mesh", "filename": "f_0000.ply", "frames": "f_%04d.ply",
                                     "material": "m"}]},
                        "key 'shapes\\[0\\].frames': unknown key \\(did you mean a shape of "
                        "\"type\": \"frames\" with a \"pattern\"\\? known keys: type, material, "
                        "filename, smooth, transform\\)"),
}


@pytest.mark.parametrize("name", list(BAD_SCENES))
def test_malformed_scene_files(tmp_path, name):
    content, match = BAD_SCENES[name]
    p = tmp_path / name
    p.write_text(content if isinstance(content, str) else json.dumps(content))
    with pytest.raises(InputError, match=match) as e:
        compile_scene(load_scene(p))
    assert str(p) in str(e.value)
    out = tmp_path / "out.exr"
    r = cli("render", p, "-o", out, "--json")
    assert r.returncode == 2 and r.stdout == "" and str(p) in r.stderr
    assert not out.exists()


def test_scene_file_roundtrip_with_mesh(tmp_path):
    import trimesh
    from scenes.meshes import sphere
    tris = sphere(8, 12)
    trimesh.Trimesh(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3), process=False).export(tmp_path / "s.ply")
    scene = {"camera": {"eye": [0, 0, 4], "target": [0, 0, 0]}, "film": {"width": 16, "height": 12},
             "materials": {"m": {"type": "plastic", "reflectance": [0.5, 0.5, 0.5]}},
             "lights": [{"type": "point", "position": [2, 2, 2], "intensity": [10, 10, 10]}],
             "shapes": [{"type": "mesh", "filename": "s.ply", "material": "m", "smooth": True,
                         "transform": {"scale": 1.5, "translate": [0, 0.1, 0]}}]}
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    r = cli("render", tmp_path / "scene.json", "-o", tmp_path / "o.exr", "--png", "--json")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert res["rays"]["primary"] == 192 and os.path.exists(res["png"])
    for k in ("output", "build_seconds", "render_seconds"):
        assert k in res


def test_cli_embree_builder_and_traversal_go_together(tmp_path):
    # one of the pair given as embree picks the other
    for given in (["--builder", "embree"], ["--traversal", "embree"]):
        r = cli("render", "cornell", *given, "--width", "8", "--height", "8", "--json",
                "-o", tmp_path / "x.exr")
        assert r.returncode == 0, r.stderr
        res = json.loads(r.stdout)
        assert (res["builder"], res["traversal"]) == ("embree", "embree")
    # the other of the pair given otherwise: an error naming both options
    (tmp_path / "x.exr").unlink()
    r = cli("render", "cornell", "--builder", "embree", "--traversal", "numba", "--width", "8",
            "--height", "8", "-o", tmp_path / "x.exr")
    assert r.returncode == 2 and r.stderr.startswith(
        "hwrt: error: --builder embree: needs --traversal embree, not numba")
    r = cli("render", "cornell", "--builder", "sweep", "--traversal", "embree", "-o",
            tmp_path / "x.exr")
    assert r.returncode == 2 and r.stderr.startswith(
        "hwrt: error: --traversal embree: needs --builder embree, not sweep")
    assert not (tmp_path / "x.exr").exists()


def test_a_scene_changed_in_place_after_its_build_is_not_rendered_with_the_old_tree():
    """build keeps its own copy of an array source: moving the scene's triangles in place
    afterwards leaves the tree on the old ones, and render refuses the pair instead of tracing
    the old geometry and shading the new."""
    import hwbvh
    from traversal import Tracer
    s = compile_scene(load_scene("cornell", width=16, height=12, spp=1))
    bvh = hwbvh.build(s.triangles)
    assert bvh.triangles is not s.triangles and not np.may_share_memory(bvh.triangles,
                                                                         s.triangles)
    tracer = Tracer(bvh)
    render(s, tracer)
    s.triangles[:] += np.float32(0.25)
    with pytest.raises(ParameterError, match="other triangles than the scene's"):
        render(s, tracer)
    Tracer(bvh)                                  # the tree itself is untouched
