"""Every hit checked against Embree.

Each ray is classified:

* ``agree``: same primitive and |t_ours - t_embree| <= tol_t, or both miss;
* ``tie``: the answers differ but both are right to within the stated tolerances, judged by a
  float64 brute-force re-test of the ray against every triangle: each answer's triangle
  contains its hit point (barycentrics within ``BARY_TOL`` of the triangle, or within the
  float32 unit's own rounding of them where that is larger, as on rays grazing a triangle far
  smaller than its distance), the point at the t it reports lies within tol_t (times |d|) of
  that triangle's plane (or within the float32 unit's own rounding of t where that is larger,
  as on slivers) and in the ray's interval, and no triangle that contains the ray strictly (by
  more than ``BARY_TOL``) is hit closer. These are the rays through shared edges and vertices
  (two triangles, one t), rays grazing an edge within the tolerance (one answer a hit on the
  edge, the other a miss) and a sliver hit at two t apart by the unit's rounding;
* ``mismatch``: anything else.

The tolerances ``T_TOL_REL``, ``T_ERR_K``, ``BEHIND_TOL_REL``, ``BARY_TOL`` and ``BARY_ERR_K``
live in ``traversal.config`` with their reasons.
"""
import numpy as np
from numba import njit

from hwbvh.errors import ParameterError, checked_flag
from hwbvh.parallel import run_ranges

from .api import ACCELS, _interval, ray_arrays, real_array
from .config import (BARY_ERR_K, BARY_TOL, BARY_TOL_MAX, BEHIND_TOL_REL, PROBE_OFFSET,
                     PROBE_STEPS, SCENE_PROBES, T_ERR_K, T_TOL_MAX_REL, T_TOL_REL, VERIFY_CHUNK)

BEHIND = BEHIND_TOL_REL / T_TOL_REL    # the slack before t_min, as a share of the t tolerance


@njit(cache=True, error_model="numpy")
def _mt64(tri, o, d):
    e1 = tri[1] - tri[0]
    e2 = tri[2] - tri[0]
    px = d[1] * e2[2] - d[2] * e2[1]
    py = d[2] * e2[0] - d[0] * e2[2]
    pz = d[0] * e2[1] - d[1] * e2[0]
    det = e1[0] * px + e1[1] * py + e1[2] * pz
    if det == 0.0:
        return np.inf, -1.0, -1.0
    inv = 1.0 / det
    s = o - tri[0]
    u = (s[0] * px + s[1] * py + s[2] * pz) * inv
    qx = s[1] * e1[2] - s[2] * e1[1]
    qy = s[2] * e1[0] - s[0] * e1[2]
    qz = s[0] * e1[1] - s[1] * e1[0]
    v = (d[0] * qx + d[1] * qy + d[2] * qz) * inv
    t = (e2[0] * qx + e2[1] * qy + e2[2] * qz) * inv
    return t, u, v


@njit(cache=True, error_model="numpy")
def _cosine(tri, d):
    """|cos| of the angle between d and the triangle's normal. A reported t is judged by how far
    its point lies off the triangle's plane, |t - t64| |cos|: a float32 t on a ray at angle a to
    the plane is off by ~eps (|o| + t) / sin(a) however right the unit is."""
    nx, ny, nz = _normal(tri)
    return abs(nx * d[0] + ny * d[1] + nz * d[2]) / \
        np.sqrt((nx * nx + ny * ny + nz * nz) * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]))


@njit(cache=True, error_model="numpy", inline="always")
def _normal(tri):
    """e1 x e2 of a (3, 3) triangle."""
    e1 = tri[1] - tri[0]
    e2 = tri[2] - tri[0]
    return (e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0])


F32_ROUNDOFF = 2.0**-24               # float32's unit roundoff: the units' error estimates


@njit(cache=True, error_model="numpy", inline="always")
def _length(x, y, z):
    return np.sqrt(x * x + y * y + z * z)


@njit(cache=True, error_model="numpy", inline="always")
def _ratio_within(err, den, least, most):
    """err / den within [least, most], without a division by zero (den 0: ``most``)."""
    if not err < most * den:
        return most
    return max(least, err / den)


