"""The compiled wavefront renderer: the same image as the NumPy reference, whatever the thread
count; one tracer interface for both back ends; verification of every closest-hit and every
shadow answer the shading used."""
import os

import numba
import numpy as np
import pytest

from raytracer import stages
from raytracer import pcg64
from raytracer.config import MIN_BANDS, PIXEL
from raytracer.render import TILE, band_rows, make_tracer, render
from traversal.camera import tile_order
from scenes import compile_scene, load_scene
from scenes.builtin import BUILTIN
from traversal.embree_ref import EmbreeTracer
from traversal.tracers import CountingTracer, RecordingTracer, VerifyingTracer

from .late_hits import LateHits
from .naive_whitted import naive_render


def small(name, w=48, h=36, spp=2, **kw):
    d = load_scene(name, width=w, height=h, spp=spp, **kw)
    return compile_scene(d)


@pytest.mark.parametrize("name,precision", [(name, "float32") for name in BUILTIN] +
                         [("cornell", "float64"), ("marbles", "float64")])
def test_compiled_stages_match_the_numpy_reference(name, precision):
    sc = small(name)
    tracer, _, _ = make_tracer(sc, precision=precision)
    res = render(sc, tracer, seed=5)
    image, rays, depth, normal, prim = naive_render(sc, tracer, seed=5)
    assert res.stats["rays"] == rays
    # same rays, same hits; only the order of the film's float64 sums differs
    np.testing.assert_allclose(res.image, image, rtol=1e-6, atol=1e-7)
    assert np.array_equal(res.prim, prim) and np.array_equal(res.depth, depth)
    np.testing.assert_array_equal(res.normal, normal)


def test_wavefront_grows_when_dielectrics_double_the_rays():
    # a glass sphere filling the view: each hit spawns a reflection and a refraction, so later
    # wavefronts outgrow the camera's (the queues must grow, not overflow); and blocks in which
    # nearly every ray spawns, which the shading's pass 4 shades in place (stages.shade)
    d = load_scene("cornell", width=24, height=18, spp=1, max_depth=6)
    d["camera"] = {"eye": [0.42, 0.38, 1.0], "target": [0.42, 0.38, 0.25], "fov": 40.0}
    sc = compile_scene(d)
    tracer, _, _ = make_tracer(sc)
    res = render(sc, tracer)
    image, rays, *_ = naive_render(sc, tracer)
    assert rays["reflection"] + rays["refraction"] > 2 * rays["primary"]
    assert res.stats["rays"] == rays
    np.testing.assert_allclose(res.image, image, rtol=1e-6, atol=1e-7)


