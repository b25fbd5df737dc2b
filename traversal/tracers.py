"""One tracer interface, two back ends, and wrappers that observe a tracer without changing it.

Every tracer answers two batched queries (pbrt's ``Intersect`` / ``IntersectP``):

* ``intersect(origins, dirs, tmin=0.0, tmax=inf, normals=True) -> Hits``: the closest hit per
  ray (t, prim with -1 for a miss, barycentrics u, v; geometric normals when ``normals``);
* ``occluded(origins, dirs, tmin=0.0, tmax=inf) -> (n,) bool``: any hit in [tmin, tmax].

Intervals start at the origin or after it (``tmin >= 0``, as in Embree): a negative ``tmin``
is a ParameterError, and so are a bound that is None or NaN and rays or bounds that are not real
numbers or not one per ray. An empty interval (``tmin > tmax``) is a miss / not blocked. A zero
direction, or a NaN or infinite origin or direction, misses.

Every tracer also has ``n_triangles``: its answers' primitive ids lie in [-1, n_triangles), so
a caller that indexes its own arrays with them (the renderer) checks one number, not every
answer. A tracer without it has its answers checked query by query. And ``triangles``, the
(n, 3, 3) triangles it traces, so that a caller can tell a tracer built over other triangles
of the same count (``check_tracer``).

A tracer may also declare ``concurrent = True``: it answers queries from several threads at
once, so the renderer traces each band of rows on its own thread (``raytracer.render``);
without it, queries come one at a time, each spread over the threads.

``traversal.Tracer`` (the appendix-A units on the raw hwbvh buffer) and
``traversal.embree_ref.EmbreeTracer`` implement it (concurrent both), as do the grid and the
kd-tree; the renderer sees nothing else. The wrappers below implement it too, so they stack
in front of any of them (the verifying and counting ones are as concurrent as the tracer they
wrap, and add to their totals under a lock; the recording one takes one query at a time, so
that its record keeps a render's order):

* :class:`VerifyingTracer` checks every answer against Embree: closest hits by
  ``verify.classify`` and any-hit answers by ``verify.classify_occluded``, on exactly the rays
  and the answers the caller received;
* :class:`CountingTracer` counts nodes visited and triangles tested per closest-hit query (the
  work counters of the single-ray unit);
* :class:`RecordingTracer` keeps a copy of every query so that the same rays can be traced
  again alone (how much of a render is tracing).
"""
import threading
import time

import numpy as np

from hwbvh.errors import ParameterError
from hwbvh.parallel import run_ranges

from .api import _rays


def check_tracer(tracer, n_triangles=None, name="tracer", triangles=None):
    """ParameterError naming ``name`` unless ``tracer`` has both queries and, where it says
    how many triangles it traces (``n_triangles``), traces ``n_triangles`` of them, and, where
    it says which (``triangles``) and the caller gives its own, those: answers over other
    triangles would be read as wrong, or index the caller's arrays out of range."""
    if not (callable(getattr(tracer, "intersect", None)) and
            callable(getattr(tracer, "occluded", None))):
        raise ParameterError(name, f"expected a tracer with intersect and occluded, got "
                                   f"{type(tracer).__name__}")
    if triangles is not None and n_triangles is None:
        n_triangles = len(triangles)
    known = getattr(tracer, "n_triangles", None)
    if n_triangles is not None and known is not None and known != n_triangles:
        raise ParameterError(name, f"{type(tracer).__name__} traces {known} triangles, the "
                                   f"scene has {n_triangles}: not built over the scene's "
                                   f"triangles")
    traced = getattr(tracer, "triangles", None)
    # compared as the float32 units and Embree hold them: a tracer keeps what it was given
    if triangles is not None and traced is not None and traced is not triangles and \
            not np.array_equal(np.asarray(traced, np.float32), np.asarray(triangles, np.float32)):
        raise ParameterError(name, f"{type(tracer).__name__} traces other triangles than the "
                                   f"scene's ({len(triangles)} each, at other coordinates): not "
                                   f"built over the scene's triangles")


class _Wrapper:
    """What a wrapper shares with the tracer it wraps (``inner``)."""

    @property
    def n_triangles(self):
        return getattr(self.inner, "n_triangles", None)

    @property
    def triangles(self):
        return getattr(self.inner, "triangles", None)


class _Tally(_Wrapper):
    """Running totals that queries from several threads at once may add to: a wrapper of a
    ``concurrent`` tracer is ``concurrent`` too, and its sums do not depend on the order in
    which the threads add."""

    def _start_tally(self):
        self._tally_lock = threading.Lock()

    @property
    def concurrent(self):
        return getattr(self.inner, "concurrent", False)

    def _add_to(self, totals, amounts):
        with self._tally_lock:
            for k, v in amounts.items():
                totals[k] += v


