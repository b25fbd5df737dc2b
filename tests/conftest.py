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
