"""Scene-file keys that reach beyond their checks: each bad value is exit status 2 with one line
naming the file and the key, no numpy warning, and nothing written."""
import json
import warnings

import numpy as np
import pytest

from hwbvh.errors import InputError, ParameterError
from hwrt.cli import main
from scenes import compile_scene, load_animation, load_scene
from scenes.loader import MAX_FRAMES, SCALE_RANGE

TRIANGLE_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"


def scene_dict(shapes=None, **top):
    d = {"type": "scene", "camera": {"eye": [0, 1, 4], "target": [0, 0, 0]},
         "film": {"width": 8, "height": 8, "spp": 1},
         "lights": [{"type": "point", "position": [1, 3, 2], "intensity": [10, 10, 10]}],
         "materials": {"white": {"type": "diffuse"}},
         "shapes": shapes or [{"type": "box", "min": [-0.5, 0, -0.5], "max": [0.5, 1, 0.5],
                               "material": "white"}]}
    d.update(top)
    return d


def write_scene(tmp_path, d, name="s.json"):
    p = tmp_path / name
    p.write_text(json.dumps(d))
    return p


def refused(capsys, tmp_path, monkeypatch, *argv):
    """Run the CLI in ``tmp_path``: (the one error line, the warnings numpy raised). Checks
    exit status 2 and that nothing was written there (renders/ included)."""
    monkeypatch.chdir(tmp_path)
    before = set(tmp_path.rglob("*"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert rc == 2 and out == "" and len(lines) == 1, err
    assert set(tmp_path.rglob("*")) == before
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], \
        [str(w.message) for w in caught]
    return lines[0]


# --------------------------------------------------------------------------------------
# animation.frames shares --frames' limit
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("frames", [MAX_FRAMES + 1, 1_000_000_000])
def test_animation_frames_beyond_the_limit_are_refused_before_any_frame(tmp_path, capsys,
                                                                         monkeypatch, frames):
    p = write_scene(tmp_path, scene_dict(animation={"frames": frames}))
    line = refused(capsys, tmp_path, monkeypatch, "animate", p, "-o", tmp_path / "d",
                   "--width", 8, "--height", 8)
    assert f"{p}: key 'animation.frames': {frames} is more than the {MAX_FRAMES} frames" in line


def test_the_frame_limit_is_one_number_for_the_key_the_option_and_the_library(tmp_path, capsys,
                                                                             monkeypatch):
    p = write_scene(tmp_path, scene_dict(animation={"frames": MAX_FRAMES}))
    anim = load_animation(p)
    assert anim.frames == MAX_FRAMES
    with pytest.raises(ParameterError, match=f"frames: {MAX_FRAMES + 1} is more than"):
        anim.check(MAX_FRAMES + 1)
    with pytest.raises(SystemExit):
        main(["animate", str(p), "--frames", str(MAX_FRAMES + 1)])
    assert f"must be at most {MAX_FRAMES}" in capsys.readouterr().err


# --------------------------------------------------------------------------------------
# name: the default outputs are named after it
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["", "../../evil", "a/b", "a\\b", ".", "..", "x\0y", "a\nb", "a\x7fb",
                                  "a\x85b", 5, [1], None])
@pytest.mark.parametrize("command", ["render", "animate"])
def test_a_name_that_is_not_a_plain_file_name_is_refused(tmp_path, capsys, monkeypatch, name,
                                                         command):
    p = write_scene(tmp_path, scene_dict(name=name))
    line = refused(capsys, tmp_path, monkeypatch, command, p, "--width", 8, "--height", 8)
    assert line.startswith(f"hwrt: error: {p}: key 'name': ")
    d = scene_dict(name=name)
    with pytest.raises(InputError, match="key 'name'"):
        compile_scene(d, source="dict")


@pytest.mark.parametrize("shape", [{"type": "mesh", "filename": "a\0b.ply", "material": "white"},
                                   {"type": "frames", "pattern": "f\0_%04d.ply",
                                    "material": "white"}])
def test_a_path_with_a_nul_byte_is_refused_as_such(tmp_path, capsys, monkeypatch, shape):
    extra = {"animation": {"frames": 2}} if shape["type"] == "frames" else {}
    p = write_scene(tmp_path, scene_dict(shapes=[shape], **extra))
    command = "animate" if shape["type"] == "frames" else "render"
    line = refused(capsys, tmp_path, monkeypatch, command, p, "--width", 8, "--height", 8)
    key = "filename" if shape["type"] == "mesh" else "pattern"
    assert line == f"hwrt: error: {p}: key 'shapes[0].{key}': a path cannot hold a NUL byte"


