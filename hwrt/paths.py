"""Where the benchmark meshes are by default: ../shared/meshes beside the project (or beside
the working directory). ``$HWRT_MESHES`` names another directory; ``hwrt.bench.mesh_directory``
reads it, and decides which directory a run uses."""
import os
from pathlib import Path

from hwbvh.primitives import MESH_EXTENSIONS


MESH_DIR_ENV = "HWRT_MESHES"


def default_mesh_dir():
    """../shared/meshes beside the project or the working directory, when it is there."""
    for base in (Path(__file__).resolve().parents[1], Path.cwd()):
        d = base.parent / "shared" / "meshes"
        if d.is_dir():
            return d
    return None


def mesh_files(directory):
    d = Path(directory)
    return sorted(p for p in d.iterdir() if p.suffix.lower() in MESH_EXTENSIONS)