def test_image_independent_of_thread_count():
    # several bands of rows, the last of a height that is not a whole camera tile, with more
    # than one block each; two lights, so a pixel's sum has an order
    d = load_scene("marbles", width=256, height=130, spp=2)
    d["lights"] = d["lights"] + [{"type": "point", "position": [0.3, 2.0, 0.8],
                                  "intensity": [1.5, 1.4, 1.2]}]
    sc = compile_scene(d)
    rows = band_rows(sc.width, sc.height)
    assert -(-sc.height // rows) >= 3 and sc.height % rows % TILE
    assert stages.n_blocks(rows * sc.width) >= 2
    tracer, _, _ = make_tracer(sc)
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = render(sc, tracer, seed=1)
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        many = render(sc, tracer, seed=1)
    finally:
        numba.set_num_threads(before)
    assert np.array_equal(one.image, many.image)
    assert np.array_equal(one.prim, many.prim) and one.stats["rays"] == many.stats["rays"]


@pytest.mark.parametrize("name", list(BUILTIN))
def test_every_builtin_scene_verifies_clean(name):
    sc = small(name, 40, 30, 1)
    tracer, _, _ = make_tracer(sc)
    checked = VerifyingTracer(tracer, sc.triangles, sc.vertices, sc.faces)
    res = render(sc, checked, seed=2)
    v = checked.summary()
    rays = res.stats["rays"]
    # every query the shading made was checked: closest hits and shadow answers alike
    assert v["shadow"]["rays"] == rays["shadow"]
    assert v["closest"]["rays"] == rays["primary"] + rays["reflection"] + rays["refraction"]
    assert v["mismatch"] == 0, v
    # and the checked render is the same render
    assert np.array_equal(res.image, render(sc, tracer, seed=2).image)


def test_shadow_verification_catches_a_wrong_answer():
    sc = small("cornell", 24, 18, 1)
    tracer, _, _ = make_tracer(sc)

    class NeverBlocked:                    # a broken tracer: shadow rays never blocked
        def intersect(self, *a, **kw):
            return tracer.intersect(*a, **kw)

        def occluded(self, o, d, tmin=0.0, tmax=np.inf):
            return np.zeros(len(o), bool)

    checked = VerifyingTracer(NeverBlocked(), sc.triangles, sc.vertices, sc.faces)
    render(sc, checked)
    assert checked.counts["shadow"]["mismatch"] > 0
    assert checked.counts["closest"]["mismatch"] == 0


def test_both_back_ends_share_the_interface_and_the_shading():
    sc = small("cloth", 32, 24, 1)
    ours, _, _ = make_tracer(sc)
    emb = EmbreeTracer(sc.vertices, sc.faces)
    o = np.tile(np.asarray(sc.camera["eye"], np.float64), (3, 1))
    d = np.array([[0.0, -1.0, 0.0], [0.0, -0.6, -0.8], [0.0, 1.0, 0.0]])
    for tr in (ours, emb):
        h = tr.intersect(o, d, 0.0, np.inf, normals=False)
        assert h.prim.dtype == np.int32 and len(h.t) == 3 and h.ng is None
        assert tr.occluded(o, d, 0.0, np.full(3, 1e30)).dtype == bool
    a = render(sc, ours)
    b = render(sc, emb)
    assert a.stats["rays"]["primary"] == b.stats["rays"]["primary"]
    assert (np.abs(a.image - b.image).max(axis=2) > 0.02).mean() < 0.01


def test_counting_and_recording_wrappers():
    sc = small("room", 32, 24, 1)
    tracer, _, _ = make_tracer(sc)
    counting = CountingTracer(tracer)
    res = render(sc, counting)
    w = counting.work()
    assert w["rays"] == res.stats["rays"]["primary"] + res.stats["rays"]["reflection"]
    assert w["nodes_per_ray"] >= 1 and w["tris_per_ray"] > 0
    with pytest.raises(ValueError, match="counters"):
        CountingTracer(EmbreeTracer(sc.vertices, sc.faces))
    rec = RecordingTracer(tracer)
    res = render(sc, rec)
    assert rec.rays() == sum(res.stats["rays"].values())
    assert rec.replay_seconds() > 0
    # a replay asks what the render asked: a scalar bound as given (a Python float's checks
    # are kept per value), an array of bounds as a copy of it
    kinds = {(type(q[3]), type(q[4])) for q in rec.queries}
    assert (float, float) in kinds and (float, np.ndarray) in kinds, kinds
    O, D = np.zeros((2, 3), np.float32), np.ones((2, 3), np.float32)
    far = np.full(2, 5.0, np.float32)
    rec.occluded(O, D, 0.0, far)
    far[:] = 0.0
    assert rec.queries[-1][3] == 0.0 and list(rec.queries[-1][4]) == [5.0, 5.0]


def test_counters_as_run_count_packet_work():
    sc = small("cornell", 32, 32, 1)
    tracer, _, _ = make_tracer(sc)
    from traversal import raysets
    O, D = raysets.primary(sc.triangles, 1024)           # camera rays in 4x4 tiles
    plain = tracer.intersect(O, D)
    run = tracer.intersect(O, D, counters=True, as_run=True)
    packets = tracer.last_packets
    single = tracer.intersect(O, D, counters=True)
    assert np.array_equal(run.prim, plain.prim) and np.array_equal(run.t, plain.t)
    assert packets > 0 and tracer.last_packets == 0
    m = 16 * (len(O) // 16)
    c = run.counters[:m].reshape(-1, 16, 2)
    packed = (c == c[:, :1]).all(axis=(1, 2))            # a packet's lanes share its work
    assert packed.sum() >= packets
    # a packet visits the union of its rays' nodes: at least each of its rays' own count
    own = single.counters[:m].reshape(-1, 16, 2)
    assert (c[packed][..., 0] >= own[packed][..., 0]).all()


def test_kept_buffers_do_not_leak_between_renders():
    from raytracer.render import release_buffers
    big, tiny = small("cornell", 40, 30, 1), small("marbles", 12, 9, 2)
    tracer_big, _, _ = make_tracer(big)
    tracer_tiny, _, _ = make_tracer(tiny)
    release_buffers()
    fresh_big = render(big, tracer_big, seed=4)
    release_buffers()
    fresh_tiny = render(tiny, tracer_tiny, seed=4)
    # kept buffers from a larger render, then from a smaller one, give the same images
    again_tiny = render(tiny, tracer_tiny, seed=4)
    again_big = render(big, tracer_big, seed=4)
    assert np.array_equal(again_tiny.image, fresh_tiny.image)
    assert np.array_equal(again_big.image, fresh_big.image)
    assert np.array_equal(again_big.prim, fresh_big.prim)


class _SeesItsOwnSurface:
    """A broken tracer: every query starts a little behind its origin, so secondary and shadow
    rays can hit the surface they leave (self-intersection)."""

    def __init__(self, inner, closest):
        self.inner, self.closest = inner, closest

    def _back(self, o, d):
        o = np.asarray(o, np.float64)
        d = np.asarray(d, np.float64)
        return o - d * (1e-5 * np.abs(o).max(axis=1, keepdims=True) + 1e-5)

    def intersect(self, o, d, tmin=0.0, tmax=np.inf, normals=True):
        if self.closest:
            o = self._back(o, d)
        return self.inner.intersect(o, d, tmin, tmax, normals=normals)

    def occluded(self, o, d, tmin=0.0, tmax=np.inf):
        if not self.closest:
            o = self._back(o, d)
        return self.inner.occluded(o, d, tmin, tmax)


@pytest.mark.parametrize("closest", [False, True])
def test_verification_catches_self_intersection(closest):
    sc = small("marbles", 32, 24, 1)
    tracer, _, _ = make_tracer(sc)
    checked = VerifyingTracer(_SeesItsOwnSurface(tracer, closest), sc.triangles, sc.vertices, sc.faces)
    render(sc, checked)
    kind = "closest" if closest else "shadow"
    assert checked.counts[kind]["mismatch"] > 0, checked.counts


def test_shadows_off_with_lights_and_no_diffuse_material():
    # lights, but only mirrors and glass: no shadow rays, and the light table must not size the
    # shadow slots (it did, and the kernel wrote past them)
    d = load_scene("cornell", width=24, height=18, spp=1)
    for m in d["materials"].values():
        if m["type"] == "diffuse":
            m.clear()
            m.update({"type": "mirror", "reflectance": [0.8, 0.8, 0.8]})
    d["lights"] = d["lights"] * 6
    sc = compile_scene(d)
    tracer, _, _ = make_tracer(sc)
    res = render(sc, tracer)
    image, rays, *_ = naive_render(sc, tracer)
    assert res.stats["rays"]["shadow"] == 0 == rays["shadow"]
    np.testing.assert_allclose(res.image, image, rtol=1e-6, atol=1e-7)


def test_bands_on_all_threads_or_one_by_one_give_the_same_render():
    """A tracer that takes queries from several threads gets the bands on all of them; a
    wrapper gets them one by one on the calling thread, each query on all threads."""
    d = load_scene("cornell", width=96, height=70, spp=3)
    d["lights"] = d["lights"] + [{"type": "directional", "direction": [0.2, -1.0, -0.3],
                                  "irradiance": [0.4, 0.4, 0.5]}]
    sc = compile_scene(d)
    tracer, _, _ = make_tracer(sc)
    assert tracer.concurrent and not getattr(RecordingTracer(tracer), "concurrent", False)
    rec = RecordingTracer(tracer)
    a = render(sc, tracer, seed=4)
    b = render(sc, rec, seed=4)
    assert np.array_equal(a.image, b.image) and np.array_equal(a.prim, b.prim)
    assert np.array_equal(a.depth, b.depth) and np.array_equal(a.normal, b.normal)
    assert a.stats["rays"] == b.stats["rays"]
    assert rec.rays() == sum(b.stats["rays"].values())


class _OneAtATime:
    """The tracer it wraps, but taking one query at a time (not ``concurrent``)."""
    concurrent = False

    def __init__(self, inner):
        self.inner = inner
        self.has_counters = getattr(inner, "has_counters", False)
        self.dtype = inner.dtype

    def intersect(self, *args, **kw):
        return self.inner.intersect(*args, **kw)

    def occluded(self, *args, **kw):
        return self.inner.occluded(*args, **kw)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two threads to overlap")
def test_counting_and_verifying_wrappers_take_bands_on_all_threads_and_sum_alike():
    """A counting or verifying wrapper of a concurrent tracer is concurrent: bands run on all
    threads and add to one set of totals, which come out as when the queries come one at a
    time."""
    sc = compile_scene(load_scene("marbles", width=96, height=72, spp=2))
    tracer, _, _ = make_tracer(sc)
    for wrap in (lambda t: CountingTracer(t, as_run=True),
                 lambda t: VerifyingTracer(t, sc.triangles, sc.vertices, sc.faces)):
        together, alone = wrap(tracer), wrap(_OneAtATime(tracer))
        assert together.concurrent and not alone.concurrent
        a = render(sc, together, seed=1)
        b = render(sc, alone, seed=1)
        assert np.array_equal(a.image, b.image)
        sums = (lambda w: w.totals) if isinstance(together, CountingTracer) else \
            (lambda w: w.counts)
        assert sums(together) == sums(alone)
        assert sum(sums(together)["closest"].values()) > 0


@pytest.mark.parametrize("width,height", [(640, 480), (7, 5), (1000, 3), (33, 130), (256, 36)])
def test_bands_are_whole_tile_rows_that_cover_the_frame(width, height):
    rows = band_rows(width, height)
    assert rows % TILE == 0 and rows >= TILE
    assert rows < height + TILE                     # no band taller than the frame needs
    if height >= MIN_BANDS * TILE:
        assert -(-height // rows) >= MIN_BANDS


def test_a_bands_camera_rays_are_its_slots_of_the_tile_order():
    W, H = 37, 30
    order = tile_order(W, H)
    rows = 8
    for y0 in range(0, H, rows):
        y1 = min(H, y0 + rows)
        n = (y1 - y0) * W
        Ot, Dt = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)
        pix = np.empty(n, PIXEL)
        terms = stages.camera_terms(W, H, 0.5, 0, 0, 1, 1)
        stages.generate_camera_rays(y0, y1, W, np.zeros(0), np.zeros(0), False, terms,
                                    np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]),
                                    np.array([0, 0, -1.0]), pix, Ot, Dt, np.empty(n),
                                    np.empty(n))
        assert np.array_equal(pix, order[y0 * W:y1 * W])