def test_a_plain_name_names_the_default_output(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert load_scene(write_scene(tmp_path, scene_dict(name="my scene.v2")))["name"] == "my scene.v2"
    assert load_scene(write_scene(tmp_path, scene_dict(), "plain.json"))["name"] == "plain"


# --------------------------------------------------------------------------------------
# huge and tiny values that pass a key's type check
# --------------------------------------------------------------------------------------
SHEET = {"type": "sheet", "resolution": [2, 2], "material": "white"}
QUAD = {"type": "quad", "corners": [[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]],
        "material": "white"}


@pytest.mark.parametrize("shape, key", [
    (dict(SHEET, size=1e300), "shapes[0].size"),
    (dict(SHEET, wave=1e300), "shapes[0].wave"),
    (dict(SHEET, wave=-1e300), "shapes[0].wave"),
    (dict(SHEET, height=1e300), "shapes[0].height"),
    (dict(SHEET, height=1e15, wave=1e14), "shapes[0].height"),      # each in bound, not the sum
    # at x = size / 2 = pi / 6 the wave reaches its full amplitude
    (dict(SHEET, size=np.pi / 3, height=1e14, wave=1e15), "shapes[0].wave"),
    (dict(QUAD, corners=[[-1, 0, -1], [1e300, 0, -1], [1, 0, 1], [-1, 0, 1]]), "shapes[0].corners"),
    (dict(QUAD, corners=[[-1, 0, -1], [2e15, 0, -1], [1, 0, 1], [-1, 0, 1]]), "shapes[0].corners"),
    ({"type": "sphere", "center": [0, 0, 0], "radius": 1e300, "material": "white"},
     "shapes[0].radius"),
    ({"type": "sphere", "center": [1e15, 0, 0], "radius": 1e15, "material": "white"},
     "shapes[0].radius"),
    ({"type": "box", "min": [-1e15] * 3, "max": [1e15] * 3, "rotate_y": 45, "material": "white"},
     "shapes[0].rotate_y"),
    ({"type": "triangles", "data": [], "material": "white"}, "shapes[0].data"),
    # not numbers, or not nested as triangles of points: refused, not converted or reshaped
    ({"type": "triangles", "data": [[[True, 0, 0], [1, 0, 0], [0, 1, 0]]], "material": "white"},
     "shapes[0].data"),
    ({"type": "triangles", "data": [[["0", 0, 0], [1, 0, 0], [0, 1, 0]]], "material": "white"},
     "shapes[0].data"),
    ({"type": "triangles", "data": [0, 0, 0, 1, 0, 0, 0, 1, 0], "material": "white"},
     "shapes[0].data"),
    ({"type": "triangles", "data": [[[0, 0, 0], [1, 0, 0], [0, 1]]], "material": "white"},
     "shapes[0].data"),
])
def test_generated_geometry_beyond_the_bound_names_its_key(tmp_path, capsys, monkeypatch, shape, key):
    p = write_scene(tmp_path, scene_dict([shape]))
    line = refused(capsys, tmp_path, monkeypatch, "render", p, "-o", tmp_path / "o.exr")
    assert line.startswith(f"hwrt: error: {p}: key '{key}': "), line


@pytest.mark.parametrize("transform, problem", [
    ({"scale": 1e-300}, "each component's magnitude must lie in"),
    ({"scale": [1, 0, 1]}, "a scale of 0 flattens the shape"),
    ({"scale": [1, 1, 1e16]}, "expected 3 finite numbers of magnitude at most 1e+15"),
    ({"scale": [-1e-16, 1, 1]}, "each component's magnitude must lie in"),
    ({"scale": 1e15, "translate": [0, 0, 0]}, None),       # 1e15 x a unit mesh: in bound
])
def test_a_mesh_scale_outside_its_range_is_refused(tmp_path, capsys, monkeypatch, transform, problem):
    (tmp_path / "tri.obj").write_text(TRIANGLE_OBJ)
    shape = {"type": "mesh", "filename": "tri.obj", "material": "white", "transform": transform}
    p = write_scene(tmp_path, scene_dict([shape]))
    if problem is None:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            c = compile_scene(load_scene(p))
        assert np.abs(c.triangles).max() == np.float32(1e15)
        return
    line = refused(capsys, tmp_path, monkeypatch, "render", p, "-o", tmp_path / "o.exr")
    assert f"{p}: key 'shapes[0].transform.scale': {problem}" in line
    if "must lie in" in problem:
        assert f"[{SCALE_RANGE[0]:g}, {SCALE_RANGE[1]:g}]" in line


def test_a_mesh_scale_that_collapses_its_triangles_in_float32_is_refused(tmp_path, capsys,
                                                                         monkeypatch):
    """1e-15 is in range, but the mesh's vertices at 1e-32 go below float32's smallest number."""
    (tmp_path / "tiny.obj").write_text("v 0 0 0\nv 1e-32 0 0\nv 0 1e-32 0\nf 1 2 3\n")
    shape = {"type": "mesh", "filename": "tiny.obj", "material": "white",
             "transform": {"scale": 1e-15}}
    p = write_scene(tmp_path, scene_dict([dict(shape, transform={"scale": 1e-15}),
                                          scene_dict()["shapes"][0]]))
    line = refused(capsys, tmp_path, monkeypatch, "render", p, "-o", tmp_path / "o.exr")
    assert f"{p}: key 'shapes[0].transform.scale': the mesh collapses: 1 of its 1 triangles" in line


def test_a_mesh_transform_beyond_the_bound_names_scale_or_translate(tmp_path, capsys, monkeypatch):
    (tmp_path / "big.obj").write_text("v 0 0 0\nv 1e14 0 0\nv 0 1 0\nf 1 2 3\n")
    for transform, key in (({"scale": 100}, "scale"), ({"translate": [1e15, 0, 0]}, "translate")):
        shape = {"type": "mesh", "filename": "big.obj", "material": "white", "transform": transform}
        p = write_scene(tmp_path, scene_dict([shape]))
        line = refused(capsys, tmp_path, monkeypatch, "render", p, "-o", tmp_path / "o.exr")
        assert f"{p}: key 'shapes[0].transform.{key}': " in line and "beyond 1e+15" in line


@pytest.mark.parametrize("translate", [[1e9, 0, 0], [0, -3e8, 0]])
def test_a_mesh_translation_that_collapses_its_triangles_in_float32_names_translate(
        tmp_path, capsys, monkeypatch, translate):
    """Moved 1e9 away, a unit triangle's vertices round together in float32 (spacing 64 there);
    only the triangles that had an area and lost it are counted (the third, flat, had none)."""
    (tmp_path / "tris.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 2 0 0\n"
                                       "f 1 2 3\nf 2 4 3\nf 1 2 5\n")
    shape = {"type": "mesh", "filename": "tris.obj", "material": "white",
             "transform": {"translate": translate}}
    p = write_scene(tmp_path, scene_dict([shape]))
    line = refused(capsys, tmp_path, monkeypatch, "render", p, "-o", tmp_path / "o.exr")
    assert (f"{p}: key 'shapes[0].transform.translate': the mesh collapses: 2 of its 3 "
            "triangles lose their area in float32") in line


def test_a_mesh_translation_that_flattens_it_in_float32_names_translate(tmp_path, capsys,
                                                                        monkeypatch):
    """Moved 1e9 along x, a unit mesh whose triangles stand in the y-z plane keeps their areas,
    but float32 spaces x 64 apart there: its depth along x is gone."""
    (tmp_path / "wall.obj").write_text("v 0 0 0\nv 0 1 0\nv 0 0 1\nv 1 0 0\nv 1 1 0\nv 1 0 1\n"
                                       "f 1 2 3\nf 4 5 6\n")
    shape = {"type": "mesh", "filename": "wall.obj", "material": "white",
             "transform": {"translate": [1e9, 0, 0]}}
    p = write_scene(tmp_path, scene_dict([shape]))
    line = refused(capsys, tmp_path, monkeypatch, "render", p, "-o", tmp_path / "o.exr")
    assert (f"{p}: key 'shapes[0].transform.translate': the mesh collapses: moved this far from "
            "the origin, its coordinates round to float32 numbers 64 apart, coarse against its "
            "size of 1") in line
    shape["transform"]["translate"] = [1e6, 0, 0]        # 0.0625 apart: kept
    compile_scene(load_scene(write_scene(tmp_path, scene_dict([shape]))))


@pytest.mark.parametrize("shape, key, what", [
    ({"type": "box", "min": [1e9, 0, 0], "max": [1e9 + 1, 1, 1], "material": "white"},
     "shapes[0].min", "the box"),
    ({"type": "sphere", "center": [1e9, 0, 0], "radius": 1, "material": "white"},
     "shapes[0].center", "the sphere"),
    (dict(QUAD, corners=[[1e9, 0, 0], [1e9 + 1, 0, 0], [1e9 + 1, 1, 0], [1e9, 1, 0]]),
     "shapes[0].corners", "the quad"),
    ({"type": "triangles", "data": [[[1e9, 0, 0], [1e9 + 1, 0, 0], [1e9, 1, 0]]],
      "material": "white"}, "shapes[0].data", "the set of triangles"),
    (dict(SHEET, size=1, height=1e9), "shapes[0].height", "the sheet"),
])
def test_a_shape_too_small_for_float32_where_it_lies_names_its_key(tmp_path, capsys, monkeypatch,
                                                                  shape, key, what):
    """As a mesh's translation is: a unit shape at 1e9, where float32 spaces numbers 64 apart,
    would be traced flat or empty; a million from the origin (0.0625 apart) it is kept."""
    p = write_scene(tmp_path, scene_dict([shape]))
    line = refused(capsys, tmp_path, monkeypatch, "render", p, "-o", tmp_path / "o.exr")
    assert line == (f"hwrt: error: {p}: key '{key}': {what} collapses: this far from the origin "
                    f"its coordinates round to float32 numbers 64 apart, coarse against its size "
                    f"of {1 if what != 'the sphere' else 2}"), line
    near = json.loads(json.dumps(shape).replace("1000000000.0", "1000000.0")
                      .replace("1000000001.0", "1000001.0"))
    compile_scene(load_scene(write_scene(tmp_path, scene_dict([near]))))


def test_a_mesh_moved_far_but_keeping_its_area_is_accepted(tmp_path):
    (tmp_path / "big.obj").write_text("v 0 0 0\nv 1e3 0 0\nv 0 1e3 0\nf 1 2 3\n")
    shape = {"type": "mesh", "filename": "big.obj", "material": "white",
             "transform": {"translate": [1e9, 0, 0]}}
    c = compile_scene(load_scene(write_scene(tmp_path, scene_dict([shape]))))
    assert c.triangles[:, :, 0].min() == np.float32(1e9)


def test_a_keyframe_scale_changing_sign_names_the_later_key(tmp_path, capsys, monkeypatch):
    """Interpolated from 1 to -1, the scale passes through 0: refused, not NaN normals."""
    box = dict(scene_dict()["shapes"][0],
               keyframes=[{"time": 0, "scale": 1}, {"time": 1, "scale": 1},
                          {"time": 2, "scale": [1, -1, 1]}])
    p = write_scene(tmp_path, scene_dict([box], animation={"frames": 3, "fps": 2}))
    line = refused(capsys, tmp_path, monkeypatch, "animate", p, "-o", tmp_path / "d",
                   "--width", 8, "--height", 8)
    assert f"{p}: key 'shapes[0].keyframes[2].scale': [1.0, -1.0, 1.0] changes the sign" in line
    assert "passes through 0" in line


def test_a_keyframe_scale_negative_throughout_is_accepted(tmp_path):
    box = dict(scene_dict()["shapes"][0],
               keyframes=[{"time": 0, "scale": -1}, {"time": 1}, {"time": 2, "scale": [-2, -1, -3]}])
    anim = load_animation(write_scene(tmp_path, scene_dict([box], animation={"frames": 5, "fps": 2})))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for i in range(anim.frames):
            tris, normals, _ = anim.geometry(i)
            assert np.isfinite(normals).all() and np.isfinite(tris).all()


@pytest.mark.parametrize("scale", [0, 1e-300, 1e16])
def test_a_keyframe_scale_outside_its_range_names_the_key_index(tmp_path, capsys, monkeypatch, scale):
    box = dict(scene_dict()["shapes"][0], keyframes=[{"time": 0}, {"time": 1, "scale": scale}])
    p = write_scene(tmp_path, scene_dict([box]))
    line = refused(capsys, tmp_path, monkeypatch, "animate", p, "-o", tmp_path / "d", "--frames", 2)
    assert f"{p}: key 'shapes[0].keyframes[1].scale': " in line
    assert ("a scale of 0 flattens" if scale == 0 else "each component's magnitude" if scale < 1
            else "magnitude at most 1e+15") in line


# --------------------------------------------------------------------------------------
# key paths in messages
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("material, key", [
    ({"type": "diffuse", "reflectance": [1.5, 0, 0]}, "materials.x.reflectance"),
    ({"type": "diffuse", "mirror": [0, -0.1, 0]}, "materials.x.mirror"),
    ({"type": "mirror", "reflectance": 2}, "materials.x.reflectance"),
])
def test_a_reflectance_out_of_range_names_its_key(tmp_path, capsys, monkeypatch, material, key):
    d = scene_dict()
    d["materials"]["x"] = material
    p = write_scene(tmp_path, d)
    line = refused(capsys, tmp_path, monkeypatch, "render", p, "-o", tmp_path / "o.exr")
    assert f"{p}: key '{key}': reflectances must lie in [0, 1]" in line


@pytest.mark.parametrize("command", ["render", "animate"])
def test_a_missing_mesh_names_the_scene_file_the_key_and_the_mesh(tmp_path, capsys, monkeypatch,
                                                                  command):
    shape = {"type": "mesh", "filename": "gone.ply", "material": "white"}
    p = write_scene(tmp_path, scene_dict([scene_dict()["shapes"][0], shape]))
    line = refused(capsys, tmp_path, monkeypatch, command, p, "--width", 8, "--height", 8)
    assert line == f"hwrt: error: {p}: key 'shapes[1].filename': {tmp_path / 'gone.ply'}: no such file"


def test_python_callers_get_errors_naming_what_they_passed():
    """The scene API from Python: unknown or negative built-in parameters, a non-dict scene,
    NumPy numbers (accepted as the numbers they are) and huge ones (shown cut short)."""
    from hwbvh.errors import InputError, ParameterError
    from scenes import compile_scene, load_scene, with_frame

    for kw, parameter in (({"foo": 1}, "foo"), ({"n": -3}, "n"), ({"seed": "5"}, "seed"),
                          ({"n": True}, "n")):
        with pytest.raises(ParameterError) as e:
            load_scene("marbles", **kw)
        assert e.value.parameter == parameter
    for bad in (None, [1]):
        with pytest.raises(InputError, match="a scene must be an object"):
            compile_scene(bad)
        with pytest.raises(ParameterError, match="expected a scene dict"):
            with_frame(bad, width=4)
    d = load_scene("cornell")
    assert compile_scene(with_frame(d, width=np.int64(8), height=np.int32(6))).width == 8
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float32)
    listed = [[list(point) for point in t] for t in tri]        # NumPy numbers in lists
    shape = {"type": "triangles", "data": listed, "material": "white"}
    assert len(compile_scene(dict(d, shapes=d["shapes"] + [shape])).triangles) == \
        len(compile_scene(d).triangles) + 1
    with pytest.raises(ParameterError) as e:
        with_frame(d, width=3 ** 2000)
    assert e.value.parameter == "width" and len(str(e.value)) < 200
    with pytest.raises(InputError) as e:
        compile_scene(dict(d, film=dict(d["film"], width=3 ** 2000)))
    assert "film.width" in str(e.value) and len(str(e.value)) < 200


