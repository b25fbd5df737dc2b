"""Cached kernels stay fresh when a function they call, in another file, changes
(``hwbvh.kernel_cache``)."""
import subprocess
import sys
import textwrap


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


def _run(code, root, cache):
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                          text=True, timeout=300, cwd=root,
                          # no .pyc: within one second, a rewritten file of the same size
                          # would be read from its stale bytecode
                          env={"PATH": "/usr/bin:/bin", "NUMBA_CACHE_DIR": str(cache),
                               "PYTHONDONTWRITEBYTECODE": "1",
                               "PYTHONPATH": str(root) + ":" + ":".join(p for p in sys.path if p)})


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
        kc.kernel_sources_digest.cache_clear()
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
