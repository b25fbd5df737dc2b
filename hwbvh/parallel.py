"""How the compiled kernels share the machine: Numba's threading layer and its wait policy.

Every ``prange`` loop runs on a pool of threads. A render is a few dozen short parallel regions
(a traversal, a shading pass and a shadow query per bounce), and each region ends when its
slowest thread ends. OpenMP's default wait policy keeps idle threads spinning between regions:
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
the environment is left as the user set it.
"""
import os

import numba

THREADING_SETUPS = {
    "omp-passive": ("omp", "passive"),
    "workqueue": ("workqueue", None),
    "omp-active": ("omp", "active"),
}
DEFAULT_THREADING = "omp-passive"


def pin_threading(setup=None):
    """Choose the threading layer and wait policy (see the module text). Returns the set-up's
    name. Effective only before the first parallel region of the process."""
    setup = setup or os.environ.get("HWRT_THREADING") or DEFAULT_THREADING
    if setup not in THREADING_SETUPS:
        raise ValueError(f"HWRT_THREADING: unknown set-up {setup!r} "
                         f"(choose from {', '.join(THREADING_SETUPS)})")
    layer, policy = THREADING_SETUPS[setup]
    if "NUMBA_THREADING_LAYER" not in os.environ:
        numba.config.THREADING_LAYER = layer
    if policy is not None:
        os.environ.setdefault("OMP_WAIT_POLICY", policy)
    return setup


THREADING = pin_threading()