@pytest.mark.parametrize("spec", ["cornell", "mesh"])
@pytest.mark.parametrize("key, value", [("width", 0), ("height", -2), ("spp", 0),
                                        ("max_depth", 0), ("spp", 2.0), ("width", True)])
def test_frame_overrides_refused_at_the_call(tmp_path, spec, key, value):
    """A film or depth setting out of range is refused where it is given, naming it, for a
    built-in scene and a file alike (not later, by compile_scene)."""
    from hwbvh.errors import ParameterError
    from scenes import load_scene, with_frame

    if spec == "mesh":
        spec = str(tmp_path / "tri.obj")
        with open(spec, "w") as f:
            f.write("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(ParameterError) as e:
        load_scene(spec, **{key: value})
    assert e.value.parameter == key
    with pytest.raises(ParameterError) as e:
        with_frame(load_scene(spec), **{key: value})
    assert e.value.parameter == key


def test_film_area_refused_at_the_call(tmp_path):
    """Sides within range whose product passes the film's pixel limit are refused where
    they are given, naming the side given, as compile_scene would refuse the film; for a
    built-in scene and a file alike."""
    from hwbvh.errors import ParameterError
    from scenes import load_scene, with_frame
    from scenes.loader import MAX_FILM_PIXELS, MAX_FILM_SIDE

    mesh = tmp_path / "tri.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    for spec in ("cornell", str(mesh)):
        with pytest.raises(ParameterError, match=str(MAX_FILM_PIXELS)) as e:
            load_scene(spec, width=MAX_FILM_SIDE, height=MAX_FILM_SIDE)
        assert e.value.parameter == "width"
    wide = with_frame(load_scene("cornell"), width=MAX_FILM_SIDE, height=1)
    with pytest.raises(ParameterError) as e:
        with_frame(wide, height=MAX_FILM_PIXELS // MAX_FILM_SIDE + 1)
    assert e.value.parameter == "height"
    assert with_frame(wide, height=MAX_FILM_PIXELS // MAX_FILM_SIDE)["film"]["height"] == \
        MAX_FILM_PIXELS // MAX_FILM_SIDE


def test_transforms_of_a_scene_compose():
    """Scaling by 2 and then by 3 (with translations) is one transform: the geometry moves
    with the camera and the lights, as it does under the single transform. A negative scale
    would mirror the scene: refused."""
    from hwbvh.errors import ParameterError
    from scenes import compile_scene, load_scene, transform_scene

    d = load_scene("cornell", width=16, height=12, spp=1)
    twice = compile_scene(transform_scene(transform_scene(d, 2.0, (1, 0, 0)), 3.0, (0, 5, 0)))
    once = compile_scene(transform_scene(d, 6.0, (3, 5, 0)))
    np.testing.assert_allclose(twice.triangles, once.triangles, rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(twice.camera["eye"], once.camera["eye"])
    np.testing.assert_allclose(twice.lights[0]["position"], once.lights[0]["position"])
    np.testing.assert_allclose(twice.lights[0]["intensity"], once.lights[0]["intensity"])
    assert not np.allclose(once.triangles, compile_scene(d).triangles)
    with pytest.raises(ParameterError, match="above 0"):
        transform_scene(d, -1.0)
    # a malformed light is compile_scene's to report, not a KeyError or ValueError here
    for light in ({"position": [0, 0, 0]},
                  {"type": "point", "position": "here", "intensity": "bright"},
                  {"type": "point", "position": [0, 1, 0], "intensity": [True, 1, 1]}):
        with pytest.raises(InputError, match="lights"):
            compile_scene(transform_scene(dict(d, lights=[light]), 2.0))


def test_mesh_scene_name_checked_at_the_call(tmp_path):
    from hwbvh.errors import ParameterError
    from scenes.loader import mesh_scene

    path = tmp_path / "tri.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    for bad in (5, "", "a/b", ".."):
        with pytest.raises(ParameterError) as e:
            mesh_scene(str(path), name=bad)
        assert e.value.parameter == "name"
    assert mesh_scene(str(path), name="tri2")["name"] == "tri2"


@pytest.mark.parametrize("call, message", [
    (lambda: load_scene(None), "spec: expected a built-in name or a file path, got NoneType"),
    (lambda: load_scene({}), "spec: expected a built-in name or a file path, got dict (a scene "
                             "dict goes to compile_scene)"),
    (lambda: load_animation(5), "spec: expected a built-in name or a file path, got int"),
    (lambda: __import__("scenes").mesh_scene(None), "path: expected a mesh file path, got "
                                                    "NoneType"),
    (lambda: __import__("scenes").transform_scene(None), "d: expected a scene dict with a camera "
                                                         "and shapes (load_scene makes one), got "
                                                         "NoneType"),
    (lambda: __import__("scenes").transform_scene(load_scene("cornell"), 0),
     "scale: expected a finite number above 0, got 0"),
    (lambda: __import__("scenes").transform_scene(load_scene("cornell"), "x"),
     "scale: expected a finite number above 0, got 'x'"),
    (lambda: __import__("scenes").transform_scene(load_scene("cornell"), 2, [1, 2]),
     "translate: expected 3 finite numbers, got [1, 2]"),
    (lambda: load_animation("exploding", mesh="bunny.ply", triangles=500),
     "triangles: makes a generated mesh: a mesh given brings its own triangles"),
])
def test_scene_functions_name_a_wrong_argument(call, message):
    with pytest.raises(ParameterError) as e:
        call()
    assert str(e.value) == message


# --------------------------------------------------------------------------------------
# a missing 'type' is named as missing
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("section, key, what", [
    ("materials", "materials.white.type", "material"),
    ("shapes", "shapes[0].type", "shape"),
    ("lights", "lights[0].type", "light")])
def test_a_missing_type_is_named_as_missing(tmp_path, capsys, monkeypatch, section, key, what):
    d = scene_dict()
    part = d[section]["white"] if section == "materials" else d[section][0]
    del part["type"]
    p = write_scene(tmp_path, d)
    line = refused(capsys, tmp_path, monkeypatch, "render", p)
    assert f"{p}: key '{key}': missing: every {what} names its type (choose from " in line
    part["type"] = "bogus"
    p = write_scene(tmp_path, d, name="t.json")
    line = refused(capsys, tmp_path, monkeypatch, "render", p)
    assert f"{p}: key '{key}': unknown {what} type 'bogus' (choose from " in line


def test_a_key_given_twice_is_refused_not_overwritten(tmp_path, capsys, monkeypatch):
    """JSON's own loader keeps the last of two equal keys; a scene file refuses it, as TOML
    does, at any depth."""
    good = json.dumps(scene_dict())
    for text, key in ((good.replace('{"type": "scene",', '{"type": "scene", "type": "scene",'),
                       "type"),
                      (good.replace('"eye": [0, 1, 4],', '"eye": [0, 1, 4], "eye": [0, 1, 5],'),
                       "camera.eye"),
                      (good.replace('"max": [0.5, 1, 0.5],', '"max": [0.5, 1, 0.5], "max": 1,'),
                       "shapes[0].max")):
        assert text != good
        p = tmp_path / "dup.json"
        p.write_text(text)
        line = refused(capsys, tmp_path, monkeypatch, "render", p)
        assert line == f"hwrt: error: {p}: key '{key}' is given twice in one object"


def test_an_empty_mesh_filename_is_named_as_empty(tmp_path, capsys, monkeypatch):
    """"" joined to the scene's directory is the directory: the key is named, not the folder."""
    p = write_scene(tmp_path, scene_dict(shapes=[{"type": "mesh", "filename": "",
                                                  "material": "white"}]))
    line = refused(capsys, tmp_path, monkeypatch, "render", p)
    assert line == f"hwrt: error: {p}: key 'shapes[0].filename': missing, empty or not a string"


def test_a_value_is_quoted_as_the_scene_file_spells_it(tmp_path, capsys, monkeypatch):
    p = write_scene(tmp_path, scene_dict(shapes=[{"type": "box", "min": [-0.5, 0, -0.5],
                                                  "max": [0.5, 1, True], "material": "white"}]))
    line = refused(capsys, tmp_path, monkeypatch, "render", p)
    assert line.endswith("key 'shapes[0].max': expected 3 numbers, got [0.5, 1, true]")


@pytest.mark.parametrize("pattern", ["seq/b_%04d.ply", "seq/b_*.ply"])
@pytest.mark.parametrize("command", ["render", "verify"])
def test_a_frame_pattern_given_to_a_still_command_points_to_animate(tmp_path, capsys,
                                                                    monkeypatch, command, pattern):
    line = refused(capsys, tmp_path, monkeypatch, command, pattern)
    assert line == (f"hwrt: error: {pattern}: no such file, nor mesh files it names as a frame "
                    f"sequence (a %d or glob pattern)")
    (tmp_path / "seq").mkdir()
    for k in (0, 2):                                 # frame 1 missing: a sequence all the same
        (tmp_path / "seq" / f"b_{k:04d}.ply").write_bytes(b"")
    line = refused(capsys, tmp_path, monkeypatch, command, pattern)
    assert line == (f"hwrt: error: {pattern}: a frame sequence (a %d or glob pattern of mesh "
                    f"files): render it with hwrt animate")


def test_an_empty_frames_pattern_is_named_as_empty(tmp_path, capsys, monkeypatch):
    p = write_scene(tmp_path, scene_dict(shapes=[{"type": "frames", "pattern": "",
                                                  "material": "white"}]))
    line = refused(capsys, tmp_path, monkeypatch, "animate", p, "-o", tmp_path / "out")
    assert line == f"hwrt: error: {p}: key 'shapes[0].pattern': missing, empty or not a string"


@pytest.mark.parametrize("material, shown", [({"type": None}, "null"), ({"type": True}, "true")])
def test_a_type_is_quoted_as_the_file_spells_it(tmp_path, capsys, monkeypatch, material, shown):
    p = write_scene(tmp_path, scene_dict(materials={"white": material}))
    line = refused(capsys, tmp_path, monkeypatch, "render", p)
    assert f"key 'materials.white.type': unknown material type {shown} (choose from" in line


def test_a_duplicate_key_with_a_line_break_stays_one_line(tmp_path, capsys, monkeypatch):
    p = tmp_path / "dup.json"
    p.write_text(json.dumps(scene_dict())[:-1] + ', "a\\nb": 1, "a\\nb": 2}')
    line = refused(capsys, tmp_path, monkeypatch, "render", p)
    assert line == f"hwrt: error: {p}: key 'a\\nb' is given twice in one object"


def test_a_files_scene_takes_film_overrides_and_refuses_others(tmp_path):
    """As a built-in scene's parameters do: the film and depth of a scene or mesh file."""
    (tmp_path / "tri.obj").write_text(TRIANGLE_OBJ)
    p = write_scene(tmp_path, scene_dict())
    for spec in (p, tmp_path / "tri.obj"):
        c = compile_scene(load_scene(spec, width=8, height=6, spp=2, max_depth=2))
        assert (c.width, c.height, c.spp, c.max_depth) == (8, 6, 2, 2)
        with pytest.raises(ParameterError, match="takes only width, height, spp, max_depth"):
            load_scene(spec, fov=30)


def test_a_scene_built_in_python_takes_numpy_values_as_it_takes_python_ones():
    """NumPy numbers, arrays, booleans and tuples mean what the Python values mean (the same
    compiled scene); NumPy booleans among numbers are refused as JSON's are, and spelled
    ``true`` in the message, as a file would spell them."""
    plain = scene_dict([{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "white",
                         "subdiv": [8, 16]},
                        {"type": "sheet", "resolution": [2, 3], "material": "white"},
                        {"type": "quad", "material": "white",
                         "corners": [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]}],
                       integrator={"max_depth": 3, "cutoff": 0.01})
    plain["film"]["jitter"] = False
    numpy = scene_dict([{"type": "sphere", "center": np.zeros(3), "radius": np.float32(1),
                         "material": np.str_("white"), "subdiv": (np.int64(8), np.int32(16))},
                        {"type": "sheet", "resolution": np.array([2, 3]), "material": "white"},
                        {"type": "quad", "material": "white",
                         "corners": np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]],
                                             np.float32)}],
                       integrator={"max_depth": np.int64(3), "cutoff": np.float64(0.01)})
    numpy["film"] = {"width": np.int64(8), "height": np.int32(8), "spp": np.uint8(1),
                     "jitter": np.bool_(False)}
    numpy["lights"] = (dict(plain["lights"][0], intensity=np.full(3, 10, np.float32)),)
    numpy["shapes"] = tuple(numpy["shapes"])
    a, b = compile_scene(plain), compile_scene(numpy)
    np.testing.assert_array_equal(a.triangles, b.triangles)
    assert (a.width, a.height, a.spp, a.max_depth, a.jitter) == \
        (b.width, b.height, b.spp, b.max_depth, b.jitter)
    for where, value, message in [
            (("camera", "eye"), np.array([True, True, False]),
             "key 'camera.eye': expected 3 numbers, got [true, true, false]"),
            (("camera", "fov"), np.bool_(True), "key 'camera.fov': expected a number, got true"),
            (("film", "jitter"), np.int64(1), "key 'film.jitter': expected true or false, got 1"),
            (("shapes", 0), {"type": "quad", "material": "white",
                             "corners": [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, np.bool_(True), 0]]},
             "key 'shapes[0].corners': expected 4 corners")]:
        d = scene_dict()
        d[where[0]][where[1]] = value
        with pytest.raises(InputError) as e:
            compile_scene(d)
        assert str(e.value).startswith(f"<scene>: {message}"), str(e.value)