def test_camera_rays_are_the_pinhole_formula_bit_for_bit():
    """The directions and origins of one band in the tracer's precision (float32 and
    float64), with and without jitter, against the formula evaluated ray by ray in NumPy in
    the kernel's order of operations, rounded to that precision."""
    W, H, y0, y1 = 37, 30, 8, 16
    eye = np.array([0.3, 1.1, 4.0])
    cu, cv, cw = np.array([0.8, 0.0, -0.6]), np.array([0.0, 1.0, 0.0]), np.array([-0.6, 0.0, -0.8])
    n = (y1 - y0) * W
    rng = np.random.default_rng(5)
    for jitter, dtype in ((False, np.float32), (True, np.float32), (True, np.float64)):
        jx, jy = (rng.random(n), rng.random(n)) if jitter else (np.zeros(0), np.zeros(0))
        terms = stages.camera_terms(W, H, 0.7, 1, 0, 2, 2)
        Ot, Dt = np.empty((n, 3), dtype), np.empty((n, 3), dtype)
        pix = np.empty(n, PIXEL)
        stages.generate_camera_rays(y0, y1, W, jx, jy, jitter, terms, eye, cu, cv, cw,
                                    pix, Ot, Dt, np.empty(n), np.empty(n))
        off_x, off_y, inv_gx, inv_gy, kx, bx, ky, by = terms
        x, y = pix % W, pix // W
        if jitter:
            px = x + (off_x + jx[pix - y0 * W]) * inv_gx
            py = y + (off_y + jy[pix - y0 * W]) * inv_gy
        else:
            px, py = x + 0.5, y + 0.5
        sx, sy = px * kx - bx, by - py * ky
        d = sx[:, None] * cu + sy[:, None] * cv + cw
        d = d * (1.0 / np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]))[:, None]
        assert np.array_equal(Dt, d.astype(dtype))
        assert np.array_equal(Ot, np.tile(eye.astype(dtype), (n, 1)))


@pytest.mark.parametrize("seed,sample", [(0, 0), (3, 1), (2 ** 40, 9)])
def test_pixel_offsets_are_numpys_stream_bit_for_bit(seed, sample):
    ref = np.random.default_rng([seed, sample]).random(5000)
    words = pcg64.stream_words(seed, sample)
    for start, n in [(0, 5000), (1, 4999), (63, 700), (64, 1), (4990, 10), (17, 0)]:
        out = np.empty(n)
        pcg64.uniforms(words, start, out)
        assert np.array_equal(out, ref[start:start + n]), (start, n)
    bits = np.random.PCG64()
    bits.state = np.random.default_rng([seed, sample]).bit_generator.state
    bits.advance(3 * 10 ** 12)
    far = np.empty(130)
    pcg64.uniforms(words, 3 * 10 ** 12, far)
    assert np.array_equal(far, np.random.Generator(bits).random(130))
    for bad in (-1, 2 ** 63 - 1):
        with pytest.raises(ValueError, match="start"):
            pcg64.uniforms(words, bad, np.empty(3))


def test_release_buffers_frees_the_shading_scratch_too():
    """Everything a thread keeps between renders (wavefronts, film, shading scratch, triangle
    records) goes with ``release_buffers``; a wrapper tracer renders every band on this
    thread."""
    from raytracer import render as renderer
    from traversal.tracers import RecordingTracer
    scene = small("cornell", 16, 12, 1)
    tracer, _, _ = make_tracer(scene)
    first = render(scene, RecordingTracer(tracer), seed=2)
    kept = renderer._kept_current()
    assert kept.scratch is not None and kept.buffers is not None and kept.film is not None
    assert kept.records is not None and kept.records.ctypes.data % 64 == 0
    renderer.release_buffers()
    kept = renderer._kept_current()
    assert kept.scratch is None and kept.buffers is None and kept.film is None
    assert kept.records is None
    again = render(scene, RecordingTracer(tracer), seed=2)
    assert np.array_equal(again.image, first.image)