@njit(cache=True, error_model="numpy")
def _answer_tol(tri, o, d):
    """How far outside ``tri`` (in barycentric units) an answer on it is still right: the
    float32 unit's rounding of the barycentrics, eps |o - v0| max|e| / (|e1 x e2| cos), times
    BARY_ERR_K, within [BARY_TOL, BARY_TOL_MAX] (``traversal.config``)."""
    e1 = tri[1] - tri[0]
    e2 = tri[2] - tri[0]
    s = o - tri[0]
    nx, ny, nz = _normal(tri)
    # |e1 x e2| cos = |n . d| / |d|
    dn = abs(nx * d[0] + ny * d[1] + nz * d[2]) / _length(d[0], d[1], d[2])
    emax = max(_length(e1[0], e1[1], e1[2]), _length(e2[0], e2[1], e2[2]))
    err = BARY_ERR_K * F32_ROUNDOFF * _length(s[0], s[1], s[2]) * emax
    return _ratio_within(err, dn, BARY_TOL, BARY_TOL_MAX)


@njit(cache=True, error_model="numpy")
def _plane_tol(tri, o, d, t, tol):
    """How far off ``tri``'s plane (|t_reported - t| |cos|, as ``_verdict`` measures it) an
    answer at t is still right: the float32 unit's rounding of t, eps (|o - v0| / |d| + |t|)
    |e1| |e2| / |e1 x e2|, times T_ERR_K; at least ``tol`` (T_TOL_REL's), at most T_TOL_MAX_REL
    / T_TOL_REL times it (``traversal.config``)."""
    e1 = tri[1] - tri[0]
    e2 = tri[2] - tri[0]
    s = o - tri[0]
    nx, ny, nz = _normal(tri)
    err = T_ERR_K * F32_ROUNDOFF * \
        (_length(s[0], s[1], s[2]) / _length(d[0], d[1], d[2]) + abs(t)) * \
        _length(e1[0], e1[1], e1[2]) * _length(e2[0], e2[1], e2[2])
    return _ratio_within(err, _length(nx, ny, nz), tol, tol * (T_TOL_MAX_REL / T_TOL_REL))


@njit(cache=True, error_model="numpy")
def _margin(u, v):
    """Signed distance inside the triangle in barycentric units (>0 inside)."""
    return min(u, min(v, 1.0 - u - v))


# The re-test's verdicts on an answer (``_reference``; ``diagnose`` words them): right, or why
# not: a miss where a triangle is hit strictly (MISSED); its triangle does not hold the point
# (OUTSIDE); its t lies before t_min (BEHIND_START) or past t_max (BEYOND_END); a triangle is hit
# strictly closer (CLOSER); the t it reports is off its triangle's plane (OFF_PLANE).
RIGHT, MISSED, OUTSIDE, BEHIND_START, BEYOND_END, CLOSER, OFF_PLANE = range(7)


@njit(cache=True, error_model="numpy")
def _verdict(tris, p, reported, o, d, tmin, tmax, scale, best):
    """The re-test's verdict on answer (p, reported t) of ray (o, d): RIGHT or why not."""
    if p < 0:
        return RIGHT if best == np.inf else MISSED
    t, u, v = _mt64(tris[p], o, d)
    tol = T_TOL_REL * (abs(t) + scale)
    if not _margin(u, v) >= -_answer_tol(tris[p], o, d):
        return OUTSIDE
    if not t >= tmin - tol * BEHIND:
        return BEHIND_START
    if not t <= tmax + tol:
        return BEYOND_END
    if best < t - tol:
        return CLOSER
    # the reported t itself in the ray's interval too: the plane's slack on a sliver is wider
    # than the interval's
    if not (abs(reported - t) * _cosine(tris[p], d) <= _plane_tol(tris[p], o, d, t, tol)
            and reported >= tmin - tol * BEHIND and reported <= tmax + tol):
        return OFF_PLANE
    return RIGHT