# --------------------------------------------------------------------------------------
# the scene's triangle count, summed over its shapes
# --------------------------------------------------------------------------------------
def test_generated_shapes_past_the_triangle_limit_together_are_refused_before_any_is_built(
        tmp_path, capsys, monkeypatch):
    import scenes.loader as loader
    built = []
    real = loader.grid_sheet
    monkeypatch.setattr(loader, "grid_sheet", lambda *a, **k: built.append(a) or real(*a, **k))
    sheet = {"type": "sheet", "resolution": [2048, 1500], "material": "white"}   # 6,144,000 each
    p = write_scene(tmp_path, scene_dict([sheet, sheet, sheet]))
    line = refused(capsys, tmp_path, monkeypatch, "render", p, "-o", tmp_path / "o.exr")
    assert line.startswith(f"hwrt: error: {p}: key 'shapes[2]': brings the scene to 18432000 "
                           f"triangles, more than the 2^24 (16777216) a tree holds"), line
    assert built == []


def test_a_mesh_that_brings_the_scene_past_the_triangle_limit_names_its_shape(tmp_path, capsys,
                                                                              monkeypatch):
    monkeypatch.setattr("scenes.loader.MAX_PRIMITIVES", 13)     # a box (12) and two triangles
    (tmp_path / "two.obj").write_text(TRIANGLE_OBJ + "v 1 1 0\nf 2 4 3\n")
    box = scene_dict()["shapes"][0]
    p = write_scene(tmp_path, scene_dict([box, {"type": "mesh", "filename": "two.obj",
                                                "material": "white"}]))
    line = refused(capsys, tmp_path, monkeypatch, "render", p, "-o", tmp_path / "o.exr")
    assert line.startswith(f"hwrt: error: {p}: key 'shapes[1]': brings the scene to 14 "
                           f"triangles"), line