def test_render_refuses_bad_arguments_and_answers_before_shading_reads_them():
    """A tracer's answers index the scene's arrays in compiled shading: a tracer built over
    other triangles, or one answering the wrong number of rays, is refused, not read past."""
    import dataclasses
    import hwbvh
    from hwbvh.errors import ParameterError
    from traversal import Tracer

    scene = small("cornell", 16, 12, 1)
    ours = Tracer(hwbvh.build(scene.triangles))
    wall = np.repeat(np.array([[[-50, -50, 2.0], [50, -50, 2.0], [0, 50, 2.0]]], np.float32), 500, 0)
    more = Tracer(hwbvh.build(np.concatenate([scene.triangles, wall])))

    class Short:
        def intersect(self, o, d, **kw):
            h = ours.intersect(o, d, **kw)
            return dataclasses.replace(h, prim=h.prim[:3])

        def occluded(self, *a, **kw):
            return ours.occluded(*a, **kw)

    class Foreign:                      # states no n_triangles: checked query by query
        def __init__(self, inner):
            self.inner = inner

        def intersect(self, *a, **kw):
            return self.inner.intersect(*a, **kw)

        def occluded(self, *a, **kw):
            return self.inner.occluded(*a, **kw)

    cases = [((scene, more), {}, "tracer", "not built over the scene's triangles"),
             ((scene, Foreign(more)), {}, "tracer", "outside the scene's"),
             ((scene, Short()), {}, "tracer", r"of shape \(3,\)"),
             ((load_scene("cornell"), ours), {}, "scene", "compiled scene"),
             ((scene, object()), {}, "tracer", "intersect and occluded"),
             ((scene, ours), {"seed": 1.5}, "seed", "integer"),
             ((scene, ours), {"progress": 5}, "progress", "callable"),
             ((dataclasses.replace(scene, spp=0), ours), {}, "scene.spp", "positive integer"),
             ((dataclasses.replace(scene, material=scene.material - 1), ours), {},
              "scene.material", r"must lie in \[0, 5\).*got -1\.\.3"),
             ((dataclasses.replace(scene, material=scene.material[1:]), ours), {},
              "scene.material", "an integer per triangle"),
             ((dataclasses.replace(scene, ior=scene.ior[:-1]), ours), {}, "scene.kd",
              "a row per material, got kd 5, ks 5, shininess 5, kr 5, ior 4"),
             ((dataclasses.replace(scene, kd=0.5), ours), {}, "scene.kd", "got kd none")]
    for args, kw, parameter, words in cases:
        with pytest.raises(ParameterError, match=words) as e:
            render(*args, **kw)
        assert e.value.parameter == parameter


def test_image_writers_refuse_what_they_cannot_write_naming_it(tmp_path):
    """A file name without the format's extension, a directory, a 4-channel image, a
    metadata value the header cannot hold as a number: named, or written as text."""
    from hwbvh.errors import ParameterError
    from hwbvh.files import OutputPathError
    from raytracer.output import read_exr, write_exr, write_png
    from raytracer.render import RenderResult

    h, w = 2, 3
    res = RenderResult(np.full((h, w, 3), 0.5, np.float32), np.ones((h, w), np.float32),
                       np.zeros((h, w, 3), np.float32), np.zeros((h, w), np.int32))
    for path in (tmp_path / "noext", tmp_path / "a.png", tmp_path / ".exr"):
        with pytest.raises(ParameterError, match=r"expected a file name with the extension "
                                                 r"\.exr, such as image\.exr"):
            write_exr(path, res)
    for path, result, problem in ((None, res, "path: expected a file path, got NoneType"),
                                  (tmp_path / "a.exr", res.image, "result: expected a render's "
                                   "result (raytracer.render.render returns one), got ndarray")):
        with pytest.raises(ParameterError) as e:
            write_exr(path, result)
        assert str(e.value) == problem
    write_exr(os.fsencode(tmp_path / "b.exr"), res)      # a path as bytes, as os functions take
    assert read_exr(tmp_path / "b.exr")[0].shape[:2] == (h, w)
    (tmp_path / "b.exr").unlink()
    for key in ("", 3):                         # each names a header attribute hwrt:<key>
        with pytest.raises(ParameterError, match="metadata: keys must be non-empty strings"):
            write_exr(tmp_path / "k.exr", res, {key: 1})
    (tmp_path / "d.exr").mkdir()
    with pytest.raises(OutputPathError, match="d.exr: is a directory; give a file path"):
        write_exr(tmp_path / "d.exr", res)
    four = RenderResult(np.zeros((h, w, 4), np.float32), res.depth, res.normal, res.prim)
    with pytest.raises(ParameterError, match=r"result.image: expected a non-empty \(h, w, 3\)"):
        write_exr(tmp_path / "four.exr", four)
    with pytest.raises(ParameterError, match="result.depth"):
        write_exr(tmp_path / "depth.exr", RenderResult(res.image, res.depth[:1], res.normal, res.prim))
    for prim in (np.full((h, w), 0.5), np.full((h, w), -2), np.full((h, w), 1 << 24)):
        with pytest.raises(ParameterError, match="result.prim: expected triangle ids"):
            write_exr(tmp_path / "prim.exr", RenderResult(res.image, res.depth, res.normal, prim))
    with pytest.raises(ParameterError, match="expected a file name with the extension .png"):
        write_png(tmp_path / "a.exr", res.image)
    write_exr(tmp_path / "ok.exr", res, {"rays": 2 ** 40, "flag": True, "t": 0.25, "n": 7,
                                         "source": "a\udcffb.ply", "\udcfe": 1})
    meta = read_exr(tmp_path / "ok.exr")[2]
    # a file name's undecodable byte (a lone surrogate in Python) goes in as its escape
    assert meta == {"rays": str(2 ** 40), "flag": "True", "t": 0.25, "n": 7,
                    "source": "a\\xffb.ply", "\\xfe": 1}
    with pytest.raises(ParameterError, match="layers: must be True or False, got 'no'"):
        write_exr(tmp_path / "no.exr", res, layers="no")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.exr", "ok.exr"]


def test_a_tracer_built_over_other_triangles_of_the_same_count_is_refused():
    """A tracer over the scene moved (as many triangles, other coordinates) would miss every
    ray: every tracer, and a wrapper of one, is refused for it."""
    import copy
    import hwbvh
    from hwbvh.errors import ParameterError
    from scenes.loader import transform_scene
    from traversal import Tracer
    from traversal.grid import GridTracer
    d = load_scene("cornell", width=8, height=6, spp=1)
    here = compile_scene(d)
    moved = compile_scene(transform_scene(copy.deepcopy(d), translate=(5, 0, 0)))
    tracers = [Tracer(hwbvh.build(here.triangles)), GridTracer(here.triangles),
               EmbreeTracer(here.vertices, here.faces)]
    tracers.append(CountingTracer(tracers[0]))
    prims = []
    for tracer in tracers:
        with pytest.raises(ParameterError, match="traces other triangles than the scene's "
                                                 r"\(9046 each, at other coordinates\)"):
            render(moved, tracer)
        prims.append(render(here, tracer).prim)
    assert (prims[0] >= 0).sum() > 30 and all(np.array_equal(p, prims[0]) for p in prims)