class VerifyingTracer(_Tally):
    """Answers with ``inner`` and checks each answer against an Embree scene built from
    ``vertices``/``faces`` (indexed form of ``triangles``). ``counts`` holds, per query kind
    ("closest", "shadow"), the rays checked and how many agree, tie or mismatch."""

    def __init__(self, inner, triangles, vertices, faces):
        from .embree_ref import embree_scene, mesh_of

        self.checked_triangles = np.asarray(triangles, np.float32)
        if self.checked_triangles.ndim != 3 or self.checked_triangles.shape[1:] != (3, 3):
            raise ParameterError("triangles", f"expected an (n, 3, 3) array, got shape "
                                              f"{self.checked_triangles.shape}")
        check_tracer(inner, name="inner", triangles=self.checked_triangles)
        vertices, faces = mesh_of(self.checked_triangles, vertices, faces)
        self.inner = inner
        self.reference = embree_scene(vertices, faces)
        zero = {"rays": 0, "agree": 0, "tie": 0, "mismatch": 0}
        self.counts = {"closest": dict(zero), "shadow": dict(zero)}
        self._start_tally()

    def _add(self, kind, counts):
        self._add_to(self.counts[kind], {k: counts[k] for k in self.counts[kind]})

    def intersect(self, origins, dirs, tmin=0.0, tmax=np.inf, normals=True):
        from .embree_ref import embree_intersect
        from .verify import classify

        h = self.inner.intersect(origins, dirs, tmin, tmax, normals=normals)
        o, d, lo, hi = _shifted(origins, dirs, tmin, tmax)
        te, pe, *_ = embree_intersect(self.reference, o, d, None if np.isinf(hi).all() else hi)
        counts, _ = classify(self.checked_triangles, origins, dirs, tmin, tmax, h.prim.astype(np.int64),
                             h.t, pe, np.where(pe >= 0, te + lo, np.inf))
        self._add("closest", counts)
        return h

    def occluded(self, origins, dirs, tmin=0.0, tmax=np.inf):
        from .embree_ref import embree_occluded
        from .verify import classify_occluded

        blocked = self.inner.occluded(origins, dirs, tmin, tmax)
        o, d, lo, hi = _shifted(origins, dirs, tmin, tmax)
        ref = embree_occluded(self.reference, o, d, hi)
        counts, _ = classify_occluded(self.checked_triangles, origins, dirs, tmin, tmax, blocked, ref)
        self._add("shadow", counts)
        return blocked

    @property
    def dtype(self):
        return getattr(self.inner, "dtype", np.float32)

    def summary(self):
        """Both kinds and their sum: {"rays", "agree", "tie", "mismatch", "closest", "shadow"}."""
        total = {k: self.counts["closest"][k] + self.counts["shadow"][k] for k in self.counts["closest"]}
        return dict(total, closest=dict(self.counts["closest"]), shadow=dict(self.counts["shadow"]))


def _shifted(origins, dirs, tmin, tmax):
    """Embree's tnear is fixed at 0 in embreex: rays with a t_min start at o + tmin d instead,
    and their t_max shrinks by t_min (distances come back relative to the shifted origin). The
    rays and bounds are checked as ``traversal.Tracer`` checks them. A ray whose interval is
    empty (tmin > tmax, or tmin infinite) keeps its origin and gets t_max -1, which the Embree
    queries answer as a miss / not blocked, like every other tracer."""
    o, d, lo, hi = _rays(origins, dirs, tmin, tmax, np.float64)
    empty = (hi < lo) | np.isinf(lo)
    if empty.any():
        lo = np.where(empty, 0.0, lo)
        hi = np.where(empty, -1.0, hi)
    if lo.any():
        o = o + d * lo[:, None]
    return o, d, lo, hi - lo