@pytest.mark.parametrize("shape", [
    {"type": "sphere", "center": [0, 0, 0], "radius": 1, "subdiv": [3, 3]},
    {"type": "sphere", "center": [0, 0, 0], "radius": 1, "subdiv": [7, 5]},
    {"type": "sphere", "center": [0, 0, 0], "radius": 1},
    {"type": "sheet", "resolution": [3, 5]},
    {"type": "sheet"},
    {"type": "box", "min": [0, 0, 0], "max": [1, 1, 1]},
    QUAD,
    {"type": "triangles", "data": [[[0, 0, 0], [1, 0, 0], [0, 1, 0]]] * 3},
])
def test_the_triangles_a_shape_is_counted_for_are_those_it_makes(shape):
    from scenes.loader import _planned_triangles
    shape = dict(shape, material="white")
    assert _planned_triangles(shape) == len(compile_scene(scene_dict([shape])).triangles)


# --------------------------------------------------------------------------------------
# light values and the float32 image
# --------------------------------------------------------------------------------------
def test_a_light_value_beyond_float32_is_refused_naming_its_key(tmp_path, capsys, monkeypatch):
    d = scene_dict(lights=[{"type": "point", "position": [1, 3, 2], "intensity": 1e39}])
    p = write_scene(tmp_path, d)
    line = refused(capsys, tmp_path, monkeypatch, "render", p, "-o", tmp_path / "o.exr")
    assert line.startswith(f"hwrt: error: {p}: key 'lights[0].intensity': "), line