# The re-tests run over ranges of rays (``hwbvh.parallel.run_ranges``), not in a parallel
# loop: a verifying tracer re-tests from every band's thread at once, and Numba's workqueue
# layer aborts when two threads enter its parallel loops together.
@njit(cache=True, nogil=True, error_model="numpy")
def _reference(lo, hi, tris, O, D, tmin, tmax, scale, pa, ta, pb, tb, out):
    """For disputed rays lo..hi: the closest strict hit and the verdicts on answers (pa, ta) and
    (pb, tb) (primitive, reported t): out[i] = (t_strict, its triangle or -1, verdict a,
    verdict b). Every t is judged with the tolerance of its float64 value,
    T_TOL_REL * (|t| + scale)."""
    for i in range(lo, hi):
        o = O[i]
        d = D[i]
        best = np.inf
        best_j = -1
        for j in range(tris.shape[0]):
            t, u, v = _mt64(tris[j], o, d)
            tol = T_TOL_REL * (abs(t) + scale[i])
            # strict hits clearly inside the ray interval (ones within tol of t_min are
            # neither required nor forbidden: the origin may sit on that surface)
            if _margin(u, v) > BARY_TOL and t > tmin[i] + tol and t < tmax[i] - tol:
                if t < best:
                    best = t
                    best_j = j
        out[i, 0] = best
        out[i, 1] = best_j
        out[i, 2] = _verdict(tris, pa[i], ta[i], o, d, tmin[i], tmax[i], scale[i], best)
        out[i, 3] = _verdict(tris, pb[i], tb[i], o, d, tmin[i], tmax[i], scale[i], best)


def _scale(O, D):
    """|o|_max / |d| per ray: the t-equivalent of the origin's own rounding (inf for a zero
    direction, a ray that misses by definition)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.abs(O).max(axis=1) / np.linalg.norm(D, axis=1)


def t_tolerance(O, D, t):
    return T_TOL_REL * (np.where(np.isfinite(t), np.abs(t), 0) + _scale(O, D))


def _checked_triangles(tris):
    t = real_array(tris, "tris")
    if t.ndim != 3 or t.shape[1:] != (3, 3):
        raise ParameterError("tris", f"must be (m, 3, 3), got shape {t.shape}")
    return t


def _checked_rays(O, D, tmin, tmax):
    """The rays as both tracers saw them (float32, held in float64) and their (n,) bounds,
    checked as ``traversal.Tracer`` checks them."""
    O, D = ray_arrays(O, D, np.float32, names=("O", "D"))
    n = len(O)
    return (O.astype(np.float64), D.astype(np.float64),
            _interval(tmin, n, np.float64, "tmin", nonnegative=True),
            _interval(tmax, n, np.float64, "tmax"))


def _per_ray(x, n, name, kinds="fiu"):
    """Answer array ``name``: one per ray, of a NumPy kind in ``kinds``."""
    a = np.asarray(x)
    if a.dtype.kind not in kinds:
        what = {"iu": "integers", "biu": "booleans (or integers 0 and 1)"}.get(kinds, "real numbers")
        raise ParameterError(name, f"must be {what}, got {a.dtype}")
    if a.shape != (n,):
        raise ParameterError(name, f"must hold one answer per ray ({n},), got shape {a.shape}")
    if kinds == "biu" and a.dtype.kind in "iu" and n and not np.isin(a, (0, 1)).all():
        bad = int(np.argmax(~np.isin(a, (0, 1))))
        raise ParameterError(name, f"must be booleans (or integers 0 and 1), got {a[bad]} "
                                   f"(ray {bad})")
    return a


def _primitive_ids(x, n, m, name):
    """Primitive ids ``name``: one per ray, each -1 (a miss) or a triangle of the m."""
    p = _per_ray(x, n, name, "iu").astype(np.int64)
    if n and (p.min() < -1 or p.max() >= m):
        bad = int(np.argmax((p < -1) | (p >= m)))
        raise ParameterError(name, f"primitive ids must be -1 or below len(tris) = {m}, "
                                   f"got {p[bad]} (ray {bad})")
    return p


def _checked_answers(tris, O, D, tmin, tmax, ours_prim, ours_t, ref_prim, ref_t):
    """The arguments of ``classify``, checked and in the re-test's types."""
    tris = _checked_triangles(tris)
    O, D, tmin, tmax = _checked_rays(O, D, tmin, tmax)
    n = len(O)
    return (tris, O, D, tmin, tmax, _primitive_ids(ours_prim, n, len(tris), "ours_prim"),
            _per_ray(ours_t, n, "ours_t").astype(np.float64),
            _primitive_ids(ref_prim, n, len(tris), "ref_prim"),
            _per_ray(ref_t, n, "ref_t").astype(np.float64))


