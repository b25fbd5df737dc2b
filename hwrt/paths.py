"""Where the benchmark meshes are: $HWRT_MESHES, else ../shared/meshes beside the project."""
import os
from pathlib import Path

from hwbvh.primitives import MESH_EXTENSIONS


MESH_DIR_ENV = "HWRT_MESHES"


def default_mesh_dir():
    env = os.environ.get(MESH_DIR_ENV)
    if env:
        return Path(env)
    for base in (Path(__file__).resolve().parents[1], Path.cwd()):
        d = base.parent / "shared" / "meshes"
        if d.is_dir():
            return d
    return None


def mesh_files(directory):
    d = Path(directory)
    return sorted(p for p in d.iterdir() if p.suffix.lower() in MESH_EXTENSIONS)
