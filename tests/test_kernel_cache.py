"""Cached kernels stay fresh when a function they call, in another file, changes
(``hwbvh.kernel_cache``)."""
import importlib
import os
import pkgutil
import subprocess
import sys
import textwrap

import pytest


def test_the_kernels_are_stamped_by_the_whole_kernel_tree():
    import hwbvh.kernel_cache as kc
    from raytracer.stages import shade
    from traversal.traverse import trace_chunks
    assert kc.install()
    for kernel in (trace_chunks, shade):
        locator = kernel._cache._impl.locator
        assert isinstance(locator, kc._StampedByTheTree)
        assert locator.get_source_stamp()[1] == kc.kernel_sources_digest()
    assert kc.is_kernel_source(kc.__file__) and not kc.is_kernel_source(__file__)


def _cached_kernels():
    """Every dispatcher compiled with ``cache=True`` in the kernel packages' modules."""
    import hwbvh.kernel_cache as kc
    from numba.core.caching import NullCache
    from numba.core.registry import CPUDispatcher
    for package in kc.KERNEL_PACKAGES:
        pkg = importlib.import_module(package)
        for info in pkgutil.walk_packages(pkg.__path__, package + "."):
            module = importlib.import_module(info.name)
            for name, value in vars(module).items():
                if isinstance(value, CPUDispatcher) and value.__module__ == info.name \
                        and not isinstance(value._cache, NullCache):
                    yield f"{info.name}.{name}", value


def test_every_cached_kernel_of_the_packages_is_stamped_by_the_tree():
    import hwbvh.kernel_cache as kc
    kernels = dict(_cached_kernels())
    assert len(kernels) > 50
    unstamped = [n for n, k in kernels.items()
                 if not isinstance(k._cache._impl.locator, kc._StampedByTheTree)]
    assert unstamped == []


def test_the_digest_follows_an_edit_within_the_process_and_skips_lock_files(tmp_path,
                                                                           monkeypatch):
    import hwbvh.kernel_cache as kc
    pkg = tmp_path / "kpkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    (pkg / "sub" / "b.py").write_text("y = 1\n")
    # an editor's lock file: a dangling link named like a module
    os.symlink(tmp_path / "nowhere", pkg / ".#a.py")
    monkeypatch.setattr(kc, "_DIRS", (str(pkg),))
    first = kc.kernel_sources_digest()
    assert first is not None and kc.is_kernel_source(str(pkg / "sub" / "b.py"))
    (pkg / "sub" / "b.py").write_text("y = 22\n")
    second = kc.kernel_sources_digest()
    assert second not in (None, first)
    # unreadable sources: no stamp, and Numba's own locators serve
    monkeypatch.setattr(kc, "_DIRS", (str(tmp_path / "missing"),))
    assert kc.kernel_sources_digest() is None


def _run(code, root, cache, **env):
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                          text=True, timeout=300, cwd=root,
                          # no .pyc: within one second, a rewritten file of the same size
                          # would be read from its stale bytecode
                          env=dict(os.environ, NUMBA_CACHE_DIR=str(cache),
                                   PYTHONDONTWRITEBYTECODE="1",
                                   PYTHONPATH=os.pathsep.join([str(root)]
                                                              + [p for p in sys.path if p]),
                                   **env))


def test_a_cached_kernel_is_compiled_again_when_a_callee_in_another_file_changes(tmp_path):
    """A kernel in a.py calls one in b.py; b.py changes, a.py does not: the next process runs
    the new b. (Numba's own stamp, the source of a.py alone, loads the stale kernel.)"""
    pkg = tmp_path / "kpkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from numba import njit\nfrom .b import g\n\n\n"
                              "@njit(cache=True)\ndef f():\n    return g()\n")
    (pkg / "b.py").write_text("from numba import njit\n\n\n@njit\ndef g():\n    return 1\n")
    code = f"""
        import hwbvh.kernel_cache as kc
        kc._DIRS = kc._DIRS + ({str(pkg)!r},)
        import kpkg.a
        print(kpkg.a.f())
        """
    cache = tmp_path / "cache"
    first = _run(code, tmp_path, cache)
    assert first.returncode == 0 and first.stdout.split() == ["1"], first.stderr
    (pkg / "b.py").write_text("from numba import njit\n\n\n@njit\ndef g():\n    return 2\n")
    second = _run(code, tmp_path, cache)
    assert second.returncode == 0, second.stderr
    assert second.stdout.split() == ["2"]


def test_locators_chosen_by_the_user_are_left_alone(tmp_path):
    from numba.core import config
    if not hasattr(config, "CACHE_LOCATOR_CLASSES"):
        pytest.skip("this Numba has no NUMBA_CACHE_LOCATOR_CLASSES")
    done = _run("""
        import hwbvh.kernel_cache as kc
        print(kc.install())
        """, tmp_path, tmp_path / "cache", NUMBA_CACHE_LOCATOR_CLASSES="InTreeCacheLocator")
    assert done.returncode == 0 and done.stdout.split() == ["False"], done.stderr
