"""How the compiled kernels share the machine: Numba's threading layer and its wait policy.

Every ``prange`` loop runs on a pool of threads, and each parallel region ends when its slowest
thread ends (a build is one or two dozen regions: two per level of its upper nodes, one for
its subtrees). OpenMP's default wait policy keeps idle threads spinning between regions:
alone on the machine that saves a wake-up, but beside another busy process the spinning
threads take the cores the working threads need, and every region can wait a scheduler time
slice. ``hwrt bench contention`` measures each set-up with a busy competitor on every core
(results in docs/contention.md).

The set-up is pinned here, before the first parallel region starts the pool:

* ``omp-passive`` (default): the OpenMP layer with ``OMP_WAIT_POLICY=passive``: idle threads
  sleep. Thread-safe (a Dask worker with several threads can call the kernels at once).
* ``workqueue``: Numba's own pool (sleeping workers too; not thread-safe across callers).
* ``omp-active``: OpenMP with its default spinning, for comparison only.

``HWRT_THREADING`` selects one; an explicit ``NUMBA_THREADING_LAYER`` or ``OMP_WAIT_POLICY`` in
the environment is left as the user set it. A name it does not know is an input error, raised by
the first parallel work (``check_threading``) rather than by the import, so that the command
line reports it as it reports any bad input; meanwhile the default set-up is pinned.

Kernels with many arguments, and work that is Python between kernels (a render's bands of
rows), run through :func:`run_ranges` instead of a ``prange`` driver: compiled with
``nogil=True`` and given a range of work items, they are called range by range from a small
pool of threads:

* compile time: a parallel driver is lowered into a gufunc whose wrapper grows with every
  argument; for a kernel of some fifty arguments (the renderer's shading stage) the driver
  alone took 5 s to compile, twice the kernel itself;
* sharing the machine: idle pool threads sleep on a condition, never spin;
* balance: ranges are handed out in order from a shared counter, a few per thread, so a thread
  slowed down by another process on its core simply takes fewer of them.

Each range writes only its own outputs, so results do not depend on how the ranges were shared
out. The thread count follows ``numba.get_num_threads()``.
"""
import os
import queue
import threading

import numba
from numba import types
from numba.extending import intrinsic

from .config import DEFAULT_THREADING, RANGES_PER_THREAD
from .errors import InputError, ParameterError

THREADING_SETUPS = {
    "omp-passive": ("omp", "passive"),
    "workqueue": ("workqueue", None),
    "omp-active": ("omp", "active"),
}