def test_pixels_too_bright_for_float32_are_counted_and_reported(tmp_path, capsys, monkeypatch):
    from raytracer.output import read_exr
    # the largest intensity 0.05 before the box's face the camera sees: 400x more
    # irradiance than float32 holds
    d = scene_dict(lights=[{"type": "point", "position": [0, 0.5, 0.55], "intensity": 3.4e38}])
    p = write_scene(tmp_path, d)
    monkeypatch.chdir(tmp_path)
    assert main(["render", str(p), "-o", "o.exr", "--json"]) == 0
    out, err = capsys.readouterr()
    n = json.loads(out)["pixels_beyond_float32"]
    px, names, _ = read_exr(tmp_path / "o.exr")
    assert n > 0 and n == np.isinf(px[..., :3]).any(axis=-1).sum()
    assert err == (f"hwrt: warning: {n} pixels brighter than float32 holds (3.4e38) are +inf "
                   f"in o.exr; lower the scene's light values\n")
    assert main(["render", str(write_scene(tmp_path, scene_dict(), "dim.json")), "-o", "dim.exr",
                 "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["pixels_beyond_float32"] == 0 and err == ""


def test_an_integer_too_long_for_python_is_named_by_key_or_line(tmp_path, capsys, monkeypatch):
    digits = "9" * 5000
    d = json.dumps(scene_dict()).replace('"target"', f'"fov": {digits}, "target"')
    (tmp_path / "long.json").write_text(d)
    line = refused(capsys, tmp_path, monkeypatch, "render", tmp_path / "long.json", "-o",
                   tmp_path / "o.exr")
    assert line.startswith(f"hwrt: error: {tmp_path / 'long.json'}: key 'camera.fov': "), line
    (tmp_path / "long.toml").write_text(f'name = "s"\n[camera]\neye = [0, 1, 4]\nfov = {digits}\n')
    line = refused(capsys, tmp_path, monkeypatch, "render", tmp_path / "long.toml", "-o",
                   tmp_path / "o.exr")
    assert line == (f"hwrt: error: {tmp_path / 'long.toml'}: line 4: a number of more than 4000 "
                    f"digits"), line


def test_a_top_level_key_is_named_bare_and_a_long_integer_as_written(tmp_path, capsys,
                                                                    monkeypatch):
    p = write_scene(tmp_path, scene_dict(background=[-1, 0, 0]))
    line = refused(capsys, tmp_path, monkeypatch, "render", p, "-o", tmp_path / "o.exr")
    assert line == f"hwrt: error: {p}: key 'background': must not be negative, got [-1.0, 0.0, 0.0]"
    (tmp_path / "w.json").write_text(
        json.dumps(scene_dict()).replace('"spp"', f'"width": 1{"0" * 5000}, "spp"', 1)
        .replace('"width": 8, ', ""))
    line = refused(capsys, tmp_path, monkeypatch, "render", tmp_path / "w.json", "-o",
                   tmp_path / "o.exr")
    assert line.startswith(f"hwrt: error: {tmp_path / 'w.json'}: key 'film.width': ") and \
        line.endswith("got an integer of 5001 digits"), line


@pytest.mark.parametrize("name, key", [("marbles", "n"), ("cloth", "n"), ("room", "slats")])
def test_a_builtin_count_beyond_one_tree_is_refused_before_its_shapes_are_made(name, key):
    """A built-in scene's count parameter stops at the largest scene one tree holds, before any
    shape is made (n=10**9 would make a billion shapes), and the limit is the scenes' own
    arithmetic: the compiled scene grows by the counted triangles per item."""
    from hwbvh.config import MAX_PRIMITIVES
    from hwbvh.errors import ParameterError
    from scenes import compile_scene, load_scene
    from scenes.builtin import COUNT_LIMITS
    most = COUNT_LIMITS[name][key]
    with pytest.raises(ParameterError, match=f"{key}: {most + 1} makes more triangles than the "
                                             f"2\\^24 a tree holds: at most {most}"):
        load_scene(name, **{key: most + 1})
    with pytest.raises(ParameterError, match=f"{key}: 1000000000 makes more"):
        load_scene(name, **{key: 10 ** 9})
    count = {v: len(compile_scene(load_scene(name, width=4, height=4, spp=1,
                                             **{key: v})).triangles) for v in (1, 2, 3)}
    if name == "cloth":                                 # quadratic: the rest plus 2 n^2
        rest = count[1] - 2
        assert all(count[v] == rest + 2 * v * v for v in count)
        total = lambda v: rest + 2 * v * v             # noqa: E731
    else:
        per = count[2] - count[1]
        rest = count[1] - per
        assert count[3] == rest + 3 * per
        total = lambda v: rest + v * per               # noqa: E731
    assert total(most) <= MAX_PRIMITIVES < total(most + 1)


def test_vectors_take_numbers_only_and_integers_past_float64_are_named():
    """Vectors take numbers only (["0", "0", "3"] is refused as fov="40" is), and an integer
    past float64's range is named with its key, as every bad value is."""
    import copy
    import hwbvh
    from hwbvh.errors import InputError
    from scenes import compile_scene, load_scene
    base = load_scene("cornell", width=8, height=6, spp=1)
    quad = next(k for k, s in enumerate(base["shapes"]) if s["type"] == "quad")
    cases = [(("camera", "eye"), ["0", "0", "3"], "camera.eye': expected 3 numbers"),
             (("camera", "eye"), [b"0", 0, 3], "camera.eye': expected 3 numbers"),
             (("camera", "eye"), [0, 0, 10 ** 400], "camera.eye': expected 3 finite numbers of "
                                                    "magnitude at most 1e+15"),
             (("lights", 0, "intensity"), 10 ** 400, "lights[0].intensity': expected 3 finite"),
             (("lights", 0, "position"), ["1", 1, 1], "lights[0].position': expected 3 numbers"),
             (("shapes", quad, "corners"), [[0, 0, 0], [1, 0, 0], [1, 1, 10 ** 400], [0, 1, 0]],
              f"shapes[{quad}].corners': expected 4 corners")]
    for keys, value, message in cases:
        d = copy.deepcopy(base)
        target = d
        for k in keys[:-1]:
            target = target[k]
        target[keys[-1]] = value
        with pytest.raises(InputError, match=message.replace("[", r"\[").replace("+", r"\+")):
            compile_scene(d)
    d = copy.deepcopy(base)
    d["shapes"].append({"type": "triangles", "material": d["shapes"][0]["material"],
                        "data": [[[0, 0, 0], [1, 0, 0], [0, 1, 10 ** 400]]]})
    with pytest.raises(InputError, match="data': expected numbers of magnitude at most 1e\\+15"):
        compile_scene(d)
    with pytest.raises(InputError, match="a coordinate is too large"):
        hwbvh.build([[[0, 0, 0], [1, 0, 0], [0, 1, 10 ** 400]]])


@pytest.mark.parametrize("radius", [1e-7, 1e-18, 1e-30])
def test_a_sphere_too_small_for_its_place_is_refused_however_small(radius, tmp_path, capsys,
                                                                    monkeypatch):
    """Beside a centre at about 1 a radius of 1e-7 rounds to a float32 step, one of 1e-18 to no
    extent at all: both collapse, and are said to, rather than the smaller rendering as
    nothing."""
    shape = {"type": "sphere", "center": [1.2, 0.4, 0.6], "radius": radius, "material": "m"}
    p = write_scene(tmp_path, scene_dict([shape]))
    line = refused(capsys, tmp_path, monkeypatch, "render", p, "-o", tmp_path / "o.exr")
    assert f"{p}: key 'shapes[0].center': the sphere collapses" in line


@pytest.mark.parametrize("file", ["..json", "a\nb.json", "..toml"])
def test_a_scene_file_whose_name_is_not_plain_needs_a_name_key(tmp_path, capsys, monkeypatch,
                                                               file):
    d = scene_dict()
    p = tmp_path / file
    p.write_text(json.dumps(d) if file.endswith(".json") else
                 "[camera]\neye = [0, 1, 4]\ntarget = [0, 0, 0]\n")
    line = refused(capsys, tmp_path, monkeypatch, "render", p, "--width", 8, "--height", 8)
    from hwrt.cli import one_line
    # the file is blamed (its name escaped to one line), not a key the file never had
    assert line.startswith(f"hwrt: error: {one_line(str(p))}: its file name makes the scene's "
                           f"name "), line
    assert line.endswith("not a plain file name (outputs are named after it): rename the file "
                         "or give the scene a key 'name'"), line
    if file.endswith(".json"):
        p.write_text(json.dumps(dict(d, name="given")))
        assert load_scene(str(p))["name"] == "given"


@pytest.mark.parametrize("file, name", [("a.b.json", "a.b"), ("Scene.JSON", "Scene"),
                                        ("x.toml.json", "x.toml")])
def test_a_scene_is_named_after_its_file_without_the_extension(tmp_path, file, name):
    p = tmp_path / file
    p.write_text(json.dumps(scene_dict()))
    assert load_scene(str(p))["name"] == name


def test_a_mesh_file_whose_name_is_not_plain_is_refused_naming_it(tmp_path, capsys, monkeypatch):
    import trimesh
    p = tmp_path / "..ply"
    trimesh.creation.box().export(p)
    line = refused(capsys, tmp_path, monkeypatch, "render", p, "--width", 8, "--height", 8)
    assert line.endswith("its file name makes the scene's name '.', which is not a plain file "
                         "name (outputs are named after it): rename the file"), line


@pytest.mark.parametrize("shape", [
    {"type": "sheet", "size": 0, "wave": 0, "resolution": [2, 2]},
    {"type": "box", "min": [1, 2, 3], "max": [1, 2, 3]},
    {"type": "quad", "corners": [[1, 1, 1]] * 4},
    {"type": "triangles", "data": [[[0.5, 0.5, 0.5]] * 3]}])
def test_a_shape_given_no_extent_is_taken_and_renders_nothing(shape):
    """What its keys say has no size has none to lose: it is not refused as collapsing, as a
    sphere that rounds to a point is (above), and no ray hits it."""
    from raytracer.render import make_tracer, render
    d = scene_dict([dict(shape, material="white")])
    scene = compile_scene(d, source="dict")
    assert (scene.triangles == scene.triangles[0, 0]).all()
    res = render(scene, make_tracer(scene)[0])
    assert (res.prim == -1).all()


def test_a_frame_pattern_may_hold_a_percent_sign_beside_its_field(tmp_path, capsys, monkeypatch):
    """Only the frame field is formatted: a '%' elsewhere in the name (50%_0001.ply) is part of
    it, not a format error."""
    import trimesh
    from scenes.animation import expand_pattern
    for k in range(3):
        trimesh.creation.box().export(tmp_path / f"50%_{k:04d}.ply")
    pattern = str(tmp_path / "50%_%04d.ply")
    assert expand_pattern(pattern) == [str(tmp_path / f"50%_{k:04d}.ply") for k in range(3)]
    line = refused(capsys, tmp_path, monkeypatch, "render", pattern)
    assert line.endswith("a frame sequence (a %d or glob pattern of mesh files): render it with "
                         "hwrt animate")


@pytest.mark.parametrize("key, value", [("spp", 4.0), ("width", 1e2), ("height", 16.0)])
def test_a_whole_number_written_as_a_float_is_not_taken_for_an_integer_key(tmp_path, capsys,
                                                                           monkeypatch, key,
                                                                           value):
    """Integer keys take integers, as a sphere's subdiv does: JSON and TOML write 4 and 4.0
    apart, so 4.0 is a float the file gave."""
    d = scene_dict()
    d["film"] = dict(d["film"], **{key: value})
    p = write_scene(tmp_path, d)
    line = refused(capsys, tmp_path, monkeypatch, "render", p)
    assert line.endswith(f"key 'film.{key}': expected an integer, got {value!r}"), line
    t = tmp_path / "s.toml"
    t.write_text(f"[camera]\neye = [0, 1, 4]\ntarget = [0, 0, 0]\n[film]\n{key} = {value!r}\n"
                 "[materials.m]\ntype = 'diffuse'\n[[shapes]]\ntype = 'sphere'\n"
                 "center = [0, 0, 0]\nradius = 1\nmaterial = 'm'\n")
    line = refused(capsys, tmp_path, monkeypatch, "render", t)
    assert line.endswith(f"key 'film.{key}': expected an integer, got {value!r}"), line


def test_a_material_named_by_a_number_in_a_python_dict_is_refused_by_key():
    """JSON's keys are strings; a scene dict made in Python may name a material 1."""
    d = load_scene("cornell", width=8, height=8, spp=1)
    d["materials"] = {1: {"type": "diffuse"}}
    for shape in d["shapes"]:
        shape["material"] = 1
    with pytest.raises(InputError) as e:
        compile_scene(d)
    assert str(e.value) == "cornell: key 'materials': material names must be strings, got 1"


@pytest.mark.parametrize("kw, problem", [
    ({"first_shape": "a"}, "first_shape: must be an integer >= 0, got 'a'"),
    ({"first_shape": -1}, "first_shape: must be an integer >= 0, got -1"),
    ({"source": 5}, "source: must be a file name or None, got int"),
])
def test_compile_scene_names_a_bad_argument(kw, problem):
    with pytest.raises(ParameterError) as e:
        compile_scene(load_scene("cornell", width=8, height=8, spp=1), **kw)
    assert str(e.value) == problem


def test_relative_mesh_names_keep_to_the_scene_files_directory(tmp_path, monkeypatch):
    """A scene file read with a relative path names its meshes relative to its own directory
    as it was when read: after a change of the working directory the dict still compiles
    the same mesh, not a file of the same name elsewhere."""
    from scenes import compile_scene, load_scene

    tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    (tmp_path / "sc").mkdir()
    (tmp_path / "sc" / "m.obj").write_text(tri)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "m.obj").write_text(tri + "v 5 5 5\nv 6 5 5\nv 5 6 5\nf 4 5 6\n")
    (tmp_path / "other" / "sc").mkdir()
    (tmp_path / "other" / "sc" / "m.obj").write_text(tri + "v 5 5 5\nv 6 5 5\nv 5 6 5\nf 4 5 6\n")
    (tmp_path / "sc" / "s.json").write_text(json.dumps({
        "camera": {"eye": [0.3, 0.3, 3], "target": [0.3, 0.3, 0]},
        "materials": {"m": {"type": "diffuse"}},
        "shapes": [{"type": "mesh", "filename": "m.obj", "material": "m"}]}))
    monkeypatch.chdir(tmp_path)
    d = load_scene("sc/s.json")
    monkeypatch.chdir(tmp_path / "other")
    assert len(compile_scene(d).triangles) == 1


def test_a_scene_dict_saved_reads_back_as_the_same_scene(tmp_path, monkeypatch):
    """save_scene writes what load_scene reads: a built-in, a mesh scene and a scene file
    with a relative mesh name saved into another directory compile to the same arrays. It
    refuses what has no file form, a name that is not .json, and a file the scene reads."""
    from hwbvh.errors import ParameterError
    from scenes import compile_scene, load_scene, mesh_scene, save_scene, transform_scene

    (tmp_path / "sc").mkdir()
    (tmp_path / "sc" / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "sc" / "s.json").write_text(json.dumps({
        "camera": {"eye": [0.3, 0.3, 3], "target": [0.3, 0.3, 0]},
        "materials": {"m": {"type": "diffuse"}},
        "shapes": [{"type": "mesh", "filename": "m.obj", "material": "m"}]}))
    monkeypatch.chdir(tmp_path)
    for i, d in enumerate((load_scene("cornell", width=16, height=12),
                           mesh_scene(str(tmp_path / "sc" / "m.obj")), load_scene("sc/s.json"))):
        path = tmp_path / "out" / f"saved{i}.json"
        assert save_scene(d, str(path)) == str(path)
        back = load_scene(str(path))
        a, b = compile_scene(d), compile_scene(back)
        assert np.array_equal(a.triangles, b.triangles) and a.name == b.name
        assert (a.width, a.height, a.spp, a.camera["eye"].tolist()) == \
            (b.width, b.height, b.spp, b.camera["eye"].tolist())
        assert not any(k.startswith("_") for k in json.loads(path.read_text()))
    unnamed = {k: v for k, v in load_scene("cornell").items() if k != "name"}
    save_scene(unnamed, str(tmp_path / "out" / "c.json"))
    assert load_scene(str(tmp_path / "out" / "c.json"))["name"] == "scene"   # as compiled
    shaped = transform_scene(d, 2.0)                  # then its shapes given as a tuple
    with pytest.raises(ParameterError, match="transform_scene"):
        save_scene(dict(shaped, shapes=tuple(shaped["shapes"])), str(tmp_path / "t.json"))
    d = load_scene("cornell")
    for bad, parameter, words in ((transform_scene(d, 2.0), "d", "transform_scene"),
                                  (d, "path", ".json")):
        with pytest.raises(ParameterError, match=words) as e:
            save_scene(bad, str(tmp_path / ("x.json" if parameter == "d" else "x.toml")))
        assert e.value.parameter == parameter
    with pytest.raises(InputError):
        save_scene(load_scene("sc/s.json"), "sc/s.json")            # its own file
    read_here = load_scene("sc/s.json")
    monkeypatch.chdir(tmp_path / "out")                           # from anywhere
    with pytest.raises(InputError, match="input"):
        save_scene(read_here, str(tmp_path / "sc" / "s.json"))
    monkeypatch.chdir(tmp_path)
    with pytest.raises(InputError):
        save_scene(dict(d, camera={}), str(tmp_path / "bad.json"))    # not a scene
    assert not (tmp_path / "bad.json").exists() and not (tmp_path / "x.json").exists()


def test_a_scene_file_that_starts_with_a_byte_order_mark_reads_as_without(tmp_path):
    d = scene_dict()
    plain = compile_scene(load_scene(str(write_scene(tmp_path, d))))
    path = tmp_path / "bom.json"
    path.write_text(json.dumps(d), encoding="utf-8-sig")
    assert np.array_equal(compile_scene(load_scene(str(path))).triangles, plain.triangles)
    toml = tmp_path / "bom.toml"
    toml.write_text('[camera]\neye = [0, 1, 4]\ntarget = [0, 1, 0]\n[materials.m]\n'
                    'type = "diffuse"\n[[shapes]]\ntype = "quad"\nmaterial = "m"\n'
                    'corners = [[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]]\n',
                    encoding="utf-8-sig")
    assert len(compile_scene(load_scene(str(toml))).triangles) == 2


def test_an_error_line_stays_short_however_long_the_files_keys_and_names(tmp_path, capsys,
                                                                          monkeypatch):
    """A key or a material name may be as long as the file, and a scene may define thousands
    of materials: the one error line names them cut short."""
    from scenes.loader import KEY_TEXT_LIMIT
    long_key = "k" * 100_000
    d = scene_dict()
    d["camera"][long_key] = 1
    line = refused(capsys, tmp_path, monkeypatch, "render", write_scene(tmp_path, d))
    assert "key 'camera.kkk" in line and "...': unknown key (known keys: type, eye" in line
    assert len(line) < 2 * KEY_TEXT_LIMIT + 100 + len(str(tmp_path))
    d = scene_dict(materials={long_key: {"type": "diffuse", "bogus": 1}})
    line = refused(capsys, tmp_path, monkeypatch, "render", write_scene(tmp_path, d))
    assert "key 'materials.kkk" in line and "....bogus': unknown key" in line
    d = scene_dict(materials={f"mat{i}": {"type": "diffuse"} for i in range(20_000)})
    line = refused(capsys, tmp_path, monkeypatch, "render", write_scene(tmp_path, d))
    assert line.endswith("key 'shapes[0].material': unknown material 'white' (defined: mat0, "
                         "mat1, mat2, mat3, mat4, mat5, mat6, mat7, mat8, mat9, mat10, mat11 and "
                         "19988 more)")
    d = scene_dict()
    d["animation"] = {long_key: 1}
    line = refused(capsys, tmp_path, monkeypatch, "animate", write_scene(tmp_path, d), "-o",
                   tmp_path / "o")
    assert "key 'animation.kkk" in line and len(line) < 400 + len(str(tmp_path))


@pytest.mark.parametrize("name", ["s.json", "s.toml"])
def test_an_empty_scene_file_is_named_as_empty(tmp_path, capsys, monkeypatch, name):
    """As an empty mesh file is: not a JSON syntax error at line 1, column 1, nor a scene
    without a camera."""
    p = tmp_path / name
    p.write_text("")
    line = refused(capsys, tmp_path, monkeypatch, "render", p)
    assert line == f"hwrt: error: {p}: empty file"
