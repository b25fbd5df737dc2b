"""Built-in scenes: functions returning plain dicts (Mitsuba style, ``"type"`` keys).

A scene file is the same dict on disk (JSON or TOML). Everything here is generated in code, so
no scene needs a download.
"""
import math

import numpy as np

from hwbvh.config import MAX_PRIMITIVES


def _materials():
    return {
        "white": {"type": "diffuse", "reflectance": [0.73, 0.73, 0.73]},
        "red": {"type": "diffuse", "reflectance": [0.63, 0.065, 0.05]},
        "green": {"type": "diffuse", "reflectance": [0.14, 0.45, 0.091]},
        "glass": {"type": "dielectric", "ior": 1.5},
        "mirror": {"type": "mirror", "reflectance": [0.9, 0.9, 0.9]},
    }


def cornell_box(width=640, height=480, spp=4, max_depth=5):
    """The default scene: a Cornell box with a glass sphere and a mirror block."""
    s = 1.0
    return {
        "type": "scene",
        "name": "cornell",
        "camera": {"type": "perspective", "eye": [0.0, 1.0, 3.4], "target": [0.0, 1.0, 0.0],
                   "up": [0.0, 1.0, 0.0], "fov": 45.0},
        "film": {"width": width, "height": height, "spp": spp},
        "integrator": {"type": "whitted", "max_depth": max_depth, "ambient": [0.04, 0.04, 0.04]},
        "background": [0.0, 0.0, 0.0],
        "lights": [{"type": "point", "position": [0.0, 1.75, 0.4], "intensity": [1.6, 1.5, 1.35]}],
        "materials": _materials(),
        "shapes": [
            {"type": "quad", "corners": [[-s, 0, -s], [s, 0, -s], [s, 0, s], [-s, 0, s]], "material": "white"},
            {"type": "quad", "corners": [[-s, 2, -s], [-s, 2, s], [s, 2, s], [s, 2, -s]], "material": "white"},
            {"type": "quad", "corners": [[-s, 0, -s], [-s, 2, -s], [s, 2, -s], [s, 0, -s]], "material": "white"},
            {"type": "quad", "corners": [[-s, 0, -s], [-s, 0, s], [-s, 2, s], [-s, 2, -s]], "material": "red"},
            {"type": "quad", "corners": [[s, 0, -s], [s, 2, -s], [s, 2, s], [s, 0, s]], "material": "green"},
            {"type": "box", "min": [-0.75, 0.0, -0.65], "max": [-0.15, 1.2, -0.05],
             "rotate_y": -28.0, "material": "mirror"},
            {"type": "sphere", "center": [0.42, 0.38, 0.25], "radius": 0.38, "subdiv": [48, 96],
             "material": "glass"},
        ],
    }


def marbles(width=640, height=480, spp=4, max_depth=5, n=60, seed=3):
    """A field of small glass and metal spheres on a floor (after the Utah 'Marbles')."""
    rng = np.random.default_rng(seed)
    shapes = [{"type": "quad", "corners": [[-3, 0, -3], [3, 0, -3], [3, 0, 3], [-3, 0, 3]],
               "material": "white"}]
    for i in range(n):
        c = rng.uniform([-2.2, 0, -2.2], [2.2, 0, 2.2])
        r = float(rng.uniform(0.08, 0.22))
        c[1] = r
        shapes.append({"type": "sphere", "center": c.tolist(), "radius": r, "subdiv": [12, 24],
                       "material": ["glass", "mirror", "red", "green"][i % 4]})
    return {
        "type": "scene", "name": "marbles",
        "camera": {"type": "perspective", "eye": [0, 2.6, 4.6], "target": [0, 0.1, 0], "fov": 45},
        "film": {"width": width, "height": height, "spp": spp},
        "integrator": {"type": "whitted", "max_depth": max_depth, "ambient": [0.05] * 3},
        "background": [0.5, 0.6, 0.8],
        "lights": [{"type": "directional", "direction": [-0.4, -1.0, -0.3], "irradiance": [2.5, 2.4, 2.2]}],
        "materials": _materials(), "shapes": shapes,
    }


