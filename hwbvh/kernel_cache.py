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
import hashlib
import os
import sys

# The packages whose modules define kernels, and whose kernels call into each other's.
KERNEL_PACKAGES = ("hwbvh", "traversal", "raytracer", "scenes")
_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_DIRS = tuple(os.path.join(_ROOT, p) for p in KERNEL_PACKAGES)

# (listing, digest) of the last call: the listing of paths, mtimes and sizes is re-read at each
# call, the bytes hashed again only when it changed, so a module edited and reloaded in a
# long-lived process (a notebook) is seen.
_last_digest = [None, None]


def _kernel_sources():
    """(path, mtime_ns, size) of every ``.py`` file under ``_DIRS`` (sub-packages included),
    in a fixed order; names starting with a dot (editor lock files, often dangling links) and
    ``__pycache__`` are not sources."""
    found = []
    dirs = list(_DIRS)
    while dirs:
        d = dirs.pop(0)
        with os.scandir(d) as entries:
            for e in sorted(entries, key=lambda e: e.name):
                if e.name.startswith(".") or e.name == "__pycache__":
                    continue
                if e.is_dir():
                    dirs.append(e.path)
                elif e.name.endswith(".py"):
                    st = e.stat()
                    found.append((e.path, st.st_mtime_ns, st.st_size))
    return tuple(found)


def kernel_sources_digest():
    """SHA-256 of the path (relative to the packages' root) and bytes of every kernel source
    file, or None when they cannot all be read (then Numba's own stamps serve)."""
    try:
        listing = _kernel_sources()
        if listing != _last_digest[0]:
            h = hashlib.sha256()
            for path, _, _ in listing:
                h.update(f"{os.path.relpath(path, _ROOT)}\0".encode())
                with open(path, "rb") as src:
                    h.update(src.read())
            _last_digest[:] = [listing, h.hexdigest()]
        return _last_digest[1]
    except OSError:
        return None


def is_kernel_source(py_file):
    """Whether ``py_file`` is a module of ``KERNEL_PACKAGES``."""
    path = os.path.abspath(py_file)
    return any(path.startswith(d + os.sep) for d in _DIRS)


class _StampedByTheTree:
    """A Numba locator, for kernel-package files only, whose stamp adds the digest of every
    kernel source file to Numba's stamp of the file itself."""

    def get_source_stamp(self):
        return (super().get_source_stamp(), kernel_sources_digest())

    @classmethod
    def from_function(cls, py_func, py_file):
        # A frozen application has no sources to digest; Numba stamps it by its executable.
        if getattr(sys, "frozen", False) or not is_kernel_source(py_file) \
                or kernel_sources_digest() is None:
            return None
        return super().from_function(py_func, py_file)


def _numba_name(module, name):
    """A class of Numba's caching module by its name (the locators are public from Numba 0.60,
    with a leading underscore before), or None."""
    return getattr(module, name, None) or getattr(module, "_" + name, None)


def install():
    """Put the stamped locators in front of Numba's own (once). Returns whether they are in
    place: False where Numba's caching module has another layout, or where the user chose the
    locators (``NUMBA_CACHE_LOCATOR_CLASSES``); Numba's own or the chosen ones then serve."""
    from numba.core import caching, config
    if getattr(config, "CACHE_LOCATOR_CLASSES", None):
        return False
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