def _judged(tris, O, D, tmin, tmax, ours_prim, ours_t, ref_prim, ref_t):
    """Checked answers -> (labels, disputed rays, their re-test rows ``_reference``)."""
    # the smaller of the two finite answers sets the tolerance: an infinite or absurd t
    # cannot widen it
    finite_t = lambda t: np.where(np.isfinite(t), np.abs(t), np.inf)
    tol = t_tolerance(O, D, np.minimum(finite_t(ours_t), finite_t(ref_t)))
    both_miss = (ours_prim < 0) & (ref_prim < 0)
    with np.errstate(invalid="ignore"):
        same = (ours_prim == ref_prim) & (ours_prim >= 0) & (np.abs(ours_t - ref_t) <= tol)
    labels = np.where(both_miss | same, 0, 2).astype(np.int8)
    disputed = np.flatnonzero(labels == 2)
    out = np.empty((len(disputed), 4))
    if len(disputed):
        pick = lambda a: np.ascontiguousarray(a[disputed])
        run_ranges(_reference, len(disputed), np.ascontiguousarray(tris, np.float64), pick(O),
                   pick(D), pick(tmin), pick(tmax), _scale(O[disputed], D[disputed]),
                   pick(ours_prim), pick(ours_t), pick(ref_prim), pick(ref_t), out)
        ok = (out[:, 2] == RIGHT) & (out[:, 3] == RIGHT)
        labels[disputed[ok]] = 1
    return labels, disputed, out


def _counts(labels):
    return {"rays": int(len(labels)), "agree": int((labels == 0).sum()),
            "tie": int((labels == 1).sum()), "mismatch": int((labels == 2).sum())}


def classify(tris, O, D, tmin, tmax, ours_prim, ours_t, ref_prim, ref_t):
    """Return (counts dict, labels (n,) int8: 0 agree, 1 tie, 2 mismatch). The float64
    re-test uses the rays as both tracers saw them: rounded to float32. ParameterError naming
    the argument on a bad shape or a primitive id out of range."""
    labels, _, _ = _judged(*_checked_answers(tris, O, D, tmin, tmax, ours_prim, ours_t,
                                             ref_prim, ref_t))
    return _counts(labels), labels


LABELS = ("agree", "tie", "mismatch")


def diagnose(tris, O, D, tmin, tmax, ours_prim, ours_t, ref_prim, ref_t,
             names=("ours", "embree")):
    """``classify``, and per ray what the re-test found: a list of {"class": agree, tie or
    mismatch, "wrong": the ``names`` of the answers it rejects (none unless a mismatch),
    "why": name -> a sentence for each of those}. Meant for the few rays of a mismatch file:
    each sentence re-tests its triangles once more."""
    args = _checked_answers(tris, O, D, tmin, tmax, ours_prim, ours_t, ref_prim, ref_t)
    tris, O, D, tmin, tmax = args[:5]
    answers = (args[5:7], args[7:9])
    labels, disputed, out = _judged(*args)
    rows = [{"class": LABELS[k], "wrong": [], "why": {}} for k in labels]
    t64 = np.ascontiguousarray(tris, np.float64)
    for r, i in enumerate(disputed):
        if labels[i] != 2:
            continue
        best, best_j = out[r, 0], int(out[r, 1])
        for k, name in enumerate(names):
            verdict = int(out[r, 2 + k])
            if verdict != RIGHT:
                p, reported = int(answers[k][0][i]), float(answers[k][1][i])
                rows[i]["wrong"].append(name)
                rows[i]["why"][name] = _why(verdict, t64, p, reported, O[i], D[i], tmin[i],
                                            tmax[i], best, best_j)
    return rows


