"""How the process keeps the memory it frees: set once, when hwbvh is imported.

glibc hands a freed block of 128 KiB or more straight back to the system (raising that
threshold only as far as the largest block freed so far), so the fresh arrays of every build
come back as new pages, and each first touch of a new page is a fault. A bunny build with its
tracer's set-up touches some 15 MB of fresh arrays: about 3,700 faults, which on a virtual
machine cost some 2 us each, a quarter of the build (measured: 25 ms per build and tracer
with ``MALLOC_MMAP_THRESHOLD`` and ``MALLOC_TRIM_THRESHOLD`` raised as in ``config``, 32 ms
without). With the thresholds raised, freed memory stays in the heap for the next build.

For the whole process, like the threading set-up (``parallel``): the peers timed beside our
build (Embree, Mitsuba) allocate from the same heap. Where the user tunes glibc's allocator in
the environment (``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_``, or these thresholds
in ``GLIBC_TUNABLES``), neither threshold is touched; a C library without ``mallopt`` (not
glibc) is left as it is.
"""
import ctypes
import os
import sys

from .config import MALLOC_MMAP_THRESHOLD, MALLOC_TRIM_THRESHOLD

M_TRIM_THRESHOLD = -1           # glibc's mallopt parameters
M_MMAP_THRESHOLD = -3
USER_SETTINGS = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")
USER_TUNABLES = ("glibc.malloc.mmap_threshold", "glibc.malloc.trim_threshold")


def user_tunes_malloc(environ=None):
    """Whether the environment sets either threshold itself."""
    env = os.environ if environ is None else environ
    return any(k in env for k in USER_SETTINGS) or \
        any(t in env.get("GLIBC_TUNABLES", "") for t in USER_TUNABLES)


def keep_freed_memory():
    """Raise glibc's mmap and trim thresholds (see the module text). Returns whether both
    were set."""
    if not sys.platform.startswith("linux") or user_tunes_malloc():
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt         # the process' own C library
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    return bool(mallopt(M_MMAP_THRESHOLD, MALLOC_MMAP_THRESHOLD)) and \
        bool(mallopt(M_TRIM_THRESHOLD, MALLOC_TRIM_THRESHOLD))


KEEPS_FREED_MEMORY = keep_freed_memory()
