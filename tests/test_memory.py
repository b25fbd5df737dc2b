"""hwbvh.memory: freed memory stays with the process, so that a build's arrays reuse pages."""
import os
import platform
import resource
import subprocess
import sys

import pytest

import hwbvh
from hwbvh.memory import KEEPS_FREED_MEMORY, user_tunes_malloc
from scenes.meshes import random_soup


GLIBC = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"


@pytest.mark.skipif(not GLIBC or user_tunes_malloc(),
                    reason="glibc's mallopt, with the thresholds not set by the user")
def test_a_repeated_build_touches_no_new_pages():
    """The third build of a 40k-triangle soup (a few MB of fresh arrays) faults in a small
    fraction of the pages its arrays span: they come from memory the earlier builds freed."""
    assert KEEPS_FREED_MEMORY
    tris = random_soup(40_000, seed=3)
    for _ in range(2):
        hwbvh.build(tris)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    hwbvh.build(tris)
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
    assert faults < 400, faults     # without: some 1,800 (every page of its arrays)


@pytest.mark.parametrize("setting", [("MALLOC_TRIM_THRESHOLD_", "131072"),
                                     ("GLIBC_TUNABLES", "glibc.malloc.mmap_threshold=131072")])
def test_a_threshold_set_in_the_environment_is_left_as_set(setting):
    env = dict(os.environ, **dict([setting]))
    r = subprocess.run([sys.executable, "-c", "import hwbvh.memory as m; print(m.KEEPS_FREED_MEMORY)"],
                       env=env, capture_output=True, text=True, timeout=120)
    assert r.stdout.strip() == "False", r.stderr