def _why(verdict, tris, p, reported, o, d, tmin, tmax, best, best_j):
    """The sentence for a verdict of ``_reference`` on answer (p, reported t)."""
    def entered(j):
        t, u, v = _mt64(tris[j], o, d)
        return f"inside it by {_margin(u, v):.3g} (barycentric), |cos| {_cosine(tris[j], d):.3g}"
    if verdict in (MISSED, CLOSER):
        what = "misses" if verdict == MISSED else "lies behind"
        return (f"{what} triangle {best_j}, which the ray enters at t = {best:.9g}, "
                f"{entered(best_j)}")
    t, u, v = _mt64(tris[p], o, d)
    if verdict == OUTSIDE:
        return (f"its point lies outside triangle {p} by {-_margin(u, v):.3g} (barycentric), "
                f"more than the {_answer_tol(tris[p], o, d):.3g} allowed")
    if verdict == BEHIND_START:
        return f"triangle {p} lies at t = {t:.9g}, before the ray starts (t_min {tmin:g})"
    if verdict == BEYOND_END:
        return f"triangle {p} lies at t = {t:.9g}, past the ray's end (t_max {tmax:g})"
    return f"reports t = {reported:.9g}, where triangle {p}'s plane lies at t = {t:.9g}"


@njit(cache=True, nogil=True, error_model="numpy")
def _reference_any(lo, hi, tris, O, D, tmin, tmax, scale, out):
    """For disputed any-hit rays lo..hi: out[i] = (a strict hit exists, a loose hit exists,
    the lowest-numbered triangle hit strictly or -1, its t), where a strict hit lies inside its triangle
    by more than BARY_TOL at t clearly inside (tmin, tmax), and a loose hit within
    ``_answer_tol`` of its triangle at t within the tolerance of [tmin, tmax]."""
    for i in range(lo, hi):
        o = O[i]
        d = D[i]
        strict = False
        loose = False
        out[i, 2] = -1.0
        out[i, 3] = np.inf
        for j in range(tris.shape[0]):
            t, u, v = _mt64(tris[j], o, d)
            if not np.isfinite(t):
                continue
            tol = T_TOL_REL * (abs(t) + scale[i])
            m = _margin(u, v)
            if not strict and m > BARY_TOL and t > tmin[i] + tol and t < tmax[i] - tol:
                strict = True
                out[i, 2] = j
                out[i, 3] = t
            if t >= tmin[i] - tol * BEHIND and t <= tmax[i] + tol and \
                    (m >= -BARY_TOL or m >= -_answer_tol(tris[j], o, d)):
                loose = True
            if strict and loose:
                break
        out[i, 0] = 1.0 if strict else 0.0
        out[i, 1] = 1.0 if loose else 0.0


def _judged_occluded(tris, O, D, tmin, tmax, ours_blocked, ref_blocked):
    """Checked any-hit answers -> (labels, disputed rays, their re-test rows
    ``_reference_any``, {"ours", "ref"}: each answer's rightness on the disputed rays)."""
    tris = _checked_triangles(tris)
    O, D, tmin, tmax = _checked_rays(O, D, tmin, tmax)
    n = len(O)
    ours = _per_ray(ours_blocked, n, "ours_blocked", "biu").astype(bool)
    ref = _per_ray(ref_blocked, n, "ref_blocked", "biu").astype(bool)
    labels = np.where(ours == ref, 0, 2).astype(np.int8)
    disputed = np.flatnonzero(labels == 2)
    out = np.empty((len(disputed), 4))
    right = {}
    if len(disputed):
        Od = np.ascontiguousarray(O[disputed])
        Dd = np.ascontiguousarray(D[disputed])
        run_ranges(_reference_any, len(disputed), np.ascontiguousarray(tris, np.float64), Od, Dd,
                   np.ascontiguousarray(tmin[disputed]), np.ascontiguousarray(tmax[disputed]),
                   _scale(Od, Dd), out)
    strict, loose = out[:, 0] > 0, out[:, 1] > 0
    for name, blocked in (("ours", ours), ("ref", ref)):
        right[name] = np.where(blocked[disputed], loose, ~strict)
    labels[disputed[right["ours"] & right["ref"]]] = 1
    return labels, disputed, out, right