def usable_cores():
    """The cores this process may run on (its CPU affinity where the OS reports one)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def pin_threading(setup=None):
    """Choose the threading layer and wait policy (see the module text). Returns the set-up's
    name. Effective only before the first parallel region of the process."""
    error = ParameterError if setup else InputError         # an argument, or the environment
    source = "setup" if setup else "HWRT_THREADING"
    setup = setup or os.environ.get("HWRT_THREADING") or DEFAULT_THREADING
    if setup not in THREADING_SETUPS:
        raise error(source, f"unknown set-up {setup!r} "
                            f"(choose from {', '.join(THREADING_SETUPS)})")
    layer, policy = THREADING_SETUPS[setup]
    if "NUMBA_THREADING_LAYER" not in os.environ:
        numba.config.THREADING_LAYER = layer
    if policy is not None:
        os.environ.setdefault("OMP_WAIT_POLICY", policy)
    return setup


try:
    THREADING = pin_threading()
    _THREADING_PROBLEM = None
except InputError as problem:
    THREADING = pin_threading(DEFAULT_THREADING)
    _THREADING_PROBLEM = (problem.source, problem.problem)


def check_threading():
    """Raise an InputError for an unknown ``HWRT_THREADING`` (see the module text): a new
    one per call, so that no traceback of an earlier call stays attached to it. Every public
    entry to parallel work calls this first."""
    if _THREADING_PROBLEM is not None:
        raise InputError(*_THREADING_PROBLEM)


class _Pool:
    """Sleeping daemon threads that run submitted callables in order of submission. Daemon
    threads, so that a process that is ending (Ctrl-C, SIGTERM) does not wait for them: a
    ``concurrent.futures`` pool is joined at exit, and a thread stuck behind the exception
    that ended the main thread (a kernel compiling, say) would keep the process alive."""

    def __init__(self, threads):
        self._queue = queue.SimpleQueue()
        for k in range(threads):
            threading.Thread(target=self._serve, name=f"hwrt-stage-{k}", daemon=True).start()

    def _serve(self):
        while True:
            job = self._queue.get()
            try:
                job()
            except BaseException:          # a job reports its own failures (run_ranges does)
                pass
            # drop it now, not when the next job comes: a job's closure holds what it worked
            # on (a render's frame, its tracer and film), which would stay alive meanwhile
            job = None

    def submit(self, job):
        self._queue.put(job)


_pool = None
_pool_lock = threading.Lock()


def _executor():
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = _Pool(max(1, numba.config.NUMBA_NUM_THREADS - 1))
        return _pool


_in_range = threading.local()           # .active: this thread is running a range


def run_ranges(kernel, n, *args, min_items=1, parts=None):
    """kernel(lo, hi, *args) over [0, n) split into ranges of at least ``min_items`` items
    (``parts`` ranges, at most, when given: one item each for items that are already coarse;
    else a few per thread), on numba.get_num_threads() threads (this one included). Re-raises
    a kernel's exception.

    It returns once every range has run and none is running. It does not wait for a pool
    thread that has not yet taken a range: that thread finds none left and stops. On a busy
    machine a pool thread may wait a time slice to be scheduled, and this thread does the
    ranges meanwhile instead of waiting for it.

    Called from inside a range (a range's work that itself asks for ranges, such as a ray
    query inside a renderer's band of rows), it runs [0, n) on the calling thread: the outer
    ranges already keep every thread busy, and a second level would only add meetings."""
    check_threading()
    if getattr(_in_range, "active", False):
        kernel(0, n, *args)              # a range's own parallel work stays on its thread
        return
    threads = numba.get_num_threads()
    parts = min(parts or threads * RANGES_PER_THREAD, max(1, n // max(1, min_items)))
    if threads == 1 or parts <= 1:
        kernel(0, n, *args)
        return
    bounds = [n * k // parts for k in range(parts + 1)]
    cond = threading.Condition()
    state = {"next": 0, "running": 0}
    errors = []

    def worker():
        was = getattr(_in_range, "active", False)
        while True:
            failed = None
            with cond:
                k = state["next"]
                if k >= parts:
                    return
                state["next"] = k + 1
                state["running"] += 1
            try:                               # straight after the claim: what runs is counted
                _in_range.active = True
                kernel(bounds[k], bounds[k + 1], *args)
            except BaseException as e:         # re-raised by the calling thread
                failed = e
            finally:
                _in_range.active = was
                with cond:
                    state["running"] -= 1
                    if failed is not None:
                        errors.append(failed)
                        state["next"] = parts      # no range starts after a failure
                    if state["running"] == 0:
                        cond.notify_all()
            if failed is not None:
                return

    for _ in range(threads - 1):
        _executor().submit(worker)
    try:
        worker()
        with cond:
            while state["running"]:
                cond.wait()
    except BaseException:                  # an interrupt (Ctrl-C) here: no range starts, and
        with cond:                         # every range in flight ends before this raises,
            state["next"] = parts          # so none writes into the caller's arrays after
            while state["running"]:
                try:
                    cond.wait()
                except BaseException:      # a second interrupt: keep waiting
                    pass
        raise
    if errors:
        raise errors[0]


@intrinsic
def fetch_add(typingctx, arr, idx, value):
    """Atomically add ``value`` to ``arr[idx]`` (a 1-D C-contiguous int64 array) and return the
    element's value before the add: a shared counter from which the threads of a ``prange``
    loop take work items in order, each thread as soon as it is free."""
    if not (isinstance(arr, types.Array) and arr.ndim == 1 and arr.layout == "C"
            and arr.dtype == types.int64 and isinstance(idx, types.Integer)
            and isinstance(value, types.Integer)):
        return None

    def codegen(context, builder, sig, args):
        ary = context.make_array(sig.args[0])(context, builder, args[0])
        ptr = builder.gep(ary.data, [args[1]])
        v = context.cast(builder, args[2], sig.args[2], types.int64)
        return builder.atomic_rmw("add", ptr, v, "seq_cst")

    return types.int64(arr, idx, value), codegen
