"""Imports flow one way: hwbvh <- traversal <- raytracer <- hwrt, with scenes beside raytracer.

Every module of the five packages is parsed (not imported), and every import in it counts:
module-level, inside functions, relative, and ``importlib.import_module`` / ``__import__``
with a literal name.
"""
import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("hwbvh", "traversal", "raytracer", "scenes", "hwrt")

# package -> the packages of this project it must not import
FORBIDDEN = {
    "hwbvh": {"traversal", "raytracer", "scenes", "hwrt"},
    "traversal": {"raytracer", "scenes", "hwrt"},
    "raytracer": {"scenes", "hwrt"},
    "scenes": {"raytracer", "hwrt"},
    "hwrt": set(),
}


def imported_packages(path, package, root=ROOT):
    """(line, top-level name) of every import in the module at ``path`` of ``package`` (a
    directory under ``root``), in line order."""
    tree = ast.parse(path.read_text(), filename=str(path))
    depth = len(path.relative_to(root / package).parts)       # 1 for package/module.py
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name.split(".")[0]) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                found.append((node.lineno, node.module.split(".")[0]))
            elif node.level <= depth:                          # inside the package
                found.append((node.lineno, package))
            else:                                              # above it: a sibling package
                if node.module:
                    found.append((node.lineno, node.module.split(".")[0]))
                else:
                    found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant) \
                and isinstance(node.args[0].value, str):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
            if name in ("import_module", "__import__"):
                found.append((node.lineno, node.args[0].value.split(".")[0]))
    return sorted(found)


def violations(package):
    out = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for line, name in imported_packages(path, package, ROOT):
            if name in FORBIDDEN[package]:
                out.append(f"{path.relative_to(ROOT)}:{line} imports {name}")
    return out


@pytest.mark.parametrize("package", PACKAGES)
def test_imports_flow_one_way(package):
    assert violations(package) == []


def test_the_check_sees_the_allowed_imports():
    """Not vacuous: each layer's real imports of the layers below are found."""
    below = {"traversal": "hwbvh", "raytracer": "traversal", "scenes": "hwbvh", "hwrt": "raytracer"}
    for package, lower in below.items():
        names = {name for path in (ROOT / package).rglob("*.py")
                 for _, name in imported_packages(path, package)}
        assert lower in names, package


def test_the_check_sees_every_kind_of_import(tmp_path):
    pkg = tmp_path / "traversal"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "a.py").write_text(
        "import numpy\n"
        "from . import camera\n"
        "from .offset import x\n"
        "def f():\n"
        "    import raytracer.render\n"
        "    from ..scenes import loader\n"
        "    from .. import hwrt\n"
        "    importlib.import_module('raytracer.stages')\n"
        "    return __import__('scenes')\n")
    (pkg / "sub" / "b.py").write_text("from .. import api\nfrom ...hwbvh import format\n")
    got = imported_packages(pkg / "a.py", "traversal", tmp_path)
    assert got == [(1, "numpy"), (2, "traversal"), (3, "traversal"), (5, "raytracer"),
                   (6, "scenes"), (7, "hwrt"), (8, "raytracer"), (9, "scenes")]
    assert imported_packages(pkg / "sub" / "b.py", "traversal", tmp_path) == \
        [(1, "traversal"), (2, "hwbvh")]