def classify_occluded(tris, O, D, tmin, tmax, ours_blocked, ref_blocked):
    """Any-hit answers: (counts dict, labels) as :func:`classify`. Equal answers agree. Where
    they differ, a float64 brute-force re-test decides: "blocked" is right when some triangle is
    hit within the tolerances, "not blocked" when no triangle is hit strictly inside the
    interval; both right is a tie (a ray grazing an edge or ending on a surface).
    ParameterError naming the argument on a bad shape."""
    labels = _judged_occluded(tris, O, D, tmin, tmax, ours_blocked, ref_blocked)[0]
    return _counts(labels), labels


def diagnose_occluded(tris, O, D, tmin, tmax, ours_blocked, ref_blocked,
                      names=("ours", "embree")):
    """``classify_occluded``, and per ray what the re-test found, as :func:`diagnose` words
    it: {"class", "wrong": the ``names`` of the answers it rejects, "why": name -> a sentence}.
    """
    labels, disputed, out, right = _judged_occluded(tris, O, D, tmin, tmax, ours_blocked,
                                                    ref_blocked)
    ours = np.asarray(ours_blocked).astype(bool)
    rows = [{"class": LABELS[k], "wrong": [], "why": {}} for k in labels]
    for r, i in enumerate(disputed):
        if labels[i] != 2:
            continue
        for name, key in zip(names, ("ours", "ref")):
            if right[key][r]:
                continue
            # the answers differ: the reference says the opposite of ours
            blocked = bool(ours[i]) == (key == "ours")
            rows[i]["wrong"].append(name)
            rows[i]["why"][name] = (
                "blocked, but no triangle is hit within the tolerances in the ray's interval"
                if blocked else
                f"not blocked, but triangle {int(out[r, 2])} is hit strictly inside the "
                f"interval, at t = {out[r, 3]:.9g}")
    return rows


def _check_embree_scene(scene):
    if not callable(getattr(scene, "run", None)):
        raise ParameterError("scene", f"expected an Embree scene (traversal.embree_ref."
                                      f"embree_scene), got {type(scene).__name__}")


def _check_scene_holds(scene, tris):
    """Refuse (ParameterError naming ``scene``) an Embree scene that does not hold ``tris``: rays
    from just off the centres of a few of them, straight at them, must hit them (or a triangle
    of the same corners) in Embree's scene. Another mesh, or the same one moved, fails the
    check, where every ray would otherwise read as a mismatch of our traversal."""
    from .embree_ref import embree_intersect

    t64 = np.asarray(tris, np.float64)
    normal = np.cross(t64[:, 1] - t64[:, 0], t64[:, 2] - t64[:, 0])
    size = np.linalg.norm(normal, axis=1)
    usable = np.flatnonzero(np.isfinite(size) & (size > 0))
    if len(usable) == 0:
        return
    k = min(SCENE_PROBES, len(usable))
    pick = usable[np.argpartition(-size[usable], k - 1)[:k]]
    centre = t64[pick].mean(axis=1)
    unit = normal[pick] / size[pick, None]
    step = np.spacing(np.abs(centre).max(axis=1).astype(np.float32)).astype(np.float64)
    off = np.maximum(PROBE_OFFSET * np.sqrt(size[pick]), PROBE_STEPS * step)[:, None]
    _, prim, _, _, _ = embree_intersect(scene, (centre + off * unit).astype(np.float32),
                                        (-unit).astype(np.float32))
    # reached: its own triangle, or one of the same corners in any order (a mesh may hold a
    # face twice, or both ways round to be seen from both sides)
    ok = (prim >= 0) & (prim < len(t64))
    same = np.zeros(len(pick), bool)
    corners = lambda rows: np.sort(t64[rows].view(np.dtype((np.void, 24))).reshape(-1, 3), axis=1)
    same[ok] = (prim[ok] == pick[ok]) | np.all(corners(prim[ok]) == corners(pick[ok]), axis=1)
    if 2 * same.sum() < len(pick):
        raise ParameterError("scene", f"does not hold the triangles tris: of {len(pick)} rays "
                                      f"aimed at their centres, Embree's scene brought "
                                      f"{int(same.sum())} to their triangle; build it from the "
                                      f"same mesh (traversal.embree_ref.embree_scene)")