def cloth(width=640, height=480, spp=4, max_depth=2, n=160):
    """A cloth-like tessellated sheet draped in waves over a floor, diffuse only."""
    return {
        "type": "scene", "name": "cloth",
        "camera": {"type": "perspective", "eye": [0, 2.2, 3.0], "target": [0, 0.3, 0], "fov": 45},
        "film": {"width": width, "height": height, "spp": spp},
        "integrator": {"type": "whitted", "max_depth": max_depth, "ambient": [0.05] * 3},
        "background": [0.2, 0.2, 0.25],
        "lights": [{"type": "point", "position": [1.5, 3.0, 1.5], "intensity": [9, 9, 9]}],
        "materials": _materials(),
        "shapes": [{"type": "quad", "corners": [[-3, 0, -3], [3, 0, -3], [3, 0, 3], [-3, 0, 3]],
                    "material": "white"},
                   {"type": "sheet", "resolution": [n, n], "size": 2.2, "wave": 0.25,
                    "height": 0.6, "material": "red"}],
    }


def room(width=640, height=480, spp=4, max_depth=3, slats=120):
    """An architectural room with long thin triangles (slatted walls, a mirror on one wall)."""
    shapes = [
        {"type": "quad", "corners": [[-4, 0, -3], [4, 0, -3], [4, 0, 3], [-4, 0, 3]], "material": "white"},
        {"type": "quad", "corners": [[-4, 3, -3], [-4, 3, 3], [4, 3, 3], [4, 3, -3]], "material": "white"},
        {"type": "quad", "corners": [[-4, 0, -3], [-4, 3, -3], [4, 3, -3], [4, 0, -3]], "material": "white"},
        {"type": "quad", "corners": [[4, 0, -3], [4, 3, -3], [4, 3, 3], [4, 0, 3]], "material": "white"},
        {"type": "quad", "corners": [[-4, 0, -3], [-4, 0, 3], [-4, 3, 3], [-4, 3, -3]], "material": "white"},
        {"type": "quad", "corners": [[-4, 0, 3], [4, 0, 3], [4, 3, 3], [-4, 3, 3]], "material": "white"},
        # the mirror hangs 1 cm in front of the right wall
        {"type": "quad", "corners": [[3.99, 0.5, -2], [3.99, 2.5, -2], [3.99, 2.5, 1], [3.99, 0.5, 1]],
         "material": "mirror"},
    ]
    for i in range(slats):
        x = -4 + 8 * (i + 0.5) / slats
        shapes.append({"type": "box", "min": [x - 0.01, 0, -2.95], "max": [x + 0.01, 3, -2.9],
                       "material": "red" if i % 2 else "green"})
    return {
        "type": "scene", "name": "room",
        "camera": {"type": "perspective", "eye": [-2.5, 1.6, 2.8], "target": [0.5, 1.2, -1.5], "fov": 60},
        "film": {"width": width, "height": height, "spp": spp},
        "integrator": {"type": "whitted", "max_depth": max_depth, "ambient": [0.05] * 3},
        "background": [0, 0, 0],
        "lights": [{"type": "point", "position": [0, 2.8, 0], "intensity": [12, 12, 11]}],
        "materials": _materials(), "shapes": shapes,
    }


BUILTIN = {"cornell": cornell_box, "marbles": marbles, "cloth": cloth, "room": room}

# The largest value of each built-in scene's count parameter whose scene still fits one tree
# (2^24 triangles), so that a larger one is refused before its shapes are made: the rest of
# the scene, then what each item adds. marbles: a floor quad (2), spheres of 12 x 24 (528
# each); cloth: the floor, an n x n sheet (2 n^2); room: six walls and a mirror (14), slats
# that are boxes (12 each). A test holds these counts to the compiled scenes'.
COUNT_LIMITS = {
    "marbles": {"n": (MAX_PRIMITIVES - 2) // 528},
    "cloth": {"n": math.isqrt((MAX_PRIMITIVES - 2) // 2)},
    "room": {"slats": (MAX_PRIMITIVES - 14) // 12},
}
