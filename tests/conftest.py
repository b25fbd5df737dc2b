import os
from pathlib import Path

import numpy as np
import pytest

MESH_DIR = Path(os.environ.get("HWRT_MESHES", Path(__file__).resolve().parents[1].parent / "shared" / "meshes"))


def shared_mesh(name):
    p = MESH_DIR / name
    if not p.exists():
        pytest.skip(f"{p} not present (shared meshes are optional)")
    return p


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


# Settings a user may have exported that change what a command prints or where it runs
# (progress bars on stderr, a remote scheduler, re-raised internal errors): each test starts
# without them and sets what it needs itself. HWRT_THREADING is read at import and stays.
def _user_settings():
    from hwrt.cli import DEBUG_ENV
    from hwrt.cluster import CELL_THREADS_ENV, SCHEDULER_ENV
    from hwrt.progress import PROGRESS_ENV
    return (PROGRESS_ENV, SCHEDULER_ENV, CELL_THREADS_ENV, DEBUG_ENV)


@pytest.fixture(autouse=True)
def _without_user_settings(monkeypatch):
    for name in _user_settings():
        monkeypatch.delenv(name, raising=False)