def verify_rays(tracer, scene, tris, O, D, tmax=None, anyhit=False):
    """Trace (O, D) with our tracer and with Embree (tnear = 0), classify every ray, a slice
    of ``VERIFY_CHUNK`` rays at a time. Closest hits: returns (counts, labels, ours Hits (t,
    prim, u, v; no normals), embree (t, prim)). ``anyhit`` checks ``occluded`` answers
    instead (shadow rays): returns (counts, labels, ours blocked, embree blocked), (n,) bool
    each. ``counts["hit"]``: the rays our tracer found a hit on (or blocked), so that "all
    agree" is not read as "all hit". ``scene`` must hold ``tris``: one that does not is
    refused (``_check_scene_holds``), not reported ray by ray."""
    from .tracers import check_tracer

    check_tracer(tracer, triangles=_checked_triangles(tris))
    _check_embree_scene(scene)
    _check_scene_holds(scene, tris)
    return _traced_and_classified(tracer, scene, tris, O, D, tmax, anyhit)


def _traced_and_classified(tracer, scene, tris, O, D, tmax, anyhit):
    """``verify_rays`` once its tracer and Embree scene are known to hold ``tris``."""
    from .api import Hits
    from .embree_ref import embree_intersect, embree_occluded

    # checked here without a copy; each tracer converts them itself
    shape = np.shape(real_array(O, "O"))
    if len(shape) != 2 or shape[1] != 3:
        raise ParameterError("O", f"must be (n, 3), got shape {shape}")
    if np.shape(real_array(D, "D")) != shape:
        raise ParameterError("D", f"must be (n, 3) with one row per origin {shape}, got shape "
                                  f"{np.shape(D)}")
    n = len(O)
    anyhit = checked_flag(anyhit, "anyhit")
    if tmax is not None and np.ndim(tmax) and np.shape(tmax) != (n,):
        raise ParameterError("tmax", f"must be a number or one per ray ({n}), got shape "
                                     f"{np.shape(tmax)}")
    tmax_of = _tmax_slices(tmax)
    if anyhit:
        ours, ref = np.empty(n, bool), np.empty(n, bool)

        def check(a, b):
            ours[a:b] = tracer.occluded(O[a:b], D[a:b], 0.0, tmax_of(a, b))
            ref[a:b] = embree_occluded(scene, O[a:b], D[a:b], tmax_of(a, b))
            return classify_occluded(tris, O[a:b], D[a:b], 0.0, tmax_of(a, b), ours[a:b],
                                     ref[a:b])

        counts, labels = _by_slices(n, check)
        counts["hit"] = int(ours.sum())
        return counts, labels, ours, ref
    prim, te = np.empty(n, np.int32), np.empty(n)
    pe = np.empty(n, np.int64)
    # t, u, v in the tracer's precision, made from its first answers
    tuv = [np.empty(0, np.float32)] * 3

    def check(a, b):
        h = tracer.intersect(O[a:b], D[a:b], 0.0, tmax_of(a, b), normals=False)
        if a == 0:
            tuv[:] = [np.empty(n, x.dtype) for x in (h.t, h.u, h.v)]
        prim[a:b] = h.prim
        for out, x in zip(tuv, (h.t, h.u, h.v)):
            out[a:b] = x
        te[a:b], pe[a:b], *_ = embree_intersect(scene, O[a:b], D[a:b],
                                                None if tmax is None else tmax_of(a, b))
        return classify(tris, O[a:b], D[a:b], 0.0, tmax_of(a, b), prim[a:b].astype(np.int64),
                        tuv[0][a:b], pe[a:b], te[a:b])

    counts, labels = _by_slices(n, check)
    counts["hit"] = int((prim >= 0).sum())
    t, u, v = tuv
    return counts, labels, Hits(t=t, prim=prim, u=u, v=v, ng=None), (te, pe)