class CountingTracer(_Tally):
    """Counts traversal work: nodes visited and triangles tested per ray, for closest-hit and
    any-hit (shadow) queries apart. By default as the single-ray unit does them; with
    ``as_run`` as the queries actually run (rays traced as a packet each count every node and
    triangle the packet tests). Only our traversal has counters."""

    def __init__(self, inner, as_run=False):
        if not getattr(inner, "has_counters", False):
            raise ParameterError("inner", "work counters need the hwbvh traversal "
                                          "(traversal.Tracer)")
        self.inner = inner
        self.as_run = bool(as_run)
        self.totals = {kind: {"nodes": 0, "triangles": 0, "rays": 0} for kind in ("closest", "shadow")}
        self._start_tally()

    def _add(self, kind, counters):
        self._add_to(self.totals[kind], {"nodes": int(counters[:, 0].sum()),
                                         "triangles": int(counters[:, 1].sum()),
                                         "rays": len(counters)})

    def intersect(self, origins, dirs, tmin=0.0, tmax=np.inf, normals=True):
        h = self.inner.intersect(origins, dirs, tmin, tmax, normals=normals, counters=True,
                                 as_run=self.as_run)
        self._add("closest", h.counters)
        return h

    def occluded(self, origins, dirs, tmin=0.0, tmax=np.inf):
        blocked, counters = self.inner.occluded(origins, dirs, tmin, tmax, counters=True,
                                                as_run=self.as_run)
        self._add("shadow", counters)
        return blocked

    @property
    def dtype(self):
        return self.inner.dtype

    def counts(self, kind="closest"):
        """{"nodes", "triangles", "rays"} of ``kind`` ("closest", "shadow" or "all") queries
        so far."""
        if kind not in ("closest", "shadow", "all"):
            raise ParameterError("kind", f"must be 'closest', 'shadow' or 'all', got {kind!r}")
        kinds = ("closest", "shadow") if kind == "all" else (kind,)
        return {k: sum(self.totals[q][k] for q in kinds) for k in ("nodes", "triangles", "rays")}

    def work(self, kind="closest"):
        """{"nodes_per_ray", "tris_per_ray", "rays"} of ``kind`` ("closest", "shadow" or
        "all") queries so far."""
        c = self.counts(kind)
        r = c["rays"]
        return {"nodes_per_ray": c["nodes"] / max(r, 1), "tris_per_ray": c["triangles"] / max(r, 1),
                "rays": r}


def _kept(bound):
    """A query's bound as a record keeps it: a copy of an array (the caller may reuse it), a
    scalar as it was given, so that a replay asks exactly what the render asked (a Python
    float bound is checked once per value, an array of bounds per query)."""
    return bound if np.isscalar(bound) else np.array(bound)


class RecordingTracer(_Wrapper):
    """Passes queries to ``inner`` and keeps a copy of each, so that :meth:`replay_seconds` can
    time tracing exactly the same rays again, alone (no shading, no ray generation). Not
    ``concurrent``: the record keeps the queries in the order a render asks them."""

    def __init__(self, inner):
        self.inner = inner
        self.queries = []

    # a query is kept once the tracer has answered it: one it refuses is not traced again
    def intersect(self, origins, dirs, tmin=0.0, tmax=np.inf, normals=True):
        h = self.inner.intersect(origins, dirs, tmin, tmax, normals=normals)
        self.queries.append(("intersect", np.array(origins), np.array(dirs), _kept(tmin),
                             _kept(tmax), normals))
        return h

    def occluded(self, origins, dirs, tmin=0.0, tmax=np.inf):
        blocked = self.inner.occluded(origins, dirs, tmin, tmax)
        self.queries.append(("occluded", np.array(origins), np.array(dirs), _kept(tmin),
                             _kept(tmax), False))
        return blocked

    @property
    def dtype(self):
        return getattr(self.inner, "dtype", np.float32)

    def rays(self):
        return sum(len(q[1]) for q in self.queries)

    def replay_seconds(self, tracer=None):
        """Seconds to trace every recorded query again with ``tracer`` (default: the wrapped
        one), as a renderer would (:func:`replay_seconds`)."""
        return replay_seconds(tracer or self.inner, self.queries)


def run_as_tracer_allows(tracer, work, n, parts=None):
    """``work(lo, hi)`` over items [0, n) whose work asks ``tracer`` queries: ranges of items
    on all threads, each query traced on the thread that asks it, when the tracer takes
    queries from several threads at once (``concurrent``; ``parts`` as for ``run_ranges``);
    else every item in order on this thread, each query then spread over the threads. The
    renderer's bands of rows and a replay of its queries both run this way, so render /
    trace-only compares like with like."""
    if getattr(tracer, "concurrent", False):
        run_ranges(work, n, parts=parts)
    else:
        work(0, n)


def replay(tracer, queries):
    """Ask ``tracer`` every query of ``queries`` (as :class:`RecordingTracer` keeps them), in
    order, on this thread."""
    for kind, o, d, lo, hi, normals in queries:
        if kind == "intersect":
            tracer.intersect(o, d, lo, hi, normals=normals)
        else:
            tracer.occluded(o, d, lo, hi)


def replay_seconds(tracer, queries):
    """Seconds to trace ``queries`` with ``tracer`` as a renderer would
    (``run_as_tracer_allows``)."""
    t = time.perf_counter()
    run_as_tracer_allows(tracer, lambda q0, q1: replay(tracer, queries[q0:q1]), len(queries))
    return time.perf_counter() - t