@pytest.mark.parametrize("name", ["a.exr", "a.png"])
def test_an_image_that_came_out_short_is_an_error_and_leaves_no_file(tmp_path, monkeypatch, name):
    """OpenImageIO's writers lose a failed last flush without a word (on a full disk the file
    ends short and close succeeds): the image is read back, and a short one is refused, named
    by the path asked for, with nothing left behind."""
    import raytracer.output as output
    from hwbvh.files import OutputError
    from raytracer.render import RenderResult
    read_back = output._check_whole

    def lose_the_end(tmp, path):
        os.truncate(tmp, os.path.getsize(tmp) - 100)
        read_back(tmp, path)
    monkeypatch.setattr(output, "_check_whole", lose_the_end)
    h, w = 40, 48
    ramp = np.linspace(0, 1, h * w * 3, dtype=np.float32).reshape(h, w, 3)
    res = RenderResult(ramp, np.ones((h, w), np.float32), ramp, np.arange(h * w).reshape(h, w))
    path = tmp_path / name
    with pytest.raises(OutputError, match="OpenImageIO could not write it") as e:
        if name.endswith(".exr"):
            output.write_exr(path, res)
        else:
            output.write_png(path, res.image)
    assert e.value.filename == str(path)
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(output, "_check_whole", read_back)     # whole: written
    output.write_exr(tmp_path / "a.exr", res)
    output.write_png(tmp_path / "a.png", res.image)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.exr", "a.png"]