def _by_slices(n, check):
    """(counts, labels) of rays [0, n), ``check(a, b)`` -> (counts, labels) of slice [a, b)
    run a ``VERIFY_CHUNK`` at a time."""
    labels = np.empty(n, np.int8)
    counts = dict.fromkeys(("rays", "agree", "tie", "mismatch"), 0)
    for a in range(0, n, VERIFY_CHUNK):
        b = min(n, a + VERIFY_CHUNK)
        c, labels[a:b] = check(a, b)
        for k in counts:
            counts[k] += c[k]
    return counts, labels


def _tmax_slices(tmax):
    """Slice [a, b) of the bound: inf for None, a number as is, else its entries."""
    if tmax is None:
        return lambda a, b: np.inf
    return lambda a, b: tmax[a:b] if np.ndim(tmax) else tmax


def query_of(kind):
    """The query a ray set of ``kind`` is verified with: shadow rays as renderers ask them,
    ``occluded``; the others ``intersect``."""
    return "occluded" if kind == "shadow" else "intersect"


RAY_KINDS = ("primary", "random", "bounces", "shadow")      # the ray sets verify_mesh traces


def verify_mesh(tris, vertices, faces, kind="random", n=100_000, bvh=None, seed=0, accel="bvh",
                tracer=None):
    """Build (unless given), trace a ray set of ``kind`` and classify against Embree: closest
    hits, or for "shadow" rays (toward a point light, bounded at it) the ``occluded``
    answers, as a renderer asks them (``verify_rays``).
    ``accel``: "bvh" (``bvh`` if given, else hwbvh's build), "grid" (``grid.GridTracer``) or
    "kdtree" (``kdtree.KdTreeTracer``);
    ``tracer``: an already built tracer of ``tris`` to check instead.
    Returns (counts, labels, (O, D, tmax), ours, embree) as ``verify_rays`` (tmax None: no
    bound)."""
    import hwbvh
    from . import raysets
    from .api import Tracer
    from .embree_ref import embree_scene

    # every argument before the build: a structure over a large mesh takes seconds; the
    # triangles as the builder takes them, then as the mesh Embree is given must hold them
    tris = raysets.checked_set_arguments(tris, n, seed)
    if kind not in RAY_KINDS:
        raise ParameterError("kind", f"must be one of {', '.join(map(repr, RAY_KINDS))}, "
                                     f"got {kind!r}")
    if tracer is None and accel not in ACCELS:
        raise ParameterError("accel", f"must be one of {', '.join(map(repr, ACCELS))}, "
                                      f"got {accel!r}")
    from .embree_ref import mesh_of
    vertices, faces = mesh_of(tris.astype(np.float32), vertices, faces)
    if tracer is not None:
        from .tracers import check_tracer
        check_tracer(tracer, triangles=tris)
    elif accel == "grid":
        from .grid import GridTracer
        tracer = GridTracer(tris)
    elif accel == "kdtree":
        from .kdtree import KdTreeTracer
        tracer = KdTreeTracer(tris)
    elif bvh is not None:
        from .tracers import check_tracer
        tracer = Tracer(bvh)
        check_tracer(tracer, triangles=tris, name="bvh")     # the argument the caller gave
    else:
        tracer = Tracer(hwbvh.build(tris))
    scene = embree_scene(vertices, faces)
    tmax = None
    # the rays as the float32 tracers take them (half the memory of float64, the same rays)
    if kind == "primary":
        O, D = raysets.primary(tris, n, np.float32)
    elif kind == "random":
        O, D = raysets.incoherent(tris, n, seed, np.float32)
    elif kind == "bounces":
        O, D = raysets.bounces(tracer, tris, n, seed, dtype=np.float32)
    else:
        O, D, tmax = raysets.shadow(tracer, tris, n, dtype=np.float32)
    # (Embree's scene is built here from the same mesh: no probe of it is needed)
    counts, labels, ours, emb = _traced_and_classified(tracer, scene, tris, O, D, tmax,
                                                       query_of(kind) == "occluded")
    return counts, labels, (O, D, tmax), ours, emb
