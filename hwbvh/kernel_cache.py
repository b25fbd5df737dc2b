"""Numba's on-disk cache of the kernels, kept fresh across the packages.

Numba keys a cached kernel to the source of the file that defines it and to nothing else, yet a
kernel carries compiled into it every function it calls, and ours call across files: the
traversal kernel in ``traversal/traverse.py`` holds the packet kernel of ``traversal/packet.py``
and the units of ``aabb_unit.py`` and ``triangle_unit.py``. Edit a unit, or install a version
whose unit changed but whose traversal file did not, and Numba would load the old traversal,
with the old unit in it, without a word.

So the kernels of the packages in ``KERNEL_PACKAGES`` are stamped with their own file's source
and with one digest of every source file of those packages: a change anywhere in them compiles
each kernel afresh once. The cache stays where Numba would put it (``NUMBA_CACHE_DIR``, else
beside the file, else the user's cache directory); only its freshness test changes. Other code
in the same process keeps Numba's own locators. ``install`` runs when ``hwbvh`` is imported,
which each kernel package does before it defines a kernel.
"""
import functools
import hashlib
import os

# The packages whose modules define kernels, and whose kernels call into each other's.
KERNEL_PACKAGES = ("hwbvh", "traversal", "raytracer", "scenes")
_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_DIRS = tuple(os.path.join(_ROOT, p) for p in KERNEL_PACKAGES)


@functools.lru_cache(maxsize=1)
def kernel_sources_digest():
    """SHA-256 of the name and bytes of every ``.py`` file of ``KERNEL_PACKAGES``, in a fixed
    order; once per process (Numba reads a cache index once per kernel as well)."""
    h = hashlib.sha256()
    for d in _DIRS:
        for name in sorted(os.listdir(d)):
            if name.endswith(".py"):
                h.update(f"{os.path.basename(d)}/{name}\0".encode())
                with open(os.path.join(d, name), "rb") as f:
                    h.update(f.read())
    return h.hexdigest()


def is_kernel_source(py_file):
    """Whether ``py_file`` is a module of ``KERNEL_PACKAGES``."""
    return os.path.dirname(os.path.abspath(py_file)) in _DIRS


class _StampedByTheTree:
    """A Numba locator, for kernel-package files only, whose stamp adds the digest of every
    kernel source file to Numba's stamp of the file itself."""

    def get_source_stamp(self):
        return (super().get_source_stamp(), kernel_sources_digest())

    @classmethod
    def from_function(cls, py_func, py_file):
        if not is_kernel_source(py_file):
            return None
        return super().from_function(py_func, py_file)


def _numba_name(module, name):
    """A class of Numba's caching module by its name (public from Numba 0.60, with a leading
    underscore before), or None."""
    return getattr(module, name, None) or getattr(module, "_" + name, None)


def install():
    """Put the stamped locators in front of Numba's own (once). Returns whether they are in
    place: False where Numba's caching module has another layout, whose own locators then
    serve."""
    from numba.core import caching
    impl = _numba_name(caching, "CacheImpl")
    bases = [_numba_name(caching, n) for n in
             ("UserProvidedCacheLocator", "InTreeCacheLocator", "UserWideCacheLocator")]
    if impl is None or not isinstance(getattr(impl, "_locator_classes", None), list) \
            or None in bases:
        return False
    if any(issubclass(c, _StampedByTheTree) for c in impl._locator_classes):
        return True
    stamped = [type(f"Stamped{b.__name__.lstrip('_')}", (_StampedByTheTree, b), {})
               for b in bases]
    impl._locator_classes[:0] = stamped
    return True


install()