def test_a_failed_write_names_the_file_asked_for_not_its_temporary_file(tmp_path, monkeypatch):
    import errno
    import hwbvh.files as files

    def full(*args, dir=None, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", os.path.join(dir, ".tmp-x.bin"))
    monkeypatch.setattr(files.tempfile, "mkstemp", full)
    with pytest.raises(OSError, match="No space left") as e:
        files.write_files([(tmp_path / "tree.bin", b"x")])
    assert e.value.filename == str(tmp_path / "tree.bin") and ".tmp-" not in str(e.value)


@pytest.mark.parametrize("kw, parameter", [
    ({"traversal": "bogus"}, "traversal"), ({"accel": "octree"}, "accel"),
    ({"accel": "grid", "leaf_size": 8}, "leaf_size"), ({"builder": "embree", "traversal": "embree",
                                                        "bins": 32}, "bins"),
    ({"watertight": "no"}, "watertight"), ({"precision": "float16"}, "precision")])
def test_make_tracer_checks_every_argument_before_building(kw, parameter, monkeypatch):
    """An argument that cannot apply is refused before the build, not ignored or after it."""
    import hwbvh
    from hwbvh.errors import ParameterError

    def no_build(*a, **k):
        raise AssertionError("built before the arguments were checked")
    monkeypatch.setattr(hwbvh, "build", no_build)
    with pytest.raises(ParameterError) as e:
        make_tracer(small("cornell", 8, 6, 1), **kw)
    assert e.value.parameter == parameter


def test_a_scene_beyond_the_float32_units_range_is_refused_before_any_work():
    """t = e2 . (s x e1) / det: at 1e13 the product of three lengths passes float32's range,
    so a float32 render is refused naming the scene; float64 traces it, and 1e12 renders."""
    import hwbvh
    from hwbvh.errors import ParameterError
    from scenes.loader import transform_scene
    from traversal import Tracer

    def scaled(s):
        return compile_scene(transform_scene(load_scene("cornell", width=16, height=12, spp=1), s))
    big = scaled(1e13)
    with pytest.raises(ParameterError, match="too large for the float32 units") as e:
        render(big, Tracer(hwbvh.build(big.triangles)))
    assert e.value.parameter == "scene"
    ref = render(scaled(1.0), Tracer(hwbvh.build(scaled(1.0).triangles), precision="float64"))
    far = render(big, Tracer(hwbvh.build(big.triangles), precision="float64"))
    assert (far.prim == ref.prim).mean() > 0.99
    near = scaled(1e12)
    assert np.isfinite(render(near, Tracer(hwbvh.build(near.triangles))).image).all()


def test_a_scene_too_small_for_the_float32_units_is_refused_before_any_work():
    """Scaled down to a span of 3.5e-14, the default scene's products of three lengths (t's
    numerator) fall below float32's normal numbers and a quarter of its pixels are wrong:
    a float32 render or tracer is refused naming the scene, float64 traces it as at scale 1,
    and a span of 3.5e-10 renders. A scene whose triangles all lie at one point is not
    refused (there is nothing to lose)."""
    import hwbvh
    from hwbvh.errors import ParameterError
    from scenes.loader import transform_scene
    from traversal import Tracer

    def scaled(s):
        return compile_scene(transform_scene(load_scene("cornell", width=16, height=12, spp=1), s))
    tiny = scaled(1e-14)
    with pytest.raises(ParameterError, match="too small for the float32 units.*scale it up") as e:
        render(tiny, Tracer(hwbvh.build(tiny.triangles)))
    assert e.value.parameter == "scene"
    with pytest.raises(ParameterError, match="too small for the float32 units"):
        make_tracer(tiny)
    ref = render(scaled(1.0), Tracer(hwbvh.build(scaled(1.0).triangles), precision="float64"))
    small = render(tiny, Tracer(hwbvh.build(tiny.triangles), precision="float64"))
    assert (small.prim == ref.prim).mean() > 0.99
    near = scaled(1e-10)
    assert (render(near, make_tracer(near)[0]).prim == ref.prim).mean() > 0.99
    point = scaled(1.0)
    point.triangles = np.zeros_like(point.triangles)
    assert (render(point, make_tracer(point)[0]).prim == -1).all()


def test_the_cli_names_the_scene_file_too_large_for_the_float32_units(tmp_path, capsys):
    import json
    from hwrt.cli import main

    big = {"camera": {"eye": [0, 3e13, 4e13], "target": [0, 0, 0]},
           "film": {"width": 8, "height": 6, "spp": 1}, "materials": {"w": {"type": "diffuse"}},
           "shapes": [{"type": "quad", "material": "w", "corners": [[-2e13, 0, -2e13],
                       [2e13, 0, -2e13], [2e13, 0, 2e13], [-2e13, 0, 2e13]]}]}
    p = tmp_path / "big.json"
    p.write_text(json.dumps(big))
    assert main(["render", str(p), "-o", str(tmp_path / "big.exr")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"hwrt: error: {p}: too large for the float32 units"), err
    assert not (tmp_path / "big.exr").exists()
    # verify traces it in float32 too: refused alike, before any work, for every ray set
    for kind in ("primary", "shadow"):
        assert main(["verify", str(p), "--kind", kind, "--rays", "100",
                     "--mismatches", str(tmp_path / "m.npz")]) == 2
        err = capsys.readouterr().err
        assert err.rstrip().startswith(f"hwrt: error: {p}: too large for the float32 units") and \
            err.rstrip().endswith("(scale it down)"), err


def test_the_cli_names_the_scene_file_too_small_for_the_float32_units(tmp_path, capsys):
    import json
    from hwrt.cli import main

    tiny = {"camera": {"eye": [0, 3e-14, 4e-14], "target": [0, 0, 0]},
            "film": {"width": 8, "height": 6, "spp": 1}, "materials": {"w": {"type": "diffuse"}},
            "shapes": [{"type": "quad", "material": "w", "corners": [[-2e-14, 0, -2e-14],
                        [2e-14, 0, -2e-14], [2e-14, 0, 2e-14], [-2e-14, 0, 2e-14]]}]}
    p = tmp_path / "tiny.json"
    p.write_text(json.dumps(tiny))
    assert main(["render", str(p), "-o", str(tmp_path / "tiny.exr")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"hwrt: error: {p}: too small for the float32 units"), err
    assert err.rstrip().endswith("(scale it up, or add --precision float64)"), err
    assert not (tmp_path / "tiny.exr").exists()
    # where the command cannot trace it wider, the advice is to scale it only
    for extra in (["--accel", "grid"], ["--builder", "embree"], ["--verify"]):
        assert main(["render", str(p), "-o", str(tmp_path / "tiny.exr"), *extra]) == 2
        err = capsys.readouterr().err
        assert "too small for the float32 units" in err and err.rstrip().endswith("(scale it up)"), err
    # and the render benchmark, whose paths all trace in float32, names the scene file
    assert main(["bench", "render", str(p), "--repeat", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"hwrt: error: {p}: too small for the float32 units"), err
    # and so does verify, whose answers would mean nothing there
    assert main(["verify", str(p), "--rays", "100"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"hwrt: error: {p}: too small for the float32 units"), err
    assert err.rstrip().endswith("(scale it up)"), err


def test_the_cli_renders_a_tiny_scene_with_the_float64_units(tmp_path, capsys):
    """``--precision float64`` renders what the float32 units refuse, as the same scene at
    scale 1 renders; it applies to our BVH traversal only, and --verify refuses a scene beyond
    Embree's float32 reach (the reference would be the one wrong)."""
    import json
    from hwrt.cli import main
    from raytracer.output import read_exr

    def scene(s):
        return {"camera": {"eye": [0, 3 * s, 4 * s], "target": [0, 0, 0]},
                "film": {"width": 8, "height": 6, "spp": 1},
                "materials": {"w": {"type": "diffuse"}},
                "lights": [{"type": "directional", "direction": [0, -1, 0], "irradiance": [1] * 3}],
                "shapes": [{"type": "quad", "material": "w", "corners": [
                    [-2 * s, 0, -2 * s], [2 * s, 0, -2 * s], [2 * s, 0, 2 * s], [-2 * s, 0, 2 * s]]}]}
    images = {}
    for s in (1.0, 1e-14):
        p = tmp_path / f"quad{s:g}.json"
        p.write_text(json.dumps(scene(s)))
        out = tmp_path / f"quad{s:g}.exr"
        assert main(["render", str(p), "-o", str(out), "--precision", "float64", "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["precision"] == "float64"
        images[s] = read_exr(str(out))[0]
    np.testing.assert_allclose(images[1e-14][..., :3], images[1.0][..., :3], rtol=1e-5)
    assert images[1.0][..., :3].max() > 0
    tiny = str(tmp_path / "quad1e-14.json")
    for extra in (["--accel", "grid"], ["--builder", "embree"]):
        assert main(["render", tiny, "-o", str(tmp_path / "x.exr"), "--precision", "float64",
                     *extra]) == 2
        assert capsys.readouterr().err.startswith("hwrt: error: --precision: float64 is a precision")
    assert main(["render", tiny, "-o", str(tmp_path / "x.exr"), "--precision", "float64",
                 "--verify"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hwrt: error: --verify: checks against Embree, which traces in float32, "
                          "and the scene is too small for the float32 units"), err
    assert not (tmp_path / "x.exr").exists()


def test_simulated_time_to_image_counts_the_tracers_set_up(capsys, tmp_path):
    """A simulated hardware build leaves our tracer's set-up to software: ``hwrt render``'s
    simulated time to image is the preset's build + that set-up + the render, as bench tti
    counts it; and a tti cell saved before set-ups were timed is computed again."""
    import json
    from hwrt.cli import main
    from hwrt.study import TTI_ROW
    from raytracer.render import simulated_ready_seconds

    assert simulated_ready_seconds({"simulated_build_seconds": {"HP": 0.25},
                                    "tracer_setup_seconds": 0.5}) == {"HP": 0.75}
    assert simulated_ready_seconds({"builder": "embree"}) is None
    row = dict.fromkeys(TTI_ROW.required)
    assert TTI_ROW.fits(row)
    del row["tracer_setup_seconds"]
    assert not TTI_ROW.fits(row)
    rc = main(["render", "cornell", "-o", str(tmp_path / "c.exr"), "--width", "32", "--height",
               "24", "--spp", "1", "--json"])
    got = json.loads(capsys.readouterr().out)
    assert rc == 0
    for preset, sim in got["simulated_build_seconds"].items():
        tti = got["time_to_image_simulated_seconds"][preset]
        assert sim + got["render_seconds"] < tti < got["time_to_image_seconds"] + sim


def test_warm_up_loads_the_wider_units_when_asked():
    """``hwrt render --precision float64`` warms up the float64 traversal before timing, so
    that its first render's time is the render, not the compilation."""
    from numba import types
    from raytracer.render import warm_up
    from traversal.traverse import trace_chunks

    warm_up(precision="float64")
    assert any(getattr(t, "dtype", None) == types.float64
               for sig in trace_chunks.signatures for t in sig)


def test_the_tracer_gets_a_wavefront_grouped_by_octant_in_spawn_order():
    """A secondary wavefront's reflections lie at rows 0.., its refractions at rows gap..;
    the tracer gets them all, grouped by octant, each group in spawn order (reflections
    first), and ``order`` gives each one's row."""
    rng = np.random.default_rng(3)
    n_first, gap, n_second = 25, 30, 15
    n = gap + n_second
    D = rng.normal(size=(n, 3))
    D[:6] = [[0.0, 1, 1], [-0.0, 1, 1], [1, -0.0, 1], [0.0, 0.0, -0.0], [-1, -1, -1],
             [1, 1, 1]]                                  # -0 counts as negative, as in packets
    D[n_first:gap] = np.nan                              # rows between the two runs: unused
    O = rng.normal(size=(n, 3))
    rows = np.r_[0:n_first, gap:n]
    sign = np.signbit(D[rows])
    key = sign[:, 0] + 2 * sign[:, 1] + 4 * sign[:, 2]
    Ot, Dt = np.zeros((len(rows), 3), np.float32), np.zeros((len(rows), 3), np.float32)
    order = np.full(len(rows), np.iinfo(PIXEL).max, PIXEL)
    stages.group_by_octant(n_first, gap, n_second, O, D, Ot, Dt, order,
                           np.bincount(key, minlength=8).astype(np.int64))
    want = rows[np.argsort(key, kind="stable")]
    assert np.array_equal(order, want)
    assert np.array_equal(Ot, O[want].astype(np.float32))
    assert np.array_equal(Dt, D[want].astype(np.float32))
    got = np.signbit(Dt) @ [1, 2, 4]                    # the float32 copies group alike
    assert (np.diff(got) >= 0).all()


def test_secondary_rays_reach_the_tracer_grouped_by_octant_and_traced_in_packets():
    sc = small("marbles", 96, 64, 1)
    tracer, _, _ = make_tracer(sc)
    rec = RecordingTracer(tracer)
    render(sc, rec)
    # camera rays all start at the eye
    secondary = [q for q in rec.queries if q[0] == "intersect" and (q[1] != q[1][0]).any()]
    assert sum(len(q[2]) for q in secondary) > 1000
    in_packets = 0
    for _, o, d, *_ in secondary:
        key = np.signbit(d) @ [1, 2, 4]
        assert (np.diff(key) >= 0).all()
        tracer.intersect(o, d)
        in_packets += 16 * tracer.last_packets
    # a group of 16 breaks only where an octant ends or at the end of a query
    assert in_packets >= sum(len(q[2]) for q in secondary) - 16 * 9 * len(secondary)


@pytest.mark.parametrize("camera,first,want", [(True, True, 0.0), (True, False, 0.0),
                                               (False, False, 1.0)])
def test_accumulate_adds_in_a_fixed_order_per_pixel(camera, first, want):
    """A pixel's float64 sum depends on the order of its terms: 1 + 1e16 - 1e16 is 0, while
    1e16 - 1e16 + 1 is 1. The camera's queue adds a ray's own contribution (1) before the
    light its shadow rays bring (1e16 from one light, -1e16 from the other); other queues add
    the shadow rays' light first. In the first sample pass the camera's own contribution is
    the pixel's first sum, whatever the film held. (A camera ray's own contribution is the
    ambient light of the material it hit, here 1; another queue's comes from ``shade``.)"""
    stride = 4
    film = np.full((3, 3), np.nan if first else 0.0)        # NaN: what a kept film may hold
    sh_cnt = np.array([1, 1], np.int64)                      # one shadow ray per light
    sh_C = np.zeros((2 * stride, 3))
    sh_C[0], sh_C[stride] = 1e16, -1e16
    sh_pix = np.zeros(2 * stride, PIXEL)                      # both on pixel 0
    blocked = np.zeros(2, np.bool_)
    pix = np.array([0], PIXEL)
    contrib = np.ones((1, 3))
    hit_prim = np.array([0], np.int32)                        # triangle 0, material 1
    material = np.array([1], np.int32)
    ambient_light = np.array([[0.5] * 3, [1.0] * 3])
    stages.accumulate(film, sh_cnt, stride, sh_C, sh_pix, blocked, pix, contrib, 1, 1, 0,
                      camera, first, hit_prim, material, ambient_light, np.zeros(3))
    assert np.array_equal(film[0], np.full(3, want))
    if first:                                                 # only the queue's pixels
        assert np.isnan(film[1:]).all()


def test_a_camera_rays_own_light_is_the_background_or_the_ambient_light_of_its_hit():
    """The camera's queue carries no contributions from ``shade``: ``accumulate`` adds each
    ray's own light from its hit, the background for a miss (primitive -1) and the ambient
    light of the hit triangle's material otherwise."""
    film = np.full((3, 3), np.nan)
    pix = np.array([2, 0], PIXEL)
    hit_prim = np.array([-1, 1], np.int32)                   # a miss, then triangle 1
    material = np.array([0, 1], np.int32)
    ambient_light = np.array([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]])
    background = np.array([7.0, 8.0, 9.0])
    stages.accumulate(film, np.zeros(1, np.int64), 2, np.zeros((2, 3)), np.zeros(2, PIXEL),
                      np.zeros(0, np.bool_), pix, np.full((2, 3), np.nan), 2, 2, 0, True,
                      True, hit_prim, material, ambient_light, background)
    assert np.array_equal(film[2], background)
    assert np.array_equal(film[0], ambient_light[1])
    assert np.isnan(film[1]).all()


def test_a_secondary_wavefronts_contributions_come_from_its_two_runs_of_rows():
    """A secondary wavefront holds its reflections at rows 0.. and its refractions at rows
    gap..; ``accumulate`` adds the contributions of those rows, reflections first, and of no
    row between (what a buffer holds there is stale). A pixel's float64 sum depends on the
    order of its terms: 1 + 2**53 - 2**53 is 0, 1 - 2**53 + 2**53 is 1."""
    film = np.array([[1.0] * 3, [0.0] * 3])
    pix = np.array([0, 1, 0, 0, 1], PIXEL)
    contrib = np.array([[2.0 ** 53] * 3, [2.0] * 3, [np.nan] * 3, [-2.0 ** 53] * 3, [3.0] * 3])
    stages.accumulate(film, np.zeros(1, np.int64), 2, np.zeros((2, 3)), np.zeros(2, PIXEL),
                      np.zeros(0, np.bool_), pix, contrib, 2, 3, 2, False, False,
                      np.zeros(5, np.int32), np.zeros(1, np.int32), np.zeros((1, 3)),
                      np.zeros(3))
    assert np.array_equal(film[0], np.zeros(3))            # rows 0 then 3, never row 2
    assert np.array_equal(film[1], np.full(3, 5.0))        # rows 1 and 4


def test_check_tracer_compares_triangles_as_the_units_hold_them():
    """A tracer keeps the triangles it was given; float64 triangles and their float32 rounding
    are the same triangles to the float32 units and to Embree, and a tracer over them passes;
    one coordinate moved by a float32 ulp does not."""
    from hwbvh.errors import ParameterError
    from traversal.grid import GridTracer
    from traversal.tracers import check_tracer
    tris = np.random.default_rng(3).uniform(0, 1, (50, 3, 3))
    rounded = tris.astype(np.float32)
    for tracer in (GridTracer(tris), GridTracer(rounded)):
        check_tracer(tracer, triangles=tris)
        check_tracer(tracer, triangles=rounded)
        other = rounded.copy()
        other[7, 1, 2] = np.nextafter(other[7, 1, 2], np.float32(2))
        with pytest.raises(ParameterError, match="traces other triangles than the scene's"):
            check_tracer(tracer, triangles=other)


def test_a_scene_changed_after_compiling_is_checked_again_before_it_renders():
    """compile_scene checks the film, the depth and the camera; a scene changed after it (by
    dataclasses.replace) is checked again by render, whose basis would be NaN and image
    black, or whose pixel indices would not fit the wavefronts'."""
    import dataclasses
    from hwbvh.errors import ParameterError
    sc = compile_scene(load_scene("cornell", width=8, height=6, spp=1))
    tracer = make_tracer(sc)[0]
    cam = sc.camera
    for change, message in (({"max_depth": 0}, "scene.max_depth: must be a positive integer"),
                            ({"camera": dict(cam, fov=float("nan"))}, "scene.camera.fov: must be"),
                            ({"camera": dict(cam, fov=180.0)}, "scene.camera.fov: must be"),
                            ({"camera": dict(cam, target=cam["eye"])}, "scene.camera: needs an "
                                                                       "eye apart"),
                            ({"camera": dict(cam, up=np.zeros(3))}, "scene.camera: needs"),
                            ({"camera": dict(cam, eye=np.array([np.nan, 0, 0]))},
                             "scene.camera.eye: must be 3 finite numbers"),
                            ({"camera": {"eye": cam["eye"]}}, "scene.camera: expected the eye"),
                            ({"width": 2 ** 16, "height": 2 ** 16},  # past 32-bit pixel indices
                             "scene.width: 65536 x 65536 pixels is more than the renderer's"),
                            # arrays the shading kernels index unchecked: read past their ends,
                            # or NaN images, without a word
                            ({"normals": np.ones((1, 3, 3), np.float32)},
                             r"scene.normals: expected numbers of shape \(\d+, 3, 3\)"),
                            ({"normals": None}, "scene.normals: expected numbers of shape"),
                            ({"kd": np.ones((len(sc.kd), 1))}, "scene.kd: expected numbers"),
                            ({"background": np.ones(1)}, r"scene.background: expected numbers of "
                                                         r"shape \(3,\)"),
                            ({"ambient": np.full(3, np.nan)}, "scene.ambient: holds a number that "
                                                              "is not finite"),
                            ({"lights": [{"type": "spot"}]}, r"scene.lights\[0\]: expected a point "
                                                             "or directional light"),
                            ({"lights": [dict(sc.lights[0], position=[0, 0, np.inf])]},
                             r"scene.lights\[0\].position: expected three finite numbers")):
        with pytest.raises(ParameterError, match=message):
            render(dataclasses.replace(sc, **change), tracer)
    assert (render(sc, tracer).prim >= 0).sum() > 30


def test_shading_puts_each_hit_point_on_its_triangles_plane():
    """Rays leave from the hit triangle's plane whatever the tracer's rounding of t: with
    every hit reported 1e-3 of t beyond its surface, the shadow rays do not start behind it
    (which would shadow every lit surface: 92% of the lit pixels lose half their light or
    more): under 1% of them do (at wall corners, where a point moved along one wall passes the
    other), and the median pixel changes by under 1% of its value."""
    from scenes import with_frame
    sc = compile_scene(with_frame(load_scene("cornell"), width=48, height=36, spp=1))
    tracer, _, _ = make_tracer(sc)
    right = render(sc, tracer).image.astype(np.float64)
    late = render(sc, LateHits(tracer)).image.astype(np.float64)
    lit = right.sum(-1) > 0.05
    assert lit.mean() > 0.5
    darkened = late.sum(-1) < 0.5 * right.sum(-1)
    assert (darkened & lit).sum() < 0.01 * lit.sum()
    assert np.median(np.abs(late - right).sum(-1)[lit] / right.sum(-1)[lit]) < 0.01


def test_make_tracer_takes_only_none_for_the_default_builder_and_traversal():
    """A false value other than None (0, "") was taken as the default."""
    from hwbvh.errors import ParameterError
    sc = compile_scene(load_scene("cornell", width=8, height=6, spp=1))
    for key, bad in (("builder", 0), ("builder", ""), ("traversal", "")):
        with pytest.raises(ParameterError, match=f"^{key}: unknown {key}"):
            make_tracer(sc, **{key: bad})


def test_make_tracer_pairs_embree_with_embree():
    """Embree's tree goes with Embree's traversal: either one named makes the other; the
    defaults are the hardware's tree on our units; a mixed pair is refused by name."""
    from hwbvh.errors import ParameterError
    from traversal.embree_ref import EmbreeTracer

    sc = compile_scene(load_scene("cornell", width=8, height=6, spp=1))
    assert isinstance(make_tracer(sc, builder="embree")[0], EmbreeTracer)
    assert isinstance(make_tracer(sc, traversal="embree")[0], EmbreeTracer)
    assert make_tracer(sc)[2]["builder"] == "hwbvh"
    assert make_tracer(sc)[0].name == "numba"
    for builder, traversal in (("embree", "numba"), ("sweep", "embree")):
        with pytest.raises(ParameterError) as e:
            make_tracer(sc, builder=builder, traversal=traversal)
        assert e.value.parameter in ("builder", "traversal")
